"""Between the window's document and the engine's project files."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from engine.conversion.correspondence import Correspondence
from engine.correction.displacement import DisplacementMap
from engine.project import (MissingSourceError, Project, Source, ViewerState,
                            discard_autosave                             as _discard,
                            find_autosave, open_project, save_project, write_autosave)
from engine.conversion import BindOptions
from engine.conversion import RootOptions

__all__ = ["to_project", "load_into", "save_from", "reset", "autosave", "discard_autosave",
           "recovery_candidate"]


def _source(doc, role: str) -> Source:
    kept = doc.sources.get(role) if hasattr(doc, "sources") else None
    path = doc.performer_path if role == "performer" else doc.target_path
    if kept is not None and (path is None or kept.path == str(path)):
        return kept
    return Source(path=str(Path(path).resolve()) if path is not None else None)


def to_project(doc) -> Project:
    """The document as a project (plain data)."""
    v = doc.viewer
    shown = tuple(name for name, on in (("performer", v.show_performer),
                                        ("intermediate", v.show_intermediate),
                                        ("target", v.show_target)) if on)
    return Project(
        performer=_source(doc, "performer"), target=_source(doc, "target"),
        correspondence=doc.correspondence, bind_options=doc.bind_options,
        root=doc.root_options, auto_contacts=doc.auto_contacts, floor=doc.floor,
        constraints=tuple(doc.constraints), displacement=doc.displacement,
        viewer=ViewerState(current_frame=int(v.current_frame),
                           play_range=tuple(v.play_range) if v.play_range else None,
                           camera=dict(v.camera), shown=shown,
                           options={"side_by_side": bool(v.side_by_side)}))


def _apply(doc, project: Project, performer, target, path) -> None:
    """Put a loaded project into the document (not undoable: a fresh history)."""
    doc.undo_stack.clear()
    doc.path = Path(path) if path is not None else None
    doc.sources = {"performer": project.performer, "target": project.target}
    doc.performer, doc.target = performer, target
    doc.performer_path = Path(project.performer.path) if project.performer.path else None
    doc.target_path = Path(project.target.path) if project.target.path else None
    doc.correspondence = project.correspondence
    doc.bind_options, doc.root_options = project.bind_options, project.root
    doc.auto_contacts, doc.floor = project.auto_contacts, project.floor
    doc.constraints = list(project.constraints)
    doc.displacement = project.displacement
    pv = project.viewer
    doc.viewer.current_frame = int(pv.current_frame)
    doc.viewer.play_range = tuple(pv.play_range) if pv.play_range else None
    doc.viewer.camera = dict(pv.camera)
    doc.viewer.show_performer = "performer" in pv.shown
    doc.viewer.show_intermediate = "intermediate" in pv.shown
    doc.viewer.show_target = "target" in pv.shown
    doc.viewer.side_by_side = bool(pv.options.get("side_by_side", True))
    doc.selection = ("", "")
    doc.sourcesChanged.emit()
    doc.mappingChanged.emit()
    doc.optionsChanged.emit()
    doc.constraintsChanged.emit()
    doc.evaluate()
    doc.frameChanged.emit(doc.viewer.current_frame)
    doc.undo_stack.setClean()
    doc.changed.emit()


def load_into(doc, path: Path, window=None) -> None:
    """Open the project at ``path`` into ``doc``. A clip that has moved is asked for (through
    ``window.ask_open_path``) and the project is retried with the new place."""
    from engine.project import project_from_json, check_project, read_sources
    path = Path(path)
    try:
        opened = open_project(path)
    except MissingSourceError as exc:
        if window is None:
            raise
        project = project_from_json(path.read_text(encoding="utf-8"), path)
        while True:
            role = exc.role if hasattr(exc, "role") else (
                "performer" if str(exc.missing) == str(project.performer.path) else "target")
            new = window.ask_open_path(f"The {role} clip {exc.missing} has moved: where is it?",
                                       "Motion files (*.bvh);;All (*)")
            if not new:
                raise
            source = dataclasses.replace(getattr(project, role), path=str(Path(new).resolve()))
            project = project.replace(**{role: source})
            try:
                performer, target = read_sources(project, path=path)
                check_project(project, performer, target, path=path)
                break
            except MissingSourceError as again:
                exc = again
        _apply(doc, project, performer, target, path)
        doc.undo_stack.resetClean()                  # the moved clip is a change to save
        doc.changed.emit()
        return
    _apply(doc, opened.project, opened.performer, opened.target, path)


def save_from(doc, path: Path) -> None:
    save_project(to_project(doc), path)
    _discard(doc.path)
    doc.path = Path(path)
    doc.undo_stack.setClean()
    _discard(doc.path)
    doc.changed.emit()


def reset(doc) -> None:
    """An empty, unsaved document."""
    doc.undo_stack.clear()
    doc.path = None
    doc.sources = {}
    doc.performer = doc.target = None
    doc.performer_path = doc.target_path = None
    doc.correspondence = Correspondence({})
    doc.bind_options, doc.root_options = BindOptions(), RootOptions()
    doc.constraints = []
    doc.displacement = DisplacementMap()
    doc.viewer.current_frame = 0
    doc.viewer.play_range = None
    doc.selection = ("", "")
    doc.sourcesChanged.emit()
    doc.mappingChanged.emit()
    doc.optionsChanged.emit()
    doc.constraintsChanged.emit()
    doc.evaluate()
    doc.changed.emit()


def autosave(doc) -> Path:
    return write_autosave(to_project(doc), doc.path)


def discard_autosave(doc) -> None:
    _discard(doc.path)


def recovery_candidate(project_path=None):
    """The autosave to offer at start (or when opening ``project_path``), or None."""
    return find_autosave(project_path)
