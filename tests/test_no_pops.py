"""Issue 14 point 2, degenerate ramps: a constraint whose ramps are one frame long (or whose
active range is one frame between one-frame ramps) is solved without a pop, by the no-pop
rule of :mod:`engine.correction.quality` (over a one-frame span a smoothstep may turn the
whole correction in that frame, times 1.5), on a real walk; the goal is still met."""
from __future__ import annotations

import numpy as np
import pytest

from ik_fixtures import walk_on_holden
from motion_composer.engine import forward_kinematics
from motion_composer.engine.correction.constraints import Constraint
from motion_composer.engine.correction.enforcement import enforce
from motion_composer.engine.correction.quality import quality


@pytest.mark.parametrize("frames", [(199, 200, 240, 241), (199, 200, 200, 201)],
                         ids=["one-frame ramps", "one frame between one-frame ramps"])
def test_one_frame_ramps_are_solved_without_a_pop(frames):
    performer, _, _, composed = walk_on_holden()
    sk = composed.skeleton
    hand = forward_kinematics(composed).positions[:, sk.index["LeftHand"]]
    c = Constraint("LeftHand", "position", {"point": hand[220] + [0.1, 0.15, 0.05]}, *frames)
    result = enforce(composed, [c])
    q = quality(performer, composed, result.motion, [c], result.residual)
    assert q["constraints"][0]["max_residual"] < 1e-3
    worst = q["pops"][0]
    assert worst["ratio"] <= 1.0, worst
    # a real correction: on the first held frame the hand is far from its own path
    moved = forward_kinematics(result.motion).positions[c.start, sk.index["LeftHand"]]
    assert np.linalg.norm(moved - hand[c.start]) > 0.1
