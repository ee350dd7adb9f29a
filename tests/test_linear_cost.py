"""Issue 14 point 6: contact building in one pass per joint, and IK in chunks of frames, with
the same results as before.

``data/contact_constraints_before.json`` holds the contacts and contact constraints that the
code before the change (one percentile per contact, commit 20ec277) built for three real
clips, written with full float precision; today's must be equal to them.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from motion_composer.engine.correction.contacts import contact_constraints, detect_contacts
from motion_composer.engine.correction.enforcement import enforce
from ik_fixtures import run_on_bandai, walk_on_bandai, walk_on_holden

BEFORE = json.loads((Path(__file__).parent / "data" / "contact_constraints_before.json")
                    .read_text(encoding="utf-8"))


def _goal(constraint) -> dict:
    return {k: v if isinstance(v, str) else np.asarray(v, dtype=float).tolist()
            for k, v in constraint.goal.items()}


@pytest.mark.parametrize("case", [walk_on_holden, walk_on_bandai, run_on_bandai],
                         ids=["walk-bundled", "walk-bandai", "run-bandai"])
def test_contact_constraints_are_those_built_before(case):
    performer, target, corr, composed = case()
    expected = BEFORE[case.__name__]
    contacts = detect_contacts(performer)
    assert [[c.joint, c.toe, c.start, c.end] for c in contacts] == expected["contacts"]
    cons = contact_constraints(contacts, performer, composed, corr.pairs)
    assert len(cons) == len(expected["constraints"])
    for c, e in zip(cons, expected["constraints"]):
        assert (c.name, c.joint, c.kind, list(c.range)) == \
            (e["name"], e["joint"], e["kind"], e["range"])
        assert _goal(c) == e["goal"], c.name          # bit for bit


def test_ik_in_small_chunks_equals_one_batch():
    performer, target, corr, composed = walk_on_holden()
    cons = contact_constraints(detect_contacts(performer), performer, composed, corr.pairs)
    whole = enforce(composed, cons, chunk_frames=composed.num_frames)
    chunked = enforce(composed, cons, chunk_frames=37)
    np.testing.assert_allclose(chunked.rotvecs, whole.rotvecs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(chunked.root, whole.root, rtol=0, atol=1e-12)
    np.testing.assert_allclose(chunked.motion.rotations, whole.motion.rotations, rtol=0,
                               atol=1e-12)
    np.testing.assert_array_equal(chunked.iterations, whole.iterations)
    for i in whole.residual:
        np.testing.assert_allclose(chunked.residual[i], whole.residual[i], rtol=0, atol=1e-12)


def test_a_chunk_of_no_frames_is_refused():
    performer, target, corr, composed = walk_on_holden()
    with pytest.raises(ValueError, match="chunk_frames"):
        enforce(composed, [], chunk_frames=0)
