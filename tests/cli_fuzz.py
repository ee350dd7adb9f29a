"""Fuzzing the real command line: mutated real files through ``info``, ``retarget``, ``export``
and ``batch``, and the check of what each run may do (tests/test_cli_fuzz.py).

A case is an ``argv`` for :func:`app.cli.main` and the files it writes. The outcome of a run
is acceptable when it is one of:

* exit 0, nothing on stderr but the program's notices (:data:`NOTICES`; ``batch``: and its
  progress lines), and every file written re-reads with finite values (``info --json``:
  strict JSON);
* exit 2 with exactly one line on stderr and no traceback;
* ``batch`` only: exit 1 when clips failed, each for a typed reason (never ``unexpected``).

Anything else (exit 3, a traceback, a warning, a crash, a case running past
:data:`CASE_TIMEOUT_S`) is a failure. ``python tests/cli_fuzz.py CASES.json RESULTS.json`` is the
driver: it runs many cases in one process (``main`` in-process, stdout and stderr captured,
warnings always shown) so that spawning is not the cost.
"""
from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import random
import re
import signal
import struct
import sys
import traceback
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

#: the lines a successful run may print on stderr: the program's own notices (a doubtful
#: unit or up axis and the override that settles it), one line each
NOTICES = ("motion-composer: warning: ", "motion-composer: note: ")
#: a case running longer than this is a hang [s]
CASE_TIMEOUT_S = 60

_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
_CHANNELS = re.compile(rb"CHANNELS\s+(\d+)")
#: what a number in a file is replaced with
WILD_NUMBERS = (b"1e308", b"-1e308", b"1e309", b"nan", b"NaN", b"inf", b"-inf", b"0", b"-0",
                b"-1", b"-999999", b"4294967296", b"1e-320", b"99999999999999999999", b"0x10",
                b"1.5.5", b"")
#: what a JSON value is replaced with
WILD_JSON = (None, True, -1, 0, 1e308, -1e308, 2 ** 63, 1.5, "", "x", "../../etc/hostname",
             [], {}, [0] * 5000, [[1e308] * 3] * 50, {"a": 1}, [None], float("nan"))


@dataclass
class Case:
    """One run of the CLI: ``argv`` (paths already in it), the files it writes (``outputs``),
    and how its input was made (``what``), to reproduce and to report by kind."""

    id: str
    argv: list[str]
    outputs: list[str] = field(default_factory=list)
    what: str = ""
    kind: str = ""


# --------------------------------------------------------------------------- mutations
def _lines(data: bytes) -> list[bytes]:
    return data.splitlines(keepends=True)


def truncate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    cut = rng.randrange(0, max(1, len(data)))
    return data[:cut], f"truncated at byte {cut}"


