"""The project file's text: a deterministic JSON encoder (:func:`project_to_json`) and a
validating decoder (:func:`project_from_json`) that names the field of any bad value."""
from __future__ import annotations

import bisect
import dataclasses
import itertools
import json
import math
import operator
import os
import re

import numpy as np

from .. import limits
from ..conversion.binding import BindOptions
from ..conversion.chains import CHAINS, ChainSettings, ChainSettingsError
from ..conversion.converter import RootOptions
from ..conversion.correspondence import Correspondence
from ..correction.constraints import KINDS, Constraint, ConstraintError
from ..correction.contacts import ContactOptions
from ..correction.displacement import (INTERPOLATIONS, ROOT, ROTATION_CHANNELS, TANGENTS,
                                       TRANSLATION_CHANNELS, Curve, DisplacementMap, Layer,
                                       stored_slopes)
from ..correction.ik import IKOptions
from ..errors import IKOptionsError, MotionComposerError
from ..units import AXES, UNITS
from .migrations import migrate
from .model import (FORMAT, ROLES, SKELETONS, SOLVED_LAYER, VERSION, Project, ProjectError,
                    Source, ViewerState, _Invalid, _kind, _show)

__all__ = ["project_to_json", "project_from_json", "ik_dict", "binding_dict", "IK_FIELDS",
           "CHAIN_FIELDS"]

#: the IK settings a project stores (``scale`` is taken from the character on each run)
IK_FIELDS = tuple(f.name for f in dataclasses.fields(IKOptions) if f.name != "scale")


def _folder(path) -> str:
    """The folder relative source paths start from: the project file's own, also when it is
    opened or saved through a symbolic link (the file is where the link points)."""
    path = os.fspath(path)
    return os.path.dirname(os.path.abspath(os.path.realpath(path) if os.path.islink(path)
                                           else path))


# --------------------------------------------------------------------------- writing
def project_to_json(project: Project, path=None) -> str:
    """The project file's text. ``path`` (where it will be written) makes source paths
    relative to its folder; without it they are written as held."""
    folder = _folder(path) if path is not None else None
    try:
        return _encode(_project_dict(project, folder), 0, "") + "\n"
    except _Invalid as exc:
        raise ProjectError(f"cannot be saved: {exc.problem}", path, exc.field) from None


def _project_dict(p: Project, folder) -> dict:
    corr = {"pairs": dict(p.correspondence.pairs)}
    if p.correspondence.notes:
        corr["notes"] = dict(sorted(p.correspondence.notes.items()))
    b = p.bind_options
    v = p.viewer
    out = {
        "format": FORMAT,
        "version": VERSION,
        "performer": _source_dict(p.performer, folder, "performer"),
        "target": _source_dict(p.target, folder, "target"),
        "correspondence": corr,
        "binding": binding_dict(b),
        "root": {"mode": p.root.mode,
                 "scale": list(p.root.scale) if p.root.scale is not None else None},
        "contacts": {"auto": bool(p.auto_contacts),
                     "options": {f.name: float(getattr(p.contact_options, f.name))
                                 for f in dataclasses.fields(ContactOptions)}},
        "floor": float(p.floor) if p.floor is not None else None,
        "stand_on_floor": bool(p.stand_on_floor),
        "ik": ik_dict(p.ik_options),
        "viewer": {"current_frame": int(v.current_frame),
                   "play_range": [int(x) for x in v.play_range] if v.play_range else None,
                   "camera": dict(sorted(v.camera.items())),
                   "shown": list(v.shown),
                   "options": dict(sorted(v.options.items()))},
        "constraints": [c.to_dict() for c in p.constraints],
        "layers": [{"name": SOLVED_LAYER, "kind": "solved",
                    **_displacement_dict(p.displacement)}]
                  + [{"name": layer.name, "kind": "animator", "weight": float(layer.weight),
                      "mute": bool(layer.mute), **_displacement_dict(layer.displacement)}
                     for layer in p.layers],
    }
    embedded = {role: getattr(p, role).embedded for role in ROLES
                if getattr(p, role).embedded is not None}
    if embedded:
        out["embedded"] = embedded
    return out


