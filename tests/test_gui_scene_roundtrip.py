"""Every project field goes through the window and back byte for byte.

A project with a non-default value in every field of :class:`engine.project.Project` (the
list is read from :func:`dataclasses.fields`, so a field added later without window support
fails here) is saved, opened in a :class:`~app.gui.document.Document` (and in the main
window), saved again, and the two files must be the same bytes; also after an edit of each
field and its undo. The document holds no copy of the project's fields: it holds a scene.
"""
from __future__ import annotations

import dataclasses

import pytest

from motion_composer.app.gui.qt import QtCore
from gui_support import quiet_window
from conftest import clip_path
from motion_composer.engine.conversion import BindOptions, ChainSettings, RootOptions
from motion_composer.engine.conversion.correspondence import BY_HAND, Correspondence
from motion_composer.engine.correction.constraints import KINDS, Constraint
from motion_composer.engine.correction.contacts import ContactOptions
from motion_composer.engine.correction.displacement import ROOT, Curve, DisplacementMap, Layer
from motion_composer.engine.correction.ik import IKOptions
from motion_composer.engine.formats import read_motion
from motion_composer.engine.project import (Project, Source, ViewerState, embed_sources, project_to_json,
                            save_project)
from ik_fixtures import MAX_TO_HOLDEN

WALK = clip_path("cmu_131_01_walk.bvh")
TPOSE = clip_path("cmu_rest_tpose.bvh")
FIELDS = [f.name for f in dataclasses.fields(Project)]
DEFAULT = Project(performer=Source(str(WALK)), target=Source(str(TPOSE)))


def every_kind() -> tuple:
    """One constraint of every kind (trajectories both ways), with non-default settings."""
    made = (
        Constraint(joint="LeftHand", kind="position", goal={"point": [0.25, 1.15, 0.2]},
                   smooth_in=380, start=400, end=420, smooth_out=440, priority=2,
                   weight=0.75, name="hand on the rail", meta={"note": "from the storyboard"}),
        Constraint(joint="RightHand", kind="trajectory",
                   goal={"points": [[0.3, 1.0 + 0.01 * i, 0.1] for i in range(11)]},
                   smooth_in=190, start=200, end=210, smooth_out=230, name="wipe"),
        Constraint(joint="LeftFoot", kind="trajectory",
                   goal={"keys": [[500, 0.1, 0.0, 0.3], [540, 0.2, 0.05, 0.5]]},
                   smooth_in=490, start=500, end=540, smooth_out=560, enabled=False),
        Constraint(joint="Head", kind="orientation", goal={"quaternion": [0.0, 0.3826834, 0.0,
                                                                         0.9238795]},
                   smooth_in=600, start=610, end=650, smooth_out=660, weight=0.5),
        Constraint(joint="RightToeBase", kind="plane",
                   goal={"point": [0.0, -0.9, 0.0], "normal": [0.0, 1.0, 0.0],
                         "side": "above"},
                   smooth_in=0, start=0, end=993, smooth_out=993, auto=True,
                   meta={"source": "floor"}),
    )
    assert {c.kind for c in made} == set(KINDS), "a constraint kind is missing here"
    return made


