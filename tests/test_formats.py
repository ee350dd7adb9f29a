"""The format registry (engine.formats): reading by content, writing by the output's suffix.

Every real file is sniffed (the bundled clips and, where present, every BVH and GLB of
../shared/data), renamed copies read the same as the originals (a GLB as ``.vrm``, a BVH as
``.txt`` or with no suffix), FBX is recognised by content and a corrupt one refused by the FBX
reader, anything else (garbage, an empty file, a folder, a device) with a typed error naming the
file. Writing refuses a suffix no
format writes, in the engine and on the command line before any work. A static check keeps
every suffix test inside engine/formats.
"""
from __future__ import annotations

import ast
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from motion_composer.app.cli import main
from conftest import BUNDLED_BVH, REPO, SHARED_BVH, clip_path, shared_path
from motion_composer.engine import formats
from motion_composer.engine.errors import (FBXError, FileFormatError, GLTFError,
                                           MotionComposerError, UnknownFormatError,
                                           UnsupportedFormatError)
from motion_composer.engine.formats import (BVH, FBX, FORMATS, GLB, GLTF, HEAD_BYTES, open_filters, output_format,
                            output_suffixes, read_character, read_motion, read_performer,
                            save_filters, sniff, with_output_suffix, write_motion)
from motion_composer.engine.formats.bvh import read_bvh
from motion_composer.engine.formats.gltf import read_gltf
from motion_composer.engine.project import Project, ProjectError, Source, read_sources

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")
SHARED_GLB = ["target_fox.glb", "target_mixamo_ely.glb", "target_mixamo_mannequin.glb",
              "target_robot_expressive.glb"]
#: FBX files of ../shared/data/fbx: binary (several versions) and ASCII
SHARED_FBX = ["fbx/mixamo.fbx", "fbx/blender_279_sausage_7400_binary.fbx",
              "fbx/maya_character_6100_ascii.fbx", "fbx/nurbs_ascii_7200.fbx"]
#: the problem each of them raises when read (``None``: it reads)
FBX_PROBLEMS = {"fbx/mixamo.fbx": None, "fbx/blender_279_sausage_7400_binary.fbx": None,
                "fbx/maya_character_6100_ascii.fbx": None,
                "fbx/nurbs_ascii_7200.fbx": "not a character"}
ROBOT = "target_robot_expressive.glb"


def same_motion(a, b) -> None:
    assert a.skeleton.names == b.skeleton.names
    assert a.num_frames == b.num_frames and a.frame_time == b.frame_time
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.translations, b.translations)


def check_error(error: FileFormatError, path, *phrases) -> None:
    """A one-line typed error naming the file, with each phrase in its message."""
    assert isinstance(error, FileFormatError) and isinstance(error, MotionComposerError)
    assert error.path == os.fspath(path)
    message = str(error)
    assert message.startswith(os.fspath(path)) and "\n" not in message
    for phrase in phrases:
        assert phrase.lower() in message.lower(), (phrase, message)


# --------------------------------------------------------------------------- sniffing real files
@pytest.mark.parametrize("name", BUNDLED_BVH)
def test_every_bundled_clip_is_bvh(name):
    assert sniff(clip_path(name)) is BVH


@pytest.mark.parametrize("name", SHARED_BVH)
def test_every_shared_bvh_is_bvh(name):
    path = shared_path(name)
    assert sniff(path) is BVH
    assert read_character(path) is None


@pytest.mark.parametrize("name", SHARED_GLB)
def test_every_shared_glb_is_glb_and_reads_as_the_character(name):
    path = shared_path(name)
    assert sniff(path) is GLB
    character = read_character(path)
    assert character.meshes and character.skeleton.names == read_gltf(path).skeleton.names
    same_motion(read_motion(path), read_gltf(path).rest_motion())


# --------------------------------------------------------------------------- renamed copies
def test_a_vrm_avatar_is_glb_and_reads_as_gltf(tmp_path):
    robot = shared_path(ROBOT)
    avatar = tmp_path / "x.vrm"
    shutil.copy(robot, avatar)
    assert sniff(avatar) is GLB
    character = read_character(avatar)
    assert character.skeleton.names == read_gltf(robot).skeleton.names
    assert character.num_vertices == read_gltf(robot).num_vertices
    same_motion(read_motion(avatar), read_gltf(robot).rest_motion())


@pytest.mark.parametrize("name", ["clip.txt", "clip", "clip.glb", "CLIP.GLTF"])
def test_a_bvh_under_any_name_reads_as_bvh(tmp_path, name):
    copy = tmp_path / name
    shutil.copy(WALK, copy)
    assert sniff(copy) is BVH
    assert read_character(copy) is None
    same_motion(read_motion(copy), read_bvh(WALK))


