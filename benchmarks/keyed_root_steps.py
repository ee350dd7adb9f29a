"""How fast the delivered keys move the root, against the dense IK solve (a report, not a test).

    python benchmarks/keyed_root_steps.py [--pairs CLIP:TARGET ...]

The solved layer's keys are fitted to the tasks (engine/correction/keyfit.py), and
``solved_keys`` keeps them when they hold every task within 1 mm, turn no joint faster than
the dense solve does (the no-pop rule, on rotations) and move the root's translation no
faster than it does (``keyfit.ROOT_MARGIN``, ``ROOT_FLOOR``). Per pair, solved as
``motion-composer retarget CLIP --target CHAR --auto-contacts`` does, this prints the frame
where the keyed root correction (the delivered root less the direct conversion's) changes most
against the dense correction's largest change within 3 frames of it, in mm per frame.
A ratio near 1 means the keys move the root as the dense solve does; before the root rule
(round 30) it was 8-9 on the CC3 walk (60 fps) onto Ely and the CMU T-pose (a 37 mm step
where the dense one is 4 mm) and on the Bandai walk (30 fps) onto the T-pose (33 mm against
4); see benchmarks/README.md for after.

Without ``--pairs``, six clips of ``../shared/data`` onto five characters.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SHARED_DATA, prepare  # noqa: E402

prepare()

import argparse  # noqa: E402
import itertools  # noqa: E402

import numpy as np  # noqa: E402

CLIPS = ["bandai1_walk_normal_001.bvh", "cmu_max_131_01_walk.bvh", "bandai1_run_active_001.bvh",
         "cc3_cmu_02_01_walk.bvh", "fair1_child8_jumping.bvh", "bandai1_kick_normal_001.bvh"]
TARGETS = ["cmu_max_131_01_walk.bvh", "target_cmu_mb_rest_tpose.bvh", "target_mixamo_ely.glb",
           "fbx/maya_kenney_character_7700_binary.fbx", "bandai1_walk_normal_001.bvh"]
#: [frames] the dense correction's largest step is taken within this of the keyed one's
NEAR = 3


def solve_pair(clip: Path, target_path: Path):
    """One pair solved as ``motion-composer retarget CLIP --target CHAR --auto-contacts``
    does: the :class:`~engine.scene.Solution`."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character, read_motion, read_performer
    from motion_composer.engine.project import Project, Source
    from motion_composer.engine.scene import Scene
    performer = read_performer(clip)
    character = read_character(target_path)
    target = character.rest_motion() if character is not None else read_motion(target_path)
    project = Project(performer=Source(str(clip)), target=Source(str(target_path)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True)
    return Scene(project, performer, target).solve(regenerate=True)


def root_steps(clip: Path, target_path: Path) -> dict:
    """The keyed and dense root corrections' steps [m per frame] of one pair, and where the
    keyed one's is largest against the dense one's near it."""
    solution = solve_pair(clip, target_path)
    composed = solution.scene.composed
    dense = solution.correction.root
    keyed = solution.motion.translations[:, 0] - composed.translations[:, 0]
    d = np.linalg.norm(np.diff(dense, axis=0), axis=1)
    k = np.linalg.norm(np.diff(keyed, axis=0), axis=1)
    near = np.array([d[max(0, i - NEAR):i + NEAR + 1].max() for i in range(len(d))])
    floor = 0.01 / composed.fps                                  # 1 cm/s
    ratio = k / np.maximum(near, floor)
    i = int(ratio.argmax())
    return {"frame": i + 1, "ratio": float(ratio[i]), "keyed_mm": 1000 * float(k[i]),
            "dense_mm": 1000 * float(near[i]), "fps": composed.fps}


def report_pairs(description: str, measure, header: str, row) -> None:
    """The reports' command line: ``--pairs CLIP:TARGET ...`` (default: :data:`CLIPS` onto
    :data:`TARGETS`), then ``header`` and per pair ``row(measure(clip, target))`` after the
    pair's names, or the error that stopped it."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--pairs", nargs="+", default=[], metavar="CLIP:TARGET",
                        help="file names under ../shared/data (default: six clips onto five "
                             "characters)")
    args = parser.parse_args()
    pairs = ([tuple(p.split(":", 1)) for p in args.pairs] if args.pairs else
             [(c, t) for c, t in itertools.product(CLIPS, TARGETS) if c != t])
    print(f"{'clip':32} {'target':42} {header}")
    for clip, target in pairs:
        try:
            r = measure(SHARED_DATA / clip, SHARED_DATA / target)
        except Exception as exc:                       # a report: say it and go on
            print(f"{clip:32} {target:42} ERROR {type(exc).__name__}: {exc}")
            continue
        print(f"{clip:32} {target:42} {row(r)}", flush=True)


def main() -> None:
    report_pairs(__doc__.splitlines()[0], root_steps,
                 f"{'frame':>5} {'keyed':>8} {'dense':>8} {'ratio':>6}"
                 "   (root correction's step, mm per frame)",
                 lambda r: f"{r['frame']:5d} {r['keyed_mm']:8.1f} {r['dense_mm']:8.1f} "
                           f"{r['ratio']:6.2f}")


if __name__ == "__main__":
    main()
