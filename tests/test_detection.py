"""Units and up axis from a file's content: every convention of the data, and files built from
real clips in the conventions of exporters not in it (tests/detect_cases.py); one warning line
where the figures are in doubt, naming the override."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import BUNDLED_BVH, SHARED_BVH, clip_path, shared_path
from detect_cases import renamed, without_joint, world_positions, written_in
from motion_composer.engine.formats import read_motion
from motion_composer.engine.formats.bvh import parse_bvh
from motion_composer.engine.units import UNITS, detect_units

#: units and up axis of every real file, as its README gives them
EXPECTED = {
    "bandai1_kick_normal_001.bvh": ("cm", "+Y"),
    "bandai1_run_active_001.bvh": ("cm", "+Y"),
    "bandai1_walk_normal_001.bvh": ("cm", "+Y"),
    "bandai2_raise-up-right-hand_normal_001.bvh": ("cm", "+Y"),
    "cc3_cmu_02_01_walk.bvh": ("cm", "+Y"),
    "cc3_cmu_02_06_pickup.bvh": ("cm", "+Y"),
    "cmu_max_131_01_walk.bvh": ("cmu", "+Y"),
    "cmu_mb_01_01_jumps.bvh": ("cmu", "+Y"),
    "cmu_xia_angry_13_000_run.bvh": ("cmu", "+Y"),
    "fair1_child5_wave_hello.bvh": ("in", "+Z"),
    "fair1_child8_jumping.bvh": ("in", "+Z"),
    "rokoko_mixamo_jesse_dance.bvh": ("cm", "+Y"),
    "target_cmu_mb_rest_tpose.bvh": ("cmu", "+Y"),
    "cmu_131_01_walk.bvh": ("cmu", "+Y"),
    "cmu_rest_tpose.bvh": ("cmu", "+Y"),
}


def _path(where: str, name: str):
    return clip_path(name) if where == "bundled" else shared_path(name)


def _head(motion) -> str:
    return next(n for n in motion.skeleton.names if n.lower().endswith("head"))


@pytest.mark.parametrize("where,name", [("bundled", n) for n in BUNDLED_BVH] +
                         [("shared", n) for n in SHARED_BVH])
def test_every_real_file_is_read_in_its_own_units_and_axes_without_a_doubt(where, name):
    src = read_motion(_path(where, name)).skeleton.source
    assert (src.units, src.up_axis) == EXPECTED[name]
    assert src.detected and src.doubt == "" and src.overrides == ()


def _rebuilt(motion, units, up_axis):
    back = parse_bvh(written_in(motion, units, up_axis))
    src = back.skeleton.source
    stature = np.ptp(world_positions(motion)[0, :, 1])
    error = np.abs(world_positions(back) - world_positions(motion)).max()
    return src, error / stature


def test_makehuman_z_up_decimetres_are_decimetres():
    # MakeHuman's BVH export: Z-up, decimetres (was read as inches, "a person of 0.40 m");
    # built from Bandai's walk (cm, Y-up), its names kept (it has a Head)
    motion = read_motion(shared_path("bandai1_walk_normal_001.bvh"))
    src, error = _rebuilt(motion, "dm", "+Z")
    assert (src.units, src.up_axis, src.doubt) == ("dm", "+Z", "")
    assert error < 1e-9


def test_makehuman_cmu_skeleton_in_decimetres_is_not_cmu_units():
    # MakeHuman can export the CMU skeleton (CMU joint names) in decimetres: 13.6 units of a
    # 1.36 m person in CMU units would be a 0.77 m one; 17 units are told by the stature
    motion = read_motion(clip_path("cmu_131_01_walk.bvh"))
    tall = motion.replace(translations=motion.translations * 1.25,
                          skeleton=_scaled(motion.skeleton, 1.25))
    src, error = _rebuilt(tall, "dm", "+Z")
    assert (src.units, src.up_axis) == ("dm", "+Z") and error < 1e-9


def _scaled(skeleton, k):
    import dataclasses
    from motion_composer.engine.skeleton import EndSite
    return dataclasses.replace(skeleton, offsets=skeleton.offsets * k,
                               end_sites=[EndSite(s.parent, s.offset * k, s.name)
                                          for s in skeleton.end_sites])


@pytest.mark.parametrize("up_axis", ["+Z", "-Z", "+X", "-X", "-Y"])
def test_video_to_bvh_millimetres_numbered_joints_no_head(up_axis):
    # video-to-BVH tools (the case: Z-up millimetres, no joint named Head, read Y-up
    # and 0.85 m under the floor): Rokoko Video's capture, joints numbered, Head taken out,
    # turned onto every up axis
    motion = renamed(without_joint(read_motion(shared_path("rokoko_mixamo_jesse_dance.bvh")),
                                   "Head"))
    assert not any("head" in n.lower() for n in motion.skeleton.names)
    src, error = _rebuilt(motion, "mm", up_axis)
    assert (src.units, src.up_axis, src.doubt) == ("mm", up_axis, "")
    assert error < 1e-9


@pytest.mark.parametrize("name", BUNDLED_BVH)
@pytest.mark.parametrize("units,up_axis", [("mm", "+Z"), ("dm", "-X"), ("cm", "+X"),
                                           ("m", "-Z")])
def test_bundled_clips_renamed_and_headless_in_other_frames(name, units, up_axis):
    # the CMU and FAIR1 clips as a generic exporter with numbered joints would write them
    motion = read_motion(clip_path(name))
    motion = renamed(without_joint(motion, _head(motion)))
    src, error = _rebuilt(motion, units, up_axis)
    assert (src.units, src.up_axis, src.doubt) == (units, up_axis, "")
    assert error < 1e-9


def test_cc3_head_with_its_face_taken_out_still_stands_up():
    # CC3's head carries the face joints; without them and renamed the body still tells Z-up
    motion = read_motion(shared_path("cc3_cmu_02_06_pickup.bvh"))
    motion = renamed(without_joint(motion, "CC_Base_Head"))
    src, error = _rebuilt(motion, "mm", "+Z")
    assert (src.units, src.up_axis) == ("mm", "+Z") and error < 1e-9


def test_detect_units_table():
    # (stature in file units, CMU names) -> unit
    cases = {(1.7, False): "m", (17.0, False): "dm", (17.0, True): "dm", (23.9, True): "cmu",
             (38.2, False): "in", (67.0, False): "in", (130.0, False): "cm",
             (1700.0, False): "mm"}
    for (stature, cmu), units in cases.items():
        got, reason, doubt, _ = detect_units(stature, cmu_names=cmu)
        assert got == units and doubt == "", (stature, cmu, reason, doubt)


def test_a_stature_outside_the_human_range_is_one_warning_naming_the_override(tmp_path):
    # Bandai's walk in "centimetres" three times too large: 4 m, no unit fits a person
    motion = read_motion(shared_path("bandai1_walk_normal_001.bvh"))
    giant = motion.replace(translations=motion.translations * 3,
                           skeleton=_scaled(motion.skeleton, 3))
    path = tmp_path / "giant.bvh"
    path.write_text(written_in(giant, "cm", "+Y"))
    src = read_motion(path).skeleton.source
    assert "fits no unit for a person" in src.doubt and src.overrides == (("units", ""),)
    line = src.warning(path, "--performer-")
    assert "\n" not in line and line.endswith("give --performer-units UNIT")
    # given, the units settle it
    assert read_motion(path, units="mm").skeleton.source.doubt == ""


def test_two_units_that_fit_nearly_as_well_name_the_other():
    # a child of 97 cm (FAIR1's five-year-old written in centimetres) is also a 2.46 m person
    # in inches: read as inches, and the warning suggests centimetres
    motion = read_motion(shared_path("fair1_child5_wave_hello.bvh"))
    src, _ = _rebuilt(motion, "cm", "+Z")
    assert src.units == "in" and src.overrides == (("units", "cm"),)
    assert src.warning("child.bvh", "--performer-").endswith("give --performer-units cm")
    assert parse_bvh(written_in(motion, "cm", "+Z"), units="cm").skeleton.source.doubt == ""


def test_a_figure_with_no_body_and_no_names_says_the_up_axis_is_assumed():
    # the bundled CMU walk cut to its left leg, joints numbered: no humanoid, no head, no feet
    motion = read_motion(clip_path("cmu_131_01_walk.bvh"))
    for name in ("RHipJoint", "lowerback"):
        motion = without_joint(motion, name)
    motion = renamed(motion)
    src = parse_bvh(written_in(motion, "m", "+Y")).skeleton.source
    assert src.up_axis == "+Y" and ("up_axis", "") in src.overrides
    assert "+Y assumed" in src.doubt
    given = parse_bvh(written_in(motion, "m", "+Y"), up_axis="+Y").skeleton.source
    assert ("up_axis", "") not in given.overrides


def test_units_table_has_decimetres():
    assert UNITS["dm"] == 0.1


def test_a_vanishingly_small_figure_is_read_without_a_numpy_warning():
    """Found by the CLI fuzz test: every OFFSET of the CMU T-pose set to 1e-300 made the
    up-axis angle divide by a norm that underflowed to zero (a RuntimeWarning on stderr)."""
    import re
    text = clip_path("cmu_rest_tpose.bvh").read_text()
    tiny = re.sub(r"OFFSET[^\n]*", "OFFSET 1e-300 1e-300 1e-300", text)
    motion = parse_bvh(tiny, "tiny.bvh")                  # warnings are errors in the suite
    assert np.all(np.isfinite(motion.skeleton.offsets))
    assert motion.skeleton.source.doubt                   # no unit fits: said, not guessed
