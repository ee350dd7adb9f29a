"""Mutated real FBX files (binary and ASCII) through the real command line: every run exits 0
with finite output, or 2 with one line on stderr; nothing else (no exit 3, traceback,
warning, crash or hang). The cases run in the driver of tests/cli_fuzz.py and are judged by
its :func:`cli_fuzz.judge`.

The seeds are the binary characters of ../shared/data/fbx (Blender's sausage with its three
takes, the Maya rigs with pivots and pre-rotations) and ASCII copies of two of them
(tests/fbx_ascii.py), plus the ASCII NURBS scene and the FBX 6.1 ASCII Maya rig. Binary mutations follow the record layout
(:mod:`engine.formats.fbx.binary`): a record's end offset, property count or length, a
property's type code, a scalar's value (NaN, infinities, huge numbers, odd ids), an array's
length, encoding or stored size; and bytes truncated or flipped anywhere. ASCII mutations are
cli_fuzz's text mutations (numbers, lines, bytes). ``MC_FBX_FUZZ_CASES`` runs more by hand and
``MC_FUZZ_SEED`` others.
"""
from __future__ import annotations

import collections
import json
import os
import random
import struct
import subprocess
import sys
from pathlib import Path

import pytest

import cli_fuzz
from conftest import CLIPS, REPO, SHARED_DATA
from fbx_ascii import ascii_fbx
from motion_composer.engine.formats.fbx.binary import parse_binary

pytestmark = [pytest.mark.shared_data, pytest.mark.slow]

CASES = int(os.environ.get("MC_FBX_FUZZ_CASES", "120"))
SEED = int(os.environ.get("MC_FUZZ_SEED", "17"))
BINARY_SEEDS = ("blender_279_sausage_7400_binary.fbx", "maya_character_7500_binary.fbx",
                "maya_kenney_character_7700_binary.fbx")
ASCII_COPIES = ("blender_279_sausage_7400_binary.fbx", "maya_character_7500_binary.fbx")
_SCALAR_SIZES = {"Y": 2, "C": 1, "I": 4, "F": 4, "D": 8, "L": 8}
_WILD_DOUBLES = (float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 0.0, 1e-320, 1e15)
_WILD_INTS = (0, -1, 1, 2 ** 31 - 1, -2 ** 31, 2 ** 62, -2 ** 62, 7, 123456789)


def _properties(data: bytes, offset: int, wide: bool) -> list[tuple[str, int]]:
    """``(type code, byte offset of the value)`` of each property of the record at
    ``offset`` (a well-formed seed)."""
    size = 8 if wide else 4
    count = struct.unpack_from("<Q" if wide else "<I", data, offset + size)[0]
    at = offset + 3 * size + 1 + data[offset + 3 * size]
    out = []
    for _ in range(count):
        code = chr(data[at])
        out.append((code, at + 1))
        at += 1
        if code in _SCALAR_SIZES:
            at += _SCALAR_SIZES[code]
        elif code in "SR":
            at += 4 + struct.unpack_from("<I", data, at)[0]
        else:
            at += 12 + struct.unpack_from("<I", data, at + 8)[0]
    return out


class _Binary:
    """A binary seed's bytes and the offsets of its records."""

    def __init__(self, data: bytes):
        self.data = data
        self.wide = struct.unpack_from("<I", data, 23)[0] >= 7500
        self.offsets = [n.offset for n in parse_binary(data).walk() if n.offset]


def record_mutation(seed: _Binary, rng: random.Random) -> tuple[bytes, str]:
    """One record's header or one of its properties changed (see the module notes)."""
    data = bytearray(seed.data)
    at = rng.choice(seed.offsets)
    size = 8 if seed.wide else 4
    fmt = "<q" if seed.wide else "<i"
    roll = rng.random()
    if roll < 0.15:
        field = rng.randrange(3)
        value = rng.choice((0, 1, at, at - 1, len(data), len(data) + 1, 2 ** 31 - 1, -1))
        struct.pack_into(fmt, data, at + field * size, value)
        return bytes(data), (f"record at byte {at}: "
                             f"{('end offset', 'property count', 'property bytes')[field]} "
                             f"= {value}")
    props = _properties(seed.data, at, seed.wide)
    if not props:
        data[at + 3 * size] = rng.randrange(256)
        return bytes(data), f"record at byte {at}: name length changed"
    code, where = rng.choice(props)
    if roll < 0.2:
        new = rng.choice(b"YCILFDSRfdilbZ\x00")
        data[where - 1] = new
        return bytes(data), f"record at byte {at}: property type {code!r} -> {chr(new)!r}"
    if code == "D":
        value = rng.choice(_WILD_DOUBLES)
        struct.pack_into("<d", data, where, value)
    elif code == "F":
        value = rng.choice(_WILD_DOUBLES)
        struct.pack_into("<f", data, where, max(min(value, 3e38), -3e38)
                         if value == value else value)
    elif code in "IL":
        value = rng.choice(_WILD_INTS)
        struct.pack_into("<q" if code == "L" else "<i", data, where,
                         max(min(value, 2 ** 31 - 1), -2 ** 31) if code == "I" else value)
    elif code in "SR":
        value = rng.choice((0, 1, 2 ** 31, len(data)))
        struct.pack_into("<I", data, where, value)
    elif code in "YC":
        value = rng.randrange(256)
        data[where] = value
    else:                                             # an array header
        field = rng.randrange(3)
        value = rng.choice((0, 1, 2, 3, 7, 2 ** 31 - 1, 2 ** 32 - 1))
        struct.pack_into("<I", data, where + 4 * field, value)
        return bytes(data), (f"record at byte {at}: array {code!r} "
                             f"{('length', 'encoding', 'stored size')[field]} = {value}")
    return bytes(data), f"record at byte {at}: a {code!r} property = {value!r}"


