"""The ``motion-composer`` command.

The contract of every command (and of the window's flags):

* an error the user can cause (a bad argument, a malformed file, an impossible mapping) is a
  :class:`~engine.errors.MotionComposerError`: one line on stderr, no traceback, exit code 2.
  Argument errors are :class:`UsageError` (the usage text is printed only with ``--help``);
* a warning (a file whose units or up axis are in doubt, a solve's warnings) is one line on
  stderr when the command ends; a command that fails prints its error's line only, with the
  warnings it had in it (a doubtful unit is often why the mapping failed);
* an unexpected exception is a bug: its traceback on stderr and exit code 3.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import json
import math
import os
import sys

from motion_composer.engine import MotionComposerError
from motion_composer.engine.correction.enforcement import largest_residuals
from motion_composer.engine.describe import describe_motion, joint_tree_lines
from motion_composer.engine.units import AXES, UNITS

EXIT_USER_ERROR = 2
#: an unexpected exception: a bug, reported with its traceback
EXIT_BUG = 3

#: the warnings of the command running, in order: printed when it ends (see the module's text)
_WARNINGS: list[str] = []


class UsageError(MotionComposerError):
    """A command line argparse refuses (a missing argument, an unknown flag, a bad value)."""


class ArgumentParser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` whose errors raise :class:`UsageError` instead of
    printing the usage text and exiting (the subcommands' parsers are of this class too)."""

    def error(self, message: str):
        raise UsageError(f"{self.prog}: {message} (see {self.prog} --help)")


def _print_error(exc: MotionComposerError) -> None:
    """``exc`` on one line of stderr, with the warnings the command had before it."""
    text = " ".join(str(exc).split())
    if isinstance(exc, UsageError):
        print(text, file=sys.stderr)
        return
    notes = "".join(f" [warning: {' '.join(w.split())}]" for w in _WARNINGS)
    print(f"motion-composer: error: {text}{notes}", file=sys.stderr)


def _warning(line: str) -> None:
    """Keep ``line`` to print as a warning when the command ends."""
    _WARNINGS.append(line)


def _print_warnings() -> None:
    for line in _WARNINGS:
        print(f"motion-composer: warning: {line}", file=sys.stderr)
    _WARNINGS.clear()


def _print_bug() -> None:
    """The traceback of the exception being handled, and what it means, on stderr."""
    import traceback
    traceback.print_exc(file=sys.stderr)
    print("motion-composer: internal error (a bug, exit 3): please report it with the "
          "traceback above", file=sys.stderr)


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
    group.add_argument("--up-axis", choices=AXES,
                       help="the file's up axis (a glTF or FBX file's: the axis its figure "
                            "stands along, where the file says another)")
    group.add_argument("--position-mode", choices=("absolute", "relative"),
                       help="position channels replace the OFFSET (absolute) or add to it "
                            "(relative)")


#: the reader settings each side of a retarget takes (``--performer-units`` ...), as
#: (option, metavar or choices, help)
SIDE_OPTIONS = (
    ("units", sorted(UNITS), "length unit"),
    ("scale", float, "metres per file unit (overrides the units)"),
    ("up_axis", AXES, "up axis (also of a glTF or FBX file written with another axis up "
                      "than it says: the axis its figure stands along)"),
    ("position_mode", ("absolute", "relative"),
     "position channels: replace the OFFSET (absolute) or add to it (relative)"),
)
SIDES = ("performer", "target")


def _add_side_options(parser: argparse.ArgumentParser, when: str) -> None:
    """``--performer-units``, ``--target-up-axis`` ... (BVH; of glTF and FBX files the up
    axis only: glTF is metres, FBX states its units)."""
    for side in SIDES:
        group = parser.add_argument_group(f"reading the {side} (BVH; the up axis of any "
                                          f"file; {when})")
        for option, kind, text in SIDE_OPTIONS:
            flag = f"--{side}-{option.replace('_', '-')}"
            if kind is float:
                group.add_argument(flag, type=float, metavar="M", help=f"the {side}'s {text}")
            else:
                group.add_argument(flag, choices=kind, help=f"the {side}'s {text}")


def side_options(args, side: str) -> dict:
    """The reader overrides given for ``side`` (``units``, ``scale``, ``up_axis``,
    ``position_mode``; those not given are left out)."""
    values = {option: getattr(args, f"{side}_{option}") for option, _, _ in SIDE_OPTIONS}
    return {k: v for k, v in values.items() if v is not None}


def _side_flags(options: dict, side: str) -> str:
    return ", ".join(f"--{side}-{k.replace('_', '-')}" for k in options)


def _warn(motion, path, flag_prefix: str) -> None:
    """Warn (:func:`_warning`) of a clip whose detected units or up axis are in doubt
    (:meth:`engine.units.SourceFrame.warning`); never Python's multi-line warning format."""
    line = motion.skeleton.source.warning(path, flag_prefix)
    if line:
        _warning(line)


