"""Issue 14 point 6: contact building in one pass per joint, and IK in chunks of frames, with
the same results as before.

``data/contact_constraints_before.json`` holds the contacts and contact constraints that the
code before the change (one percentile per contact, commit 20ec277) built for three real
clips, written with full float precision; today's contacts must be equal to them (the
constraints built on them are now the foot model's).
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


@pytest.mark.parametrize("case", [walk_on_holden, walk_on_bandai, run_on_bandai],
                         ids=["walk-bundled", "walk-bandai", "run-bandai"])
def test_contacts_are_those_found_before(case):
    """The foot contacts are those found before; the constraints built on them are the foot
    model's (issue 14 point 1: heel and toe held, not an ankle pin), so they are no longer
    those recorded (tests/test_foot_contacts.py checks what they do)."""
    performer, target, corr, composed = case()
    expected = BEFORE[case.__name__]
    contacts = detect_contacts(performer)
    assert [[c.joint, c.toe, c.start, c.end] for c in contacts] == expected["contacts"]


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
