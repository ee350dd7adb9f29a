"""Files in the conventions of other exporters, built from real clips: the same motion written
in other units and with another up axis, its joints renamed, its Head joint taken out.

Each builder returns BVH text whose content alone must tell its units and up axis; the tests
say which real exporter each case stands for (MakeHuman: Z-up decimetres; video-to-BVH tools:
millimetres, Z-up, numbered joints and no head joint).
"""
from __future__ import annotations

import numpy as np

from motion_composer.engine.formats.bvh import format_bvh
from motion_composer.engine.kinematics import fk_arrays
from motion_composer.engine.motion import Motion
from motion_composer.engine.skeleton import EndSite, Skeleton
from motion_composer.engine.units import UNITS, SourceFrame


def without_joint(motion: Motion, name: str) -> Motion:
    """``motion`` with the joint ``name`` and everything below it taken out: an End Site of
    its parent (at its offset) is left where it was; its channels go."""
    sk = motion.skeleton
    j = sk.joint(name)
    gone = {j}
    for k in range(j + 1, sk.num_joints):            # parents come before their children
        if sk.parents[k] in gone:
            gone.add(k)
    keep = [k for k in range(sk.num_joints) if k not in gone]
    new_index = {old: new for new, old in enumerate(keep)}
    parents = np.array([-1 if sk.parents[k] < 0 else new_index[sk.parents[k]] for k in keep])
    sites = [EndSite(new_index[s.parent], s.offset, s.name) for s in sk.end_sites
             if s.parent not in gone]
    sites.append(EndSite(new_index[sk.parents[j]], sk.offsets[j], f"{name}_end"))
    skeleton = Skeleton(names=[sk.names[k] for k in keep], parents=parents,
                        offsets=sk.offsets[keep], channels=[sk.channels[k] for k in keep],
                        position_modes=[sk.position_modes[k] for k in keep], end_sites=sites,
                        source=sk.source)
    kept_translations = [i for i, k in enumerate(sk.translated) if k not in gone]
    return Motion(skeleton=skeleton, rotations=motion.rotations[:, keep],
                  translations=motion.translations[:, kept_translations],
                  frame_time=motion.frame_time, name=motion.name)


def renamed(motion: Motion, names: dict[str, str] | None = None) -> Motion:
    """``motion`` with its joints renamed (``names``: old -> new; ``None``: ``joint_<k>`` for
    every joint, as video-to-BVH tools number them)."""
    sk = motion.skeleton
    new = ([f"joint_{k}" for k in range(sk.num_joints)] if names is None
           else [names.get(n, n) for n in sk.names])
    sites = [EndSite(s.parent, s.offset, f"{new[s.parent]}_end") for s in sk.end_sites]
    skeleton = Skeleton(names=new, parents=sk.parents, offsets=sk.offsets,
                        channels=list(sk.channels), position_modes=list(sk.position_modes),
                        end_sites=sites, source=sk.source)
    return motion.replace(skeleton=skeleton)


def written_in(motion: Motion, units: str, up_axis: str) -> str:
    """The BVH text of ``motion`` in ``units`` with ``up_axis`` up (10 decimals, so that a
    millimetre or decimetre file keeps the original's precision)."""
    return format_bvh(motion, source=SourceFrame(units=units, scale=UNITS[units],
                                                 up_axis=up_axis), decimals=10)


def world_positions(motion: Motion) -> np.ndarray:
    """``(F, J, 3)`` [m] world joint positions, internal axes."""
    return fk_arrays(motion.skeleton, motion.rotations, motion.translations).positions
