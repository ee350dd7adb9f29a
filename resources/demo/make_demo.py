"""Builds resources/demo/demo.mcp, the bundled demo project (run again after format changes, and
after any engine change that changes its solve: tests/test_demo_project.py says when).

A freely licensed capture (CMU 131_01, an adult's styled walk, from resources/clips) retargeted
onto a differently built character (the FAIR1 child skeleton from AnimatedDrawings: four spine
joints, child proportions, authored Z-up in inches), with automatic foot contacts and one hand
constraint (the left hand reaches 15 cm higher while walking past), solved, ready to play.
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))

import numpy as np  # noqa: E402

from motion_composer.engine import forward_kinematics, read_bvh  # noqa: E402
from motion_composer.engine.conversion.automap import automap  # noqa: E402
from motion_composer.engine.correction.constraints import Constraint  # noqa: E402
from motion_composer.engine.project import Project, Source, ViewerState, save_project  # noqa: E402
from motion_composer.engine.scene import solve_project  # noqa: E402
from motion_composer.engine.conversion import retarget  # noqa: E402

PERFORMER = HERE.parent / "clips" / "cmu_131_01_walk.bvh"
TARGET = HERE.parent / "clips" / "fair1_child8_jumping.bvh"


def build() -> Project:
    performer, target = read_bvh(PERFORMER), read_bvh(TARGET)
    corr = automap(target.skeleton, performer.skeleton)
    composed = retarget(performer, target, corr)
    hand = forward_kinematics(composed).positions[:, target.skeleton.index["LeftHand"]]
    goal = hand[560] + np.array([0.0, 0.15, 0.05])
    reach = Constraint("LeftHand", "position", {"point": goal}, 520, 545, 575, 600,
                       priority=2, name="left hand reaches up")
    project = Project(performer=Source(path=str(PERFORMER)), target=Source(path=str(TARGET)),
                      correspondence=corr, auto_contacts=True, constraints=(reach,),
                      viewer=ViewerState(current_frame=560,
                                         shown=("performer", "target")))
    return solve_project(project, performer, target, regenerate=True)


if __name__ == "__main__":
    out = HERE / "demo.mcp"
    save_project(build(), out, backup=False)
    print(f"wrote {out}")