def full_project() -> Project:
    """Every field of a project away from its default."""
    return Project(
        performer=Source(str(WALK), units="cmu", up_axis="+Y", position_mode="absolute",
                         take="Take 001"),
        target=Source(str(TPOSE), scale=0.0254 / 0.45, up_axis="+Y",
                      position_mode={"Hips": "absolute"}),
        correspondence=Correspondence(MAX_TO_HOLDEN, {"Hips": "by hand", "Head": BY_HAND,
                                                      "LeftHand": "hand L (auto-mapped)"}),
        bind_options=BindOptions(performer_reference="rest", target_reference=0,
                                 rest_alignment=False, distribute="first",
                                 pose_offsets={"LeftArm": (0.0, 0.0, 0.0871557427,
                                                           0.9961946981)},
                                 chains={"arm_r": ChainSettings(weight=0.5, twist=False,
                                                                distribute="even",
                                                                ik_blend=0.25)},
                                 flat_feet=True),
        root=RootOptions(mode="absolute", scale=(1.05, 0.98)),
        auto_contacts=True,
        contact_options=ContactOptions(height=0.04, speed=0.3, min_duration=0.1,
                                       max_gap=0.05, ramp=0.1),
        floor=-0.02,
        stand_on_floor=False,
        ik_options=IKOptions(tolerance=2e-4, max_iterations=40, damping=0.01, max_step=0.04,
                             attraction=0.4, settle=2e-5, nullspace_damping=2e-6,
                             step_cap=0.25, polish_share=0.3, priority_gate=8.0,
                             joint_limits=((3, 2.5), (8, 2.0))),
        constraints=every_kind(),
        displacement=DisplacementMap({
            ("LeftForeArm", "rx"): Curve([100.0, 150.0, 200.0], [0.0, 0.1, 0.0],
                                         ("smooth", "constant", "linear")),
            ("Head", "ry"): Curve([0.0, 400.0], [0.05, -0.05], ("linear", "smooth")),
            (ROOT, "ty"): Curve([300.0, 320.0, 340.0], [0.0, 0.02, 0.0], ("smooth",) * 3)}),
        layers=(Layer("arm raise", DisplacementMap({
            ("LeftArm", "rz"): Curve([380.0, 440.0, 500.0], [0.0, 0.3, 0.0], ("smooth",) * 3,
                                     ("flat", "aligned", "broken"),
                                     [(0.0, 0.0), (0.004, 0.004), (-0.01, 0.02)])}),
                      weight=0.75, mute=True), Layer("second")),
        viewer=ViewerState(current_frame=417, play_range=(100, 900),
                           camera={"center": [0.1, 0.9, -0.2], "distance": 3.75,
                                   "azimuth": -31.5, "elevation": 12.25},
                           shown=("intermediate", "target"),
                           options={"side_by_side": False, "grid": "1 m"}))


def field_json(project: Project, name: str) -> str:
    """The file a default project would be with only ``name`` taken from ``project``."""
    return project_to_json(DEFAULT.replace(**{name: getattr(project, name)}))


def assert_same_files(first, second, original: Project, reopened: Project) -> None:
    for name in FIELDS:                       # name the field first, then the bytes
        assert field_json(reopened, name) == field_json(original, name), name
    assert second.read_bytes() == first.read_bytes()


def test_every_field_is_away_from_its_default():
    project = full_project()
    same = [name for name in FIELDS if field_json(project, name) == project_to_json(DEFAULT)]
    assert not same, (f"Project fields {same} keep their default in full_project(): give "
                      "them a value here and make the window carry them")


#: the option classes inside a project, by the project fields that hold them
PARTS = {("performer", "target"): Source, ("bind_options",): BindOptions, ("root",): RootOptions,
         ("contact_options",): ContactOptions, ("ik_options",): IKOptions,
         ("viewer",): ViewerState}
#: never part of a project (each solve takes the character's stature)
NOT_SAVED = {(IKOptions, "scale")}


def test_every_option_is_away_from_its_default():
    """Each field of each option class, in the project with paths or with embedded clips."""
    variants = [full_project(), embed_sources(full_project())]
    kept = []
    for names, cls in PARTS.items():
        for f in dataclasses.fields(cls):
            if (cls, f.name) in NOT_SAVED:
                continue
            base = getattr(cls(), f.name)
            if not any(getattr(getattr(v, n), f.name) != base for v in variants for n in names):
                kept.append(f"{'/'.join(names)}.{f.name}")
    assert not kept, (f"{kept} keep their default in full_project(): give them a value here "
                      "and make the window carry them")


def edits(doc, project: Project):
    """``(field, edit)`` for every field: an undoable change of it through the document (the
    viewer, outside the history, is changed and set back)."""
    def source(role):
        path = TPOSE if role == "target" else WALK
        motion = read_motion(path)
        return lambda: doc.set_source(role, motion, Source(str(path)), f"Import {role}")

    def field(name):
        return lambda: doc.edit(f"Edit {name}", **{name: getattr(DEFAULT, name)})

    for name in FIELDS:
        if name == "viewer":
            yield name, None
        elif name in ("performer", "target"):
            yield name, source(name)
        else:
            yield name, field(name)


