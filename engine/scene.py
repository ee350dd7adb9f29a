"""The scene: one retargeting session's choices, its sources, and what is derived from them.

A :class:`Scene` is immutable. It holds a :class:`~engine.project.Project` (the user's choices:
sources, correspondence, binding, root, contact and IK options, floor, constraints,
displacement map, viewer state) and the two source motions read from it. Everything else is
derived on demand and cached by its inputs in a :class:`Derived` store shared by the scenes
made from one another, so an edit recomputes only what it touches::

    binding      <- performer, target, correspondence, bind options      (Anatomic Binding)
    intermediate <- binding, root options, floor (its lift)               (Motion Converter)
    composed     <- intermediate                                         (Motion Composer)
    edited       <- composed, animator layers                            (what IK starts from)
    motion       <- edited, solved layer                                 (the final motion)

A constraint edit therefore binds and converts nothing; a mapping edit re-binds. What was
computed is counted in ``scene.derived.computed`` (a test reads it). IK never runs implicitly:
:meth:`Scene.solve` runs the two passes of section 3.3 and returns a :class:`Solution` whose
``scene`` carries the solved constraints and their correction as displacement keys: the solved
layer, on top of the composed motion with the animator's layers (which a solve keeps).

The command line (``retarget``, ``export``, ``batch``), project files and the window all go
through a scene, so a result never depends on which of them asked for it.
"""
from __future__ import annotations

import dataclasses
import os
import time
from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .conversion.automap import automap
from .conversion.binding import bind
from .conversion.composer import compose
from .conversion.converter import convert
from .conversion.followers import above_floor, carriers, follow
from .conversion.correspondence import Correspondence
from .correction.constraints import Constraint, ConstraintError, floor_constraint
from .correction.contacts import (below_foot, capture_noise, contact_constraints,
                                  detect_contacts, find_feet, target_ground)
from .correction.enforcement import Correction, describe_residuals, enforce
from .correction.keyfit import parting, solved_keys
from .correction.reach import SOURCE as REACH, reach_constraints, unreached
from .correction import preview as _preview
from .correction.quality import goal_jumps, quality
from .errors import MotionComposerError
from .motion import Motion
from .project import (Project, Source, check_project, correction_keys, open_project,
                      read_sources)

__all__ = ["Scene", "Solution", "Derived", "remap", "ProjectMotion", "evaluate_project",
           "solve_project"]

#: results kept per derived stage (a few, so that undo and redo hit the cache without holding
#: a motion per undo step)
CACHE_SIZE = 4


class Derived:
    """Results computed from a scene's inputs, by stage and key, a few per stage (LRU).

    Attributes:
        computed: how many times each stage ran (``"binding"``, ``"intermediate"``,
            ``"composed"``, ``"motion"``).
    """

    def __init__(self, size: int = CACHE_SIZE):
        self.size = size
        self.computed: Counter = Counter()
        self._stages: dict[str, OrderedDict] = {}
        #: the live preview's window solver, for the composed motion and solver settings it
        #: was made for (:meth:`Scene.preview`)
        self.window_solver: _preview.WindowSolver | None = None

    def get(self, stage: str, key, compute):
        entries = self._stages.setdefault(stage, OrderedDict())
        if key in entries:
            entries.move_to_end(key)
            return entries[key]
        value = compute()
        self.computed[stage] += 1
        entries[key] = value
        while len(entries) > self.size:
            entries.popitem(last=False)
        return value


class _Failed:
    """A derived stage that raised a user error (an impossible mapping while it is edited)."""

    def __init__(self, error: MotionComposerError):
        self.error = error
        self.message = str(error)


def _guarded(compute):
    """``compute`` returning a :class:`_Failed` instead of raising a user error."""
    def run():
        try:
            return compute()
        except MotionComposerError as exc:
            return _Failed(exc)
    return run


def _pairs_key(correspondence: Correspondence) -> tuple:
    return tuple(correspondence.pairs.items())


@dataclass(frozen=True, eq=False)
class Solution:
    """What :meth:`Scene.solve` gives.

    Attributes:
        scene: the scene with the constraints solved and their correction as keys (the
            solved layer).
        constraints: every constraint enforced.
        correction: the dense IK result (``None`` without enabled constraints), before its
            keys were fitted.
        report: JSON-ready figures (residuals, contact drift, timings) and ``"warnings"``:
            lines on what the settings asked for but could not do (feet for automatic
            contacts, :meth:`Scene.contact_warnings`; a joint's goals it would have to jump
            between, :func:`~engine.correction.quality.goal_jumps`).
    """

    scene: "Scene"
    constraints: list
    correction: Correction | None
    report: dict

    @property
    def motion(self) -> Motion:
        """The motion delivered: the solved scene's (the keys, as a saved project evaluates
        to), not the dense IK result."""
        return self.scene.motion


