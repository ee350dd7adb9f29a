"""Constraint kinds (engine/correction/constraints/, one module per kind): the registry, each
kind's IK rows against central finite differences on a real skeleton and posture, satisfied
tasks, goal validation and files, and that nothing outside the kind modules tests a kind by
its name."""
from __future__ import annotations

import ast
import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from motion_composer.engine import read_bvh
from motion_composer.engine.correction.constraints import (KINDS, Constraint, ConstraintError,
                                                           ConstraintKind)
from motion_composer.engine.correction.constraints.base import DRAWINGS
from motion_composer.engine.correction.ik import TaskState, rotvec_to_quat
from motion_composer.engine.kinematics import fk_arrays
from motion_composer.engine.quaternions import qmul, to_matrix

from conftest import REPO, clip_path

EPS = 1e-6
FRAMES = np.array([0, 120, 260, 400])


@lru_cache(maxsize=None)
def _walk():
    motion = read_bvh(clip_path("cmu_131_01_walk.bvh"))
    return motion.skeleton, motion.rotations[FRAMES], motion.translations[FRAMES]


def _state(sk, kind: ConstraintKind, joint: int, rot, tra) -> TaskState:
    """The joint's task state from full forward kinematics (not the solver's own)."""
    pose = fk_arrays(sk, rot, tra, end_sites=False)
    chain = kind.chain(sk, joint)
    frames = []
    for a in chain:
        p = int(sk.parents[a])
        frames.append(np.broadcast_to(np.eye(3), (len(rot), 3, 3)) if p < 0
                      else to_matrix(pose.rotations[:, p]))
    return TaskState(pose.positions[:, joint], pose.rotations[:, joint],
                     [pose.positions[:, a] for a in chain], frames)


def _perturbed(chain, rot, tra, col, eps):
    """The posture with unknown ``col`` moved by ``eps``: root translation (0-2), then a
    rotation vector in each chain joint's parent frame."""
    rot, tra = rot.copy(), tra.copy()
    if col < 3:
        tra[:, 0, col] += eps
        return rot, tra
    k, axis = divmod(col - 3, 3)
    v = np.zeros(3)
    v[axis] = eps
    rot[:, chain[k]] = qmul(rotvec_to_quat(v), rot[:, chain[k]])
    return rot, tra


def _check_rows(kind: ConstraintKind, joint_name: str, goal_of):
    """The kind's analytic Jacobian against -d(error) by central differences; ``goal_of``
    makes the task goals ``(B, goal_size)`` from the state at the posture."""
    sk, rot, tra = _walk()
    j = sk.index[joint_name]
    state = _state(sk, kind, j, rot, tra)
    goal = goal_of(state)
    assert goal.shape == (len(FRAMES), kind.goal_size)
    assert np.all(kind.active(goal, state))
    jac = kind.jacobian(goal, state)
    chain = kind.chain(sk, j)
    assert jac.shape == (len(FRAMES), kind.rows, 3 + 3 * len(chain))
    numeric = np.zeros_like(jac)
    for col in range(jac.shape[2]):
        plus = _state(sk, kind, j, *_perturbed(chain, rot, tra, col, EPS))
        minus = _state(sk, kind, j, *_perturbed(chain, rot, tra, col, -EPS))
        numeric[:, :, col] = -(kind.error(goal, plus) - kind.error(goal, minus)) / (2 * EPS)
    assert np.abs(jac).max() > 0.1                         # not vacuous
    np.testing.assert_allclose(jac, numeric, atol=1e-6)


