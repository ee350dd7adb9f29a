"""The Motion Converter (the paper's section 2.2): every frame, orient the Intermediate
Skeleton's bones along the performer's virtual bones, root to leaves, and carry the root's
translation (:class:`RootOptions`). See :mod:`engine.conversion` for how each joint turns."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import limits
from ..errors import MappingError, MotionComposerError
from ..kinematics import fk_arrays
from ..motion import Motion
from ..quaternions import qconj, qmul, qpow, qrot, quat_between, twist_about
from ..skeleton import Skeleton
from .binding import Binding, _align

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
            progress=None) -> IntermediatePose:
    """Motion Converter: orient the intermediate bones along the virtual bones, every frame."""
    root = root or RootOptions()
    if performer.skeleton.names != binding.performer.names:
        raise MappingError("this binding was made for another performer skeleton")
    F, J = performer.num_frames, binding.target.num_joints
    world = np.empty((F, J, 4))
    positions = {j: np.empty((F, 3)) for j in binding.driven}
    known = None
    for lo in range(0, F, _CHUNK):
        hi = min(F, lo + _CHUNK)
        w, pos, known = _convert_frames(binding, performer.skeleton,
                                        performer.rotations[lo:hi],
                                        performer.translations[lo:hi], root)
        world[lo:hi] = w
        for j, p in pos.items():
            positions[j][lo:hi] = p
        if progress is not None:
            progress(hi / F)
    return IntermediatePose(world=world, positions=positions, known=known)


def _convert_frames(binding: Binding, psk: Skeleton, rotations: np.ndarray,
                    translations: np.ndarray, root: RootOptions):
    """:func:`convert` on a run of frames: world rotations, driven positions, known mask."""
    tsk = binding.target
    pose = fk_arrays(psk, rotations, translations, end_sites=False)
    pq, pp = pose.rotations, pose.positions
    F, J = rotations.shape[0], tsk.num_joints
    world = np.empty((F, J, 4))
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
        world[:, mj[whole]] = qmul(pq[:, pm[whole]],
                                   qmul(ref_inv[whole], binding.rest_world[mj[whole]]))
    by_twist = [k for k, j in enumerate(mj) if bones[j].children and not bones[j].roll_by_bones]
    if by_twist:
        js = mj[by_twist]
        ref = np.array([bones[j].reference[0] for j in js])                # (T, 3)
        now = pp[:, [bones[j].performer[0] for j in js]] - pp[:, mapped[js]]
        swing = quat_between(ref, now)
        axis = ref / np.linalg.norm(ref, axis=-1, keepdims=True)
        full = qmul(pq[:, pm[by_twist]], ref_inv[by_twist])
        twist = twist_about(qmul(qconj(swing), full), axis)
        world[:, js] = qmul(qmul(swing, twist), binding.rest_world[js])
    for k, j in enumerate(mj):
        b = bones[j]
        if b.children and b.roll_by_bones:
            now = pp[:, b.performer] - pp[:, [mapped[j]]]                 # (F, C, 3)
            delta = _align(np.broadcast_to(b.reference, now.shape), now, True)
            world[:, j] = qmul(delta, binding.rest_world[j])

    # unmapped joints follow their parent (their local value is their bound rest one, so only
    # those above a mapped joint need a world rotation); chains share their first joint's turn
    even = binding.options.distribute == "even"
    known = mapped >= 0
    for j in range(J):
        parent = tsk.parents[j]
        if known[j]:
            chain = binding.chains.get(j)
            if chain and even and mapped[j] >= 0:
                b = bones[j]
                world[:, j] = _distribute(binding, j, chain, world[:, j], world,
                                          pp[:, b.performer[0]] - pp[:, mapped[j]], local_t)
                known[chain] = True
            continue
        if not binding.above_mapped[j]:
            continue
        world[:, j] = (np.broadcast_to(binding.rest_local[j], (F, 4)) if parent < 0
                       else qmul(world[:, parent], binding.rest_local[j]))
        known[j] = True
    positions = {}
    for j in binding.driven:
        ph = mapped[j]
        disp = pp[:, ph] - binding.performer_rest_positions[ph]
        if root.mode == "absolute":
            positions[j] = pp[:, ph].copy()
        else:
            h, v = root.scale if root.scale is not None else (binding.hip_height_ratio,) * 2
            scaled = disp * np.array([h, v, h])
            if root.mode == "in-place":
                scaled[:, [0, 2]] = 0.0
            positions[j] = binding.rest_positions[j] + scaled
    return world, positions, known


def _distribute(binding: Binding, j: int, chain: list[int], rigid: np.ndarray,
                world: np.ndarray, target_dir: np.ndarray, local_t: np.ndarray) -> np.ndarray:
    """Spread joint ``j``'s turn over ``j`` and the unmapped ``chain`` below it, then turn the
    whole chain so that the primary child still lies along ``target_dir``. Fills ``world`` for
    the chain's joints and returns ``j``'s world rotation."""
    tsk = binding.target
    parent = tsk.parents[j]
    follow = (np.broadcast_to(binding.rest_local[j], rigid.shape) if parent < 0
              else qmul(world[:, parent], binding.rest_local[j]))
    n = len(chain) + 1
    step = qpow(qmul(rigid, qconj(follow)), 1.0 / n)
    rots = [qmul(step, follow)]
    for k in chain:
        rots.append(qmul(step, qmul(rots[-1], binding.rest_local[k])))
    # where the primary child ends up, relative to j
    child = binding.bones[j].children[0]
    pos = np.zeros(rigid.shape[:-1] + (3,))
    for r, k in zip(rots, chain + [child]):
        pos = pos + qrot(r, local_t[k])
    fix = quat_between(pos, target_dir)
    rots = [qmul(fix, r) for r in rots]
    for r, k in zip(rots[1:], chain):
        world[:, k] = r
    return rots[0]


def _chain_fk(skeleton: Skeleton, local: np.ndarray, translations: np.ndarray, slot: dict,
              joint: int):
    """World rotations and positions of ``joint`` and its ancestors only: dicts of ``(F, ...)``."""
    chain = [joint] + skeleton.ancestors(joint)
    rot, pos = {}, {}
    for k in reversed(chain):
        t = translations[:, slot[k]] if k in slot else skeleton.offsets[k]
        p = skeleton.parents[k]
        if p < 0:
            rot[k], pos[k] = local[:, k], np.broadcast_to(t, (local.shape[0], 3))
        else:
            rot[k] = qmul(rot[p], local[:, k])
            pos[k] = pos[p] + qrot(rot[p], t)
    return rot, pos