@dataclass(frozen=True, eq=False)
class Scene:
    """A session: choices (``project``), the source motions, and derived results (cached).

    Project fields read through the scene (``scene.constraints``, ``scene.correspondence``,
    ``scene.viewer``...). Change it with :meth:`replace` (choices), :meth:`with_source`
    (a new performer or target) or :meth:`solve`.
    """

    project: Project
    performer: Motion | None = None
    target: Motion | None = None
    derived: Derived = field(default_factory=Derived, repr=False)

    # ------------------------------------------------------------------ making scenes
    @classmethod
    def empty(cls) -> "Scene":
        return cls(Project(performer=Source(), target=Source()))

    @classmethod
    def from_project(cls, project: Project, performer: Motion | None = None,
                     target: Motion | None = None, *, path=None) -> "Scene":
        """The scene of ``project``, reading its sources unless given; raises
        :class:`~engine.project.ProjectError` naming the field when the project does not fit
        its clips (``path``, the project file, is named in errors)."""
        if performer is None or target is None:
            performer, target = read_sources(project, path=path)
        check_project(project, performer, target, path=path)
        return cls(project, performer, target)

    @classmethod
    def open(cls, path) -> "Scene":
        """The scene of the project file at ``path``."""
        opened = open_project(path)
        return cls(opened.project, opened.performer, opened.target)

    def replace(self, **changes) -> "Scene":
        """A scene with some project fields changed; it shares this one's derived results."""
        return Scene(self.project.replace(**changes), self.performer, self.target, self.derived)

    def with_source(self, role: str, motion: Motion, source: Source, *,
                    remap_pairs: bool = True) -> "Scene":
        """A scene whose performer or target (``role``) is ``motion`` read from ``source``,
        re-mapped (:func:`remap`, unless ``remap_pairs`` is False): the pairs set by hand that still
        name joints of both skeletons are kept, the rest auto-mapped. Constraints and curves
        that name joints the new target does not have are dropped, and so are constraints
        past a new performer's last frame."""
        performer = motion if role == "performer" else self.performer
        target = motion if role == "target" else self.target
        changes = {role: source}
        if remap_pairs and performer is not None and target is not None:
            changes["correspondence"] = remap(self.correspondence, target.skeleton,
                                              performer.skeleton)
        project = self.project.replace(**changes)
        scene = Scene(project, performer, target, self.derived)
        return scene._fitted()

    def _fitted(self) -> "Scene":
        """Drop what no longer fits the sources (joints gone, frames past the end)."""
        p = self.project
        changes = {}
        if self.target is not None:
            names = self.target.skeleton.index
            kept = tuple(c for c in p.constraints if c.joint in names)
            if len(kept) != len(p.constraints):
                changes["constraints"] = kept
            curves = p.displacement.restricted_to(names)
            if curves is not p.displacement:
                changes["displacement"] = curves
            layers = tuple(layer.replace(displacement=layer.displacement.restricted_to(names))
                           for layer in p.layers)
            if any(a.displacement is not b.displacement for a, b in zip(layers, p.layers)):
                changes["layers"] = layers
        if self.performer is not None:
            last = self.performer.num_frames - 1
            kept = tuple(c for c in changes.get("constraints", p.constraints)
                         if c.smooth_out <= last)
            if len(kept) != len(changes.get("constraints", p.constraints)):
                changes["constraints"] = kept
            v = p.viewer
            frame = min(v.current_frame, max(last, 0))
            play = v.play_range
            if play is not None and play[1] > last:
                play = None
            if (frame, play) != (v.current_frame, v.play_range):
                changes["viewer"] = dataclasses.replace(v, current_frame=frame, play_range=play)
        return self.replace(**changes) if changes else self

    def __getattr__(self, name):
        # the project's fields read through the scene (scene.constraints, scene.viewer, ...)
        if name.startswith("__") or name in ("project", "performer", "target", "derived"):
            raise AttributeError(name)
        project = object.__getattribute__(self, "project")
        if name in _PROJECT_FIELDS:
            return getattr(project, name)
        raise AttributeError(f"{type(self).__name__!s} has no attribute {name!r}")

    # ------------------------------------------------------------------ plain facts
    @property
    def num_frames(self) -> int:
        """Frames of the result (the performer's)."""
        return self.performer.num_frames if self.performer is not None else 0

    @property
    def performer_path(self) -> Path | None:
        return Path(self.project.performer.path) if self.project.performer.path else None

    @property
    def target_path(self) -> Path | None:
        return Path(self.project.target.path) if self.project.target.path else None

    @property
    def has_sources(self) -> bool:
        return self.performer is not None and self.target is not None

    # ------------------------------------------------------------------ derived
    def _raw(self, stage: str):
        """A stage's value: the result, a :class:`_Failed`, or None (nothing to compute)."""
        if not self.has_sources or not len(self.correspondence):
            return None
        p = self.project
        bkey = (self.performer, self.target, _pairs_key(p.correspondence), p.bind_options)
        if stage == "binding":
            return self.derived.get("binding", bkey, _guarded(
                lambda: bind(self.performer, self.target, p.correspondence, p.bind_options)))
        binding = self._raw("binding")
        if isinstance(binding, _Failed):
            return binding
        lift = self.lift()
        key = (bkey, p.root, lift)
        if stage == "intermediate":
            return self.derived.get("intermediate", key, _guarded(
                lambda: convert(binding, self.performer, p.root, lift=lift)))
        pose = self._raw("intermediate")
        if isinstance(pose, _Failed):
            return pose
        if stage == "composed":
            name = (f"{self.performer.name}_on_{self.target.name}"
                    if self.performer.name and self.target.name else "")
            return self.derived.get("composed", key, lambda: compose(
                binding, pose, self.performer.frame_time, name=name))
        composed = self._raw("composed")
        layers = tuple((layer.displacement, layer.weight, layer.mute) for layer in p.layers)
        # the control joints carried with the limbs stand where the changed limbs put them;
        # the animator's layers turn them with their parents (a root turned turns the feet),
        # the solved layer does not (the IK's small turn of the root is no turn of the feet,
        # which turn as the performer's)
        if stage == "edited":
            return self.derived.get("edited", (key, layers), lambda: follow(
                binding.followers, _apply_layers(p.layers, composed)))
        edited = self._raw("edited")
        soles = self._soles(p.constraints)
        return self.derived.get("motion", (key, layers, p.displacement, soles), lambda: (
            self._placed(p.displacement.apply(edited), edited, soles)))

    def _soles(self, constraints) -> tuple:
        """``(floor, names)``: the carried feet whose meshes an enabled floor among
        ``constraints`` keeps above the character's floor (:meth:`_placed`); ``names`` empty
        where there are none."""
        carried = {self.target.skeleton.names[j] for j in self.carried}
        if not carried:              # most characters: nothing to look for (asked per frame)
            return 0.0, ()
        names = tuple(sorted({c.joint for c in constraints
                              if c.enabled and c.meta.get("floor") and c.joint in carried}))
        if not names:
            return 0.0, ()
        ground = self.ground()
        return ground.floor, tuple(n for n in names if n in ground.soles)

    def _placed(self, motion: Motion, reference: Motion, soles: tuple) -> Motion:
        """The IK's ``motion`` (a correction of ``reference``) as delivered: the control joints
        carried with the limbs where the limbs put them, turned as their performer joints
        (:func:`~engine.conversion.followers.follow`), and the carried feet ``soles``
        (:meth:`_soles`) turned back towards flat where their meshes would go under the
        floor (:func:`~engine.conversion.followers.above_floor`)."""
        followers = self.binding.followers
        motion = follow(followers, motion, reference)
        floor, names = soles
        if names:
            ground, index = self.ground(), self.target.skeleton.index
            motion = above_floor(followers, motion, floor,
                                 {index[n]: ground.soles[n] for n in names})
        return motion

    def _value(self, stage: str):
        value = self._raw(stage)
        return None if isinstance(value, _Failed) else value

    @property
    def binding(self):
        """The Anatomic Binding (the Intermediate Skeleton), or None (no sources, no map, or
        a map that cannot bind: see :attr:`evaluation_error`)."""
        return self._value("binding")

    @property
    def carried(self) -> dict:
        """The control joints the binding carries with the limbs (joint index -> ``(anchor,
        offset)``, :func:`~engine.conversion.followers.carriers`): the IK holds their goals
        through the limbs. Empty without a binding."""
        binding = self.binding
        return carriers(binding.followers) if binding is not None else {}

    def foot_pairs(self) -> dict[str, str]:
        """The map the feet are found by (target joint -> performer joint): the
        correspondence, and each carried control joint that takes the turn of a performer
        joint the map leaves unmapped (the robot's ``FootL``, past its shin, for the
        performer's ankle): its contacts are held through the limb that carries it."""
        pairs = dict(self.correspondence.pairs)
        binding = self.binding
        if binding is None:
            return pairs
        mapped = set(pairs.values())
        for f in binding.followers:
            if f.source >= 0:
                source = binding.performer.names[f.source]
                if source not in mapped:
                    pairs[binding.target.names[f.joint]] = source
                    mapped.add(source)
        return pairs

    @property
    def intermediate(self):
        """The Intermediate Skeleton over frames (Motion Converter), or None."""
        return self._value("intermediate")

    @property
    def composed(self) -> Motion | None:
        """The direct conversion (Motion Composer): the IK's attraction posture."""
        return self._value("composed")

    @property
    def edited(self) -> Motion | None:
        """The direct conversion with the animator's layers applied: what a solve starts
        from (the IK's attraction posture), or None."""
        return self._value("edited")

    @property
    def motion(self) -> Motion | None:
        """The final motion: the direct conversion, the animator's layers, then the solved
        layer (no IK runs)."""
        return self._value("motion")

    @property
    def ready(self) -> bool:
        """A final motion exists."""
        return self.motion is not None

    def check(self) -> None:
        """Raise the error that stopped the conversion (an impossible map), if any."""
        value = self._raw("motion")
        if isinstance(value, _Failed):
            raise value.error

    @property
    def evaluation_error(self) -> str:
        """Why there is no motion although both sources and a map exist ("" otherwise)."""
        value = self._raw("motion")
        return value.message if isinstance(value, _Failed) else ""

    @property
    def character(self):
        """The target's character with its mesh and skin (a glTF target), or None (a BVH
        target, or one embedded in the project whose file is gone). Cached by the file's
        path, size and time, so that a file written again is read again."""
        path = self.project.target.path
        if path is None or not os.path.isfile(path):
            return None
        from .formats import read_character
        stat = os.stat(path)
        up_axis = self.project.target.up_axis
        return self.derived.get("character", (path, stat.st_size, stat.st_mtime_ns, up_axis),
                                lambda: read_character(path, up_axis=up_axis))

    # ------------------------------------------------------------------ correction
    def automatic_constraints(self) -> list[Constraint]:
        """The constraints the project's settings generate: foot contacts found in the
        performer (``auto_contacts``, with ``contact_options``) and keep-above-floor planes on
        the target's feet (``floor``), each foot joint at or above its planted height over the
        floor (:meth:`ground`). Empty without a direct conversion."""
        composed = self.composed
        if composed is None:
            return []
        p = self.project
        out: list[Constraint] = []
        ground = self.ground()
        pairs = self.foot_pairs()
        sk = self.target.skeleton
        if p.auto_contacts:
            out += contact_constraints(self.contacts(), self.performer, composed, pairs,
                                       p.contact_options, ground=ground,
                                       carried={sk.names[j] for j in self.carried})
        if p.floor is not None:
            # the contacts' floor planes stand on the same floor (``ground``): once is enough
            floored = {c.joint for c in out if c.meta.get("floor")}
            carried = {sk.names[j] for j in self.carried}
            for ankle, toe in self.target_feet(pairs):
                below = [sk.names[k] for k in below_foot(sk, ankle, toe, carried)]
                for joint in (ankle, toe, *below):
                    if joint and joint in ground.heights and joint not in floored:
                        floored.add(joint)          # a foot found twice gets one plane each
                        out.append(floor_constraint(joint, composed.num_frames,
                                                    p.floor + ground.heights[joint]))
        return out

    def regenerated(self) -> "Scene":
        """This scene with its automatic constraints made again from the project's settings
        beside the user's (:meth:`automatic_constraints`): the constraints a solve with
        ``regenerate`` enforces, before it runs (the window's timeline shows them at once).
        The scene itself where it has no direct conversion to find them in."""
        if self.composed is None:
            return self
        return self.replace(constraints=tuple(c for c in self.constraints if not c.auto)
                            + tuple(self.automatic_constraints()))

    def ground(self):
        """Where the target's feet stand (:class:`~engine.correction.contacts.Ground`): the
        target's feet in its reference pose on the floor under them (the lowest mesh vertex
        of the feet where the character has a mesh), moved to ``floor`` where it is set
        (the direct conversion moves with it by :meth:`lift`, where that is not 0)."""
        standing = self._standing()
        if self.project.floor is None:
            return standing
        return dataclasses.replace(standing, floor=float(self.project.floor))

    def lift(self) -> float:
        """[m] How far the direct conversion is raised (lowered, where negative) so that the
        character stands on the project's ``floor``: the floor less the one the character
        stands on in its reference pose (:meth:`standing_floor`). 0 without a floor or feet,
        where the project does not ``stand_on_floor`` (the floor is only the feet's plane, as
        format 3 and older read it), without both sources and a map, and in the
        ``absolute`` root mode, which places the root where the performer's is.

        A floor the conversion does not stand on would otherwise be a correction: the
        contacts would pull each planted foot to it and let it go at every step, and a floor
        above the feet would lift the body by force on every frame (the CMU walk onto the
        CMU T-pose skeleton, whose hips are at 0, with ``--floor 0``: 0.92 m, and joints
        turning at 4.8 times the no-pop limit)."""
        p = self.project
        if p.floor is None or not p.stand_on_floor or p.root.mode == "absolute" \
                or not self.has_sources or not len(self.correspondence):
            return 0.0
        standing = self.standing_floor()
        return 0.0 if standing is None else float(p.floor) - standing

    def floor_changes(self, **fields) -> dict:
        """The project fields that set the floor (``floor``, ``stand_on_floor``) as one edit:
        ``fields``, and the constraints set by hand with their goals moved up or down by as
        much as the new floor moves the character (the change of :meth:`lift`). A goal placed
        on the character as it was shown (a hand on a prop beside it) stays where it was
        against it, and against the floor it stood on: the floor moves the whole set-up, not
        the body alone. The automatic constraints are made again with the floor."""
        rise = self.replace(**fields).lift() - self.lift()
        if rise == 0.0 or all(c.auto for c in self.project.constraints):
            return dict(fields)
        offset = np.array([0.0, rise, 0.0])
        return {**fields, "constraints": tuple(c if c.auto else c.moved(offset)
                                               for c in self.project.constraints)}

    def standing_floor(self) -> float | None:
        """[m] The floor the character stands on in its reference pose, whatever the
        project's ``floor`` (the lowest point of its feet: :meth:`ground` without a floor);
        None without both sources or where no feet are found on either side (a quadruped:
        where it stands is not known, and the floor moves nothing)."""
        if not self.has_sources:
            return None
        standing = self._standing()
        return standing.floor if standing.heights else None

    def _standing(self):
        """The :class:`~engine.correction.contacts.Ground` the character stands on in its
        reference pose, whatever the project's floor (cached: a skinned character's sole is
        found by skinning its mesh)."""
        p = self.project
        reference = p.bind_options.target_reference
        path = p.target.path
        stat = os.stat(path) if path is not None and os.path.isfile(path) else None
        # (the bind options too: the feet carried with the limbs are the binding's followers)
        key = (self.performer, self.target, _pairs_key(p.correspondence), p.bind_options,
               path, stat and (stat.st_size, stat.st_mtime_ns))

        def compute():
            try:
                character = self.character
            except MotionComposerError:      # unreadable now: the feet's joints, not its mesh
                character = None
            feet = self.target_feet(self.foot_pairs())
            # skinned once for the sole under the feet and a carried foot's own vertices
            skinned = _skinned_reference(character, self.target, reference)
            ground = target_ground(self.target, feet, reference=reference,
                                   sole=_sole(skinned, self.target, feet))
            carried = {self.target.skeleton.names[j] for j in self.carried}
            soles = _sole_points(skinned, self.target, [a for a, t in feet
                                                        if a in carried and t is None])
            return dataclasses.replace(ground, soles=soles) if soles else ground
        return self.derived.get("standing", key, compute)

    def target_feet(self, pairs: dict | None = None) -> list:
        """The target's feet ``(ankle, toe)``: those :func:`find_feet` finds on its skeleton,
        and the target joints the map (``pairs``, by default :meth:`foot_pairs`) puts the
        performer's feet on: the robot's feet, control joints carried with its shins. Empty
        without both sources."""
        if not self.has_sources:
            return []
        if pairs is None:
            pairs = self.foot_pairs()
        by_performer = {a: t for t, a in pairs.items()}
        mapped = [(by_performer[a], by_performer.get(t)) for a, t in
                  find_feet(self.performer.skeleton) if a in by_performer]
        return list(dict.fromkeys(find_feet(self.target.skeleton) + mapped))

    def contact_warnings(self) -> list[str]:
        """Why automatic contacts (``auto_contacts``) cannot pin some or all feet, one line
        each: no feet found on the target or the performer, or performer feet the map leaves
        unmapped. Empty when every foot is pinned or automatic contacts are off."""
        if not self.project.auto_contacts or not self.has_sources:
            return []
        performer_feet = [a for a, _ in find_feet(self.performer.skeleton)]
        mapped = set(self.foot_pairs().values())
        unmapped = [a for a in performer_feet if a not in mapped]
        if not find_feet(self.target.skeleton) and len(unmapped) == len(performer_feet):
            return ["no feet found on the target: no automatic contacts"]
        if not performer_feet:
            return ["no feet found on the performer: no automatic contacts"]
        if len(unmapped) == len(performer_feet):
            return [f"the performer's feet ({', '.join(unmapped)}) are not mapped to the "
                    "target: no automatic contacts"]
        return [f"the performer's foot {a} is not mapped to the target: no automatic "
                "contacts on it" for a in unmapped]

    def contacts(self) -> list:
        """The performer's foot contacts (on mapped feet) under the project's options: from
        the heel alone where the map leaves the toe out (the ankle is then held over the
        contact, its orientation too), but for a foot carried with a limb (the robot's),
        found from heel and toe: it has no toe of its own, and
        :func:`~engine.correction.contacts.contact_constraints` holds its ankle where it
        planted on a path that rises through heel-off (found from the heel alone, a
        contact ended before the performer's heel rose and the hold on the other foot threw
        the released one 19 cm in a frame)."""
        return detect_contacts(self.performer, self._contact_feet(),
                               self.project.contact_options)

    def _contact_feet(self) -> list[tuple[str, str | None]]:
        """The performer's feet :meth:`contacts` reads: ``(ankle, toe)``, mapped ankles."""
        pairs = self.foot_pairs()
        mapped = set(pairs.values())
        binding = self.binding
        carried = {binding.performer.names[f.source] for f in binding.followers
                   if f.source >= 0} if binding is not None else set()
        return [(a, t if t in mapped or a in carried else None)
                for a, t in find_feet(self.performer.skeleton) if a in mapped]

    def contact_detection(self) -> dict:
        """How the performer's contacts are read: ``noise_mm``, the noise of its foot paths
        per axis and frame, and ``smoothed``, whether that makes it a noisy capture whose
        paths the detector smooths (:func:`~engine.correction.contacts.capture_noise`)."""
        noise, smoothed = capture_noise(self.performer, self._contact_feet(),
                                        self.project.contact_options)
        return {"noise_mm": 1000.0 * noise, "smoothed": smoothed}

    def solve(self, *, regenerate: bool = False, constraints=None, ik_options=None,
              progress=None, cancel=None, warm_start: bool = False,
              on_dense=None) -> Solution:
        """Run the IK's two passes and store the correction as displacement keys.

        ``constraints``: the list to enforce (default: the scene's own). With
        ``regenerate``, the automatic constraints are dropped and made again from the
        project's settings (:meth:`automatic_constraints`) beside the user's. The IK starts
        from :attr:`edited` (the composed motion with the animator's layers) and its
        correction, as fitted keys, replaces the solved layer only: the animator's layers are
        kept bit for bit. The chains' IK blends add their reach goals (made again on every
        solve, :meth:`reach_constraints`). ``ik_options`` overrides the project's.
        ``on_dense(motion)`` is called once the IK has run, with the dense corrected motion as
        delivered, before its keys are fitted (most of a long solve: the window shows it
        meanwhile). Raises :class:`~engine.errors.MotionComposerError` (``cancel()``
        returning True stops it).
        """
        timings = {}
        t0 = time.perf_counter()
        self.check()
        composed = self.composed
        if composed is None:
            raise MotionComposerError("nothing to solve: the scene has no direct conversion "
                                      "(a performer, a target and a map are needed)")
        timings["conversion_s"] = time.perf_counter() - t0
        chosen = list(self.constraints if constraints is None else constraints)
        warnings = self.contact_warnings() if regenerate else []
        if regenerate:
            t0 = time.perf_counter()
            chosen = [c for c in chosen if not c.auto] + self.automatic_constraints()
            timings["contact_detection_s"] = time.perf_counter() - t0
        _refuse_carried(self.binding, chosen)
        chosen, unreached = self._with_reach(chosen)
        warnings += unreached + goal_jumps(self.edited, chosen)
        correction = None
        if any(c.enabled for c in chosen):
            t0 = time.perf_counter()
            options = ik_options if ik_options is not None else self.project.ik_options
            correction = enforce(self.edited, chosen, options=options,
                                 progress=progress, cancel=cancel, warm_start=warm_start,
                                 carried=self.carried)
            timings["ik_s"] = time.perf_counter() - t0
            timings.update({f"ik_{k.replace(' ', '_')}_s": v
                            for k, v in correction.seconds.items()})
        delivered = correction
        if correction is not None and self.binding.followers:
            # the dense solve as delivered: its carried control joints where its limbs put
            # them (the IK holds their goals through the limbs and leaves them behind)
            delivered = dataclasses.replace(correction, motion=self._placed(
                correction.motion, self.edited, self._soles(chosen)))
        if delivered is not None and on_dense is not None:
            on_dense(delivered.motion)
        # the solved layer: keys fitted to the tasks where they hold them and pop no more
        # than the dense solve, else keys fitted to the dense curves
        t0 = time.perf_counter()
        why: dict = {}
        keys = solved_keys(composed, self.edited, chosen, correction, cancel=cancel,
                           carried=self.carried, why=why)
        timings["keys_s"] = time.perf_counter() - t0
        correction = delivered
        scene = self.replace(constraints=tuple(chosen), displacement=(
            keys if keys is not None else correction_keys(correction)))
        # measured on what is delivered: the keys on top of the animator's layers
        measured = quality(self.performer, composed, scene.motion, chosen,
                           correction.residual if correction is not None else None,
                           self.binding)
        report = _report(composed, correction, chosen, len(self.correspondence), timings,
                         measured)
        report["keys"] = _keys_report(scene, correction, keys is not None, why.get("reason"))
        # the floor the character stands on: the project's, with the conversion moved onto
        # it (``lift_m``), else the one under its feet in its reference pose
        report["floor"] = {"height_m": self.ground().floor, "lift_m": self.lift()}
        # how the two figures were bound: reference poses, root scale, a turn of the target
        report["binding"] = dict(self.binding.notes)
        # the capture's one-frame glitches under held goals, solved from the frames around
        report["glitches"] = list(correction.glitches) if correction is not None else []
        if regenerate and self.project.auto_contacts:
            report["contact_detection"] = self.contact_detection()
        report["warnings"] = warnings
        return Solution(scene=scene, constraints=chosen, correction=correction, report=report)

    def reach_constraints(self, constraints=()) -> list[Constraint]:
        """The chains' IK blends as reach goals on their effectors
        (:mod:`engine.correction.reach`), one priority level below the contacts among
        ``constraints`` (level 2 without contacts). Empty without a direct conversion or
        without IK blends."""
        composed = self.composed
        if composed is None or not any(s.ik_blend > 0 for _, s in self.bind_options.chains):
            return []
        below = 1 + max((c.priority for c in constraints
                         if c.meta.get("source") == "contact"), default=1)
        return reach_constraints(self.binding, self.performer, composed, self.project.root,
                                 priority=below)

    def _with_reach(self, constraints: list) -> tuple[list, list[str]]:
        """``constraints`` with the reach goals made again from the chain settings (any
        previous ones dropped), and lines naming the IK blends that have no goal."""
        kept = [c for c in constraints if c.meta.get("source") != REACH]
        if not any(s.ik_blend > 0 for _, s in self.bind_options.chains):
            return (kept if len(kept) != len(constraints) else constraints), []
        return kept + self.reach_constraints(kept), unreached(self.binding)

    def quality(self) -> dict | None:
        """The quality figures (:func:`~engine.correction.quality.quality`) of the motion as
        it is now, without solving: between solves, what an edit (a key on an animator layer,
        a moved constraint) breaks in the contacts and the turning speeds. No residuals (no
        IK ran). None without a final motion."""
        motion = self.motion
        if motion is None:
            return None
        return quality(self.performer, self.composed, motion, list(self.constraints), None,
                       self.binding)

    def preview(self, constraints: list, *, base_constraints: list | None = None,
                base_motion: Motion | None = None, whole: bool = True) -> tuple[Motion, str]:
        """The corrected motion for ``constraints`` without changing the scene, for a live
        preview while a handle or goal is dragged: ``(motion, mode)``.

        With ``whole`` (or when the change cannot be localised) the whole set is solved
        (mode ``"full"``); otherwise only the frames the change from ``base_constraints`` can
        reach are solved and spliced into ``base_motion`` (mode ``"window"``, see
        :mod:`engine.correction.preview`)."""
        composed = self.edited
        if composed is None:
            raise MotionComposerError("nothing to preview: the scene has no direct conversion")
        _refuse_carried(self.binding, constraints)
        options = self.project.ik_options
        if not whole and base_constraints is not None and base_motion is not None:
            # the window's frames alone, with what the whole clip gives them worked out once
            # per conversion and settings (kept with the derived results across a drag)
            solver = self.derived.window_solver
            if solver is None or not solver.serves(composed, options):
                solver = self.derived.window_solver = _preview.WindowSolver(
                    composed, options, self.carried)
                self.derived.computed["window solver"] += 1
            motion = solver.preview(constraints, base_constraints, base_motion)
            if motion is not None:
                return self._placed(motion, composed, self._soles(constraints)), "window"
        return self._placed(enforce(composed, constraints, options=options,
                                    carried=self.carried).motion,
                            composed, self._soles(constraints)), "full"


