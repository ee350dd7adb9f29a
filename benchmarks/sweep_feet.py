"""Issue 14's foot and no-pop rules swept over every clip and every character (a report, not a
test).

    python benchmarks/sweep_feet.py [--clip SUBSTR ...] [--target SUBSTR ...]
                                    [--pairs CLIP:TARGET ...] [--json OUT.jsonl] [--list]

For every motion clip (the ``*.bvh`` of ``../shared/data`` that move, and ``resources/clips``)
against every character target (``target_*.glb``, ``target_cmu_mb_rest_tpose.bvh``,
``resources/clips/cmu_rest_tpose.bvh`` and the FBX characters of ``../shared/data/fbx``), the
pair is solved as ``motion-composer retarget CLIP --target CHAR --auto-contacts`` does (the
same readers, automatic map, project and :meth:`Scene.solve`), and one row is printed:

* ``frames``, ``contacts`` (the engine's detected contacts on mapped feet) and ``cover``: the
  share of the performer's planted frames (found independently by tests/test_foot_contacts.py's
  ``_intervals``) that the contacts cover (the test asks >= 90 %);
* ``heel`` / ``toe``: the worst excess of the target's planted drift over the performer's, in
  % of stature (rule 1; the test allows 0.1 %), over the performer's planted intervals;
* ``floor``: the worst breach [mm] of a planted foot joint under its rest height over the
  character's floor (rule 2; positive = below, allowed 1 mm);
* ``tip``: the same [mm] for the joints below each foot that no performer joint maps (a
  toe's end joint such as Mixamo's ``*Toe_End``, separate toes): each foot joint stays at or
  above its own rest height (rule 2); ``-`` where the character has none;
* ``pop``: the worst angular-speed ratio of ``quality()["pops"]`` with its joint and frame
  (rule 3; allowed 1);
* ``steady``: the delivered keys' worst turn on any frame over 1.5 times the conversion's or
  the dense solve's fastest turn of that joint within two frames (at least 30 deg/s;
  test_foot_contacts' ``keyed_steadiness``; allowed 1); ``keys``: ``tasks`` where the keys
  were fitted to the constraints' tasks, ``dense`` where to the dense curves;
* ``res``: the largest residual of a metric constraint [mm] (rule 4; allowed 1 mm) and of an
  orientation one [deg];
* ``s``: solve seconds; ``notes``: warnings (the CLI's one-line ones), anything else written
  to stderr or raised as a Python warning, and errors.

The rules' checks reuse tests/test_foot_contacts.py's helpers (imported, not copied). Files that
cannot be targets are listed with why. Byte-identical files (resources/clips copies of shared
clips) are solved once and their rows say so. Pairs run one after another in this process;
``--timeout`` bounds one pair (SIGALRM).
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CLIPS, REPO, SHARED_DATA, prepare  # noqa: E402

prepare()

import argparse  # noqa: E402
import contextlib  # noqa: E402
import hashlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import signal  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(REPO / "tests"))

#: FBX files of ../shared/data/fbx that are not characters (data/fbx/README.md, and the reader)
NOT_TARGETS = {
    "max7_skin_5000_binary.fbx": "FBX 6-era header (version 3000): the reader refuses FBX "
                                 "older than 7.1",
    "motionbuilder_actor_7700_binary.fbx": "a MotionBuilder actor file: no skeleton",
    "nurbs_ascii_7200.fbx": "a NURBS scene: no skeleton",
}


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def clips_and_targets():
    """``(clips, targets, skipped)``: paths, and ``(path, why)`` of files that are not used."""
    from motion_composer.engine.formats import read_motion
    clips, targets, skipped = [], [], []
    for path in sorted(SHARED_DATA.glob("*.bvh")) + sorted(CLIPS.glob("*.bvh")):
        if path.name.startswith("target_"):
            targets.append(path)
            continue
        motion = read_motion(path)
        if motion.num_frames < 2:
            targets.append(path)             # a one-frame rest pose: a character
        else:
            clips.append(path)
    targets += sorted(SHARED_DATA.glob("target_*.glb"))
    for path in sorted((SHARED_DATA / "fbx").glob("*.fbx")):
        if path.name in NOT_TARGETS:
            skipped.append((path, NOT_TARGETS[path.name]))
        else:
            targets.append(path)
    return clips, targets, skipped


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def _short(path: Path) -> str:
    return ("res/" if path.parent == CLIPS else "fbx/" if path.parent.name == "fbx" else "") + \
        path.name


def solve_pair(clip: Path, target_path: Path, flat_feet: bool = False) -> dict:
    """Solve ``clip`` onto ``target_path`` as the CLI's ``retarget --auto-contacts`` does
    (with ``--flat-feet`` where ``flat_feet``) and measure the rules. Returns the row (a
    dict)."""
    import test_foot_contacts as tfc
    from motion_composer.engine.conversion import BindOptions
    from motion_composer.engine.conversion.automap import automap
    from motion_composer.engine.correction.contacts import find_feet
    from motion_composer.engine.describe import stature
    from motion_composer.engine.formats import read_character, read_motion, read_performer
    from motion_composer.engine.kinematics import fk_arrays
    from motion_composer.engine.project import Project, Source
    from motion_composer.engine.scene import Scene

    row = {"clip": _short(clip), "target": _short(target_path), "notes": []}
    stderr = io.StringIO()
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stderr(stderr):
        warnings.simplefilter("always")
        try:
            performer = read_performer(clip)
            line = performer.skeleton.source.warning(clip, "--performer-")
            if line:
                row["notes"].append(f"warning: {line}")
            character = read_character(target_path)
            target = (character.rest_motion() if character is not None else
                      read_motion(target_path))
            line = target.skeleton.source.warning(target_path, "--target-")
            if line:
                row["notes"].append(f"warning: {line}")
            project = Project(performer=Source(str(clip)), target=Source(str(target_path)),
                              correspondence=automap(target.skeleton, performer.skeleton),
                              auto_contacts=True, bind_options=BindOptions(flat_feet=flat_feet))
            t0 = time.perf_counter()
            solution = Scene(project, performer, target).solve(regenerate=True)
            row["seconds"] = time.perf_counter() - t0
            row["notes"] += [f"warning: {w}" for w in solution.report["warnings"]]
            scene = solution.scene
            row["frames"] = scene.composed.num_frames
            contacts = scene.contacts()
            row["contacts"] = len(contacts)
            solved = (scene, solution, target_path)
            intervals, _, _ = tfc._intervals(scene)
            row["intervals"] = len(intervals)
            # the detector's cover of the performer's planted frames (heel intervals by ankle)
            covered, total = tfc.covered_frames(intervals, contacts)
            row["cover"] = covered / total if total else None
            for part in ("heel", "toe"):
                excess, where = tfc._drift_excess(solved, part)
                row[part] = excess
                row[f"{part}_where"] = where
            # the floor rule over the performer's planted intervals (as the test does)
            motion = solution.motion
            sk = motion.skeleton
            joints = sorted({sk.index[tj] for _, tj, _, _, _, _ in intervals})
            breach, breach_where = 0.0, ""
            y = fk_arrays(sk, motion.rotations, motion.translations,
                          end_sites=False).positions[..., 1]
            if joints:
                floor, heights = tfc.rest_floor_and_heights(target_path, scene.target, joints)
                for _, tj, part, _, s, e in intervals:
                    j = sk.index[tj]
                    k = s + int(np.argmin(y[s:e + 1, j]))
                    below = float(floor + heights[j] - y[k, j])
                    if below > breach:
                        breach, breach_where = below, f"{part} {tj} {s}-{e} @{k}"
            row["floor_mm"] = breach * 1000.0
            row["floor_where"] = breach_where
            # the same rule on the joints below each foot that no performer joint maps (a
            # toe's end joint, separate toes), over the foot's planted intervals
            by_performer = {p: t for t, p in scene.correspondence.pairs.items()}
            below = {}
            for ankle, toe in find_feet(scene.performer.skeleton):
                if ankle in by_performer:
                    t_ankle, t_toe = by_performer[ankle], by_performer.get(toe)
                    below[ankle] = [k for k in range(sk.num_joints)
                                    if sk.index[t_ankle] in sk.ancestors(k)
                                    and sk.names[k] != t_toe]
            tips = sorted({k for ks in below.values() for k in ks})
            tip, tip_where = 0.0, ""
            if tips and intervals:
                floor, heights = tfc.rest_floor_and_heights(target_path, scene.target, tips)
                for _, _, part, ankle, s, e in intervals:
                    for k in below.get(ankle, ()):
                        f = s + int(np.argmin(y[s:e + 1, k]))
                        low = float(floor + heights[k] - y[f, k])
                        if low > tip:
                            tip, tip_where = low, f"{part} {sk.names[k]} {s}-{e} @{f}"
            row["tip_mm"] = tip * 1000.0 if tips else None
            row["tip_where"] = tip_where
            row["stature"] = stature(motion)
            q = solution.report["quality"]
            pops = q["pops"]
            if pops:
                row["pop"] = pops[0]["ratio"]
                row["pop_where"] = (f"{pops[0]['joint']}@{pops[0]['frame']} "
                                    f"{pops[0]['speed_deg_s']:.0f}/{pops[0]['limit_deg_s']:.0f}"
                                    " deg/s")
            else:
                row["pop"], row["pop_where"] = None, ""
            if solution.correction is not None:
                row["steady"], row["steady_where"] = tfc.keyed_steadiness(scene, solution)
            else:
                row["steady"], row["steady_where"] = None, ""
            row["keys"] = (solution.report.get("keys") or {}).get("fitted_to")
            metric = [c for c in q["constraints"] if c["residual_unit"] == "m"
                      and c["max_residual"] is not None]
            angular = [c for c in q["constraints"] if c["residual_unit"] == "rad"
                       and c["max_residual"] is not None]
            if metric:
                worst = max(metric, key=lambda c: c["max_residual"])
                row["res_mm"] = worst["max_residual"] * 1000.0
                row["res_where"] = f"{worst['name']}@{worst['frame']}"
            else:
                row["res_mm"], row["res_where"] = None, ""
            if angular:
                worst = max(angular, key=lambda c: c["max_residual"])
                row["res_deg"] = float(np.degrees(worst["max_residual"]))
                row["res_deg_where"] = f"{worst['name']}@{worst['frame']}"
            else:
                row["res_deg"], row["res_deg_where"] = None, ""
        except _Timeout:
            row["error"] = "timeout"
        except Exception as exc:      # noqa: BLE001 - a report: every failure is a row
            row["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0][:160]}"
            row["traceback"] = traceback.format_exc()
        for w in caught:
            row["notes"].append(f"python warning: {w.category.__name__}: {w.message} "
                                f"({Path(w.filename).name}:{w.lineno})")
    text = stderr.getvalue().strip()
    if text:
        row["notes"].append(f"stderr: {text[:300]}")
    return row


def _fmt(x, spec, empty="-"):
    return empty.rjust(len(format(0.0, spec))) if x is None else format(x, spec)


HEADER = (f"{'clip':40s} {'target':38s} {'frames':>6s} {'cont':>4s} {'cover':>6s} "
          f"{'heel%':>7s} {'toe%':>7s} {'floor':>7s} {'tip':>6s} {'pop':>6s} {'pop at':32s} "
          f"{'steady':>6s} {'keys':>5s} {'res mm':>7s} {'res deg':>7s} {'s':>6s}  notes")


def format_row(row: dict) -> str:
    if "same_as" in row:
        return f"{row['clip']:40s} {row['target']:38s} same bytes as {row['same_as']}: see that row"
    if "error" in row and "frames" not in row:
        return f"{row['clip']:40s} {row['target']:38s} ERROR {row['error']}"
    flags = []
    if (row.get("heel") or 0) > 1e-3:
        flags.append("R1heel")
    if (row.get("toe") or 0) > 1e-3:
        flags.append("R1toe")
    if (row.get("floor_mm") or 0) > 1.0:
        flags.append("R2")
    if (row.get("tip_mm") or 0) > 1.0:
        flags.append("R2tip")
    if (row.get("pop") or 0) > 1.0:
        flags.append("R3")
    if (row.get("res_mm") or 0) > 1.0:
        flags.append("R4")
    if (row.get("steady") or 0) > 1.0:
        flags.append("steady " + row["steady_where"])
    if row.get("cover") is not None and row["cover"] < 0.9:
        flags.append("cover")
    if row.get("error"):
        flags.append("ERROR " + row["error"])
    notes = "; ".join(flags + row["notes"])
    return (f"{row['clip']:40s} {row['target']:38s} {row.get('frames', 0):6d} "
            f"{row.get('contacts', 0):4d} {_fmt(row.get('cover'), '6.1%')} "
            f"{_fmt(None if row.get('heel') is None else 100 * row['heel'], '7.3f')} "
            f"{_fmt(None if row.get('toe') is None else 100 * row['toe'], '7.3f')} "
            f"{_fmt(row.get('floor_mm'), '7.1f')} {_fmt(row.get('tip_mm'), '6.1f')} "
            f"{_fmt(row.get('pop'), '6.2f')} "
            f"{row.get('pop_where', ''):32s} {_fmt(row.get('steady'), '6.2f')} "
            f"{row.get('keys') or '-':>5s} {_fmt(row.get('res_mm'), '7.2f')} "
            f"{_fmt(row.get('res_deg'), '7.2f')} {_fmt(row.get('seconds'), '6.1f')}  {notes}")


def add_filters(parser: argparse.ArgumentParser) -> None:
    """The ``--clip`` and ``--target`` name filters (sweep_variants.py's too)."""
    parser.add_argument("--clip", action="append", default=[],
                        help="only clips whose name contains this (repeatable)")
    parser.add_argument("--target", action="append", default=[],
                        help="only targets whose name contains this (repeatable)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_filters(parser)
    parser.add_argument("--pairs", nargs="+", default=[], metavar="CLIP:TARGET",
                        help="only these pairs (substrings of the clip and target names)")
    parser.add_argument("--json", help="also write each row as a JSON line to this file")
    parser.add_argument("--timeout", type=float, default=600.0,
                        help="seconds allowed to one pair (default 600)")
    parser.add_argument("--list", action="store_true", help="list the pairs and exit")
    parser.add_argument("--flat-feet", action="store_true",
                        help="bind with flat feet (BindOptions.flat_feet, --flat-feet)")
    args = parser.parse_args()

    clips, targets, skipped = clips_and_targets()
    print("not targets:")
    for path, why in skipped:
        print(f"  {_short(path)}: {why}")
    pairs = []
    for clip in clips:
        for target in targets:
            if args.clip and not any(s in clip.name for s in args.clip):
                continue
            if args.target and not any(s in target.name for s in args.target):
                continue
            if args.pairs and not any(c in clip.name and t in target.name
                                      for c, t in (p.split(":", 1) for p in args.pairs)):
                continue
            pairs.append((clip, target))
    print(f"{len(pairs)} pairs ({len(clips)} clips x {len(targets)} targets before filters)")
    if args.list:
        for clip, target in pairs:
            print(f"  {_short(clip)} -> {_short(target)}")
        return
    out = open(args.json, "w") if args.json else None
    signal.signal(signal.SIGALRM, _alarm)
    seen: dict[tuple, str] = {}
    digests: dict[Path, str] = {}
    rows = []
    started = time.perf_counter()
    print(HEADER, flush=True)
    for clip, target in pairs:
        key = tuple(digests.setdefault(p, _digest(p)) for p in (clip, target))
        if key in seen:
            row = {"clip": _short(clip), "target": _short(target), "same_as": seen[key]}
        else:
            seen[key] = f"{_short(clip)} -> {_short(target)}"
            signal.setitimer(signal.ITIMER_REAL, args.timeout)
            try:
                row = solve_pair(clip, target, args.flat_feet)
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
        rows.append(row)
        print(format_row(row), flush=True)
        if out:
            out.write(json.dumps(row, default=float) + "\n")
            out.flush()
    if out:
        out.close()
    broken = [r for r in rows if "same_as" not in r and format_row(r).split("  ")[-1]
              .strip() and any(f in format_row(r) for f in ("R1", "R2", "R3", "R4", "ERROR",
                                                            "cover"))]
    print(f"\n{len(rows)} rows, {len(broken)} breaking a rule or failing; "
          f"{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