def _binary_mutations(seed: _Binary):
    record = lambda d, r: record_mutation(seed, r)      # noqa: E731
    return (record,) * 6 + (cli_fuzz.truncate, cli_fuzz.flip_bytes)


ASCII_MUTATIONS = (cli_fuzz.wild_numbers, cli_fuzz.wild_numbers, cli_fuzz.delete_lines,
                   cli_fuzz.duplicate_lines, cli_fuzz.truncate, cli_fuzz.flip_bytes)


def make_cases(seeds: list[tuple[Path, object]], folder: Path, walk: Path, tpose: Path,
               count: int, seed: int) -> list[cli_fuzz.Case]:
    """``count`` cases: about half ``info`` (with ``--json`` or ``--take`` now and then), a
    third the mutated file as the target (written as BVH or GLB), the rest as the
    performer."""
    rng = random.Random(seed)
    cases = []
    for n in range(count):
        cid = f"f{n:05d}"
        src, mutations = rng.choice(seeds)
        data = src.read_bytes()
        steps = []
        for _ in range(rng.choice((1, 1, 1, 2))):
            muts = mutations if isinstance(mutations, tuple) else _binary_mutations(mutations)
            if steps and not isinstance(mutations, tuple):
                muts = (cli_fuzz.flip_bytes, cli_fuzz.truncate)   # offsets moved
            data, what = rng.choice(muts)(data, rng)
            steps.append(what)
        path = folder / f"{cid}.fbx"
        path.write_bytes(data)
        what = f"{src.name}: {'; '.join(steps)}"
        roll = rng.random()
        if roll < 0.5:
            argv = ["info", str(path)] + (["--json"] if rng.random() < 0.5 else [])
            if rng.random() < 0.2:
                argv += ["--take", rng.choice(("Wiggle", "Take 001", "nope"))]
            cases.append(cli_fuzz.Case(cid, argv, [], what, "info fbx"))
        elif roll < 0.8:
            out = folder / f"{cid}.out{rng.choice(('.bvh', '.glb'))}"
            argv = ["retarget", str(walk), "--target", str(path), "-o", str(out)]
            cases.append(cli_fuzz.Case(cid, argv, [str(out)], what, "retarget target fbx"))
        else:
            out = folder / f"{cid}.out.bvh"
            argv = ["retarget", str(path), "--target", str(tpose), "-o", str(out)]
            cases.append(cli_fuzz.Case(cid, argv, [str(out)], what, "retarget performer fbx"))
    return cases


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


def test_fuzzed_fbx_files_through_the_real_cli(tmp_path):
    folder_in = SHARED_DATA / "fbx"
    if not folder_in.is_dir():
        pytest.skip(f"../shared/data/fbx is absent ({SHARED_DATA}); this test mutates its files")
    seeds_dir = tmp_path / "seeds"
    seeds_dir.mkdir()
    seeds: list[tuple[Path, object]] = []
    for name in BINARY_SEEDS:
        path = folder_in / name
        seeds.append((path, _Binary(path.read_bytes())))
    for name in ASCII_COPIES:
        copy = seeds_dir / f"{Path(name).stem}_ascii.fbx"
        copy.write_bytes(ascii_fbx(parse_binary((folder_in / name).read_bytes())))
        seeds.append((copy, ASCII_MUTATIONS))
    seeds.append((folder_in / "nurbs_ascii_7200.fbx", ASCII_MUTATIONS))
    seeds.append((folder_in / "maya_character_6100_ascii.fbx", ASCII_MUTATIONS))
    cases_dir = tmp_path / "cases"
    cases_dir.mkdir()
    walk = REPO / "tests" / "data" / "walk_first_60.bvh"
    cases = make_cases(seeds, cases_dir, walk, CLIPS / "cmu_rest_tpose.bvh", CASES, SEED)
    cases_file, results_file = tmp_path / "cases.json", tmp_path / "results.jsonl"
    cli_fuzz.write_cases(cases, cases_file)
    subprocess.run([sys.executable, str(REPO / "tests" / "cli_fuzz.py"), str(cases_file),
                    str(results_file)], capture_output=True, text=True, cwd=tmp_path,
                   env=_env(), timeout=cli_fuzz.CASE_TIMEOUT_S * (len(cases) + 1))
    results = {}
    if results_file.exists():
        for line in results_file.read_text().splitlines():
            r = json.loads(line)
            results[r["id"]] = r
    failures = [(c, results.get(c.id)) for c in cases
                if results.get(c.id) is None or results[c.id]["problem"]]
    report = "\n".join(
        f"{c.id} [{c.kind}] {c.what}\n    argv: {' '.join(c.argv)}\n    "
        f"{(r or {}).get('problem', 'no result (the driver died on an earlier case)')}\n    "
        f"stderr: {(r or {}).get('stderr', '')[-600:]}" for c, r in failures[:15])
    codes = collections.Counter((c.kind, results.get(c.id, {}).get("code")) for c in cases)
    print(f"{len(cases)} FBX cases; exit codes {dict(sorted(codes.items(), key=str))}")
    assert not failures, f"{len(failures)} of {len(cases)} cases failed:\n{report}"
    # the mutations reach the scene reader: both outcomes are common
    assert sum(n for (_, code), n in codes.items() if code == 0) > len(cases) // 20
    assert sum(n for (_, code), n in codes.items() if code == 2) > len(cases) // 4