_PROJECT_FIELDS = frozenset(f.name for f in dataclasses.fields(Project))


class ProjectMotion(NamedTuple):
    """``composed``: the direct conversion; ``motion``: with the displacement layers
    applied."""

    composed: Motion
    motion: Motion


def evaluate_project(project: Project, performer: Motion | None = None,
                     target: Motion | None = None) -> ProjectMotion:
    """The direct conversion and the final motion (the conversion plus the displacement map).

    No IK runs: the result is a pure function of the project's data, so a saved and reloaded
    project gives the same motion bit for bit. ``performer`` and ``target`` skip reading the
    sources again when the caller has them."""
    scene = Scene.from_project(project, performer, target)
    scene.check()
    return ProjectMotion(scene.composed, scene.motion)


def solve_project(project: Project, performer: Motion | None = None,
                  target: Motion | None = None, *, regenerate: bool = False,
                  ik_options=None, progress=None, cancel=None) -> Project:
    """A copy whose displacement map is the IK correction of its constraints, as keys.

    With ``regenerate``, the automatic constraints are dropped and made again from the
    project's settings (``auto_contacts``, ``floor``); otherwise the constraints are solved as
    they are (automatic ones as edited). The map replaces the previous one, hand edits
    included. ``ik_options`` solve with other settings than the project's."""
    if ik_options is not None:
        # solved with other settings than the project's: the copy holds them (their scale
        # is each run's: the character's stature)
        project = project.replace(ik_options=dataclasses.replace(ik_options, scale=None))
    scene = Scene.from_project(project, performer, target)
    return scene.solve(regenerate=regenerate, progress=progress,
                       cancel=cancel).scene.project