def test_bvh_overrides_reach_the_bvh_reader(tmp_path):
    copy = tmp_path / "clip.txt"
    shutil.copy(WALK, copy)
    same_motion(read_motion(copy, units="cm", up_axis="+Z"),
                read_bvh(WALK, units="cm", up_axis="+Z"))


def test_a_byte_order_mark_and_blank_lines_before_hierarchy(tmp_path):
    path = tmp_path / "bom"
    path.write_bytes(b"\xef\xbb\xbf \r\n\t\n" + WALK.read_bytes())
    assert sniff(path) is BVH
    assert read_motion(path).num_frames == 994


def test_a_gltf_json_file_under_any_name(tmp_path):
    motion = read_bvh(TPOSE)
    written = tmp_path / "t.gltf"
    write_motion(motion, written)
    assert written.read_bytes().lstrip()[:1] == b"{"             # JSON, not GLB
    for name in ("t.json", "t", "t.glb"):              # a JSON glTF named .glb too
        copy = tmp_path / name
        shutil.copy(written, copy)
        assert sniff(copy) is GLTF
        character = read_character(copy)
        assert character.skeleton.names == motion.skeleton.names
    assert read_motion(tmp_path / "t").skeleton.names == motion.skeleton.names


def test_a_large_json_object_naming_asset_late_is_left_to_the_gltf_reader(tmp_path):
    """Only the first bytes are looked at: an object without "asset" in them but longer may
    still name it further on, so the glTF reader decides (and says what is missing)."""
    path = tmp_path / "big.json"
    path.write_text(json.dumps({"padding": "x" * HEAD_BYTES, "other": 1}))
    assert sniff(path) is GLTF
    with pytest.raises(GLTFError) as info:
        read_motion(path)
    check_error(info.value, path, "asset")


def test_bvh_overrides_on_a_gltf_file_are_refused(tmp_path):
    robot = shared_path(ROBOT)
    with pytest.raises(GLTFError) as info:
        read_motion(robot, units="cm")
    check_error(info.value, robot, "units", "BVH files only")


def test_a_gltf_character_is_not_a_performer():
    robot = shared_path(ROBOT)
    with pytest.raises(UnsupportedFormatError) as info:
        read_performer(robot)
    check_error(info.value, robot, "character", "target")
    same_motion(read_performer(WALK), read_bvh(WALK))


# --------------------------------------------------------------------------- refused content
FBX_BINARY_HEADER = b"Kaydara FBX Binary  \x00\x1a\x00\xe8\x1c\x00\x00"
FBX_ASCII_HEADER = b"; FBX 7.4.0 project file\n; ----\n\nFBXHeaderExtension:  {\n"


@pytest.mark.parametrize("head, problem", [
    (FBX_BINARY_HEADER, "byte"), (FBX_ASCII_HEADER, "not UTF-8"),
    (b"FBXHeaderExtension:  {\n\tFBXVersion: 6100\n}\n", "not UTF-8")],
    ids=["binary", "ascii", "ascii-without-comment"])
def test_a_corrupt_fbx_file_is_sniffed_as_fbx_and_refused_by_its_reader(tmp_path, head,
                                                                        problem):
    path = tmp_path / "rig.bvh"                       # the name does not matter
    path.write_bytes(head + bytes(range(256)) * 4)
    assert sniff(path) is FBX
    for read in (read_motion, read_character, read_performer):
        with pytest.raises(FBXError) as info:
            read(path)
        check_error(info.value, path, problem)


@pytest.mark.parametrize("name", SHARED_FBX)
def test_real_fbx_files_are_sniffed_as_fbx(name):
    path = shared_path(name)
    assert sniff(path) is FBX
    if FBX_PROBLEMS[name] is None:
        assert read_character(path) is not None and read_motion(path).num_frames == 1
        return
    with pytest.raises(FBXError) as info:
        read_motion(path)
    check_error(info.value, path, FBX_PROBLEMS[name])


def test_binary_garbage_names_the_file_and_the_formats(tmp_path):
    path = tmp_path / "noise.glb"
    path.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(UnknownFormatError) as info:
        read_motion(path)
    check_error(info.value, path, "binary", "BVH", "glTF", "GLB")
    assert info.value.line is None