def binding_dict(b: BindOptions) -> dict:
    """The ``"binding"`` object; ``pose_offsets`` and ``chains`` only when set (files without
    them mean none)."""
    out = {"performer_reference": _reference_out(b.performer_reference),
           "target_reference": _reference_out(b.target_reference),
           "rest_alignment": bool(b.rest_alignment), "distribute": b.distribute}
    if b.flat_feet:                      # files without it were solved without it
        out["flat_feet"] = True
    if b.pose_offsets:
        out["pose_offsets"] = {joint: [float(x) for x in q] for joint, q in b.pose_offsets}
    if b.chains:
        out["chains"] = {name: {key: getattr(settings, key) for key in CHAIN_FIELDS}
                         for name, settings in b.chains}
    return out


def ik_dict(options: IKOptions) -> dict:
    """The ``"ik"`` object: every setting but ``scale`` (a per-run value), in field order;
    ``joint_limits`` as ``[[joint index, angle], ...]``."""
    return {name: ([[j, a] for j, a in options.joint_limits] if name == "joint_limits"
                   else getattr(options, name)) for name in IK_FIELDS}


def _displacement_dict(displacement: DisplacementMap) -> dict:
    """``DisplacementMap.to_dict`` with one interpolation (or tangent) name instead of a
    list where every key has the same (the IK's keys are all smooth); the numbers stay
    arrays until :func:`_encode` writes each."""
    channels = []
    for item in displacement.to_dict(arrays=True)["channels"]:
        for name in ("interpolation", "tangents"):
            kinds = item.get(name)
            if kinds and kinds.count(kinds[0]) == len(kinds):
                item = dict(item, **{name: kinds[0]})
        channels.append(item)
    return {"channels": channels}


def _reference_out(ref):
    return ref if isinstance(ref, str) else int(ref)


def _source_dict(source: Source, folder, role: str) -> dict:
    if source.path is None and source.embedded is None:
        raise _Invalid(role, "needs a path to a clip or the clip embedded")
    path = source.path
    if path is not None and folder is not None:
        absolute = os.path.abspath(path)
        try:
            path = os.path.relpath(absolute, folder).replace(os.sep, "/")
        except ValueError:                    # another drive (Windows): keep it absolute
            path = absolute
    mode = source.position_mode
    out = {"path": path, "units": source.units,
           "scale": float(source.scale) if source.scale is not None else None,
           "up_axis": source.up_axis,
           "position_mode": dict(mode) if isinstance(mode, dict) else mode}
    if source.take is not None:                  # optional: absent in files without one
        out["take"] = source.take
    return out


_LINE = 100
#: what a file cut inside a value ends with: part of a number, a word or a string
_PARTIAL_TOKEN = re.compile(r'[\w.+\-]*|"(?:[^"\\\n]|\\.)*\\?')


def _encode(value, depth: int, where: str, lead: int = 0) -> str:
    """Deterministic, readable JSON: objects one key per line in the given order, lists of
    numbers packed on lines of at most 100 characters, floats as their shortest repr.
    ``lead``: the column where the value starts."""
    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return _scalar(value, where)
    pad = "  " * (depth + 1)
    end = "  " * depth
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = []
        for k, v in value.items():
            if not isinstance(k, str):
                raise _Invalid(where, f"the key {k!r} is not a string")
            key = f"{pad}{_scalar(k, where)}: "
            items.append(key + _encode(v, depth + 1, _sub(where, k), len(key)))
        return "{\n" + ",\n".join(items) + "\n" + end + "}"
    if isinstance(value, (list, tuple, np.ndarray)):
        value = value.tolist() if isinstance(value, np.ndarray) else value
        if not value:
            return "[]"
        numbers = set(map(type, value)) <= _NUMBERS                    # the fast common case
        if numbers:
            if not all(map(math.isfinite, value)):
                i = next(i for i, v in enumerate(value) if not math.isfinite(v))
                raise _Invalid(f"{where}[{i}]", f"{value[i]!r} is not a finite number")
            parts = list(map(repr, value))
        else:
            parts = [_encode(v, depth + 1, f"{where}[{i}]", len(pad))
                     for i, v in enumerate(value)]
        flat = numbers or all("\n" not in s for s in parts)
        one_line = "[" + ", ".join(parts) + "]"
        if flat and lead + len(one_line) + 1 <= _LINE:
            return one_line
        if numbers or (flat and all(not isinstance(v, (dict, list, tuple)) for v in value)):
            lines = _packed(parts, _LINE - len(pad) - 1)
            return "[\n" + pad + (",\n" + pad).join(lines) + "\n" + end + "]"
        return "[\n" + ",\n".join(pad + s for s in parts) + "\n" + end + "]"
    raise _Invalid(where, f"{type(value).__name__} values cannot be saved")