# ---------------------------------------------------------------------- the registry
def test_the_registry_lists_the_kinds_and_the_plane_sides():
    assert list(KINDS) == ["position", "trajectory", "plane", "orientation"]
    assert all(KINDS[name].name == name for name in KINDS)
    choices = [(k.name, v, k.choice_label(v)) for k in KINDS.values() for v in k.variants]
    assert choices == [("position", None, "Position"), ("trajectory", None, "Trajectory"),
                       ("plane", "above", "Plane: above"), ("plane", "on", "Plane: on"),
                       ("plane", "below", "Plane: below"),
                       ("orientation", None, "Orientation")]
    assert {k.draw for k in KINDS.values()} == set(DRAWINGS)
    # a trajectory is solved with a position's rows: they share task slots
    assert KINDS["trajectory"].task_kind is KINDS["position"]
    assert [k.residual_unit for k in KINDS.values()] == ["m", "m", "m", "rad"]


def test_every_kind_describes_its_goal_fields():
    examples = _examples()
    for name, kind in KINDS.items():
        c = examples[name]
        assert c.kind_object is kind
        for f in kind.fields:
            assert f.label and f.editor in ("vector", "euler", "summary")
            if f.editor != "summary":
                assert f.key in c.goal and f.name
    assert KINDS["trajectory"].summary(examples["trajectory"]) == \
        "2 keys from frame 0 to 10"


# ---------------------------------------------------------------------- IK rows
@pytest.mark.parametrize("joint", ["LeftAnkle", "RightWrist", "Head", "Hips"])
def test_position_rows_match_finite_differences(joint):
    _check_rows(KINDS["position"], joint, lambda s: s.position + [0.05, -0.02, 0.03])


def test_trajectory_rows_match_finite_differences():
    """The goal of each frame from a path through keys (the frames of the batch lie
    between them)."""
    keys = [[0, 0.1, 0.9, 0.2], [200, 0.3, 1.0, 0.4], [400, 0.6, 0.8, 0.1]]
    c = Constraint("LeftWrist", "trajectory", {"keys": keys}, 0, 0, 400, 400)
    kind = c.kind_object
    goals = kind.task_goals(c, FRAMES)
    np.testing.assert_allclose(goals[1], [0.1 + 0.2 * 0.6, 0.9 + 0.1 * 0.6, 0.2 + 0.2 * 0.6])
    _check_rows(kind, "LeftWrist", lambda s: goals)


@pytest.mark.parametrize("normal", [[0, 1, 0], [0.3, 0.9, -0.2]])
@pytest.mark.parametrize("side", [1.0, 0.0])
def test_plane_rows_match_finite_differences(normal, side):
    kind = KINDS["plane"]
    n = np.array(normal, float) / np.linalg.norm(normal)
    # the toe is below the plane: an "above" plane is active, an "on" one always
    _check_rows(kind, "LeftToe", lambda s: kind.task_goal(s.position + 0.02 * n, n, side))


@pytest.mark.parametrize("joint", ["LeftWrist", "Head", "RightAnkle", "Hips"])
def test_orientation_rows_match_finite_differences(joint):
    # the goal is the current orientation: the error's map is linear to first order there
    _check_rows(KINDS["orientation"], joint, lambda s: s.rotation.copy())


def _satisfied_goals(sk, state, name):
    kind = KINDS[name]
    if name == "orientation":
        return state.rotation.copy()
    if name == "plane":
        return kind.task_goal(state.position, [0.0, 1.0, 0.0], 0.0)
    return state.position.copy()


@pytest.mark.parametrize("name", list(KINDS))
def test_a_satisfied_task_gives_zero_error(name):
    sk, rot, tra = _walk()
    kind = KINDS[name]
    j = sk.index["RightWrist"]
    state = _state(sk, kind, j, rot, tra)
    err = kind.error(_satisfied_goals(sk, state, name), state)
    assert err.shape == (len(FRAMES), kind.rows)
    np.testing.assert_allclose(err, 0.0, atol=1e-12)


