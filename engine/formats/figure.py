"""Which way a figure stands, for the readers: the humanoid's roles and its vertical.

A BVH file's up axis is detected from the body (:mod:`.bvh`); glTF and FBX state theirs, and a
figure that still does not stand along +Y once read (a glTF written Z-up, against the format's
definition; an FBX whose axis settings say nothing true) is a doubt the reader records on its
:class:`~engine.units.SourceFrame` (:func:`lying_doubt`), with the up axis to read it with,
which the command line and the window show as one warning line naming that override.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..kinematics import fk_arrays
from ..skeleton import Skeleton
from ..units import nearest_axis, up_axis_rotation

__all__ = ["body_roles", "body_vertical", "lying_doubt", "with_lying_doubt",
           "UP_AXIS_TOLERANCE"]

#: an up axis is trusted when the body's vertical lies within this angle of it [deg] (at 45
#: degrees two axes are as near; a runner's median lean stays under 40)
UP_AXIS_TOLERANCE = 40.0


def body_roles(skeleton: Skeleton, positions: np.ndarray):
    """The humanoid roles of a skeleton (:func:`engine.conversion.automap.identify`, by
    names or, where names say nothing, by structure), or ``None`` for a figure that is not
    a humanoid. ``positions`` ``(J, 3)``: a frame's joints, to tell the sides by."""
    from ..conversion.automap import identify
    from ..errors import MappingError
    try:
        return identify(skeleton, positions)
    except MappingError:
        return None


def _feet(roles, skeleton: Skeleton, pose) -> np.ndarray:
    """``(S, 3)`` the middle of the two legs' ends per frame (a leg without a foot ends at its
    shin's End Site where that continues the leg, else at the shin; a leg the roles do not
    find is left out, and without either the hips stand for them).

    An End Site that turns back up the leg (its offset from the shin against the thigh's
    direction) is a node the exporter placed, not an ankle: Blender's glTF of the robot puts
    its shins' ``_end`` nodes above the knees, and the standing robot was said to stand
    along -Y."""
    index = skeleton.index
    positions = pose.positions
    site_of = {site.parent: e for e, site in enumerate(skeleton.end_sites)}
    ends = []
    for side in ("l", "r"):
        if f"foot_{side}" in roles:
            ends.append(positions[:, index[roles[f"foot_{side}"]]])
            continue
        role = next((r for r in (f"shin_{side}", f"thigh_{side}", f"hip_joint_{side}")
                     if r in roles), None)
        if role is None:            # a leg the roles do not find (a file's numbers broken)
            continue
        last = index[roles[role]]
        end = positions[:, last]
        if last in site_of and skeleton.parents[last] >= 0:
            site = pose.end_positions[:, site_of[last]]
            along = np.sum((site - end) * (end - positions[:, skeleton.parents[last]]), axis=1)
            end = np.where((along > 0.0)[:, None], site, end)
        ends.append(end)
    if not ends:                    # no leg: the hips themselves (no direction to tell by)
        return positions[:, index[roles["hips"]]]
    return sum(ends) / len(ends)


def body_vertical(roles, skeleton: Skeleton, pose) -> np.ndarray:
    """The body's vertical per frame ``(S, 3)``: from the feet to the head (a leg without a
    foot ends at its shin's End Site, or at the shin), with its component along the
    shoulders removed (arms either side: the vertical is square to them)."""
    index = skeleton.index
    positions = pose.positions
    vertical = positions[:, index[roles["head"]]] - _feet(roles, skeleton, pose)
    arm = next((r for r in ("upper_arm", "forearm", "hand")
                if f"{r}_l" in roles and f"{r}_r" in roles), None)
    if arm is not None:
        across = positions[:, index[roles[f"{arm}_l"]]] - positions[:, index[roles[f"{arm}_r"]]]
        norm = np.linalg.norm(across, axis=1, keepdims=True)
        across = np.divide(across, norm, out=np.zeros_like(across), where=norm > 0)
        vertical = vertical - np.sum(vertical * across, axis=1, keepdims=True) * across
    return vertical