#: the types of a list written by the fast path (``bool`` is not one: it is written as a word)
_NUMBERS = frozenset((int, float))


def _packed(parts: list, width: int) -> list:
    """``parts`` joined by ``", "`` into lines of at most ``width`` characters, each as full
    as it can be (a part longer than ``width`` has a line of its own). A line is found by a
    binary search on the running lengths, not by adding the parts one at a time: a solve's
    keys are 1.2 million numbers at 40,000 frames (frames, values, slopes), and the
    per-number loop this replaces was about a quarter of a save. The search looks only as
    far as a line can reach (a part and its ", " are at least 3 characters), so that its
    cost does not grow with the list."""
    # where each part's ", " ends, from the line's start: the lengths + 2, summed in C
    ends = [0, *itertools.accumulate(map(operator.add, map(len, parts), itertools.repeat(2)))]
    reach = max(width, 0) // 3 + 2
    lines, i = [], 0
    while i < len(parts):
        j = bisect.bisect_right(ends, ends[i] + width + 2, i, min(i + reach, len(ends)))
        j = max(j - 1, i + 1)
        lines.append(", ".join(parts[i:j]))
        i = j
    return lines


def _scalar(value, where: str) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        raise _Invalid(where, f"{value!r} is not a finite number")
    if isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)
        try:
            text.encode("utf-8")
        except UnicodeEncodeError:            # a lone surrogate: escape it
            text = json.dumps(value)
        return text
    return json.dumps(value)


# --------------------------------------------------------------------------- reading
def project_from_json(text: str, path=None) -> Project:
    """A project from a file's text; ``path`` (the file) resolves relative source paths and
    is named in errors. Sources are not read here (see :func:`open_project`)."""
    folder = _folder(path) if path is not None else None
    try:
        data = _parse(text)
        data = migrate(data)
        return _build(data, folder)
    except _Invalid as exc:
        raise ProjectError(exc.problem, path, exc.field) from None


def _parse(text: str):
    bad = []                                  # NaN, Infinity, too large: found after parsing

    def constant(name):
        bad.append(_NotANumber(f"{name} is not a number a project may hold"))
        return bad[-1]

    def number(s):
        value = float(s)
        if not math.isfinite(value):
            bad.append(_NotANumber(f"the number {s[:20]} is too large"))
            return bad[-1]
        return value

    def unique(pairs):
        out = {}
        for k, v in pairs:
            if k in out:
                raise _Invalid("", f"the key {k!r} appears twice in one object")
            out[k] = v
        return out

    try:
        data = json.loads(text, parse_constant=constant, parse_float=number,
                          object_pairs_hook=unique)
        if bad:
            _reject_not_a_number(data, "")
        return data
    except json.JSONDecodeError as exc:
        tail = (" (the file ends there: it looks truncated)"
                if _ends_the_text(text, exc.pos) else "")
        raise _Invalid("", f"not valid JSON at line {exc.lineno}, column {exc.colno}: "
                           f"{exc.msg}{tail}") from None
    except RecursionError:
        raise _Invalid("", "not a project: the JSON is nested too deeply") from None
    except ValueError as exc:                 # e.g. an integer with too many digits
        raise _Invalid("", f"not valid JSON: {exc}") from None