def remap(correspondence: Correspondence, target, performer) -> Correspondence:
    """The map for a new pair of skeletons: the pairs set by hand (those without an auto-map
    note) that still name joints of both skeletons and keep the map one to one, then the
    automatic map for the target joints left (:func:`~engine.conversion.automap.automap`)."""
    kept = {t: p for t, p in correspondence.pairs.items()
            if correspondence.set_by_hand(t) and t in target.index and p in performer.index}
    auto = automap(target, performer)
    used = set(kept.values())
    pairs = dict(kept)
    notes = {}
    for t, p in auto.pairs.items():
        if t in pairs or p in used:
            continue
        pairs[t] = p
        used.add(p)
        notes[t] = auto.notes.get(t) or "auto-mapped"
    ordered = {t: pairs[t] for t in target.names if t in pairs}
    notes.update({t: correspondence.notes[t] for t in kept if t in correspondence.notes})
    return Correspondence(ordered, notes)


def _refuse_carried(binding, constraints) -> None:
    """Raise :class:`ConstraintError` for an enabled constraint the IK cannot hold on a
    control joint the binding carries with a limb (:mod:`engine.conversion.followers`): an
    orientation on it (the IK holds a point there through the limb that carries it, but the
    joint turns as its performer joint, or its anchor, placed after the correction, so no
    turn of the limb meets an orientation goal on it), or any goal on a joint that hangs
    from it (Kenney's ``LeftHeelRoll`` under ``LeftFootCtrl``: the IK would turn the control
    joint and the root above it, and the control joint is placed after the correction)."""
    sk = binding.target
    carried = {sk.names[f.joint]: sk.names[f.anchor] for f in binding.followers}
    for c in constraints:
        if not c.enabled:
            continue
        if c.joint in carried and c.kind_object.task_kind.angular:
            raise ConstraintError(
                f"constraint {c.name or c.joint!r}: {c.joint} is a control joint carried with "
                f"{carried[c.joint]} (unmapped, turned as the performer's joint after the "
                f"IK): no turn of the limb holds its orientation; put the orientation goal on "
                f"{carried[c.joint]} or map {c.joint} to a performer joint")
        if c.joint in sk.index:
            control = next((sk.names[a] for a in sk.ancestors(sk.index[c.joint])
                            if sk.names[a] in carried), None)
            if control is not None:
                raise ConstraintError(
                    f"constraint {c.name or c.joint!r}: {c.joint} hangs from {control}, a "
                    f"control joint carried with {carried[control]} and placed after the IK, "
                    f"which cannot move it; put the goal on {control} or on "
                    f"{carried[control]}")