#: (flag, IKOptions field, help) of the solver settings the commands that run IK take
IK_FLAGS = (
    ("--ik-tolerance", "tolerance", "metres: a position or plane task is met below this error"),
    ("--ik-iterations", "max_iterations", "the cap of iterations per frame"),
    ("--ik-damping", "damping",
     "damped least squares lambda, as a fraction of the character's stature"),
    ("--ik-max-step", "max_step",
     "the largest correction asked of one task per iteration, as a fraction of the stature"),
    ("--ik-attraction", "attraction",
     "gain from 0 to 1 of the pull towards the converted posture per iteration"),
    ("--ik-settle", "settle", "a frame whose tasks are met stops once its largest step is "
                              "below this, radians or metres"),
    ("--ik-nullspace-damping", "nullspace_damping",
     "the lambda, as a fraction of the stature, of the null-space projections of the lower "
     "priorities and the attraction"),
    ("--ik-step-cap", "step_cap", "radians: the largest turn of any joint in one iteration"),
    ("--ik-polish-share", "polish_share",
     "the share from 0 to 1 of the iterations, at their end, that only restore the first "
     "priority level"),
    ("--ik-priority-gate", "priority_gate",
     "a lower priority runs while the higher ones are within this many tolerances, fading "
     "out at twice that"),
)


def _add_ik_options(parser: argparse.ArgumentParser, defaults: str) -> None:
    from motion_composer.engine.correction.ik import IKOptions

    solver = IKOptions()
    group = parser.add_argument_group(f"IK settings (not given: {defaults})")
    for flag, name, text in IK_FLAGS:
        group.add_argument(flag, dest=f"ik_{name}", metavar="N" if name == "max_iterations"
                           else "X", help=f"{text} (default {getattr(solver, name):g})")


def ik_options_from_args(args, base):
    """``base`` (an :class:`~engine.correction.ik.IKOptions`) with the ``--ik-*`` values
    given on the command line; a bad value raises :class:`MotionComposerError` naming its
    flag."""
    import dataclasses

    from motion_composer.engine.errors import IKOptionsError

    changes, flags = {}, {}
    for flag, name, _ in IK_FLAGS:
        text = getattr(args, f"ik_{name}")
        if text is None:
            continue
        flags[name] = flag
        try:
            changes[name] = int(text) if name == "max_iterations" else float(text)
        except ValueError:
            wanted = "a whole number" if name == "max_iterations" else "a number"
            raise MotionComposerError(f"{flag}: expected {wanted}, not {text!r}") from None
    try:
        return dataclasses.replace(base, **changes)
    except IKOptionsError as exc:
        raise MotionComposerError(f"{flags[exc.field]}: {exc.problem}") from None


def _gltf_info(args, character, fmt):
    """The motion ``info`` shows of a glTF or FBX ``character`` (``fmt`` its format) and the
    extra figures."""
    given = [flag for flag, value in (("--units", args.units), ("--scale", args.scale),
                                      ("--position-mode", args.position_mode))
             if value is not None]
    if given:
        convention = ("glTF is metres by definition" if fmt.read_take is None else
                      f"an {fmt.name} file states its units")
        raise MotionComposerError(f"{args.file}: {', '.join(given)} apply to BVH files only; "
                                  f"{convention}")
    if args.take is not None and fmt.read_take is not None:
        from motion_composer.engine.formats.fbx.scene import take_motion
        motion = take_motion(character, args.take)
    elif args.take is not None:
        raise MotionComposerError(f"{args.file}: --take applies to FBX files (a {fmt.name} "
                                  "file has no takes)")
    else:
        motion = character.motions[0] if character.motions else character.rest_motion()
    extra = {
        "character": character.name,
        "format": fmt.name,
        "motion_shown": motion.name if character.motions else "bind pose (no animation)",
        "skins": list(character.skin_names),
        "meshes": [{"name": m.name, "vertices": m.num_vertices, "triangles": m.num_triangles,
                    "skin": m.skin, "influences": int(m.joints.shape[1])}
                   for m in character.meshes],
        "animations": [{"name": m.name, "frames": m.num_frames, "fps": m.fps,
                        "duration": m.duration} for m in character.motions],
        "notes": list(character.notes),
    }
    return motion, extra