class _NotANumber:
    """A value the file holds that no project may (NaN, Infinity, a number too large)."""

    def __init__(self, problem: str):
        self.problem = problem


def _ends_the_text(text: str, pos: int) -> bool:
    """Whether a JSON error at ``pos`` is the end of ``text``, or inside a number, word or
    string cut off there (``1.`` or ``"na`` at the end): the file was truncated."""
    rest = text[pos:].rstrip()
    return not rest or (len(rest) < 64 and _PARTIAL_TOKEN.fullmatch(rest) is not None)


def _reject_not_a_number(value, where: str) -> None:
    """Raise naming the field of the first :class:`_NotANumber` in ``value``."""
    if isinstance(value, _NotANumber):
        raise _Invalid(where, value.problem)
    if isinstance(value, dict):
        for k, v in value.items():
            _reject_not_a_number(v, _sub(where, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _reject_not_a_number(v, f"{where}[{i}]")


_TOP = ("format", "version", "performer", "target", "correspondence", "binding", "root",
        "contacts", "floor", "stand_on_floor", "ik", "viewer", "constraints", "layers", "embedded")


def _build(data: dict, folder) -> Project:
    _obj(data, "", required=("format", "version", "performer", "target", "correspondence"),
         optional=_TOP)
    embedded = _obj(data.get("embedded", {}), "embedded", optional=ROLES)
    for role, text in embedded.items():
        _str(text, f"embedded.{role}")
    sources = {role: _source(data[role], role, folder, embedded.get(role)) for role in ROLES}
    auto_contacts, contact_options = _contacts(data.get("contacts", {}))
    return Project(
        performer=sources["performer"], target=sources["target"],
        correspondence=_correspondence(data["correspondence"]),
        bind_options=_binding(data.get("binding", {})),
        root=_root(data.get("root", {})),
        auto_contacts=auto_contacts, contact_options=contact_options,
        floor=_optional(_num, data.get("floor"), "floor"),
        stand_on_floor=_bool(data.get("stand_on_floor", True), "stand_on_floor"),
        ik_options=_ik(data.get("ik", {})),
        constraints=tuple(_constraint(c, f"constraints[{i}]")
                          for i, c in enumerate(_list(data.get("constraints", []),
                                                      "constraints"))),
        **_layers(data.get("layers", [{"name": SOLVED_LAYER, "kind": "solved"}])),
        viewer=_viewer(data.get("viewer", {})))


def _source(data, where: str, folder, embedded) -> Source:
    d = _obj(data, where, optional=("path", "units", "scale", "up_axis", "position_mode",
                                    "take"))
    path = _optional(_str, d.get("path"), f"{where}.path")
    if path is not None:
        if not path or "\x00" in path:
            raise _Invalid(f"{where}.path", f"expected a file path, not {_show(path)}")
        if folder is not None and not os.path.isabs(path):
            path = os.path.join(folder, path)
        path = os.path.normpath(path)
    units = _optional(_choice, d.get("units"), f"{where}.units", tuple(UNITS))
    scale = _optional(_num, d.get("scale"), f"{where}.scale", positive=True)
    up_axis = _optional(_choice, d.get("up_axis"), f"{where}.up_axis", AXES)
    mode = d.get("position_mode")
    if isinstance(mode, dict):
        mode = {_str(k, f"{where}.position_mode"): _choice(v, _sub(f"{where}.position_mode", k),
                                                          ("absolute", "relative"))
                for k, v in mode.items()}
    elif mode is not None:
        mode = _choice(mode, f"{where}.position_mode", ("absolute", "relative"))
    take = _optional(_str, d.get("take"), f"{where}.take")
    if path is None and embedded is None:
        raise _Invalid(where, "needs the clip's path or the clip embedded in the project")
    return Source(path=path, embedded=embedded, units=units, scale=scale, up_axis=up_axis,
                  position_mode=mode, take=take)


def _correspondence(data) -> Correspondence:
    d = _obj(data, "correspondence", required=("pairs",), optional=("notes",))
    pairs = _obj(d["pairs"], "correspondence.pairs")
    for t, p in pairs.items():
        _str(p, _sub("correspondence.pairs", t))
    notes = _obj(d.get("notes", {}), "correspondence.notes")
    for t, n in notes.items():
        _str(n, _sub("correspondence.notes", t))
    return Correspondence(pairs, notes)


def _reference(value, where: str):
    if value in ("auto", "rest") and isinstance(value, str):
        return value
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    raise _Invalid(where, f"expected \"auto\", \"rest\" or a frame number, not {_show(value)}")


def _binding(data) -> BindOptions:
    keys = [f.name for f in dataclasses.fields(BindOptions)]
    d = _obj(data, "binding", optional=keys)
    default = BindOptions()
    return BindOptions(
        performer_reference=_reference(d.get("performer_reference",
                                             default.performer_reference),
                                       "binding.performer_reference"),
        target_reference=_reference(d.get("target_reference", default.target_reference),
                                    "binding.target_reference"),
        rest_alignment=_bool(d.get("rest_alignment", default.rest_alignment),
                             "binding.rest_alignment"),
        distribute=_choice(d.get("distribute", default.distribute), "binding.distribute",
                           ("even", "first")),
        pose_offsets=_pose_offsets(d.get("pose_offsets", {}), "binding.pose_offsets"),
        chains=_chains(d.get("chains", {}), "binding.chains"),
        flat_feet=_bool(d.get("flat_feet", default.flat_feet), "binding.flat_feet"))


def _pose_offsets(data, where: str) -> tuple:
    """``{joint: [x, y, z, w]}``: unit quaternions in each joint's binding frame."""
    out = []
    for joint, value in _obj(data, where).items():
        at = _sub(where, joint)
        if not joint:
            raise _Invalid(at, "expected a target joint's name, not an empty string")
        q = [_num(x, f"{at}[{i}]") for i, x in enumerate(_list(value, at))]
        if len(q) != 4 or abs(math.sqrt(sum(x * x for x in q)) - 1.0) > 1e-6:
            raise _Invalid(at, f"expected a unit quaternion [x, y, z, w], not {_show(value)}")
        out.append((joint, tuple(q)))
    return tuple(out)


#: a chain's settings in a file, in order
CHAIN_FIELDS = tuple(f.name for f in dataclasses.fields(ChainSettings))


def _chains(data, where: str) -> tuple:
    """``{chain: {"weight", "twist", "distribute", "ik_blend"}}`` (each setting optional)."""
    out = []
    for name, value in _obj(data, where).items():
        at = _sub(where, name)
        if name not in CHAINS:
            raise _Invalid(at, f"unknown chain (expected one of {', '.join(CHAINS)})")
        d = _obj(value, at, optional=CHAIN_FIELDS)
        values = {}
        for key in ("weight", "ik_blend"):
            if key in d:
                values[key] = _num(d[key], f"{at}.{key}")
        if "twist" in d:
            values["twist"] = _bool(d["twist"], f"{at}.twist")
        if d.get("distribute") is not None:
            values["distribute"] = _choice(d["distribute"], f"{at}.distribute",
                                           ("even", "first"))
        try:
            settings = ChainSettings(**values)
        except ChainSettingsError as exc:
            raise _Invalid(f"{at}.{exc.field}", exc.problem) from None
        if name.startswith("fingers") and settings.ik_blend > 0:
            raise _Invalid(f"{at}.ik_blend", "the fingers have no end effector to reach with "
                                             "(expected 0)")
        out.append((name, settings))
    return tuple(out)


def _root(data) -> RootOptions:
    d = _obj(data, "root", optional=("mode", "scale"))
    mode = _choice(d.get("mode", "scaled"), "root.mode", ("scaled", "absolute", "in-place"))
    scale = d.get("scale")
    if scale is not None:
        scale = _list(scale, "root.scale")
        if len(scale) != 2:
            raise _Invalid("root.scale", f"expected [horizontal, vertical], not {_show(scale)}")
        scale = tuple(_num(s, f"root.scale[{i}]") for i, s in enumerate(scale))
    return RootOptions(mode=mode, scale=scale)


def _contacts(data) -> tuple[bool, ContactOptions]:
    d = _obj(data, "contacts", optional=("auto", "options"))
    keys = [f.name for f in dataclasses.fields(ContactOptions)]
    o = _obj(d.get("options", {}), "contacts.options", optional=keys)
    options = ContactOptions(**{k: _num(v, f"contacts.options.{k}", positive=True)
                                for k, v in o.items()})
    return _bool(d.get("auto", False), "contacts.auto"), options


def _ik(data) -> IKOptions:
    d = _obj(data, "ik", optional=IK_FIELDS)
    values = {}
    for key, value in d.items():
        where = f"ik.{key}"
        if key == "max_iterations":
            values[key] = _int(value, where, minimum=0)
        elif key == "joint_limits":
            values[key] = tuple(_joint_limit(item, f"{where}[{i}]")
                                for i, item in enumerate(_list(value, where)))
        else:
            values[key] = _num(value, where)
    try:
        return IKOptions(**values)
    except IKOptionsError as exc:
        raise _Invalid(f"ik.{exc.field}", exc.problem) from None


def _joint_limit(data, where: str) -> tuple[int, float]:
    pair = _list(data, where)
    if len(pair) != 2:
        raise _Invalid(where, f"expected [joint index, angle], not {_show(pair)}")
    return _int(pair[0], f"{where}[0]", minimum=0), _num(pair[1], f"{where}[1]")


_CONSTRAINT_KEYS = ("priority", "weight", "name", "enabled", "auto", "meta")


def _constraint(data, where: str) -> Constraint:
    d = _obj(data, where, required=("joint", "kind", "goal", "range"),
             optional=_CONSTRAINT_KEYS)
    joint = _str(d["joint"], f"{where}.joint")
    if not joint:
        raise _Invalid(f"{where}.joint", "expected a target joint's name, not an empty string")
    _choice(d["kind"], f"{where}.kind", KINDS)
    _obj(d["goal"], f"{where}.goal")
    rng = _list(d["range"], f"{where}.range")
    if len(rng) != 4:
        raise _Invalid(f"{where}.range", f"expected [smooth_in, start, end, smooth_out], not "
                                         f"{_show(rng)}")
    for i, x in enumerate(rng):
        _int(x, f"{where}.range[{i}]", minimum=0)
    if "priority" in d:
        _int(d["priority"], f"{where}.priority", minimum=1)
    if "weight" in d:
        _num(d["weight"], f"{where}.weight", positive=True)
    for key, check in (("name", _str), ("enabled", _bool), ("auto", _bool), ("meta", _obj)):
        if key in d:
            check(d[key], f"{where}.{key}")
    label = f"constraint {(d.get('name') or joint)!r}: "
    try:
        return Constraint.from_dict(d)
    except (ConstraintError, TypeError, ValueError) as exc:
        message = str(exc)
        message = message[len(label):] if message.startswith(label) else message
        sub = getattr(exc, "field", None)          # "goal.point" is reported as the goal
        sub = sub.partition(".")[0] if sub else None
        raise _Invalid(f"{where}.{sub}" if sub else where, message) from None


def _layers(data) -> dict:
    """``displacement`` (the solved layer) and ``layers`` (the animator's) of a project."""
    items = _list(data, "layers")
    solved, animator = None, []
    for i, item in enumerate(items):
        where = f"layers[{i}]"
        d = _obj(item, where, required=("name", "kind"),
                 optional=("name", "kind", "weight", "mute", "channels"))
        kind = _choice(d["kind"], f"{where}.kind", ("solved", "animator"))
        name = _str(d["name"], f"{where}.name")
        curves = _displacement(d, where)
        if kind == "solved":
            if i != 0:
                raise _Invalid(f"{where}.kind", "the solved layer must be the first layer, "
                                                "and there is only one")
            if name != SOLVED_LAYER or "weight" in d or "mute" in d:
                raise _Invalid(where, f"the solved layer is named {SOLVED_LAYER!r} and has "
                                      "no weight or mute")
            solved = curves
            continue
        if name == SOLVED_LAYER or name in [layer.name for layer in animator]:
            raise _Invalid(f"{where}.name", f"a second layer named {name!r}")
        weight = _num(d.get("weight", 1.0), f"{where}.weight")
        try:
            animator.append(Layer(name, curves, weight, _bool(d.get("mute", False),
                                                              f"{where}.mute")))
        except MotionComposerError as exc:
            raise _Invalid(f"{where}.weight", str(exc)) from None
    if solved is None:
        raise _Invalid("layers", f"expected the solved layer first "
                                 f"({{\"name\": \"{SOLVED_LAYER}\", \"kind\": \"solved\", ...}})")
    return {"displacement": solved, "layers": tuple(animator)}


def _displacement(d: dict, parent: str) -> DisplacementMap:
    curves = {}
    for i, item in enumerate(_list(d.get("channels", []), f"{parent}.channels")):
        where = f"{parent}.channels[{i}]"
        c = _obj(item, where, required=("joint", "channel", "frames", "values"),
                 optional=("interpolation", "tangents", "slopes", "slopes_in"))
        joint = _str(c["joint"], f"{where}.joint")
        allowed = TRANSLATION_CHANNELS if joint == ROOT else ROTATION_CHANNELS
        channel = _choice(c["channel"], f"{where}.channel", allowed)
        frames = [_num(x, f"{where}.frames[{k}]")
                  for k, x in enumerate(_list(c["frames"], f"{where}.frames"))]
        values = [_num(x, f"{where}.values[{k}]")
                  for k, x in enumerate(_list(c["values"], f"{where}.values"))]
        interp = _names(c.get("interpolation", []), f"{where}.interpolation", INTERPOLATIONS,
                        len(frames))
        tangents = _names(c.get("tangents", []), f"{where}.tangents", TANGENTS, len(frames))
        out, inward = ([_num(x, f"{where}.{side}[{k}]")
                        for k, x in enumerate(_list(c[side], f"{where}.{side}"))]
                       if side in c else None for side in ("slopes", "slopes_in"))
        for side, given in (("slopes", out), ("slopes_in", inward)):
            if given is not None and len(given) != len(frames):
                raise _Invalid(f"{where}.{side}", f"expected one slope per key "
                                                  f"({len(frames)} keys, {len(given)} slopes)")
        if inward is not None and out is None:
            raise _Invalid(f"{where}.slopes_in", "in slopes need the (out) slopes beside them")
        slopes = stored_slopes(tangents, out, inward)
        if (joint, channel) in curves:
            raise _Invalid(where, f"a second curve for {joint} {channel}")
        try:
            curves[(joint, channel)] = Curve(frames, values, interp, tangents, slopes)
        except MotionComposerError as exc:
            message = str(exc)
            sub = ("interpolation" if "interpolation" in message else
                   "tangents" if "tangent" in message else
                   "slopes" if "slope" in message else
                   "frames" if "increase" in message else "values")
            raise _Invalid(f"{where}.{sub}", message) from None
    return DisplacementMap(curves)


def _names(value, where: str, allowed, count: int) -> tuple:
    """Per-key names: one name for every key, or a list."""
    if isinstance(value, str):
        return (_choice(value, where, allowed),) * count
    return tuple(_choice(x, f"{where}[{k}]", allowed)
                 for k, x in enumerate(_list(value, where)))


def _viewer(data) -> ViewerState:
    d = _obj(data, "viewer", optional=("current_frame", "play_range", "camera", "shown",
                                        "options"))
    frame = _int(d.get("current_frame", 0), "viewer.current_frame", minimum=0)
    play = d.get("play_range")
    if play is not None:
        play = _list(play, "viewer.play_range")
        if len(play) != 2:
            raise _Invalid("viewer.play_range", f"expected [first, last], not {_show(play)}")
        play = tuple(_int(x, f"viewer.play_range[{i}]", minimum=0) for i, x in enumerate(play))
        if play[0] > play[1]:
            raise _Invalid("viewer.play_range", f"the first frame {play[0]} is after the last "
                                                f"{play[1]}")
    camera = {}
    for k, v in _obj(d.get("camera", {}), "viewer.camera").items():
        where = _sub("viewer.camera", k)
        if isinstance(v, list):
            camera[k] = [_num(x, f"{where}[{i}]") for i, x in enumerate(v)]
        else:
            camera[k] = _num(v, where)
    shown = _list(d.get("shown", list(ViewerState().shown)), "viewer.shown")
    for i, s in enumerate(shown):
        _choice(s, f"viewer.shown[{i}]", SKELETONS)
    options = _obj(d.get("options", {}), "viewer.options")
    for k, v in options.items():
        if not (v is None or isinstance(v, (str, bool, int, float))):
            raise _Invalid(_sub("viewer.options", k), f"expected a string, number, true/false "
                                                      f"or null, not {_kind(v)}")
    return ViewerState(current_frame=frame, play_range=play, camera=camera, shown=tuple(shown),
                       options=options)


# --------------------------------------------------------------------------- field checks
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _sub(parent: str, key: str) -> str:
    """The JSON path of ``key`` in the object at ``parent``."""
    if _IDENT.fullmatch(key):
        return f"{parent}.{key}" if parent else key
    return f"{parent}[{json.dumps(key, ensure_ascii=False)}]"


def _obj(value, where: str, *, required=(), optional=None) -> dict:
    if not isinstance(value, dict):
        raise _Invalid(where, f"expected an object, not {_kind(value)} ({_show(value)})")
    for key in required:
        if key not in value:
            raise _Invalid(_sub(where, key), "is missing")
    if optional is not None:
        known = dict.fromkeys((*required, *optional))
        for key in value:
            if key not in known:
                raise _Invalid(_sub(where, key), f"unknown field (expected one of "
                                                 f"{', '.join(known)})")
    return value


def _list(value, where: str) -> list:
    if not isinstance(value, list):
        raise _Invalid(where, f"expected a list, not {_kind(value)} ({_show(value)})")
    return value


def _str(value, where: str) -> str:
    if not isinstance(value, str):
        raise _Invalid(where, f"expected a string, not {_kind(value)} ({_show(value)})")
    return value


def _bool(value, where: str) -> bool:
    if not isinstance(value, bool):
        raise _Invalid(where, f"expected true or false, not {_kind(value)} ({_show(value)})")
    return value


def _int(value, where: str, *, minimum: int | None = None) -> int:
    if isinstance(value, float) and value.is_integer() and abs(value) < 2 ** 53:
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise _Invalid(where, f"expected a whole number, not {_kind(value)} ({_show(value)})")
    if minimum is not None and value < minimum:
        raise _Invalid(where, f"expected a whole number from {minimum}, not {value}")
    return value


def _num(value, where: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _Invalid(where, f"expected a number, not {_kind(value)} ({_show(value)})")
    value = float(value)
    if not math.isfinite(value):
        raise _Invalid(where, f"expected a finite number, not {value!r}")
    if limits.problem(value) is not None:
        raise _Invalid(where, f"expected a number of magnitude at most "
                              f"{limits.MAX_MAGNITUDE:g}, not {value!r}")
    if positive and value <= 0:
        raise _Invalid(where, f"expected a positive number, not {value!r}")
    return value


def _choice(value, where: str, allowed) -> str:
    if not isinstance(value, str) or value not in allowed:
        raise _Invalid(where, f"expected one of {', '.join(allowed)}, not {_show(value)}")
    return value


def _optional(check, value, where: str, *args, **kwargs):
    return None if value is None else check(value, where, *args, **kwargs)