def flip_bytes(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    buf = bytearray(data)
    n = rng.choice((1, 2, 8, 64))
    for _ in range(n):
        i = rng.randrange(len(buf))
        buf[i] ^= 1 << rng.randrange(8) if rng.random() < 0.5 else rng.randrange(1, 256)
    return bytes(buf), f"{n} bytes flipped"


def duplicate_lines(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    lines = _lines(data)
    i = rng.randrange(len(lines))
    k = rng.choice((1, 1, 3, 50))
    return b"".join(lines[:i] + [lines[i]] * (k + 1) + lines[i + 1:]), \
        f"line {i + 1} repeated {k} times"


def delete_lines(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    lines = _lines(data)
    i = rng.randrange(len(lines))
    k = rng.choice((1, 1, 2, 10))
    return b"".join(lines[:i] + lines[i + k:]), f"lines {i + 1}-{i + k} deleted"


def wild_numbers(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    matches = list(_NUMBER.finditer(data))
    if not matches:
        return flip_bytes(data, rng)
    chosen = sorted(rng.sample(matches, min(len(matches), rng.choice((1, 1, 3, 20)))),
                    key=lambda m: m.start())
    value = rng.choice(WILD_NUMBERS)
    out, at = [], 0
    for m in chosen:
        out += [data[at:m.start()], value]
        at = m.end()
    out.append(data[at:])
    line = data[:chosen[0].start()].count(b"\n") + 1
    return b"".join(out), f"{len(chosen)} numbers from line {line} replaced with {value!r}"


def channel_counts(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    matches = list(_CHANNELS.finditer(data))
    if not matches:
        return wild_numbers(data, rng)
    m = rng.choice(matches)
    new = rng.choice((b"0", b"1", b"2", b"5", b"7", b"9", b"-3", b"100000"))
    line = data[:m.start()].count(b"\n") + 1
    return data[:m.start(1)] + new + data[m.end(1):], f"CHANNELS on line {line} set to {new!r}"


#: numbers a reader takes, but odd for a body: huge, tiny, negative, zero
ODD_NUMBERS = (b"1e6", b"-1e6", b"1e30", b"-1e30", b"1e300", b"1e-300", b"-0.0", b"0", b"720",
               b"-360000", b"3.4e38", b"1e15")


def _replace_numbers(data: bytes, start: int, end: int, rng: random.Random,
                     values) -> tuple[bytes, int, bytes]:
    """Some numbers between byte ``start`` and ``end`` replaced by one of ``values``: the
    data, the line of the first one, the value."""
    matches = [m for m in _NUMBER.finditer(data, start, end)]
    if not matches:
        return data, 0, b""
    chosen = sorted(rng.sample(matches, min(len(matches), rng.choice((1, 3, 30, 1000)))),
                    key=lambda m: m.start())
    value = rng.choice(values)
    out, at = [], 0
    for m in chosen:
        out += [data[at:m.start()], value]
        at = m.end()
    out.append(data[at:])
    return b"".join(out), data[:chosen[0].start()].count(b"\n") + 1, value


def odd_motion_values(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Numbers of the MOTION rows (after ``Frame Time``) replaced with odd values."""
    at = data.find(b"Frame Time")
    if at < 0:
        return wild_numbers(data, rng)
    start = data.find(b"\n", at) + 1
    new, line, value = _replace_numbers(data, start, len(data), rng,
                                        ODD_NUMBERS + (b"nan", b"1e309"))
    return new, f"motion values from line {line} replaced with {value!r}"


def odd_offsets(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """The numbers of some OFFSET lines replaced with odd values."""
    lines = _lines(data)
    offsets = [i for i, l in enumerate(lines) if l.lstrip().startswith(b"OFFSET")]
    if not offsets:
        return wild_numbers(data, rng)
    value = rng.choice(ODD_NUMBERS)
    chosen = rng.sample(offsets, min(len(offsets), rng.choice((1, 2, len(offsets)))))
    for i in chosen:
        indent = lines[i][:len(lines[i]) - len(lines[i].lstrip())]
        lines[i] = indent + b"OFFSET " + b" ".join([value] * 3) + b"\n"
    return b"".join(lines), f"{len(chosen)} OFFSETs from line {min(chosen) + 1} set to {value!r}"


def odd_frames(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """A consistent file with other frames: ``Frame Time`` odd, or only the first rows kept
    (the ``Frames`` count fixed), or none."""
    lines = _lines(data)
    try:
        f = next(i for i, l in enumerate(lines) if l.startswith(b"Frames:"))
    except StopIteration:
        return wild_numbers(data, rng)
    if rng.random() < 0.5:
        value = rng.choice((b"1e-9", b"10", b"10.5", b"1e308", b"0", b"-0.01", b"0.0000001",
                            b"3600"))
        lines[f + 1] = b"Frame Time: " + value + b"\n"
        return b"".join(lines), f"Frame Time {value!r}"
    keep = rng.choice((0, 1, 2, 3))
    rows = [l for l in lines[f + 2:] if l.strip()][:keep]
    return b"".join(lines[:f] + [b"Frames: %d\n" % keep, lines[f + 1]] + rows), \
        f"only {keep} frames kept"


def rename_joints(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Joint names replaced: a duplicate, an empty-looking, a long or a non-ASCII one."""
    names = re.findall(rb"(?:ROOT|JOINT)[ \t]+(\S+)", data)
    if not names:
        return flip_bytes(data, rng)
    old = rng.choice(names)
    new = rng.choice([n for n in names if n != old] or [b"X"]) if rng.random() < 0.4 else \
        rng.choice((b"_", b"x" * 300, "Kopf-\u00e9".encode(), b"Head", b"LeftHand"))
    return re.sub(rb"((?:ROOT|JOINT)[ \t]+)" + re.escape(old) + rb"(\s)",
                  lambda m: m.group(1) + new + m.group(2), data, count=1), \
        f"joint {old.decode(errors='replace')!r} renamed {new.decode(errors='replace')[:20]!r}"


BVH_MUTATIONS = (truncate, flip_bytes, duplicate_lines, delete_lines, wild_numbers,
                 channel_counts, odd_motion_values, odd_motion_values, odd_offsets, odd_frames,
                 rename_joints)


def _json_paths(value, path=()):
    """Every (path, value) in a JSON document, containers included."""
    yield path, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _json_paths(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value[:40]):
            yield from _json_paths(v, path + (i,))


def _json_edit(doc, rng: random.Random) -> str:
    """Change ``doc`` in place at a random place: a value of another type, a missing key, a
    huge array, a huge or negative number. Returns what was done."""
    paths = [p for p, _ in _json_paths(doc) if p]
    if not paths:                              # a small document edited down to nothing
        return "nothing left to edit"
    path = rng.choice(paths)
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    key = path[-1]
    where = ".".join(str(k) for k in path)
    if isinstance(parent, dict) and rng.random() < 0.3:
        del parent[key]
        return f"{where} deleted"
    value = copy.deepcopy(rng.choice(WILD_JSON))
    if isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool) and \
            rng.random() < 0.6:
        value = parent[key] * rng.choice((-1, 0, 1e3, 1e30, 1e300)) if rng.random() < 0.7 \
            else rng.choice((float("nan"), float("inf")))
    parent[key] = value
    shown = json.dumps(value)[:40] if not (isinstance(value, float) and math.isnan(value)) \
        else "NaN"
    return f"{where} = {shown}"


def json_edit(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    try:
        doc = json.loads(data.decode("utf-8-sig"))
    except (ValueError, UnicodeDecodeError):
        return flip_bytes(data, rng)
    what = "; ".join(_json_edit(doc, rng) for _ in range(rng.choice((1, 1, 2, 4))))
    return json.dumps(doc, indent=1).encode(), what


def _glb_chunks(data: bytes):
    """``(json_bytes, bin_bytes)`` of a well-formed GLB."""
    length = struct.unpack_from("<I", data, 12)[0]
    js = data[20:20 + length]
    rest = data[20 + length:]
    binary = rest[8:] if len(rest) >= 8 else b""
    return js, binary


def _glb(js: bytes, binary: bytes) -> bytes:
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<I4s", len(js), b"JSON") + js
    if binary:
        body += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def glb_json_edit(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    js, binary = _glb_chunks(data)
    new, what = json_edit(js, rng)
    return _glb(new, binary), "JSON chunk: " + what


def glb_garbage(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Random bytes over part of the binary chunk (or of the header and chunk headers)."""
    js, binary = _glb_chunks(data)
    if rng.random() < 0.25 or not binary:
        buf = bytearray(data)
        i = rng.randrange(0, 28)
        buf[i:i + 4] = rng.randbytes(4)
        return bytes(buf), f"container bytes {i}-{i + 3} replaced"
    buf = bytearray(binary)
    n = rng.choice((4, 64, 4096, len(buf)))
    i = rng.randrange(0, max(1, len(buf) - n))
    buf[i:i + n] = rng.randbytes(min(n, len(buf) - i))
    return _glb(js, bytes(buf)), f"BIN chunk bytes {i}-{i + n} garbage"


GLTF_MUTATIONS = (json_edit, json_edit, json_edit, truncate, flip_bytes, wild_numbers)
GLB_MUTATIONS = (glb_json_edit, glb_json_edit, glb_garbage, glb_garbage, truncate, flip_bytes)
PROJECT_MUTATIONS = (json_edit, json_edit, json_edit, json_edit, truncate, flip_bytes,
                     wild_numbers, duplicate_lines, delete_lines)


# --------------------------------------------------------------------------- cases
@dataclass
class Seeds:
    """The real files mutated: BVH clips (performer ``walk``, target ``tpose``), glTF
    characters (JSON and GLB) and projects (sources by path, and embedded)."""

    walk: Path
    tpose: Path
    bvh: list[Path]
    gltf: list[Path]
    glb: list[Path]
    projects: list[Path]


def make_cases(seeds: Seeds, folder: Path, count: int, seed: int) -> list[Case]:
    """``count`` cases, the same ones for the same ``seed``, their mutated files in
    ``folder``. The commands are spread: about a third ``info``, a third ``retarget``
    (performer or target mutated), a fifth ``export`` and a few ``batch``."""
    rng = random.Random(seed)
    folder.mkdir(parents=True, exist_ok=True)
    cases = []
    for n in range(count):
        cid = f"c{n:05d}"
        roll = rng.random()
        if roll < 0.34:
            kind, src, muts = _pick_input(seeds, rng)
            path, what = _mutate(src, muts, folder / f"{cid}{src.suffix}", rng)
            argv = ["info", str(path)] + (["--json"] if rng.random() < 0.5 else [])
            cases.append(Case(cid, argv, [], what, f"info {kind}"))
        elif roll < 0.52:
            src = rng.choice(seeds.bvh)
            path, what = _mutate(src, BVH_MUTATIONS, folder / f"{cid}.bvh", rng)
            out = folder / f"{cid}.out.bvh"
            argv = ["retarget", str(path), "--target", str(seeds.tpose), "-o", str(out)]
            if rng.random() < 0.3:
                argv.append("--auto-contacts")
            cases.append(Case(cid, argv, [str(out)], what, "retarget performer"))
        elif roll < 0.72:
            kind, src, muts = _pick_input(seeds, rng)
            path, what = _mutate(src, muts, folder / f"{cid}{src.suffix}", rng)
            suffix = ".glb" if kind != "bvh" and rng.random() < 0.5 else ".bvh"
            out = folder / f"{cid}.out{suffix}"
            argv = ["retarget", str(seeds.walk), "--target", str(path), "-o", str(out)]
            cases.append(Case(cid, argv, [str(out)], what, f"retarget target {kind}"))
        elif roll < 0.92:
            src = rng.choice(seeds.projects)
            path, what = _mutate(src, PROJECT_MUTATIONS, folder / f"{cid}.mcp", rng)
            out = folder / f"{cid}.out.bvh"
            argv = ["export", str(path), "-o", str(out)]
            if rng.random() < 0.3:
                argv.append("--solve")
            cases.append(Case(cid, argv, [str(out)], what, "export project"))
        else:
            if rng.random() < 0.5:
                src = rng.choice(seeds.projects)
                project, what = _mutate(src, PROJECT_MUTATIONS, folder / f"{cid}.mcp", rng)
                clip = seeds.walk
                kind = "batch project"
            else:
                project = seeds.projects[0]
                clip, what = _mutate(rng.choice(seeds.bvh), BVH_MUTATIONS,
                                     folder / f"{cid}.bvh", rng)
                kind = "batch clip"
            out = folder / f"{cid}.batch"
            summary = folder / f"{cid}.summary.json"
            argv = ["batch", str(project), str(clip), "-o", str(out), "--workers", "1",
                    "--summary", str(summary)]
            cases.append(Case(cid, argv, [str(out), str(summary)], what, kind))
    return cases


def _pick_input(seeds: Seeds, rng: random.Random):
    kind = rng.choice(["bvh", "bvh", "gltf", "glb"] if seeds.glb else ["bvh", "bvh", "gltf"])
    if kind == "bvh":
        return kind, rng.choice(seeds.bvh), BVH_MUTATIONS
    if kind == "gltf":
        return kind, rng.choice(seeds.gltf), GLTF_MUTATIONS
    return kind, rng.choice(seeds.glb), GLB_MUTATIONS


def _mutate(src: Path, mutations, dest: Path, rng: random.Random) -> tuple[Path, str]:
    data = src.read_bytes()
    steps = []
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        if not data:
            break
        data, what = rng.choice(mutations)(data, rng)
        steps.append(what)
    dest.write_bytes(data)
    return dest, f"{src.name}: {'; '.join(steps)}"


# --------------------------------------------------------------------------- checking
def _strict_json(text: str):
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


def _finite(name: str, *arrays) -> str | None:
    import numpy as np
    for a in arrays:
        if not np.all(np.isfinite(np.asarray(a, dtype=float))):
            return f"{name} holds non-finite values"
    return None


def check_outputs(case: Case, stdout: str) -> str | None:
    """What is wrong with the files a run that exited 0 wrote (``None``: nothing)."""
    from motion_composer.engine.formats import read_character, read_motion
    if case.argv[0] == "info" and "--json" in case.argv:
        try:
            _strict_json(stdout)
        except ValueError as exc:
            return f"info --json printed no strict JSON: {exc}"
    for out in case.outputs:
        path = Path(out)
        if path.suffix == ".json":
            continue
        files = sorted(path.glob("*.bvh")) if path.is_dir() else [path]
        if not files:
            return f"{out} was not written"
        for file in files:
            if not file.is_file():
                return f"{file} was not written"
            character = read_character(file)
            motions = ([read_motion(file)] if character is None else
                       [character.rest_motion(), *character.motions])
            for m in motions:
                problem = _finite(str(file), m.rotations, m.translations, m.frame_time,
                                  m.skeleton.offsets)
                if problem:
                    return problem
    return None


def judge(case: Case, code, stdout: str, stderr: str) -> str | None:
    """Why the outcome of ``case`` is not acceptable, or ``None`` when it is."""
    lines = stderr.splitlines()
    if "Traceback" in stderr:
        return f"exit {code} with a traceback"
    if code == 2:
        if len(lines) != 1 or not stderr.endswith("\n"):
            return f"exit 2 with {len(lines)} lines on stderr"
        return None
    if case.argv[0] == "batch" and code in (0, 1):
        noise = [l for l in lines if not l.startswith(("[",) + NOTICES)]
        if noise:
            return f"batch exit {code} with stderr beyond progress: {noise[0][:120]}"
        summary = Path(case.outputs[1])
        reasons = [s.get("reason", "") for s in json.loads(summary.read_text())
                   if s["status"] != "written"]
        bad = [r for r in reasons if r.startswith(("unexpected", "the worker process"))]
        if bad:
            return f"batch clip failed with a bug: {bad[0][:200]}"
        if code == 1 and not reasons:
            return "batch exit 1 with no failed clip"
    elif code == 0:
        noise = [l for l in lines if not l.startswith(NOTICES)]
        if noise:
            return f"exit 0 with stderr: {noise[0][:120]}"
    else:
        return f"exit {code}"
    try:
        return check_outputs(case, stdout) if code == 0 else None
    except Exception as exc:               # noqa: BLE001 - an output we cannot re-read
        return f"an output does not re-read: {' '.join(str(exc).split())[:200]}"


# --------------------------------------------------------------------------- the driver
class CaseTimeout(BaseException):
    """A case ran past :data:`CASE_TIMEOUT_S` (not an ``Exception``: ``main`` must not catch
    it as a bug)."""


def _alarm(signum, frame):
    raise CaseTimeout()


def run_in_process(case: Case) -> dict:
    """Run ``case`` with :func:`app.cli.main` in this process; its outcome and the verdict."""
    from motion_composer.app.cli import main
    out, err = io.StringIO(), io.StringIO()
    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CASE_TIMEOUT_S)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
                warnings.catch_warnings():
            warnings.simplefilter("always")
            try:
                code = main(list(case.argv))
            except SystemExit as exc:
                code = exc.code
    except CaseTimeout:
        return dict(id=case.id, code=None, stderr=err.getvalue()[-2000:],
                    problem=f"no answer after {CASE_TIMEOUT_S} s (a hang)")
    finally:
        signal.alarm(0)
    stdout, stderr = out.getvalue(), err.getvalue()
    problem = judge(case, code, stdout, stderr)
    return dict(id=case.id, code=code, stderr=stderr[-4000:], problem=problem)


def drive(cases_file: str, results_file: str) -> None:
    """Run every case of ``cases_file`` (JSON) in this process, appending one JSON line of
    results per case to ``results_file`` as it ends (a crash of the process loses none)."""
    cases = [Case(**c) for c in json.loads(Path(cases_file).read_text())]
    with open(results_file, "a", encoding="utf-8") as handle:
        for case in cases:
            try:
                result = run_in_process(case)
            except Exception:              # noqa: BLE001 - the checker itself must not stop
                result = dict(id=case.id, code=None, stderr=traceback.format_exc(),
                              problem="the fuzz driver failed on this case")
            handle.write(json.dumps(result) + "\n")
            handle.flush()


def write_cases(cases: list[Case], path: Path) -> None:
    path.write_text(json.dumps([asdict(c) for c in cases]))


if __name__ == "__main__":
    drive(sys.argv[1], sys.argv[2])