#: frames of each clip the clips' stance is judged on (evenly spread)
STANCE_SAMPLES = 32


def _hips_angle(roles, skeleton: Skeleton, pose) -> tuple[np.ndarray, np.ndarray]:
    """``(S,)`` [deg] how far the legs (their ends to the hips) lie from +Y per frame, and
    the vectors ``(S, 3)``."""
    v = pose.positions[:, skeleton.index[roles["hips"]]] - _feet(roles, skeleton, pose)
    norm = np.linalg.norm(v, axis=1)
    cos = np.divide(v[:, 1], norm, out=np.ones_like(norm), where=norm > 0.0)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), v


def lying_doubt(skeleton: Skeleton, what: str, read_with: str = "+Y",
                motions=()) -> tuple[str, str]:
    """``("", "")`` where the skeleton's zero pose (``what``: ``"bind pose"``, ``"rest
    pose"``) stands along +Y, or is no humanoid to tell by; else one sentence saying along
    which axis it stands, and the up axis to read the file with (``read_with``: the one it
    was read with): its legs, from their ends to the hips, more than
    :data:`UP_AXIS_TOLERANCE` off +Y. (The legs, not the feet-to-head vertical that tells a
    BVH file's up axis: a quadruped read as a humanoid, the glTF fox, stands on its hind
    legs' line but carries its head 59 degrees forward of it.)

    Where the file has clips (``motions``, on this skeleton), they tell: a figure whose
    clips stand along +Y (the median over :data:`STANCE_SAMPLES` frames of each) was read
    with the right axis up, whatever its zero pose. Blender's glTF of a BANDAI clip keeps the
    BVH's zero pose, which lies along +X, and the reader said to read it with +X up, which
    laid the walking figure down."""
    J = skeleton.num_joints
    rest = np.zeros((1, J, 4))
    rest[..., 3] = 1.0
    pose = fk_arrays(skeleton, rest, skeleton.offsets[skeleton.translated][None])
    roles = body_roles(skeleton, pose.positions[0])
    if roles is None:
        return "", ""
    angle, v = _hips_angle(roles, skeleton, pose)
    if not np.linalg.norm(v[0]) > 0.0 or angle[0] <= UP_AXIS_TOLERANCE:
        return "", ""
    angles = []
    for motion in (m for m in motions if m.num_frames):
        frames = np.unique(np.linspace(0, motion.num_frames - 1,
                                       STANCE_SAMPLES).round().astype(np.intp))
        sample = fk_arrays(skeleton, motion.rotations[frames], motion.translations[frames])
        angles.append(_hips_angle(roles, skeleton, sample)[0])
    if angles and float(np.median(np.concatenate(angles))) <= UP_AXIS_TOLERANCE:
        return "", ""
    # read with ``read_with`` up, the file's vectors were turned by its rotation
    axis = nearest_axis(up_axis_rotation(read_with).T @ v[0])
    return (f"the figure stands along {nearest_axis(v[0])}, not +Y, in its {what} "
            f"({angle[0]:.0f} degrees off){' and its clips' if angles else ''}: the file was "
            "probably written with another axis up"), axis


def with_lying_doubt(skeleton: Skeleton, what: str, motions=()) -> Skeleton:
    """``skeleton`` read from a glTF or FBX file, with the doubt of :func:`lying_doubt` (read
    with its source's up axis; ``motions``: the file's clips on it) on its source and the up
    axis to read it with as the override; itself where it stands."""
    source = skeleton.source
    doubt, axis = lying_doubt(skeleton, what, source.up_axis, motions)
    if not doubt:
        return skeleton
    return dataclasses.replace(skeleton, source=dataclasses.replace(
        source, doubt=doubt, overrides=(("up_axis", axis),)))