# --------------------------------------------------------------------------- the document
@pytest.fixture(params=["paths", "embedded"])
def saved(tmp_path, request):
    project = full_project()
    if request.param == "embedded":
        project = embed_sources(project)
    path = tmp_path / "full.mcp"
    save_project(project, path)
    return project, path


def test_the_document_saves_what_it_opened(qtbot, saved, tmp_path):
    from motion_composer.app.gui.document import Document
    project, path = saved
    doc = Document()
    doc.open(path)
    assert doc.scene.ready, doc.scene.evaluation_error
    held = [getattr(doc.scene.project, name) for name in FIELDS]
    copies = [attr for attr, value in vars(doc).items() if any(value is v for v in held)]
    assert not copies, f"the document holds project fields itself: {copies}"
    again = tmp_path / "again.mcp"
    doc.save(again)
    assert_same_files(path, again, project, doc.scene.project)
    doc.close()


@pytest.mark.parametrize("name", FIELDS)
def test_an_edit_and_its_undo_save_the_same_bytes(qtbot, saved, tmp_path, name):
    from motion_composer.app.gui.document import Document
    project, path = saved
    doc = Document()
    doc.open(path)
    opened = doc.scene
    edit = dict(edits(doc, project))[name]
    if edit is None:
        viewer = doc.scene.viewer
        doc.set_viewer(play_range=None, camera={}, show_performer=True, side_by_side=True)
        doc.set_frame(0)
        assert doc.scene.viewer != viewer
        doc.set_viewer(play_range=viewer.play_range, camera=viewer.camera,
                       show_performer=False, side_by_side=False)
        doc.set_frame(viewer.current_frame)
    else:
        edit()
        assert doc.undo_stack.count() == 1 and doc.modified, f"editing {name} made no step"
        assert field_json(doc.scene.project, name) != field_json(project, name), name
        doc.undo_stack.undo()
        assert doc.scene is opened and not doc.modified
    again = tmp_path / "again.mcp"
    doc.save(again)
    assert_same_files(path, again, project, doc.scene.project)
    doc.close()


# --------------------------------------------------------------------------- the window
@pytest.fixture
def window(qtbot, tmp_path, monkeypatch):
    w = quiet_window(qtbot, tmp_path, monkeypatch)
    w.ask_yes_no = lambda question: False
    w.show()
    yield w
    w.doc.undo_stack.setClean()


def test_the_window_saves_what_it_opened(window, saved, tmp_path, qtbot):
    """Through every panel the window builds (viewport, timeline, inspector, curves, playback,
    mapping and binding panels), an edit of each field and its undo, then Save As."""
    project, path = saved
    assert window.open_project(path), window.errors
    QtCore.QCoreApplication.processEvents()     # queued refreshes run
    for name, edit in edits(window.doc, project):
        if edit is not None:
            edit()
            window.undo_action.trigger()
    QtCore.QCoreApplication.processEvents()
    again = tmp_path / "again.mcp"
    window.ask_save_path = lambda caption, filters: str(again)
    assert window.save_as(), window.errors
    assert_same_files(path, again, project, window.doc.scene.project)


def test_a_moved_camera_is_saved(window, saved, tmp_path):
    """The camera comes back as opened only while the view has not moved since."""
    project, path = saved
    assert window.open_project(path), window.errors
    window.viewport.orbit(10.0, 5.0)
    moved = tmp_path / "moved.mcp"
    window.ask_save_path = lambda caption, filters: str(moved)
    assert window.save_as(), window.errors
    camera = window.doc.scene.viewer.camera
    assert camera["azimuth"] == pytest.approx(project.viewer.camera["azimuth"] + 10.0)
    assert camera["elevation"] == pytest.approx(project.viewer.camera["elevation"] + 5.0)
    assert moved.read_bytes() != path.read_bytes()