def cmd_info(args) -> int:
    from motion_composer.engine.formats import read_character, read_motion, sniff
    character = read_character(args.file, up_axis=args.up_axis)
    if character is not None:
        motion, extra = _gltf_info(args, character, sniff(args.file))
        _warn(motion, args.file, "--")
    else:
        if args.take is not None:
            raise MotionComposerError(f"{args.file}: --take applies to FBX files (a BVH file "
                                      "has no takes)")
        motion, extra = read_motion(args.file, **_reader_options(args)), None
        _warn(motion, args.file, "--")
    info = describe_motion(motion)
    if extra is not None:
        info.update(extra)
    if args.json:
        json.dump(info, sys.stdout, indent=2, allow_nan=False)      # strict JSON
        sys.stdout.write("\n")
        return 0
    sk = motion.skeleton
    # the reader keeps one "detected" flag; say per figure whether the user gave it
    unit_note = "given" if args.units or args.scale is not None else "detected"
    up_note = "given" if args.up_axis else "detected"
    if extra is not None:
        unit_note = up_note = ("the glTF convention" if extra["format"] in ("glTF", "GLB") else
                               "converted from the file's GlobalSettings")
        if args.up_axis:
            up_note = "given"
    lines = [
        f"file:        {args.file}",
        f"frames:      {info['frames']}",
        f"frame rate:  {info['fps']:.6g} fps (frame time {info['frame_time']!r} s)",
        f"duration:    {info['duration']:.3f} s",
        f"units:       {info['units']} ({info['metres_per_unit']:.6g} m per unit, {unit_note})",
        f"up axis:     {info['up_axis']} ({up_note})",
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
    if extra is not None:
        lines[1:1] = [f"character:   {extra['character']} ({extra['format']}), motion shown: "
                      f"{extra['motion_shown']}"]
        meshes = extra["meshes"]
        rigid = sum(1 for m in meshes if m["skin"] is None)
        lines.insert(-2, f"skins:       {len(extra['skins'])} ({', '.join(extra['skins'])})")
        lines.insert(-2, f"meshes:      {len(meshes)} ({rigid} rigid parts), "
                         f"{sum(m['vertices'] for m in meshes)} vertices, "
                         f"{sum(m['triangles'] for m in meshes)} triangles")
        anims = extra["animations"]
        label = "takes:      " if extra["format"] == "FBX" else "animations: "
        lines.insert(-2, f"{label} {len(anims)}" + (": " + ", ".join(
            f"{a['name']} ({a['frames']} frames, {a['duration']:.2f} s)" for a in anims)
            if anims else ""))
        for note in extra["notes"]:
            lines.insert(-2, f"note:        {note}")
    lines += ["  " + line for line in joint_tree_lines(motion)]
    print("\n".join(lines))
    return 0


def _reference(text: str):
    """``rest``, ``auto`` or ``frame:N`` for a reference pose."""
    if text in ("rest", "auto"):
        return text
    if text.startswith("frame:") and text[6:].isdigit():
        return int(text[6:])
    raise argparse.ArgumentTypeError(f"expected rest, auto or frame:N (N a frame number), "
                                     f"not {text!r}")


def _frame_range(text: str):
    """``A:B`` (0-based, inclusive; either end may be left out) for ``--frames``."""
    from motion_composer.engine.motion import parse_frame_range
    try:
        return parse_frame_range(text)
    except MotionComposerError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _fps(text: str) -> float:
    """A frame rate in (0, 1000] for ``--fps``."""
    from motion_composer.engine.motion import MAX_FPS
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value <= MAX_FPS:
        raise argparse.ArgumentTypeError(f"expected frames per second in (0, {MAX_FPS:g}], "
                                         f"not {text!r}")
    return value


def _add_output_options(parser) -> None:
    group = parser.add_argument_group("output")
    group.add_argument("--frames", type=_frame_range, metavar="A:B",
                       help="write only frames A to B (0-based, inclusive; A: or :B for the "
                            "rest of the clip); checked against the clip")
    group.add_argument("--fps", type=_fps, metavar="N",
                       help="resample to N frames per second (slerp per joint, linear for "
                            "translations); default: the motion's own rate")
    group.add_argument("--rotation-only", action="store_true",
                       help="BVH: rotation channels only on every joint but the root (many "
                            "DCC importers expect that); default: each joint's own channels")


def _write_output(args, motion, character):
    """Select frames, resample and write ``motion`` as the output options say; returns what
    was written."""
    from motion_composer.engine.formats import write_motion
    from motion_composer.engine.motion import export_selection
    motion = export_selection(motion, args.frames, args.fps)
    write_motion(motion, args.output, character,
                 channels="rotation" if args.rotation_only else "all")
    return motion


def _settings_inputs(args) -> tuple:
    """The settings files a run reads, as ``(what, path)`` for the output checks."""
    return tuple((f"the {flag} file", path) for flag, path in (
        ("--profile", args.profile), ("--pose-offsets", args.pose_offsets),
        ("--chain-settings", args.chain_settings)) if path)


def _profile(args):
    """The ``--profile`` file's profile, or the defaults."""
    from motion_composer.engine.project import Profile, read_profile
    return read_profile(args.profile) if args.profile else Profile()


def bind_options_from_args(args, base, target_skeleton=None):
    """``base`` (the profile's :class:`~engine.conversion.BindOptions`, or the defaults) with
    the binding flags given (``--reference``, ``--target-reference``, ``--keep-target-pose``,
    ``--distribute``, ``--flat-feet``), then the ``--pose-offsets`` file's offsets (by joint,
    replacing the profile's for those joints; checked against ``target_skeleton`` when given)
    and the ``--chain-settings`` file's settings (by chain, over the profile's for the
    settings it gives)."""
    import dataclasses

    from motion_composer.engine.project import (SettingsFileError, read_chain_settings,
                                                read_pose_offsets)

    flags = {"performer_reference": "reference", "target_reference": "target_reference",
             "distribute": "distribute",                 # batch has none of these
             "flat_feet": "flat_feet"}
    changes = {k: getattr(args, flag, None) for k, flag in flags.items()}
    changes = {k: v for k, v in changes.items() if v is not None}
    if getattr(args, "keep_target_pose", False):
        changes["rest_alignment"] = False
    options = dataclasses.replace(base, **changes)
    if args.pose_offsets:
        for joint, quat in read_pose_offsets(args.pose_offsets).items():
            if target_skeleton is not None and joint not in target_skeleton.index:
                raise SettingsFileError(f"{joint!r} is not a joint of the target skeleton",
                                        args.pose_offsets, joint)
            options = options.with_offset(joint, tuple(quat))
    if args.chain_settings:
        for name, settings in read_chain_settings(args.chain_settings, options).items():
            options = options.with_chain(name, settings)
    return options


def cmd_retarget(args) -> int:
    import time

    from motion_composer.engine.formats import (output_format, read_character, read_motion,
                                                read_performer)
    from motion_composer.engine.correction.constraints import constraints_from_json
    from motion_composer.engine.conversion.correspondence import Correspondence
    from motion_composer.engine.errors import MotionComposerError
    from motion_composer.engine.fileio import atomic_write, check_outputs, read_regular_file
    from motion_composer.engine.conversion import RootOptions
    from motion_composer.engine.project import Project, Source
    from motion_composer.engine.scene import Scene

    started = time.perf_counter()
    # an output that is an input, a folder or a device, or an unwritable suffix, fails
    # before any work
    check_outputs((("-o", args.output), ("--save-map", args.save_map),
                   ("--save-project", args.save_project), ("--save-profile", args.save_profile),
                   ("--report", args.report)),
                  (("the performer", args.performer), ("the target", args.target),
                   ("the --map file", args.map), ("the --constraints file", args.constraints),
                   *_settings_inputs(args)))
    output_format(args.output)
    profile = _profile(args)
    ik_options = ik_options_from_args(args, profile.ik_options)
    performer_options = side_options(args, "performer")
    if args.take is not None:
        from motion_composer.engine.formats import sniff
        if sniff(args.performer).read_take is None:
            raise MotionComposerError(f"{args.performer}: --take applies to FBX files (a "
                                      f"{sniff(args.performer).name} file has no takes)")
        performer_options["take"] = args.take
    target_options = side_options(args, "target")
    performer = read_performer(args.performer, **performer_options)
    _warn(performer, args.performer, "--performer-")
    if args.frames:
        performer.excerpt(*args.frames)              # a range outside the clip fails first
    # a glTF's or FBX's bind pose is the target (its up axis may be given: a file written
    # with another axis up than it says)
    character = read_character(args.target, up_axis=target_options.get("up_axis"))
    other = {k: v for k, v in target_options.items() if k != "up_axis"}
    if character is not None and other:
        raise MotionComposerError(f"{args.target}: {_side_flags(other, 'target')} apply to "
                                  "BVH files only; glTF is metres by definition, FBX states "
                                  "its units")
    target = (character.rest_motion() if character is not None else
              read_motion(args.target, **target_options))
    _warn(target, args.target, "--target-")
    if args.map:
        correspondence = Correspondence.load(args.map)
        correspondence.validate(target.skeleton, performer.skeleton, path=args.map)
    elif args.profile and len(profile.correspondence):
        correspondence = profile.correspondence
        correspondence.validate(target.skeleton, performer.skeleton, path=args.profile)
    else:
        from motion_composer.engine.conversion.automap import automap
        correspondence = automap(target.skeleton, performer.skeleton)
    constraints = ()
    if args.constraints:
        try:
            text = read_regular_file(args.constraints).decode("utf-8")
        except OSError as exc:
            raise MotionComposerError(f"{args.constraints}: cannot be read: "
                                      f"{exc.strerror or exc}") from None
        except UnicodeDecodeError as exc:
            raise MotionComposerError(f"{args.constraints}: not a constraints file: byte "
                                      f"{exc.start} is not UTF-8 text") from None
        constraints = tuple(constraints_from_json(text, args.constraints))
    project = Project(
        performer=Source(os.path.abspath(args.performer), **performer_options),
        target=Source(os.path.abspath(args.target), **target_options),
        correspondence=correspondence,
        bind_options=bind_options_from_args(args, profile.bind_options, target.skeleton),
        root=RootOptions(mode=args.root or profile.root.mode,
                         scale=tuple(args.root_scale) if args.root_scale else profile.root.scale),
        constraints=constraints, auto_contacts=args.auto_contacts or profile.auto_contacts,
        contact_options=profile.contact_options, floor=args.floor, ik_options=ik_options)
    result = Scene(project, performer, target).solve(regenerate=True)
    for line in result.report["warnings"]:
        _warning(line)
    written = _write_output(args, result.motion, character)  # mesh and skin when it has
    if args.save_map:
        correspondence.save(args.save_map)
    if args.save_profile:
        from motion_composer.engine.project import profile_of, save_profile
        save_profile(args.save_profile, profile_of(result.scene.project))
    if args.save_project:
        # the session as a project, with every constraint enforced (the user's and the
        # automatic ones) and the IK correction as displacement-map keys
        from motion_composer.engine.project import embed_sources, save_project
        saved = result.scene.project
        save_project(embed_sources(saved) if args.embed_sources else saved, args.save_project)
    elapsed = time.perf_counter() - started
    if args.report:
        report = dict(result.report, output=str(args.output), total_s=elapsed)
        atomic_write(args.report, json.dumps(report, indent=2, allow_nan=False) + "\n")
    note = ""
    if result.correction is not None:
        keys = result.report["keys"]
        note = (f", {len(result.constraints)} constraints (largest residual "
                f"{_residual_text(largest_residuals(result.report['constraints']), 2)}), "
                f"{keys['count']} keys fitted to the {keys['fitted_to']} (at most "
                f"{keys['largest_distance_from_dense_m'] * 1000:.1f} mm from the dense solve)")
        if keys.get("why_dense_curves"):
            note += f" because {keys['why_dense_curves']}"
        detection = result.report.get("contact_detection") or {}
        if detection.get("smoothed"):
            note += (f", contacts found on smoothed foot paths (a noisy capture: "
                     f"{detection['noise_mm']:.1f} mm a frame)")
        floor = result.report["floor"]
        if floor["lift_m"]:
            note += (f", standing on the floor at {floor['height_m']:.3f} m (the conversion "
                     f"{'raised' if floor['lift_m'] > 0 else 'lowered'} "
                     f"{abs(floor['lift_m']) * 1000:.0f} mm onto it)")
    print(f"wrote {args.output}: {written.num_frames} frames at "
          f"{written.fps:.6g} fps onto {written.skeleton.num_joints} joints "
          f"({len(correspondence)} mapped){note} in {elapsed:.2f} s")
    return 0


def cmd_export(args) -> int:
    """``export P.mcp -o OUT.bvh``: evaluate a saved project headless and write its motion
    (``OUT.glb``/``OUT.gltf``: with the target character's mesh and skin, when it has them)."""
    import time

    from motion_composer.engine.fileio import check_outputs
    from motion_composer.engine.formats import output_format

    started = time.perf_counter()
    outputs = (("-o", args.output),)
    check_outputs(outputs, (("the project", args.project),))    # all before any work
    fmt = output_format(args.output)
    scene = _open_with_overrides(args)
    check_outputs(outputs, (("the project's performer", scene.project.performer.path),
                            ("the project's target", scene.project.target.path)))
    if args.solve:
        scene = scene.replace(ik_options=ik_options_from_args(args, scene.ik_options))
        scene = scene.solve().scene
    scene.check()
    motion = _write_output(args, scene.motion, scene.character if fmt.mesh else None)
    print(f"wrote {args.output}: {motion.num_frames} frames at {motion.fps:.6g} fps onto "
          f"{motion.skeleton.num_joints} joints ({len(scene.constraints)} constraints, "
          f"{len(scene.displacement)} displacement curves) in "
          f"{time.perf_counter() - started:.2f} s")
    return 0


def _open_with_overrides(args):
    """The scene of ``args.project``, its sources read with the project's reader settings
    except where ``--performer-*``/``--target-*`` give others (for this run; the project file
    is not changed)."""
    import dataclasses

    from motion_composer.engine.project import open_project
    from motion_composer.engine.scene import Scene

    overrides = {side: side_options(args, side) for side in SIDES}
    if not any(overrides.values()):
        opened = open_project(args.project)
        scene = Scene(opened.project, opened.performer, opened.target)
    else:
        from motion_composer.engine.project import load_project
        project = load_project(args.project, check_sources=False)
        project = project.replace(**{side: dataclasses.replace(getattr(project, side),
                                                               **options)
                                     for side, options in overrides.items() if options})
        scene = Scene.from_project(project, path=args.project)
    for side in SIDES:
        source = getattr(scene.project, side)
        _warn(getattr(scene, side), source.path or f"the embedded {side}", f"--{side}-")
    return scene


def cmd_batch(args) -> int:
    """``batch PROJECT CLIP... -o DIR``: one project's rules over many clips, in parallel."""
    import dataclasses
    import time

    from motion_composer.engine.batch import check_batch_outputs, recipe_from_project, run_batch
    from motion_composer.engine.fileio import check_outputs
    from motion_composer.engine.project import load_project

    started = time.perf_counter()
    project = load_project(args.project, check_sources=False)
    if args.profile:
        from motion_composer.engine.project import apply_profile, read_profile
        project = apply_profile(project, read_profile(args.profile))
    target_skeleton = None
    if args.pose_offsets and project.target.path is not None:
        from motion_composer.engine.formats import read_motion
        target_skeleton = read_motion(project.target.path, **{
            **project.target.reader_options(), **side_options(args, "target")}).skeleton
    project = project.replace(bind_options=bind_options_from_args(
        args, project.bind_options, target_skeleton))
    recipe = recipe_from_project(project, suffix=args.suffix)
    performer_reader = side_options(args, "performer")
    if args.take is not None:
        performer_reader["take"] = args.take
    recipe = dataclasses.replace(recipe, performer_reader=performer_reader,
                                 target_reader={**recipe.target_reader,
                                                **side_options(args, "target")})
    if args.any_skeleton:
        recipe = type(recipe)(**{**recipe.__dict__, "pairs": {}})
    ik = ik_options_from_args(args, project.ik_options)
    recipe = type(recipe)(**{**recipe.__dict__, "ik": dataclasses.asdict(ik)})
    inputs = (("the project", args.project), ("the target", recipe.target_path),
              *_settings_inputs(args), *((f"the clip {clip}", clip) for clip in args.clips))
    check_outputs((("--summary", args.summary),), inputs)
    check_batch_outputs(recipe, args.clips, args.output, inputs[:1])
    width = len(str(len(args.clips)))

    def progress(done, total, summary):
        bar = "#" * int(30 * done / total)
        state = ("written" if summary["status"] == "written" else
                 f"FAILED: {summary['reason']}")
        for doubt in summary.get("warnings", ()):
            print(f"motion-composer: warning: {doubt}", file=sys.stderr)
        print(f"[{bar:<30}] {done:>{width}}/{total} {Path(summary['clip']).name}: {state}",
              file=sys.stderr, flush=True)

    summaries = run_batch(recipe, args.clips, args.output, workers=args.workers,
                          scheduler=args.scheduler, progress=progress)
    written = [s for s in summaries if s["status"] == "written"]
    print(f"{len(written)} of {len(summaries)} clips written to {args.output} in "
          f"{time.perf_counter() - started:.1f} s")
    for s in summaries:
        if s["status"] == "written":
            drift = s.get("contact_drift") or {}
            largest = {"m": s["max_residual_m"], "rad": s.get("max_residual_rad")}
            extra = (f", contact drift {drift['direct_mean_m'] * 1000:.1f} -> "
                     f"{drift['corrected_mean_m'] * 1000:.2f} mm" if drift else "")
            print(f"  written  {Path(s['clip']).name} -> {s['output']} ({s['frames']} frames, "
                  f"largest residual {_residual_text(largest, 3)}{extra})")
        else:
            print(f"  failed   {Path(s['clip']).name}: {s['reason']}")
    if args.summary:
        from motion_composer.engine.fileio import atomic_write
        atomic_write(args.summary, json.dumps(summaries, indent=2, allow_nan=False) + "\n")
    bugs = [s for s in summaries
            if s["reason"].startswith(("unexpected ", "the worker process failed"))]
    for s in bugs:                      # a bug in a clip never stops the rest, but says so
        print(f"{s['clip']}: {s.get('traceback', '')}{s['reason']}", file=sys.stderr)
    if bugs:
        print(f"motion-composer: internal error (a bug, exit 3) in {len(bugs)} of "
              f"{len(summaries)} clips: please report it with the traceback above",
              file=sys.stderr)
        return EXIT_BUG
    return 0 if len(written) == len(summaries) else 1


def _add_window_options(parser) -> None:
    """The window's flags (``motion-composer [PROJECT] ...``), on ``parser`` or a group."""
    parser.add_argument("--demo", action="store_true", help="open the bundled demo project")
    parser.add_argument("--frame", type=int, metavar="N", help="go to frame N")
    parser.add_argument("--screenshot", metavar="PNG",
                        help="save a picture of the window once drawn, then quit; no dialogs: a "
                             "project that does not load is one line on stderr and exit 2")
    parser.add_argument("--self-test", action="store_true",
                        help="start the window, load the demo, step through frames, check "
                             "that the viewport draws, load the bundled skinned character, "
                             "then quit; prints 'self-test: ok (...)' (exit 0) or "
                             "'self-test: FAILED: reason' (exit 1)")


def _add_binding_options(parser, batch: bool = False) -> None:
    """The binding flags and the retarget-pose files of ``retarget`` and ``batch``: given,
    each overrides the ``--profile``'s (or, for batch, the project's) setting."""
    group = parser.add_argument_group(
        "binding and retarget pose (given flags override the --profile's"
        + (" and the project's)" if batch else ")"))
    group.add_argument("--profile", metavar="P.mcprofile",
                       help="a retarget profile (map, binding, pose offsets, chain settings, "
                            "root, IK and contact settings) to apply"
                            + (" to every clip" if batch else ""))
    group.add_argument("--pose-offsets", metavar="FILE.json",
                       help='pose offsets: {"LeftArm": [x, y, z], ...}, degrees about each '
                            "joint's binding-frame axes (intrinsic XYZ); by joint over the "
                            "profile's")
    group.add_argument("--chain-settings", metavar="FILE.json",
                       help='per-chain settings: {"arm_l": {"weight": 0.5, "twist": false, '
                            '"distribute": "first", "ik_blend": 1.0}, ...} (chains spine, '
                            "neck, arm_l/r, leg_l/r, fingers_l/r); by setting over the "
                            "profile's")
    group.add_argument("--flat-feet", action="store_true", default=None,
                       help="stand the character's feet as flat as its own where the "
                            "performer's stand flat, instead of along the performer's feet "
                            "(feet of other shapes stand flat through every stance)")
    if batch:
        return
    group.add_argument("--reference", type=_reference,
                       help="the performer's reference pose: rest (zero rotations), frame:N, "
                            "or auto (rest if it stands upright, else frame 0; the default)")
    group.add_argument("--target-reference", type=_reference,
                       help="the target's initial posture: rest, frame:N or auto (default)")
    group.add_argument("--keep-target-pose", action="store_true",
                       help="keep the target's own initial posture instead of turning its "
                            "bones onto the performer's (rest-posture alignment)")
    group.add_argument("--distribute", choices=("even", "first"),
                       help="how a target chain with unmapped inner joints turns: spread over "
                            "the chain (default) or all at its first joint")


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(
        prog="motion-composer",
        usage="%(prog)s [PROJECT.mcp] [--demo] [--frame N] [--screenshot PNG] [--self-test]\n"
              "       %(prog)s COMMAND [options]   (%(prog)s COMMAND --help for each)",
        description="Retarget captured motion onto any character and correct it with IK. "
                    "Without a COMMAND: open the composer window (on PROJECT.mcp if given).")
    _add_window_options(parser.add_argument_group("the window (without a COMMAND)"))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", prog="motion-composer")
    info = sub.add_parser("info", help="describe a motion file",
                          description="Describe a BVH file, a glTF character (.glb, .gltf) or "
                                      "an FBX file: joint tree, frames, frame rate, duration, "
                                      "units, up axis, stature, channel layout; for glTF and "
                                      "FBX also skins, meshes and animations or takes (the "
                                      "first animation is the motion shown, or the bind pose "
                                      "when there is none).")
    info.add_argument("file", help="a BVH file, a glTF character (.glb, .gltf, .vrm) or an FBX "
                                   "file (.fbx); the content says which, not the name")
    info.add_argument("--json", action="store_true", help="print JSON for machines")
    info.add_argument("--take", metavar="NAME", help="FBX: the take shown (default: the first)")
    _add_reader_options(info)
    info.set_defaults(func=cmd_info)

    rt = sub.add_parser("retarget", help="convert a capture onto another character",
                        description="Convert a performer's motion onto a target character "
                                    "through an intermediate skeleton; with the correction "
                                    "options (constraints, automatic contacts, floor) then "
                                    "correct it with whole-body inverse kinematics.")
    rt.add_argument("performer", help="the capture (.bvh, or an FBX file's take)")
    rt.add_argument("--take", metavar="NAME",
                    help="the performer's take when it is an FBX file (default: the first "
                         "that moves a joint; info lists them)")
    rt.add_argument("--target", required=True,
                    help="the character: a .bvh whose rest pose or first frame gives it, or a "
                         "glTF or FBX character (.glb/.gltf/.fbx, its bind pose)")
    rt.add_argument("-o", "--output", required=True,
                    help="the file to write: .bvh, or .glb/.gltf (with the character's mesh "
                         "and skin when the target is glTF)")
    rt.add_argument("--map", help="a mapping file (JSON with a \"pairs\" object); "
                                  "automatic mapping when not given")
    rt.add_argument("--save-map", help="write the mapping actually used to this JSON file")
    _add_binding_options(rt)
    rt.add_argument("--root", choices=("scaled", "absolute", "in-place"),
                    help="root translation: scaled by the ratio of hip heights (default), as "
                         "captured, or with the horizontal displacement removed")
    rt.add_argument("--root-scale", type=float, nargs=2, metavar=("H", "V"),
                    help="horizontal and vertical root scale, overriding the hip-height ratio")
    fix = rt.add_argument_group("correction (inverse kinematics)")
    fix.add_argument("--constraints", metavar="FILE.json",
                     help='Cartesian constraints to enforce (JSON: {"constraints": [...]})')
    fix.add_argument("--auto-contacts", action="store_true",
                     help="detect the performer's foot contacts and pin the target's feet")
    fix.add_argument("--floor", type=float, metavar="HEIGHT",
                     help="stand the character on a floor at HEIGHT metres: the conversion "
                          "is raised or lowered onto it (not with --root absolute), and the "
                          "feet and toes are kept on or above it (also the floor automatic "
                          "contacts stand on)")
    fix.add_argument("--report", metavar="REPORT.json",
                     help="write residuals per constraint, contact drift and timings")
    proj = rt.add_argument_group("project")
    proj.add_argument("--save-project", metavar="P.mcp",
                      help="also save the session as a project file (sources, map, options, "
                           "constraints and the IK correction), to reopen or export later")
    proj.add_argument("--embed-sources", action="store_true",
                      help="embed both clips in the project so that it can be sent on its own")
    proj.add_argument("--save-profile", metavar="P.mcprofile",
                      help="also save the retarget profile used (map, binding with pose "
                           "offsets and chain settings, root, IK and contact settings), for "
                           "--profile on other clips")
    _add_side_options(rt, "detected when not given; --save-project stores them")
    _add_ik_options(rt, "the solver's defaults; --save-project stores them")
    _add_output_options(rt)
    rt.set_defaults(func=cmd_retarget)

    bt = sub.add_parser("batch", help="apply one project's rules to many clips",
                        description="Retarget many clips with one project's mapping, binding, "
                                    "root options, automatic contacts and floor, in parallel "
                                    "processes (or on a Dask cluster). A failing clip never "
                                    "stops the rest; the exit code is 1 if any failed (3 if one "
                                    "failed by a bug, with its traceback).")
    bt.add_argument("project", help="a .mcp project whose rules to apply")
    bt.add_argument("clips", nargs="+", help="the clips (.bvh, or FBX files' takes)")
    bt.add_argument("--take", metavar="NAME",
                    help="the take of every FBX clip (default: each file's first)")
    bt.add_argument("-o", "--output", required=True,
                    help="folder for the results, created if missing; a run locks it until it "
                         "ends, so a second run into the same folder is refused at once "
                         "(one file per clip: <clip stem><suffix>.bvh, existing files of "
                         "those names are replaced)")
    bt.add_argument("--workers", type=int, help="parallel processes (default: CPUs)")
    bt.add_argument("--scheduler", metavar="ADDRESS",
                    help="run on a Dask cluster (e.g. tcp://10.0.0.5:8786); needs the batch "
                         "extra: pip install 'motion-composer[batch]'")
    bt.add_argument("--suffix", default="", help="added to each output file's name")
    bt.add_argument("--any-skeleton", action="store_true",
                    help="map each clip automatically instead of with the project's map "
                         "(clips from other skeletons)")
    bt.add_argument("--summary", metavar="FILE.json", help="write the per-clip summary")
    _add_binding_options(bt, batch=True)
    _add_side_options(bt, "detected per clip when not given; the target's: the project's")
    _add_ik_options(bt, "the project's")
    bt.set_defaults(func=cmd_batch)

    ex = sub.add_parser("export", help="write the motion of a saved project",
                        description="Load a project (.mcp), evaluate it headless (the direct "
                                    "conversion plus the saved correction) and write the "
                                    "result.")
    ex.add_argument("project", help="the project (.mcp)")
    ex.add_argument("-o", "--output", required=True,
                    help="the file to write: .bvh, or .glb/.gltf (with the target character's "
                         "mesh and skin when it has them)")
    ex.add_argument("--solve", action="store_true",
                    help="solve the project's constraints with IK again instead of using the "
                         "saved correction (hand edits to the curves are then replaced)")
    _add_side_options(ex, "the project's when not given")
    _add_ik_options(ex, "the project's; they apply with --solve")
    _add_output_options(ex)
    ex.set_defaults(func=cmd_export)
    return parser


def _gui(argv: list[str]) -> int:
    """``motion-composer [PROJECT] [--demo] [--frame N] [--screenshot PNG] [--self-test]``:
    the window."""
    parser = ArgumentParser(prog="motion-composer",
                            description="Open the composer window (or run a command: "
                                        "motion-composer info|retarget|export ...).")
    parser.add_argument("project", nargs="?", help="a .mcp project to open")
    _add_window_options(parser)
    args = parser.parse_args(argv)
    from motion_composer.app.gui.main import run
    if args.self_test:
        return run(self_test=True)
    return run(args.project, demo=args.demo, screenshot=args.screenshot, frame=args.frame)


def _residual_text(largest: dict, digits: int) -> str:
    """``0.00 mm`` (metric constraints), with ``, 0.74 deg`` where there are angular ones."""
    text = f"{largest['m'] * 1000:.{digits}f} mm"
    if largest.get("rad") is not None:
        text += f", {math.degrees(largest['rad']):.{digits}f} deg"
    return text


def main(argv: list[str] | None = None) -> int:
    """Run the command (or open the window) ``argv`` names; the exit code.

    A :class:`UsageError` prints its line and raises ``SystemExit(2)``, as argparse does; any
    other error the user can cause prints its line and returns 2; an unexpected exception
    prints its traceback and returns 3.
    """
    import sys as _sys
    from motion_composer.app.runtime import tune_allocator
    tune_allocator()
    argv = list(_sys.argv[1:] if argv is None else argv)
    _WARNINGS.clear()
    try:
        code = _run(argv)
        _print_warnings()
        return code
    except UsageError as exc:
        _print_error(exc)
        raise SystemExit(EXIT_USER_ERROR) from None
    except MotionComposerError as exc:
        _print_error(exc)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("motion-composer: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except Exception:                     # noqa: BLE001 - a bug: say so, with its traceback
        _print_warnings()
        _print_bug()
        return EXIT_BUG


def _run(argv: list[str]) -> int:
    parser = build_parser()
    commands = set(parser._subparsers._group_actions[0].choices)   # noqa: SLF001
    if not argv or (argv[0] not in commands and argv[0] not in ("-h", "--help")):
        return _gui(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
