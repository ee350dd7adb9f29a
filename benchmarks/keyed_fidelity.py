"""How far the delivered keys take the body from the dense IK solve (a report, not a test).

    python benchmarks/keyed_fidelity.py [--pairs CLIP:TARGET ...]

The solved layer's keys are fitted to the tasks (engine/correction/keyfit.py): they hold
every task within 1 mm, but between and around the tasks they are free to part from the
dense solve, the posture nearest the capture that meets them. Per pair, solved as
``motion-composer retarget CLIP --target CHAR --auto-contacts`` does, this prints the largest
distance of any joint between the delivered motion and the dense solve (in % of the stature,
and the frame and joint), the share of frames where it is over 1 % of the stature, and the
dense solve's own largest distance from the direct conversion, for scale; ``path``, the
largest distance from the dense solve's path (from the nearest of its positions on the frame
and either side; a fit may smooth a one-frame jerk of the dense solve away), which is the solve
report's ``keys.largest_distance_from_dense_m`` (also on the CLI's summary line) and what the
solve judges keys by (at most ``keyfit.FIDELITY`` of the figure's size); ``dense keys`` where
the keys fitted to the tasks were not kept (the delivered keys follow the dense curves).

Without ``--pairs``, the six clips and five characters of ``keyed_root_steps.py``.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import prepare  # noqa: E402

prepare()

import numpy as np  # noqa: E402

from keyed_root_steps import report_pairs, solve_pair  # noqa: E402

#: a frame parts from the dense solve where a joint is further than this share of the stature
PART = 0.01


def fidelity(clip: Path, target_path: Path) -> dict:
    from motion_composer.engine.describe import stature
    from motion_composer.engine.kinematics import fk_arrays
    solution = solve_pair(clip, target_path)
    composed = solution.scene.composed
    sk = composed.skeleton

    def pos(m):
        return fk_arrays(sk, m.rotations, m.translations, end_sites=False).positions

    size = stature(composed)
    keyed, dense, direct = pos(solution.motion), pos(solution.correction.motion), pos(composed)
    apart = np.linalg.norm(keyed - dense, axis=-1) / size
    f, j = np.unravel_index(apart.argmax(), apart.shape)
    keys = solution.report["keys"]
    path = keys["largest_distance_from_dense_m"] / size
    return {"percent": 100 * float(apart[f, j]), "frame": int(f), "joint": sk.names[j],
            "path": 100 * path,
            "share": float(np.mean(apart.max(axis=1) > PART)),
            "dense_percent": 100 * float(np.linalg.norm(dense - direct, axis=-1).max() / size),
            "fallback": keys["fitted_to"] != "tasks", "keys": keys["count"],
            "frames": composed.num_frames, "fps": composed.fps}


def main() -> None:
    report_pairs(__doc__.splitlines()[0], fidelity,
                 f"{'fps':>4} {'apart':>6} {'frame':>5} {'joint':16} {'>1%':>5} {'dense':>6}"
                 f" {'path':>6}   (% of stature)",
                 lambda r: f"{r['fps']:4.0f} {r['percent']:6.2f} {r['frame']:5d} "
                           f"{r['joint'][:16]:16} {100 * r['share']:4.0f}% "
                           f"{r['dense_percent']:6.2f} {r['path']:6.2f}"
                           + ("   dense keys" if r["fallback"] else ""))


if __name__ == "__main__":
    main()