def _apply_layers(layers, motion: Motion) -> Motion:
    """``motion`` with the animator ``layers`` applied in order (muted ones skipped)."""
    for layer in layers:
        motion = layer.apply(motion)
    return motion


def _skinned_reference(character, target: Motion, reference):
    """``(world pose, [(mesh, vertices (V, 3))], main joint per vertex of each mesh)`` of
    ``character`` skinned in ``target``'s reference pose, or None (no mesh, or a mesh on
    another skeleton)."""
    if character is None or not character.meshes or \
            character.skeleton.names != target.skeleton.names:
        return None
    from .conversion.binding import reference_pose
    from .kinematics import fk_arrays
    from .skinning import skin_character
    sk = target.skeleton
    rot, tra, _ = reference_pose(target, reference)
    pose = Motion._trusted(sk, rot[None], tra[None], target.frame_time, target.name)
    meshes = [(vertices[0], mesh.joints[np.arange(len(mesh.joints)),
                                        np.argmax(mesh.weights, axis=1)])
              for mesh, vertices in zip(character.meshes, skin_character(character, pose))]
    return fk_arrays(sk, rot[None], tra[None], end_sites=False), meshes


def _on_foot(sk, joints) -> np.ndarray:
    """``(J,)`` the joints that are one of ``joints`` or below one."""
    joints = set(joints)
    return np.array([j in joints or bool(set(sk.ancestors(j)) & joints)
                     for j in range(sk.num_joints)])