def test_a_satisfied_one_sided_plane_is_not_active():
    sk, rot, tra = _walk()
    kind = KINDS["plane"]
    state = _state(sk, kind, sk.index["LeftToe"], rot, tra)
    up = [0.0, 1.0, 0.0]
    below_it = kind.task_goal(state.position - [0, 0.05, 0], up, 1.0)    # "above": it is
    above_it = kind.task_goal(state.position + [0, 0.05, 0], up, -1.0)   # "below": it is
    assert not np.any(kind.active(below_it, state))
    assert not np.any(kind.active(above_it, state))
    assert np.all(kind.active(kind.task_goal(state.position + [0, 0.05, 0], up, 1.0), state))


# ---------------------------------------------------------------------- goals and files
def _examples() -> dict:
    return {
        "position": Constraint("LeftHand", "position", {"point": [0.1, 1.2, 0.3]}, 1, 2, 3, 4),
        "trajectory": Constraint("RightHand", "trajectory",
                                 {"keys": [[0, 0, 1, 0], [10, 1, 1, 0]]}, 0, 2, 8, 10),
        "plane": Constraint("LeftToe", "plane", {"point": [0, 0.5, 0], "normal": [0, 2, 0],
                                                     "side": "above"}, 0, 3, 9, 9),
        "orientation": Constraint("Head", "orientation", {"quaternion": [0, 0, 0.6, 0.8]},
                                  3, 4, 5, 6),
    }


@pytest.mark.parametrize("goal, field", [
    ({"point": [1, 2]}, "goal.point"),
    ({"points": [[0, 0, 0]]}, "goal.points"),
    ({"points": [[0, 0], [1]]}, "goal.points"),
    ({"keys": [[3, 0, 0, 0], [1, 0, 0, 0]]}, "goal.keys"),
    ({"side": "beside"}, "goal.side"),
    ({"normal": [0, 0, 0]}, "goal.normal"),
    ({"quaternion": [0, 0, 0, 0]}, "goal.quaternion"),
])
def test_a_bad_goal_names_its_field(goal, field):
    kind = field.split(".")[1]
    name = {"point": "position", "points": "trajectory", "keys": "trajectory",
            "side": "plane", "normal": "plane", "quaternion": "orientation"}[kind]
    with pytest.raises(ConstraintError, match=field.replace(".", r"\.")) as exc:
        Constraint("Hips", name, goal, 0, 0, 5, 5)
    assert exc.value.field == field


@pytest.mark.parametrize("name", list(KINDS))
def test_goals_go_to_json_and_back_bit_for_bit(name):
    c = _examples()[name]
    text = json.dumps(c.to_dict())
    back = Constraint.from_dict(json.loads(text))
    assert back.kind_object is c.kind_object
    assert json.dumps(back.to_dict()) == text
    for key, value in c.goal.items():
        assert np.array_equal(back.goal[key], value)


# ---------------------------------------------------------------------- one place
_KIND_WORDS = set(KINDS) | {v for k in KINDS.values() for v in k.variants if v}


def _literals(node):
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        yield node.value
    elif isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        for element in node.elts:
            yield from _literals(element)


def kind_comparisons(root: Path) -> list[str]:
    """Comparisons with a constraint kind's name or a plane side as a string literal in the
    modules under ``engine/`` and ``app/``, outside the kind modules."""
    found = []
    for path in sorted([*root.glob("engine/**/*.py"), *root.glob("app/**/*.py")]):
        rel = path.relative_to(root).as_posix()
        if rel.startswith("engine/correction/constraints/"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), rel)):
            if isinstance(node, ast.Compare) and any(
                    word in _KIND_WORDS for operand in [node.left, *node.comparators]
                    for word in _literals(operand)):
                found.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_no_module_outside_the_kinds_compares_a_kind_to_a_string():
    assert kind_comparisons(REPO) == []


def test_the_check_finds_a_kind_comparison(tmp_path):
    (tmp_path / "engine").mkdir()
    (tmp_path / "engine" / "x.py").write_text(
        'def f(c):\n    return c.kind == "plane" or c.goal["side"] in ("above", "on")\n')
    assert len(kind_comparisons(tmp_path)) == 2
