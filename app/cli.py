"""The ``motion-composer`` command.

Errors a user can cause print one line on stderr (no traceback) and exit with code 2.
"""
from __future__ import annotations

import argparse
import json
import sys

from engine import MotionComposerError, read_bvh
from engine.describe import describe_motion, joint_tree_lines
from engine.units import AXES, UNITS

EXIT_USER_ERROR = 2


def _reader_options(args) -> dict:
    options = {}
    if args.units:
        options["units"] = args.units
    if args.scale is not None:
        options["scale"] = args.scale
    if args.up_axis:
        options["up_axis"] = args.up_axis
    if args.position_mode:
        options["position_mode"] = args.position_mode
    return options


def _add_reader_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("reading (detected when not given)")
    group.add_argument("--units", choices=sorted(UNITS), help="the file's length unit")
    group.add_argument("--scale", type=float, help="metres per file unit (overrides --units)")
    group.add_argument("--up-axis", choices=AXES, help="the file's up axis")
    group.add_argument("--position-mode", choices=("absolute", "relative"),
                       help="position channels replace the OFFSET (absolute) or add to it "
                            "(relative)")


def cmd_info(args) -> int:
    motion = read_bvh(args.file, **_reader_options(args))
    info = describe_motion(motion)
    if args.json:
        json.dump(info, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    sk = motion.skeleton
    unit_note = "detected" if info["detected"] else "given"
    lines = [
        f"file:        {args.file}",
        f"frames:      {info['frames']}",
        f"frame rate:  {info['fps']:.6g} fps (frame time {info['frame_time']!r} s)",
        f"duration:    {info['duration']:.3f} s",
        f"units:       {info['units']} ({info['metres_per_unit']:.6g} m per unit, {unit_note})",
        f"up axis:     {info['up_axis']} ({unit_note})",
    ]
    if info["detection"]:
        lines.append(f"detection:   {info['detection']}")
    lines += [
        f"stature:     {info['stature_m']:.2f} m (approximate)",
        f"joints:      {sk.num_joints} (+{len(sk.end_sites)} End Sites), "
        f"{info['channel_count']} channels",
        f"rotation orders: {', '.join(info['rotation_orders']) or 'none'}",
        "joint tree:",
    ]
    lines += ["  " + line for line in joint_tree_lines(motion)]
    print("\n".join(lines))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="motion-composer",
        description="Retarget captured motion onto any character and correct it with IK.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    info = sub.add_parser("info", help="describe a motion file",
                          description="Describe a BVH file: joint tree, frames, frame rate, "
                                      "duration, units, up axis, stature, channel layout.")
    info.add_argument("file", help="a .bvh file")
    info.add_argument("--json", action="store_true", help="print JSON for machines")
    _add_reader_options(info)
    info.set_defaults(func=cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except MotionComposerError as exc:
        print(f"motion-composer: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("motion-composer: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
