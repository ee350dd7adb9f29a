"""The whole retargeting job in one call: conversion, constraints, IK, report.

The command line, the project files and (later) the window all run a :class:`Job` through
:func:`run_job`, so a result never depends on which of them asked for it.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .correction.constraints import Constraint, floor_constraint
from .correction.contacts import (ContactOptions, contact_constraints, detect_contacts, find_feet,
                                  horizontal_drift)
from .correction.enforcement import Correction, describe_residuals, enforce
from .conversion.correspondence import Correspondence
from .correction.ik import IKOptions
from .motion import Motion
from .conversion.binding import BindOptions, bind
from .conversion.converter import RootOptions, convert
from .conversion.composer import compose

__all__ = ["Job", "JobResult", "run_job"]


@dataclass(frozen=True, eq=False)
class Job:
    """What to do: performer and target motions, the map, the binding and root choices, the
    user's constraints, automatic contacts and a floor."""

    performer: Motion
    target: Motion
    correspondence: Correspondence
    bind_options: BindOptions = field(default_factory=BindOptions)
    root: RootOptions = field(default_factory=RootOptions)
    constraints: tuple = ()
    auto_contacts: bool = False
    contact_options: ContactOptions = field(default_factory=ContactOptions)
    floor: float | None = None
    ik_options: IKOptions | None = None


@dataclass(frozen=True, eq=False)
class JobResult:
    """What came out: the direct conversion, the corrected motion and a report.

    Attributes:
        composed: the direct conversion (the attraction posture).
        motion: the final motion (``composed`` when there is nothing to enforce).
        constraints: every constraint enforced (the user's, then generated ones).
        correction: the IK result, or None.
        report: JSON-ready figures (residuals, contact drift, timings).
    """

    composed: Motion
    motion: Motion
    constraints: list
    correction: Correction | None
    report: dict


def run_job(job: Job, *, progress=None, cancel=None) -> JobResult:
    timings = {}
    t0 = time.perf_counter()
    binding = bind(job.performer, job.target, job.correspondence, job.bind_options)
    pose = convert(binding, job.performer, job.root)
    name = (f"{job.performer.name}_on_{job.target.name}"
            if job.performer.name and job.target.name else "")
    composed = compose(binding, pose, job.performer.frame_time, name=name)
    timings["conversion_s"] = time.perf_counter() - t0

    constraints: list[Constraint] = list(job.constraints)
    contacts = []
    if job.auto_contacts:
        t0 = time.perf_counter()
        mapped = set(job.correspondence.pairs.values())
        feet = [(a, t if t in mapped else None) for a, t in find_feet(job.performer.skeleton)
                if a in mapped]
        contacts = detect_contacts(job.performer, feet, job.contact_options)
        constraints += contact_constraints(contacts, job.performer, composed,
                                           job.correspondence.pairs, job.contact_options,
                                           floor=job.floor)
        timings["contact_detection_s"] = time.perf_counter() - t0
    if job.floor is not None:
        for ankle, toe in find_feet(job.target.skeleton):
            for joint in (ankle, toe):
                if joint:
                    constraints.append(floor_constraint(joint, composed.num_frames, job.floor))
    correction = None
    motion = composed
    if constraints:
        t0 = time.perf_counter()
        correction = enforce(composed, constraints, options=job.ik_options, progress=progress,
                             cancel=cancel)
        timings["ik_s"] = time.perf_counter() - t0
        timings.update({f"ik_{k.replace(' ', '_')}_s": v
                        for k, v in correction.seconds.items()})
        motion = correction.motion
    report = {
        "frames": composed.num_frames,
        "fps": composed.fps,
        "mapped_joints": len(job.correspondence),
        "constraints": describe_residuals(correction, constraints) if correction else [],
        "contacts": [],
        "timings": timings,
    }
    if contacts:
        pins = [c for c in constraints if c.auto and c.kind_object.fixed_point]
        for c in pins:
            before = horizontal_drift(composed, c.joint, c.start, c.end)
            after = horizontal_drift(motion, c.joint, c.start, c.end)
            report["contacts"].append({"joint": c.joint, "start": c.start, "end": c.end,
                                       "drift_direct_m": before, "drift_corrected_m": after})
        drift_d = [x["drift_direct_m"] for x in report["contacts"]]
        drift_c = [x["drift_corrected_m"] for x in report["contacts"]]
        report["contact_drift"] = {
            "count": len(drift_d),
            "direct_mean_m": float(np.mean(drift_d)) if drift_d else 0.0,
            "direct_max_m": float(np.max(drift_d)) if drift_d else 0.0,
            "corrected_mean_m": float(np.mean(drift_c)) if drift_c else 0.0,
            "corrected_max_m": float(np.max(drift_c)) if drift_c else 0.0,
        }
    return JobResult(composed=composed, motion=motion, constraints=constraints,
                     correction=correction, report=report)
