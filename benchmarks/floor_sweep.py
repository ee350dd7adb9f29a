"""A floor given on the command line, over many pairs (a report, not a test).

    python benchmarks/floor_sweep.py [--floor HEIGHT] [--pairs CLIP:TARGET ...]

Per pair, solved as ``motion-composer retarget CLIP --target CHAR --auto-contacts --floor
HEIGHT`` does (the project's floor stands the character on it: ``Scene.lift``), this prints
where the character stands in its reference pose, how far the floor moves the conversion,
the floor planes per joint (``dup``: joints with more than one, which should be none), the
worst no-pop ratio of the dense solve and of the delivered keys (``quality.pops``; at most 1
is the rule), the largest residual of a metric constraint and what the keys were fitted to
with their largest distance from the dense solve (% of the figure's size).

Before round 33 the floor was only the feet's plane: ``--floor 0`` onto the CMU T-pose
skeleton (hips at 0, feet 0.92 m lower) lifted the body by force on every frame, and the
delivered motion popped 2.4-4.8 times the limit on all four clips tried. See
benchmarks/README.md for the figures since.

Without ``--pairs``, six clips of ``../shared/data`` onto five characters
(``keyed_root_steps.CLIPS``, ``TARGETS``).
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SHARED_DATA, prepare  # noqa: E402

prepare()

import argparse  # noqa: E402
import collections  # noqa: E402
import itertools  # noqa: E402

from keyed_root_steps import CLIPS, TARGETS  # noqa: E402


def solve(clip: Path, character: Path, floor: float):
    """``retarget CLIP --target CHARACTER --auto-contacts --floor FLOOR``: the scene solved."""
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.formats import read_character, read_motion, read_performer
    from motion_composer.engine.project import Project, Source
    from motion_composer.engine.scene import Scene
    performer = read_performer(clip)
    found = read_character(character)
    target = found.rest_motion() if found is not None else read_motion(character)
    project = Project(performer=Source(str(clip)), target=Source(str(character)),
                      correspondence=automap(target.skeleton, performer.skeleton),
                      auto_contacts=True, floor=floor)
    scene = Scene(project, performer, target)
    return scene, scene.solve(regenerate=True)


def main(argv=None) -> int:
    from motion_composer.engine.correction.quality import quality
    from motion_composer.engine.describe import figure_size
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--floor", type=float, default=0.0)
    parser.add_argument("--pairs", nargs="+", metavar="CLIP:TARGET")
    args = parser.parse_args(argv)
    pairs = ([tuple(p.split(":", 1)) for p in args.pairs] if args.pairs else
             [(c, t) for c, t in itertools.product(CLIPS, TARGETS) if c != t])
    print(f"{'clip':24} {'target':28} {'stands':>7} {'lift':>7} planes dup  dense keyed "
          f"resid_mm keys")
    for clip, target in pairs:
        scene, sol = solve(SHARED_DATA / clip, SHARED_DATA / target, args.floor)
        planes = collections.Counter(c.joint for c in sol.constraints if c.kind == "plane")
        dup = sorted(j for j, n in planes.items() if n > 1)
        dense = quality(sol.scene.performer, sol.scene.composed, sol.correction.motion,
                        sol.constraints, None)["pops"]
        keyed = sol.report["quality"]["pops"]
        worst = max((c["max_residual"] or 0.0 for c in sol.report["constraints"]
                     if c["residual_unit"] == "m"), default=0.0)
        keys = sol.report["keys"]
        apart = 100 * keys["largest_distance_from_dense_m"] / figure_size(sol.scene.composed)
        standing = scene.standing_floor()
        print(f"{clip[:24]:24} {target[-28:]:28} "
              f"{'-' if standing is None else f'{standing:7.3f}':>7} {scene.lift():7.3f} "
              f"{sum(planes.values()):6} {len(dup):3} "
              f"{max((p['ratio'] for p in dense), default=0):6.2f} "
              f"{max((p['ratio'] for p in keyed), default=0):5.2f} {worst * 1e3:8.2f} "
              f"{keys['fitted_to']} {apart:.1f}%", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
