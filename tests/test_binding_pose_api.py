"""The animator's hand on the binding (issue 18), the data side: pose offsets and chain
settings in BindOptions, chains from the automatic roles, left/right mirrors, typed angles,
the binding pose, and their place in project and profile files.

Real skeletons throughout: the bundled CMU walk and T-pose, and Mixamo, CC3, Bandai and
RobotExpressive from ../shared/data where present.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import clip_path, shared_path
from motion_composer.engine.conversion import (CHAINS, BindOptions, ChainSettings, automap,
                                               bind, chain_of_joint, chains_of, effector,
                                               euler_to_offset, mirror_joint, mirrored_offset,
                                               offset_to_euler)
from motion_composer.engine.conversion.automap import identify
from motion_composer.engine.conversion.chains import ChainSettingsError, left_axis
from motion_composer.engine.errors import MappingError, MotionComposerError
from motion_composer.engine.formats import read_motion
from motion_composer.engine.project import (Profile, ProfileError, Project, ProjectError,
                                            Source, apply_profile, check_project, profile_of,
                                            project_from_json, project_to_json, read_profile,
                                            save_profile)
from motion_composer.engine.quaternions import qconj, qmul, qrot

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")


def _read(path):
    return read_motion(path)


def _walk_on_tpose(options=None):
    performer, target = _read(WALK), _read(TPOSE)
    corr = automap(target.skeleton, performer.skeleton)
    return performer, target, corr, bind(performer, target, corr, options)


def _angle(a, b) -> np.ndarray:
    """[deg] between rotations ``a`` and ``b`` (``(..., 4)``)."""
    d = np.abs(np.sum(a * b, axis=-1))
    return np.degrees(2 * np.arccos(np.clip(d, 0, 1)))


# --------------------------------------------------------------------------- BindOptions
def test_pose_offsets_are_sorted_pairs_and_identity_removes_one():
    q = tuple(euler_to_offset([0, 0, 10]))
    r = tuple(euler_to_offset([5, 0, 0]))
    options = BindOptions(pose_offsets={"b": q, "a": r})
    assert options.pose_offsets == (("a", r), ("b", q))
    assert hash(options) == hash(BindOptions(pose_offsets=[("a", r), ("b", q)]))
    assert np.array_equal(options.offset("b"), q)
    assert np.array_equal(options.offset("nobody"), [0, 0, 0, 1])
    assert options.with_offset("a", None).pose_offsets == (("b", q),)
    assert options.with_offset("a", (0, 0, 0, 1)).pose_offsets == (("b", q),)
    assert options.with_offset("c", q).pose_offsets[-1] == ("c", q)
    assert options.without_offsets() == BindOptions()


@pytest.mark.parametrize("bad, words", [
    ({"LeftArm": (0, 0, 0.1, 0.9)}, "unit quaternion"),
    ({"LeftArm": (0, 0, float("nan"), 1)}, "unit quaternion"),
    ({"LeftArm": (0, 0, 1)}, "unit quaternion"),
    ({"LeftArm": "up"}, "unit quaternion"),
    ({"": (0, 0, 0, 1)}, "joint's name"),
    ([("LeftArm",)], "pairs"),
])
def test_bad_pose_offsets_name_the_joint(bad, words):
    with pytest.raises(MotionComposerError, match=words):
        BindOptions(pose_offsets=bad)


def test_chain_settings_are_validated_by_field():
    s = ChainSettings(weight=0.25, twist=False, distribute="first", ik_blend=1)
    assert (s.weight, s.twist, s.distribute, s.ik_blend) == (0.25, False, "first", 1.0)
    for kwargs, field in [({"weight": 1.5}, "weight"), ({"weight": float("nan")}, "weight"),
                          ({"weight": "1"}, "weight"), ({"ik_blend": -0.1}, "ik_blend"),
                          ({"ik_blend": True}, "ik_blend"), ({"twist": 1}, "twist"),
                          ({"distribute": "odd"}, "distribute")]:
        with pytest.raises(ChainSettingsError, match=field) as info:
            ChainSettings(**kwargs)
        assert info.value.field == field


def test_chains_override_the_defaults():
    arm = ChainSettings(weight=0.5)
    options = BindOptions(chains={"leg_r": ChainSettings(twist=False), "arm_l": arm,
                                  "spine": ChainSettings()})
    assert [n for n, _ in options.chains] == ["arm_l", "leg_r"]       # sorted, defaults gone
    assert options.chain("arm_l") == arm and options.chain("neck") == ChainSettings()
    assert options.with_chain("arm_l", ChainSettings()).chain("arm_l") == ChainSettings()
    assert options.with_chain("arm_l", None).chains == (("leg_r", ChainSettings(twist=False)),)
    with pytest.raises(MotionComposerError, match="not a chain"):
        BindOptions(chains={"tail": arm})
    with pytest.raises(MotionComposerError, match="not a chain"):
        options.chain("tail")
    with pytest.raises(ChainSettingsError, match="ik_blend"):
        BindOptions(chains={"fingers_l": ChainSettings(ik_blend=0.5)})


# --------------------------------------------------------------------------- chains
CHARACTERS = [("bundled", "cmu_rest_tpose.bvh"), ("shared", "target_mixamo_ely.glb"),
              ("shared", "cc3_cmu_02_01_walk.bvh"), ("shared", "bandai1_walk_normal_001.bvh"),
              ("shared", "target_robot_expressive.glb")]


def _character(where, name):
    return _read(clip_path(name) if where == "bundled" else shared_path(name))


@pytest.mark.parametrize("where, name", CHARACTERS, ids=[n for _, n in CHARACTERS])
def test_chains_follow_the_roles_root_to_tip(where, name):
    motion = _character(where, name)
    sk = motion.skeleton
    roles = identify(sk)
    chains = chains_of(sk)
    assert {"spine", "neck", "arm_l", "arm_r", "leg_l", "leg_r"} <= set(chains)
    assert list(chains) == [c for c in CHAINS if c in chains]
    for chain, joints in chains.items():
        idx = [sk.index[j] for j in joints]
        assert idx == sorted(idx), chain                       # parents before children
        if not chain.startswith("fingers"):
            for a, b in zip(idx, idx[1:]):
                assert sk.parents[b] == a, chain               # one unbroken run
            assert effector(chains, chain) in joints
    for s in ("l", "r"):
        assert chains[f"arm_{s}"][-1] == roles.get(f"hand_{s}", chains[f"arm_{s}"][-1])
        assert effector(chains, f"arm_{s}") == roles.get(f"hand_{s}",
                                                         effector(chains, f"arm_{s}"))
        if f"foot_{s}" in roles:
            assert effector(chains, f"leg_{s}") == roles[f"foot_{s}"]
        assert roles[f"upper_arm_{s}"] in chains[f"arm_{s}"]
        assert chain_of_joint(chains, roles[f"thigh_{s}"]) == f"leg_{s}"
    assert effector(chains, "neck") == roles["head"]
    assert chain_of_joint(chains, roles["hips"]) is None
    if "fingers_l" in chains:
        with pytest.raises(MotionComposerError, match="no end effector"):
            effector(chains, "fingers_l")


@pytest.mark.parametrize("where, name", CHARACTERS, ids=[n for _, n in CHARACTERS])
def test_mirror_joint_swaps_sides_by_role(where, name):
    sk = _character(where, name).skeleton
    roles = identify(sk)
    for key in ("upper_arm", "forearm", "hand", "thigh", "shin"):
        if f"{key}_l" in roles:
            assert mirror_joint(sk, roles[f"{key}_l"]) == roles[f"{key}_r"]
            assert mirror_joint(sk, roles[f"{key}_r"]) == roles[f"{key}_l"]
    for key in ("hips", "chest", "head"):
        assert mirror_joint(sk, roles[key]) is None


def test_typed_angles_round_trip():
    rng = np.random.default_rng(18)
    for angles in rng.uniform([-179, -89, -179], [179, 89, 179], size=(200, 3)):
        q = euler_to_offset(angles)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        assert np.allclose(offset_to_euler(q), angles, atol=1e-9)
    # intrinsic XYZ: R = Rx Ry Rz, about the joint's own axes
    q = euler_to_offset([90, 0, 0])
    assert np.allclose(qrot(q, [0, 1, 0]), [0, 0, 1])
    with pytest.raises(MotionComposerError, match="three finite"):
        euler_to_offset([1, 2])


# --------------------------------------------------------------------------- binding pose
def test_the_binding_pose_carries_the_offsets():
    q = euler_to_offset([0, 0, 10])
    _, target, _, plain = _walk_on_tpose()
    assert plain.rest_local is plain.aligned_local and plain.rest_world is plain.aligned_world
    assert not plain.chain_of
    _, _, _, posed = _walk_on_tpose(BindOptions(pose_offsets={"LeftArm": tuple(q)}))
    j = target.skeleton.index["LeftArm"]
    assert np.allclose(posed.rest_local[j], qmul(plain.rest_local[j], q), atol=1e-15)
    others = np.arange(target.skeleton.num_joints) != j
    assert np.array_equal(posed.rest_local[others], plain.rest_local[others])
    assert np.array_equal(posed.aligned_local, plain.aligned_local)
    # the arm below the shoulder moves, the rest of the body does not
    below = [k for k in range(target.skeleton.num_joints)
             if j in target.skeleton.ancestors(k)]
    assert np.linalg.norm(posed.rest_positions[below] - plain.rest_positions[below],
                          axis=1).min() > 1e-3
    still = [k for k in range(target.skeleton.num_joints) if k not in below]
    assert np.allclose(posed.rest_positions[still], plain.rest_positions[still], atol=1e-12)
    with pytest.raises(MappingError, match="not a joint of the target"):
        _walk_on_tpose(BindOptions(pose_offsets={"Tail": tuple(q)}))


def test_chain_of_names_the_set_chains_joints():
    options = BindOptions(chains={"arm_l": ChainSettings(weight=0.5)})
    _, target, _, binding = _walk_on_tpose(options)
    arm = chains_of(target.skeleton)["arm_l"]
    assert binding.chain_of == {target.skeleton.index[j]: "arm_l" for j in arm}


def test_mirrored_offset_is_the_mirror_image_world_turn():
    """Mixamo's Ely: a left shoulder offset mirrored gives the right shoulder the mirror-image
    world turn (reflection through the sagittal plane)."""
    performer = _read(WALK)
    target = _read(shared_path("target_mixamo_ely.glb"))
    corr = automap(target.skeleton, performer.skeleton)
    left, right = "mixamorig:LeftArm", "mixamorig:RightArm"
    q = euler_to_offset([12, -7, 25])
    binding = bind(performer, target, corr, BindOptions(pose_offsets={left: tuple(q)}))
    other, mirrored = mirrored_offset(binding, left, q)
    assert other == right
    both = bind(performer, target, corr,
                BindOptions(pose_offsets={left: tuple(q), right: tuple(mirrored)}))
    plain = bind(performer, target, corr)
    sk = target.skeleton
    n = left_axis(plain)
    assert abs(n[0]) > 0.99                                  # Ely faces +Z: her left is +X
    reflect = np.eye(3) - 2 * np.outer(n, n)
    for joint in (left, right):
        assert not np.allclose(both.rest_world[sk.index[joint]],
                               plain.rest_world[sk.index[joint]])
    # the world turns of the two shoulders, and what they do to the hands
    for vec in np.eye(3):
        turn_l = qmul(both.rest_world[sk.index[left]], qconj(plain.rest_world[sk.index[left]]))
        turn_r = qmul(both.rest_world[sk.index[right]],
                      qconj(plain.rest_world[sk.index[right]]))
        assert np.allclose(qrot(turn_r, vec), reflect @ qrot(turn_l, reflect @ vec),
                           atol=1e-9)
    hand_l, hand_r = sk.index["mixamorig:LeftHand"], sk.index["mixamorig:RightHand"]
    moved_l = both.rest_positions[hand_l] - plain.rest_positions[hand_l]
    moved_r = both.rest_positions[hand_r] - plain.rest_positions[hand_r]
    assert np.linalg.norm(moved_l) > 0.05
    assert np.allclose(moved_r, reflect @ moved_l, atol=0.01)   # the rig is nearly symmetric
    with pytest.raises(MotionComposerError, match="no mirror joint"):
        mirrored_offset(binding, "mixamorig:Spine", q)


# --------------------------------------------------------------------------- files
def _project(options: BindOptions) -> Project:
    performer, target, corr, _ = _walk_on_tpose()
    return Project(performer=Source(str(WALK)), target=Source(str(TPOSE)),
                   correspondence=corr, bind_options=options)


POSED = BindOptions(
    distribute="first",
    pose_offsets={"LeftArm": tuple(euler_to_offset([0, 0, 10])),
                  "RightUpLeg": tuple(euler_to_offset([-3.5, 1e-3, 0.25]))},
    chains={"arm_l": ChainSettings(weight=0.3, twist=False, distribute="even", ik_blend=1.0),
            "leg_r": ChainSettings(ik_blend=0.125)})


def test_project_round_trip_of_offsets_and_chains(tmp_path):
    project = _project(POSED)
    text = project_to_json(project, tmp_path / "p.mcp")
    back = project_from_json(text, tmp_path / "p.mcp")
    assert back.bind_options == POSED
    for (ja, qa), (jb, qb) in zip(POSED.pose_offsets, back.bind_options.pose_offsets):
        assert ja == jb and qa == qb                          # value by value, bit for bit
    for (na, sa), (nb, sb) in zip(POSED.chains, back.bind_options.chains):
        assert na == nb and sa == sb
    assert project_to_json(back, tmp_path / "p.mcp") == text  # deterministic
    binding = json.loads(text)["binding"]
    assert list(binding["pose_offsets"]) == ["LeftArm", "RightUpLeg"]
    assert binding["chains"]["leg_r"] == {"weight": 1.0, "twist": True, "distribute": None,
                                          "ik_blend": 0.125}


def test_files_without_offsets_or_chains_are_unchanged(tmp_path):
    project = _project(BindOptions())
    data = json.loads(project_to_json(project))
    assert set(data["binding"]) == {"performer_reference", "target_reference",
                                    "rest_alignment", "distribute"}
    assert project_from_json(project_to_json(project)).bind_options == BindOptions()


def _with(text: str, path: list, value) -> str:
    data = json.loads(text)
    node = data
    for key in path[:-1]:
        node = node.setdefault(key, {})
    node[path[-1]] = value
    return json.dumps(data)


BAD = [
    (["binding", "pose_offsets"], [1], "binding.pose_offsets", "object"),
    (["binding", "pose_offsets", "LeftArm"], [0, 0, 0.5, 0.5], "binding.pose_offsets.LeftArm",
     "unit quaternion"),
    (["binding", "pose_offsets", "LeftArm"], "up", "binding.pose_offsets.LeftArm", "list"),
    (["binding", "pose_offsets", "LeftArm"], [0, 0, "x", 1],
     "binding.pose_offsets.LeftArm[2]", "number"),
    (["binding", "chains", "tail"], {}, "binding.chains.tail", "unknown chain"),
    (["binding", "chains", "arm_l", "weight"], 2, "binding.chains.arm_l.weight", "0 to 1"),
    (["binding", "chains", "arm_l", "twist"], "no", "binding.chains.arm_l.twist",
     "true or false"),
    (["binding", "chains", "arm_l", "distribute"], "odd", "binding.chains.arm_l.distribute",
     "even, first"),
    (["binding", "chains", "arm_l", "ik_blend"], -1, "binding.chains.arm_l.ik_blend",
     "0 to 1"),
    (["binding", "chains", "arm_l", "reach"], 1, "binding.chains.arm_l.reach",
     "unknown field"),
    (["binding", "chains", "fingers_r", "ik_blend"], 0.5, "binding.chains.fingers_r.ik_blend",
     "end effector"),
]


@pytest.mark.parametrize("path, value, field, words", BAD, ids=[b[2] for b in BAD])
def test_bad_offsets_and_chains_name_the_field(path, value, field, words):
    text = _with(project_to_json(_project(POSED)), path, value)
    with pytest.raises(ProjectError, match=words) as info:
        project_from_json(text, "bad.mcp")
    assert info.value.field == field and info.value.path == "bad.mcp"


def test_an_offset_on_a_joint_the_target_lacks_names_the_field():
    project = _project(BindOptions(pose_offsets={"Tail": tuple(euler_to_offset([1, 0, 0]))}))
    with pytest.raises(ProjectError, match="not a joint") as info:
        check_project(project, _read(WALK), _read(TPOSE))
    assert info.value.field == "binding.pose_offsets.Tail"


def test_profile_round_trip(tmp_path):
    from motion_composer.engine.correction.contacts import ContactOptions
    from motion_composer.engine.correction.ik import IKOptions
    from motion_composer.engine.conversion import RootOptions
    project = _project(POSED).replace(
        root=RootOptions(mode="in-place", scale=(1.25, 0.75)), auto_contacts=True,
        contact_options=ContactOptions(height=0.05), ik_options=IKOptions(max_iterations=12),
        floor=0.5)
    profile = profile_of(project)
    path = tmp_path / "ely.mcprofile"
    save_profile(path, profile)
    back = read_profile(path)
    for name in ("bind_options", "root", "ik_options", "contact_options", "auto_contacts"):
        assert getattr(back, name) == getattr(profile, name), name
    assert list(back.correspondence.pairs.items()) == list(project.correspondence.pairs.items())
    assert back.correspondence.notes == project.correspondence.notes
    first = path.read_bytes()
    save_profile(path, back)
    assert path.read_bytes() == first                        # deterministic
    # applied to a bare project of the same pair: its settings, the project's own rest
    bare = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)), floor=-1.0)
    applied = apply_profile(bare, back)
    assert applied.bind_options == POSED and applied.root == project.root
    assert applied.floor == -1.0 and applied.auto_contacts
    assert isinstance(profile_of(applied), Profile)


@pytest.mark.parametrize("content, field, words", [
    (b"", None, "empty"),
    (b"{\"format\": \"motion-composer-profile\", \"version\": 1,", None, "truncated"),
    (b"\xff\xfe", None, "UTF-8"),
    (b"[]", None, "object"),
    (b"{\"format\": \"motion-composer-project\", \"version\": 1, \"correspondence\": {}}",
     "format", "not a Motion Composer profile"),
    (b"{\"format\": \"motion-composer-profile\", \"version\": 9, \"correspondence\": "
     b"{\"pairs\": {}}}", "version", "newer"),
    (b"{\"format\": \"motion-composer-profile\", \"version\": 1}", "correspondence",
     "missing"),
    (b"{\"format\": \"motion-composer-profile\", \"version\": 1, \"correspondence\": "
     b"{\"pairs\": {}}, \"binding\": {\"chains\": {\"arm_l\": {\"weight\": 7}}}}",
     "binding.chains.arm_l.weight", "0 to 1"),
    (b"{\"format\": \"motion-composer-profile\", \"version\": 1, \"correspondence\": "
     b"{\"pairs\": {}}, \"floor\": 1}", "floor", "unknown field"),
])
def test_bad_profiles_raise_typed_errors(tmp_path, content, field, words):
    path = tmp_path / "bad.mcprofile"
    path.write_bytes(content)
    with pytest.raises(ProfileError, match=words) as info:
        read_profile(path)
    assert info.value.field == field and info.value.path == str(path)
    assert isinstance(info.value, ProjectError)
    with pytest.raises(ProfileError, match="no such profile"):
        read_profile(tmp_path / "none.mcprofile")
    with pytest.raises(ProfileError, match="folder"):
        read_profile(tmp_path)