def _sole(skinned, target: Motion, feet) -> float | None:
    """[m] The lowest vertex of the character's feet (vertices bound mostly to a foot joint
    or a joint below it) in its reference pose (``skinned``: :func:`_skinned_reference`),
    or None (no mesh, or none on the feet)."""
    if skinned is None or not feet:
        return None
    sk = target.skeleton
    foot = _on_foot(sk, [sk.index[n] for f in feet for n in f if n])
    lowest = [float(vertices[foot[main], 1].min()) for vertices, main in skinned[1]
              if foot[main].any()]
    return min(lowest) if lowest else None


def _sole_points(skinned, target: Motion, ankles) -> dict:
    """Per ankle in ``ankles`` the character's mesh vertices bound mostly to it or a joint
    below it, in the ankle's frame in its reference pose (``skinned``:
    :func:`_skinned_reference`; ``{}`` without a mesh)."""
    if skinned is None:
        return {}
    from .quaternions import qconj, qrot
    sk = target.skeleton
    world, meshes = skinned
    out = {}
    for name in ankles:
        a = sk.index[name]
        foot = _on_foot(sk, [a])
        points = np.concatenate([vertices[foot[main]] for vertices, main in meshes] +
                                [np.zeros((0, 3))])
        if len(points):
            q = np.broadcast_to(qconj(world.rotations[0, a]), (len(points), 4))
            out[name] = qrot(q, points - world.positions[0, a])
    return out


