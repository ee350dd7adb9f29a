"""The Motion Converter (the paper's section 2.2): every frame, orient the Intermediate
Skeleton's bones along the performer's virtual bones, root to leaves, and carry the root's
translation (:class:`RootOptions`). See :mod:`engine.conversion` for how each joint turns."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import limits
from ..errors import MappingError, MotionComposerError
from ..kinematics import fk_components, joint_major
from ..motion import Motion
from ..quaternions import (cconj, cmul, components, cquat_between, crot, ctwist_about,
                           interleaved, qconj, qmul, qpow, qslerp)
from .binding import Binding

__all__ = ["RootOptions", "IntermediatePose", "convert"]


@dataclass(frozen=True)
class RootOptions:
    """How the root's translation is carried over.

    Attributes:
        mode: ``"scaled"`` (the performer's displacement times the ratio of hip heights, the
            default), ``"absolute"`` (the performer's world trajectory as it is, in metres) or
            ``"in-place"`` (horizontal displacement removed, vertical scaled).
        scale: ``(horizontal, vertical)`` factors overriding the hip-height ratio in the
            ``scaled`` and ``in-place`` modes.
    """

    mode: str = "scaled"
    scale: tuple[float, float] | None = None

    def __post_init__(self):
        if self.mode not in ("scaled", "absolute", "in-place"):
            raise MotionComposerError(f"root mode must be 'scaled', 'absolute' or 'in-place', "
                                      f"not {self.mode!r}")
        if self.scale is not None:
            h, v = self.scale
            if not limits.all_usable((h, v)):
                raise MotionComposerError(f"root scale must be two finite numbers of magnitude "
                                          f"at most {limits.MAX_MAGNITUDE:g}, not "
                                          f"{self.scale!r}")
            object.__setattr__(self, "scale", (float(h), float(v)))


@dataclass(frozen=True, eq=False)
class IntermediatePose:
    """The Intermediate Skeleton over frames.

    Attributes:
        world: ``(F, J, 4)`` world rotations of the target's joints where ``known``; the
            others are unmapped joints below every mapped one, whose local value is their
            bound rest rotation (forward kinematics of the composed motion gives their world
            rotation when it is wanted).
        positions: target joint index -> ``(F, 3)`` [m] world positions of the joints whose
            translation is driven (``Binding.driven``: the body root first).
        known: ``(J,)`` which joints of ``world`` are filled.
    """

    world: np.ndarray
    positions: dict
    known: np.ndarray


#: frames converted at a time, which bounds the temporaries' memory on long clips (every frame
#: is independent, so the pieces give exactly the same result; smaller pieces measured slower)
_CHUNK = 8192


def convert(binding: Binding, performer: Motion, root: RootOptions | None = None,
            progress=None, *, lift: float = 0.0) -> IntermediatePose:
    """Motion Converter: orient the intermediate bones along the virtual bones, every frame.

    ``lift`` [m] raises the driven joints' positions (lowers, where negative): the scene
    stands the character on the project's floor with it (:meth:`engine.scene.Scene.lift`)."""
    root = root or RootOptions()
    _check_performer(binding, performer)
    F, J = performer.num_frames, binding.target.num_joints
    world = np.empty((F, J, 4))
    positions = {j: np.empty((F, 3)) for j in binding.driven}
    known = None
    for lo, hi in chunks(F):
        w, pos, known = convert_frames(binding, performer, lo, hi, root, lift)
        world[lo:hi] = w.T
        for j, p in pos.items():
            positions[j][lo:hi] = p.T
        if progress is not None:
            progress(hi / F)
    return IntermediatePose(world=world, positions=positions, known=known)


def chunks(frames: int) -> list[tuple[int, int]]:
    """``(first, end)`` of the runs of at most :data:`_CHUNK` frames converted at a time."""
    return [(lo, min(frames, lo + _CHUNK)) for lo in range(0, frames, _CHUNK)]


def _check_performer(binding: Binding, performer: Motion) -> None:
    if performer.skeleton.names != binding.performer.names:
        raise MappingError("this binding was made for another performer skeleton")


def convert_frames(binding: Binding, performer: Motion, lo: int, hi: int, root: RootOptions,
                   lift: float = 0.0):
    """:func:`convert` on frames ``lo`` to ``hi`` (exclusive), on component arrays: the
    intermediate world rotations ``(4, J, n)`` (filled where ``known``), the driven joints'
    positions ``{j: (3, n)}`` [m], raised by ``lift`` [m], and the ``(J,)`` known mask."""
    tsk = binding.target
    pq, pp, _ = fk_components(performer.skeleton, joint_major(performer.rotations[lo:hi]),
                              joint_major(performer.translations[lo:hi]), end_sites=False)
    F, J = hi - lo, tsk.num_joints
    world = np.empty((4, J, F))
    local_t = np.broadcast_to(tsk.offsets, (J, 3)).copy()
    local_t[tsk.translated] = binding.root_translation
    mapped = binding.mapped
    bones = binding.bones

    # every mapped joint at once: its world rotation is delta * rest_world, delta from the
    # performer alone (so no mapped joint waits for its parent)
    mj = np.flatnonzero(mapped >= 0)
    pm = mapped[mj]
    ref_inv = qconj(binding.performer_rest_world[pm])
    # a joint without virtual bones takes the performer joint's whole change:
    # world = pq * (ref^-1 * rest_world), one product with a constant
    whole = [k for k, j in enumerate(mj) if not bones[j].children]
    if whole:
        world[:, mj[whole]] = cmul(pq[:, pm[whole]],
                                   _rows(qmul(ref_inv[whole], binding.aligned_world[mj[whole]])))
    by_twist = [k for k, j in enumerate(mj) if bones[j].children and not bones[j].roll_by_bones]
    if by_twist:
        js = mj[by_twist]
        ref = np.array([bones[j].reference[0] for j in js])                # (T, 3)
        now = pp[:, [bones[j].performer[0] for j in js]] - pp[:, mapped[js]]
        swing = cquat_between(_rows(ref), now)
        axis = _rows(ref / np.linalg.norm(ref, axis=-1, keepdims=True))
        full = cmul(pq[:, pm[by_twist]], _rows(ref_inv[by_twist]))
        twist = ctwist_about(cmul(cconj(swing), full), axis)
        world[:, js] = cmul(cmul(swing, twist), _rows(binding.aligned_world[js]))
    for k, j in enumerate(mj):
        b = bones[j]
        if b.children and b.roll_by_bones:
            now = pp[:, b.performer] - pp[:, [mapped[j]]]                 # (3, C, F)
            world[:, j] = cmul(_align_rows(b.reference, now), binding.aligned_world[j][:, None])

    # unmapped joints follow their parent (their local value is their bound rest one, so only
    # those above a mapped joint need a world rotation); chains share their first joint's turn
    known = mapped >= 0
    for j in range(J):
        parent = tsk.parents[j]
        if known[j]:
            chain = binding.chains.get(j)
            if chain and _distribution(binding, j) == "even" and mapped[j] >= 0:
                b = bones[j]
                world[:, j] = _distribute(binding, j, chain, world[:, j], world,
                                          pp[:, b.performer[0]] - pp[:, mapped[j]], local_t)
                known[chain] = True
            continue
        if not binding.above_mapped[j]:
            continue
        rest = binding.aligned_local[j][:, None]
        world[:, j] = rest if parent < 0 else cmul(world[:, parent], rest)
        known[j] = True
    if binding.options.pose_offsets or binding.chain_of:
        world = _posed(binding, world, known)
    for f in binding.followers:
        # a control joint carried with a limb turns as the performer joint that continues
        # the limb's chain (a foot: as its heading and pitch turn), or with the limb
        # (engine.conversion.followers)
        if f.toe >= 0:
            world[:, f.joint] = f.foot_turn(pq[:, f.source].T, pp[:, f.source].T,
                                            pp[:, f.toe].T).T
        else:
            world[:, f.joint] = cmul(pq[:, f.source] if f.source >= 0 else
                                     world[:, f.anchor], f.turn[:, None])
        known[f.joint] = True
    positions = {}
    for j in binding.driven:
        ph = mapped[j]
        if root.mode == "absolute":
            positions[j] = pp[:, ph].copy()
            positions[j][1] += lift
            continue
        disp = pp[:, ph] - binding.performer_rest_positions[ph][:, None]
        h, v = root.scale if root.scale is not None else (binding.hip_height_ratio,) * 2
        scaled = disp * np.array([h, v, h])[:, None]
        if root.mode == "in-place":
            scaled[[0, 2]] = 0.0
        positions[j] = binding.aligned_positions[j][:, None] + scaled
        positions[j][1] += lift
    return world, positions, known


def _distribution(binding: Binding, j: int) -> str:
    """How the chain below mapped target joint ``j`` turns: its named chain's own choice
    (:class:`~engine.conversion.chains.ChainSettings`), else the binding's."""
    name = binding.chain_of.get(j)
    own = binding.options.chain(name).distribute if name is not None else None
    return own or binding.options.distribute


def _posed(binding: Binding, world: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The converted world rotations ``(4, J, F)`` (filled where ``known``) with the chain
    settings and the pose offsets applied, as changes of local rotations, root to leaves: each
    joint's local rotation ``L`` (relative to its parent, before the offsets) loses its twist
    relative to the binding where its chain's ``twist`` is off, is slerped from the bound rest
    local towards the converted one by its chain's ``weight``, then turned by its offset
    (``L * offset``); every other local rotation is left as it is."""
    tsk = binding.target
    options = binding.options
    offset = np.any(binding.offsets[:, :3] != 0.0, axis=1)
    changed = np.zeros(tsk.num_joints, dtype=bool)
    for j in range(tsk.num_joints):
        p = tsk.parents[j]
        changed[j] = known[j] and (j in binding.chain_of or offset[j] or
                                   (p >= 0 and changed[p]))
    out = world.copy()
    axes = _bone_axes(tsk) if any(not s.twist for _, s in options.chains) else {}
    for j in np.flatnonzero(changed):
        p = tsk.parents[j]
        local = world[:, j] if p < 0 else cmul(cconj(world[:, p]), world[:, j])
        name = binding.chain_of.get(j)
        if name is not None:
            local = _chain_local(options.chain(name), binding.aligned_local[j], local,
                                 axes.get(j))
        if offset[j]:
            local = cmul(local, binding.offsets[j][:, None])
        out[:, j] = local if p < 0 else cmul(out[:, p], local)
    return out


def _chain_local(settings, rest: np.ndarray, local: np.ndarray, axis) -> np.ndarray:
    """A chain joint's local rotation ``(4, F)`` under its chain's ``settings``: without its
    twist about ``axis`` (``(3,)``, its bone in its own frame) relative to the bound rest
    ``rest`` ``(4,)`` when ``twist`` is off, then slerped from ``rest`` by ``weight`` (exactly
    ``rest`` at 0)."""
    if settings.weight == 0.0:
        return np.broadcast_to(rest[:, None], local.shape).copy()
    if not settings.twist and axis is not None:
        change = cmul(cconj(rest[:, None]), local)                 # in the bound rest frame
        twist = ctwist_about(change, axis[:, None])
        local = cmul(rest[:, None], cmul(change, cconj(twist)))
    if settings.weight < 1.0:
        rows = interleaved(local)
        local = components(qslerp(np.broadcast_to(rest, rows.shape), rows, settings.weight))
    return local


def _bone_axes(tsk) -> dict[int, np.ndarray]:
    """Per target joint, its bone's direction ``(3,)`` in its own frame: towards its child
    with the largest subtree, or its End Site; joints with neither (or a zero-length bone)
    have none."""
    subtree = tsk.subtree_sizes
    ends = {site.parent: np.asarray(site.offset, dtype=float) for site in tsk.end_sites}
    axes = {}
    for j in range(tsk.num_joints):
        kids = tsk.children[j]
        bone = (tsk.offsets[max(kids, key=lambda c: subtree[c])] if kids else ends.get(j))
        if bone is not None and np.linalg.norm(bone) > 1e-9:
            axes[j] = np.asarray(bone, dtype=float) / np.linalg.norm(bone)
    return axes


def _rows(values: np.ndarray) -> np.ndarray:
    """Constants ``(n, c)`` (quaternions or vectors, one per joint) as component arrays
    ``(c, n, 1)`` that broadcast over frames."""
    return np.asarray(values, dtype=float).T[:, :, None]


def _align_rows(reference: np.ndarray, now: np.ndarray) -> np.ndarray:
    """:func:`binding._align` with roll by bones on component arrays: the rotation ``(4, F)``
    taking the ``reference`` virtual bones ``(C, 3)`` (the primary first) to the bones ``now``
    ``(3, C, F)``: the primary exactly, the roll about it to best match the others."""
    swing = cquat_between(reference[0][:, None], now[:, 0])
    if len(reference) < 2:
        return swing
    n = now[:, 0] / np.sqrt(_dot(now[:, 0], now[:, 0]))                    # (3, F)
    a = crot(swing[:, None], _rows(reference[1:]))                          # (3, C-1, F)
    b = now[:, 1:]
    a = a - _dot(a, n[:, None]) * n[:, None]
    b = b - _dot(b, n[:, None]) * n[:, None]
    a = a / np.maximum(np.sqrt(_dot(a, a)), 1e-12)
    b = b / np.maximum(np.sqrt(_dot(b, b)), 1e-12)
    cross = np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                      a[0] * b[1] - a[1] * b[0]])
    sin = np.sum(_dot(cross, n[:, None]), axis=0)
    cos = np.sum(_dot(a, b), axis=0)
    half = 0.5 * np.arctan2(sin, cos)
    roll = np.concatenate([n * np.sin(half), np.cos(half)[None]])
    return cmul(roll, swing)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of vectors as component arrays ``(3, ...)``, broadcasting."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _distribute(binding: Binding, j: int, chain: list[int], rigid: np.ndarray,
                world: np.ndarray, target_dir: np.ndarray, local_t: np.ndarray) -> np.ndarray:
    """Spread joint ``j``'s turn (``rigid``, ``(4, F)``) over ``j`` and the unmapped ``chain``
    below it, then turn the whole chain so that the primary child still lies along
    ``target_dir`` (``(3, F)``). Fills ``world`` (``(4, J, F)``) for the chain's joints and
    returns ``j``'s world rotation."""
    tsk = binding.target
    parent = tsk.parents[j]
    rest = binding.aligned_local[j][:, None]
    follow = (np.broadcast_to(rest, rigid.shape) if parent < 0
              else cmul(world[:, parent], rest))
    n = len(chain) + 1
    step = components(qpow(interleaved(cmul(rigid, cconj(follow))), 1.0 / n))
    rots = [cmul(step, follow)]
    for k in chain:
        rots.append(cmul(step, cmul(rots[-1], binding.aligned_local[k][:, None])))
    # where the primary child ends up, relative to j
    child = binding.bones[j].children[0]
    pos = np.zeros((3,) + rigid.shape[1:])
    for r, k in zip(rots, chain + [child]):
        pos = pos + crot(r, local_t[k][:, None])
    fix = cquat_between(pos, target_dir)
    rots = [cmul(fix, r) for r in rots]
    for r, k in zip(rots[1:], chain):
        world[:, k] = r
    return rots[0]

