"""Plain-data summaries of skeletons and motions (for ``motion-composer info`` and the GUI)."""
from __future__ import annotations

import numpy as np

from .kinematics import fk_arrays
from .motion import Motion

__all__ = ["stature", "figure_size", "describe_motion", "joint_tree_lines"]


def stature(motion: Motion, *, samples: int = 48) -> float:
    """Approximate standing height [m]: the median over sampled frames of the vertical extent
    of all joints and End Sites (internal +Y up)."""
    F = motion.num_frames
    idx = np.unique(np.linspace(0, F - 1, min(F, samples)).round().astype(int))
    pose = fk_arrays(motion.skeleton, motion.rotations[idx], motion.translations[idx])
    y = pose.all_positions()[..., 1]
    return float(np.median(y.max(axis=1) - y.min(axis=1)))


#: a figure's size for the solvers is at least this share of its largest extent: a figure
#: lying flat (or a snake) has almost no height
FLAT_SHARE = 0.1


def figure_size(motion: Motion, *, samples: int = 48) -> float:
    """[m] the length the correction measures a figure by (its tolerances, steps and
    thresholds are shares of it, or shrink with it, so that a character is solved alike at
    any size): its :func:`stature`, but at least :data:`FLAT_SHARE` of its body's largest
    extent along an axis (median over the same sampled frames; the nodes above the body, a
    ground root or an exporter's node that stays at the origin while the body walks away,
    left out); 1 for a figure of no size (every joint at one point)."""
    F = motion.num_frames
    sk = motion.skeleton
    idx = np.unique(np.linspace(0, F - 1, min(F, samples)).round().astype(int))
    pose = fk_arrays(sk, motion.rotations[idx], motion.translations[idx])
    points = pose.all_positions()
    height = np.ptp(points[..., 1], axis=1)                           # (S,)
    body = np.ptp(np.delete(points, sk.above_the_body(), axis=1), axis=1)      # (S, 3)
    size = max(float(np.median(height)), FLAT_SHARE * float(np.median(body.max(axis=1))))
    return size if size > 0 else 1.0


def joint_tree_lines(motion: Motion) -> list[str]:
    """One line per joint, indented by depth, with its channel layout."""
    sk = motion.skeleton
    out = []
    for j, name in enumerate(sk.names):
        chans = sk.channels[j]
        rot = sk.rotation_orders[j]
        pos = "".join(c[0] for c in chans if c.endswith("position"))
        parts = []
        if pos:
            parts.append(f"pos {pos} ({sk.position_modes[j]})")
        if rot:
            parts.append(f"rot {rot}")
        layout = ", ".join(parts) if parts else "no channels"
        out.append(f"{'  ' * int(sk.depth[j])}{name}  [{layout}]")
    return out


def describe_motion(motion: Motion) -> dict:
    """A JSON-ready summary: frames, frame rate, duration, units, up axis, stature, joints."""
    sk = motion.skeleton
    src = sk.source
    orders = sorted({o for o in sk.rotation_orders if o})
    return {
        "name": motion.name,
        "frames": motion.num_frames,
        "fps": motion.fps,
        "frame_time": motion.frame_time,
        "duration": motion.duration,
        "units": src.units,
        "metres_per_unit": src.scale,
        "up_axis": src.up_axis,
        "detected": src.detected,
        "detection": src.reason,
        "stature_m": stature(motion),
        "joints": list(sk.names),
        "parents": [int(p) for p in sk.parents],
        "end_sites": [site.name for site in sk.end_sites],
        "channels": {name: list(ch) for name, ch in zip(sk.names, sk.channels)},
        "channel_count": sk.num_channels,
        "rotation_orders": orders,
        "position_channels": {sk.names[j]: sk.position_modes[j]
                              for j in range(sk.num_joints) if sk.position_modes[j]},
    }
