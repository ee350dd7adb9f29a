"""Project files: one file holds a whole retargeting session.

A :class:`Project` is plain data: the performer and target clips (paths, or the BVH text
embedded), the correspondence, the binding and root choices, automatic-contact settings and a
floor, the constraints (automatic ones included, as edited), the displacement layers (the
solved layer: the IK correction as fitted keys, which a solve replaces; the animator's layers,
with weights and mutes, which a solve keeps) and the viewer state.
Loading never runs IK: the final motion is the direct conversion plus the saved layers,
so it is the same, bit for bit, as before saving (:func:`engine.scene.evaluate_project`). :func:`engine.scene.solve_project`
runs IK again and stores the new correction.

The file is JSON (``.mcp``), human-readable, written deterministically (fixed key order,
floats as Python's shortest round-trip repr, number lists packed on lines), so save, load, save
gives the same bytes::

    {
      "format": "motion-composer-project",
      "version": 4,
      "performer": {"path": "clips/walk.bvh", "units": null, "scale": null, "up_axis": null,
                    "position_mode": null},
      "target": {...},
      "correspondence": {"pairs": {"Hips": "Hips", ...}},
      "binding": {"performer_reference": "auto", "target_reference": "auto",
                  "rest_alignment": true, "distribute": "even", "flat_feet": true,
                  "pose_offsets": {"LeftArm": [x, y, z, w]},
                  "chains": {"arm_l": {"weight": 1.0, "twist": true, "distribute": null,
                                       "ik_blend": 0.0}}},
      "root": {"mode": "scaled", "scale": null},
      "contacts": {"auto": true, "options": {"height": 0.03, ...}},
      "floor": null, "stand_on_floor": true,
      "ik": {"tolerance": 0.0001, "max_iterations": 60, "damping": 0.005, ...},
      "viewer": {"current_frame": 0, "play_range": null, "camera": {...},
                 "shown": ["performer", "target"], "options": {}},
      "constraints": [{"joint": "LeftFoot", "kind": "position", ...}, ...],
      "layers": [{"name": "solved", "kind": "solved",
                  "channels": [{"joint": "LeftLeg", "channel": "rx", "frames": [...],
                                "values": [...], "interpolation": "smooth",
                                "tangents": "aligned", "slopes": [...]}, ...]},
                 {"name": "edit", "kind": "animator", "weight": 1.0, "mute": false,
                  "channels": [...]}],
      "embedded": {"performer": "HIERARCHY\\n..."}
    }

``binding.pose_offsets`` and ``binding.chains`` are written only when set: a file without
them (every file before them) means none, so they need no new version; so is
``binding.flat_feet`` (``true``), which every file before it was solved without.
:mod:`.profile` holds the retarget profiles (``.mcprofile``): the parts of a project that
belong to the pair of skeletons.

Source paths are stored relative to the project file's folder (so a project folder moved with
its clips still opens) and held absolute in memory. ``embedded`` (last, as it is long) holds the
BVH text of clips embedded so that a project can be sent on its own; an embedded clip is read
from the project, its path is kept only to say where it came from.

Every format change gets a new version and a migrator from the one before (:data:`MIGRATIONS`);
an older file is migrated forward on load, a newer one is refused with a clear message.

Bad input raises :class:`ProjectError` naming the file and the field as a JSON path
(``constraints[3].range``); a clip that is not where the project says raises
:class:`MissingSourceError` naming the missing path. Saving is atomic
(:func:`engine.fileio.atomic_write`) and keeps one backup of the previous file
(``<name>.bak``); :func:`write_autosave` and :func:`find_autosave` support crash recovery.

The package: :mod:`.model` (the data, constants, errors), :mod:`.json` (the file's text),
:mod:`.migrations` (older versions), :mod:`.files` (saving, opening, the clips) and
:mod:`.autosave`.
"""
from __future__ import annotations

from .autosave import (autosave_path, discard_autosave, find_autosave, new_session,
                       remove_autosave_file, write_autosave)
from .files import (backup_path, check_project, correction_keys, embed_sources, load_project,
                    open_project, read_sources, save_project)
from .json import project_from_json, project_to_json
from .migrations import MIGRATIONS, migrate, migrator
from .model import (FORMAT, ROLES, SKELETONS, SUFFIX, VERSION, MissingSourceError,
                    OpenedProject, Project, ProjectError, Source, ViewerState)
from .profile import (PROFILE_FORMAT, PROFILE_SUFFIX, PROFILE_VERSION, Profile, ProfileError,
                      SettingsFileError, apply_profile, profile_from_json, profile_of,
                      profile_to_json, read_chain_settings, read_pose_offsets, read_profile,
                      save_profile)

__all__ = ["Project", "Source", "ViewerState", "ProjectError", "MissingSourceError",
           "OpenedProject", "FORMAT", "VERSION", "SUFFIX", "ROLES",
           "SKELETONS", "MIGRATIONS", "migrate", "migrator", "project_to_json",
           "project_from_json", "save_project", "load_project", "open_project", "read_sources",
           "check_project", "correction_keys",
           "embed_sources", "autosave_path", "write_autosave", "find_autosave",
           "discard_autosave", "remove_autosave_file", "new_session", "backup_path",
           "Profile", "ProfileError", "profile_of", "apply_profile", "save_profile",
           "read_profile", "profile_to_json", "profile_from_json", "PROFILE_FORMAT",
           "PROFILE_VERSION", "PROFILE_SUFFIX", "SettingsFileError", "read_pose_offsets",
           "read_chain_settings"]