def _keys_report(scene: "Scene", correction, fitted: bool, why: str | None = None) -> dict:
    """The solved layer's keys: fitted to the tasks (``"tasks"``) or to the dense curves
    (``"dense curves"``, with why the keys fitted to the tasks were not kept in
    ``"why_dense_curves"``; ``None`` without a correction), how many, and how far the delivered
    motion puts any joint from the path the dense solve takes it along
    (``largest_distance_from_dense_m``, with the joint and frame; from the nearest of that
    path's positions on the frame and either side: :func:`~.correction.keyfit.parting`):
    the keys fitted to the tasks hold them within 1 mm but may part from the dense solve,
    the posture nearest the capture, between and around them."""
    keys = scene.displacement
    out = {"fitted_to": None if correction is None else "tasks" if fitted else "dense curves",
           "count": sum(len(c) for c in keys.curves.values()),
           "largest_distance_from_dense_m": 0.0, "joint": None, "frame": None,
           "why_dense_curves": None if fitted or correction is None else why}
    if correction is None:                   # nothing solved: no keys (``fitted_to`` None)
        return out
    apart, f, j = parting(scene.motion, correction.motion)
    out.update({"largest_distance_from_dense_m": apart,
                "joint": correction.motion.skeleton.names[j], "frame": f})
    return out


def _report(composed: Motion, correction, constraints: list, mapped: int, timings: dict,
            measured: dict) -> dict:
    """The solve's report; ``measured`` is its :func:`~engine.correction.quality.quality`
    (kept as ``"quality"``), whose contacts give the drift figures: the longest first."""
    contacts = sorted(measured["contacts"], key=lambda c: (c["start"] - c["end"], c["start"]))
    report = {
        "frames": composed.num_frames,
        "fps": composed.fps,
        "mapped_joints": mapped,
        "constraints": describe_residuals(correction, constraints) if correction else [],
        "contacts": contacts,
        "timings": timings,
        "quality": measured,
    }
    if contacts:
        drift_d = [x["drift_direct_m"] for x in contacts]
        drift_c = [x["drift_corrected_m"] for x in contacts]
        report["contact_drift"] = {
            "count": len(drift_d),
            "direct_mean_m": float(np.mean(drift_d)),
            "direct_max_m": float(np.max(drift_d)),
            "corrected_mean_m": float(np.mean(drift_c)),
            "corrected_max_m": float(np.max(drift_c)),
        }
    return report