def test_text_garbage_names_the_line_and_the_word_found(tmp_path):
    path = tmp_path / "mesh.obj"
    path.write_bytes(b"\r\n\n  # Blender OBJ\nv 0 0 0\n")
    with pytest.raises(UnknownFormatError) as info:
        sniff(path)
    check_error(info.value, path, "expected the keyword HIERARCHY (BVH)", "glTF", "GLB",
                "found '#'")
    assert info.value.line == 3
    assert str(info.value).startswith(f"{path}:3: ")


def test_json_that_is_not_gltf(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(json.dumps({"pairs": {"Hips": "Hips"}}))
    with pytest.raises(UnknownFormatError) as info:
        read_character(path)
    check_error(info.value, path, "not glTF", "asset")


@pytest.mark.parametrize("data", [b"", b" \r\n\t\n"], ids=["empty", "blank"])
def test_an_empty_file(tmp_path, data):
    path = tmp_path / "empty.bvh"
    path.write_bytes(data)
    with pytest.raises(UnknownFormatError) as info:
        read_motion(path)
    check_error(info.value, path, "empty", "BVH", "glTF")


def test_a_missing_file(tmp_path):
    path = tmp_path / "gone.glb"
    with pytest.raises(FileFormatError) as info:
        read_character(path)
    check_error(info.value, path, "no such file")


def test_a_folder_is_refused(tmp_path):
    folder = tmp_path / "clips.bvh"
    folder.mkdir()
    with pytest.raises(FileFormatError) as info:
        read_motion(folder)
    check_error(info.value, folder, "folder")


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero here")
def test_a_device_is_refused_before_reading():
    with pytest.raises(FileFormatError) as info:
        read_motion("/dev/zero")                      # reading it would never end
    check_error(info.value, "/dev/zero", "not a regular file")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_a_named_pipe_is_refused_before_reading(tmp_path):
    pipe = tmp_path / "pipe.bvh"
    os.mkfifo(pipe)                                   # opening it would wait for a writer
    with pytest.raises(FileFormatError) as info:
        sniff(pipe)
    check_error(info.value, pipe, "not a regular file")


def test_sniffing_reads_only_the_first_bytes(tmp_path, monkeypatch):
    path = tmp_path / "long.bvh"
    path.write_bytes(WALK.read_bytes() * 8)
    assert path.stat().st_size > HEAD_BYTES
    reads = []
    real_open = open

    def recording_open(*args, **kwargs):
        handle = real_open(*args, **kwargs)
        real_read = handle.read
        handle.read = lambda size=-1: reads.append(size) or real_read(size)
        return handle

    monkeypatch.setattr(formats, "open", recording_open, raising=False)
    assert sniff(path) is BVH
    assert reads == [HEAD_BYTES]


# --------------------------------------------------------------------------- writing
@pytest.mark.parametrize("name, fmt", [("o.bvh", BVH), ("O.BVH", BVH), ("o.glb", GLB),
                                       ("o.gltf", GLTF), ("o.tar.glb", GLB)])
def test_the_output_suffix_chooses_the_writer(tmp_path, name, fmt):
    motion = read_bvh(TPOSE)
    path = tmp_path / name
    assert output_format(path) is fmt
    write_motion(motion, path)
    assert sniff(path) is fmt
    assert read_motion(path).skeleton.names == motion.skeleton.names


def test_a_gltf_output_carries_the_character(tmp_path):
    robot = read_character(shared_path(ROBOT))
    out = tmp_path / "onto.glb"
    write_motion(robot.rest_motion(), out, robot)
    assert read_character(out).num_vertices == robot.num_vertices
    bvh = tmp_path / "onto.bvh"
    write_motion(robot.rest_motion(), bvh, robot)     # BVH holds no mesh: the skeleton only
    assert read_character(bvh) is None
    assert read_motion(bvh).skeleton.names == robot.skeleton.names


@pytest.mark.parametrize("name", ["out.txt", "out", "out.vrm", "out.bvh.tmp"])
def test_an_unknown_output_suffix_is_refused_and_nothing_written(tmp_path, name):
    path = tmp_path / name
    for call in (lambda: output_format(path), lambda: write_motion(read_bvh(TPOSE), path)):
        with pytest.raises(UnsupportedFormatError) as info:
            call()
        check_error(info.value, path, "cannot write", ".bvh", ".glb", ".gltf")
    assert list(tmp_path.iterdir()) == []


def test_output_suffixes_and_a_default_suffix():
    assert output_suffixes() == (".bvh", ".glb", ".gltf", ".fbx")
    assert with_output_suffix("take") == "take.bvh"
    assert with_output_suffix("take.txt") == "take.txt.bvh"
    assert with_output_suffix(Path("a/take.GLB")) == os.path.join("a", "take.GLB")
    assert with_output_suffix("take", GLB) == "take.glb"


# --------------------------------------------------------------------------- dialog filters
def _filter_patterns(filters: str) -> list[list[str]]:
    """Each ``Name (*.a *.b)`` entry's patterns, checking the Qt filter syntax."""
    entries = filters.split(";;")
    out = []
    for entry in entries:
        m = re.fullmatch(r"[^()]+ \(([^()]+)\)", entry)
        assert m, entry
        out.append(m.group(1).split(" "))
    return out


def test_the_open_filters_list_every_readable_format():
    entries = _filter_patterns(open_filters())
    together, *each, everything = entries
    assert everything == ["*"]                        # reading goes by content: any name
    assert len(each) == len(FORMATS)
    for fmt, patterns in zip(FORMATS, each):
        wanted = [f"*{s}" for s in fmt.suffixes + fmt.other_suffixes]
        assert patterns == wanted and set(wanted) <= set(together)
    assert {"*.bvh", "*.glb", "*.gltf", "*.vrm", "*.fbx"} == set(together)


def test_the_save_filters_list_every_written_format_bvh_first():
    entries = _filter_patterns(save_filters())
    assert entries == [[f"*{s}"] for s in output_suffixes()]
    assert entries[0] == ["*.bvh"]


# --------------------------------------------------------------------------- projects
def test_a_project_target_reads_by_content(tmp_path):
    avatar = tmp_path / "robot.vrm"
    shutil.copy(shared_path(ROBOT), avatar)
    clip = tmp_path / "walk.txt"
    shutil.copy(WALK, clip)
    performer, target = read_sources(Project(performer=Source(str(clip)),
                                             target=Source(str(avatar))))
    same_motion(performer, read_bvh(WALK))
    assert target.skeleton.names == read_gltf(avatar).skeleton.names


def test_a_project_with_a_corrupt_fbx_target_says_so(tmp_path):
    rig = tmp_path / "rig.fbx"
    rig.write_bytes(FBX_BINARY_HEADER + bytes(64))
    project = Project(performer=Source(str(WALK)), target=Source(str(rig)))
    with pytest.raises(ProjectError) as info:
        read_sources(project, path="p.mcp")
    assert info.value.field == "target.path"
    assert "the target character cannot be read" in str(info.value)
    assert "rig.fbx" in str(info.value) and "not a character" in str(info.value)


# --------------------------------------------------------------------------- command line
def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_exit_2(code, out, err, *phrases):
    assert code == 2 and out == ""
    assert err.endswith("\n") and err.count("\n") == 1 and "Traceback" not in err
    for phrase in phrases:
        assert phrase in err, (phrase, err)


def test_cli_retarget_refuses_an_unknown_output_suffix_before_any_work(capsys, tmp_path):
    out = tmp_path / "out.txt"
    # the performer does not even exist: the output is checked first
    one_line_exit_2(*run(capsys, "retarget", tmp_path / "missing.bvh", "--target", TPOSE,
                         "-o", out), "out.txt", "cannot write", ".bvh")
    one_line_exit_2(*run(capsys, "retarget", WALK, "--target", TPOSE, "-o", out),
                    "out.txt", "cannot write")
    assert list(tmp_path.iterdir()) == []


def test_cli_retarget_into_a_missing_folder_with_a_known_suffix(capsys, tmp_path):
    """The suffix check comes first, so a missing folder is still reported for a .bvh."""
    one_line_exit_2(*run(capsys, "retarget", TPOSE, "--target", TPOSE,
                         "-o", tmp_path / "no_such_folder" / "take.bvh"), "no_such_folder")
    code, out, err = run(capsys, "retarget", TPOSE, "--target", TPOSE, "-o", tmp_path / "t.BVH")
    assert (code, err) == (0, "") and read_motion(tmp_path / "t.BVH").num_frames == 1


def test_cli_export_refuses_an_unknown_output_suffix_before_any_work(capsys, tmp_path):
    out = tmp_path / "out.txt"
    one_line_exit_2(*run(capsys, "export", tmp_path / "none.mcp", "-o", out),
                    "out.txt", "cannot write")
    assert list(tmp_path.iterdir()) == []


def test_cli_info_reads_by_content(capsys, tmp_path):
    clip = tmp_path / "walk.txt"
    shutil.copy(WALK, clip)
    code, out, err = run(capsys, "info", clip, "--json")
    assert (code, err) == (0, "") and json.loads(out)["frames"] == 994
    avatar = tmp_path / "robot.vrm"
    shutil.copy(shared_path(ROBOT), avatar)
    code, out, err = run(capsys, "info", avatar, "--json")
    assert (code, err) == (0, "")
    assert json.loads(out)["character"] == "robot" and json.loads(out)["meshes"]


def test_cli_info_on_a_truncated_fbx_says_so(capsys, tmp_path):
    rig = tmp_path / "rig.fbx"
    rig.write_bytes(FBX_ASCII_HEADER)
    one_line_exit_2(*run(capsys, "info", rig), "rig.fbx", "truncated")


def test_cli_retarget_refuses_a_gltf_performer(capsys, tmp_path):
    robot = shared_path(ROBOT)
    one_line_exit_2(*run(capsys, "retarget", robot, "--target", TPOSE,
                         "-o", tmp_path / "o.bvh"), ROBOT, "character")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- one dispatch
#: every suffix a motion format's file has (the project file's ``.mcp`` is not one)
MOTION_SUFFIXES = {s for fmt in FORMATS for s in fmt.suffixes + fmt.other_suffixes} | {".fbx"}


def _is_motion_suffix(node) -> bool:
    return (isinstance(node, ast.Constant) and isinstance(node.value, str) and
            node.value.lower() in MOTION_SUFFIXES)


def _mentions_suffix(node) -> bool:
    """``x.suffix`` (``Path``) or ``splitext(x)`` somewhere in ``node``."""
    return any((isinstance(n, ast.Attribute) and n.attr == "suffix") or
               (isinstance(n, ast.Call) and isinstance(n.func, (ast.Attribute, ast.Name)) and
                getattr(n.func, "attr", getattr(n.func, "id", None)) == "splitext")
               for n in ast.walk(node))


def suffix_tests(source: str) -> list[tuple[int, str]]:
    """``(line, what)`` for each place in ``source`` that picks a format by a file's suffix:
    a comparison with a motion format's suffix, ``endswith`` one, a table of them, or a
    suffix compared with anything but plain non-motion constants (``== ".mcp"`` is fine)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            if any(_is_motion_suffix(n) for o in operands for n in ast.walk(o)):
                found.append((node.lineno, "compares with a motion suffix"))
            elif any(_mentions_suffix(o) for o in operands) and not all(
                    _mentions_suffix(o) or isinstance(o, ast.Constant) or
                    (isinstance(o, (ast.Tuple, ast.List, ast.Set)) and
                     all(isinstance(e, ast.Constant) for e in o.elts)) for o in operands):
                found.append((node.lineno, "compares a suffix with a table"))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and
              node.func.attr in ("endswith", "startswith") and
              any(_is_motion_suffix(n) for a in node.args for n in ast.walk(a))):
            found.append((node.lineno, f"{node.func.attr} a motion suffix"))
        elif (isinstance(node, (ast.Tuple, ast.List, ast.Set)) and
              any(_is_motion_suffix(e) for e in node.elts)):
            found.append((node.lineno, "a table of motion suffixes"))
    return sorted(set(found))


def test_the_suffix_check_finds_the_old_dispatch():
    """The detector below would have caught each suffix test this registry replaced."""
    old = [
        'if Path(source.path).suffix.lower() in (".glb", ".gltf"):\n    pass\n',
        'if not path.lower().endswith((".bvh", ".glb", ".gltf")):\n    path += ".bvh"\n',
        'GLTF_SUFFIXES = (".glb", ".gltf")\n',
        'def f(path):\n    return os.path.splitext(str(path))[1].lower() in GLTF_SUFFIXES\n',
        'binary = Path(path).suffix.lower() != ".gltf"\n',
    ]
    for text in old:
        assert suffix_tests(text), text
    fine = ['if path.suffix == ".mcp":\n    pass\n', 'if not path.suffix:\n    pass\n',
            'out = f"{stem}{suffix}.bvh"\n', 'p = path.with_suffix(".json")\n']
    for text in fine:
        assert not suffix_tests(text), text


def test_no_module_outside_engine_formats_picks_a_format_by_suffix():
    formats_dir = REPO / "engine" / "formats"
    offenders = []
    for top in ("engine", "app"):
        for path in sorted((REPO / top).rglob("*.py")):
            if formats_dir in path.parents:
                continue
            for line, what in suffix_tests(path.read_text(encoding="utf-8")):
                offenders.append(f"{path.relative_to(REPO)}:{line}: {what}")
    assert not offenders, "use engine.formats instead:\n" + "\n".join(offenders)
