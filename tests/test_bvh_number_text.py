"""The writer's vectorised fixed-point formatting against ``%`` formatting (what the writer
did value by value before), text for text: on every clip and on the values where a fast
formatter goes wrong (near ties, negative zero, values beyond 2^52 at their precision)."""
from __future__ import annotations

import numpy as np
import pytest

from motion_composer.engine import read_bvh
from motion_composer.engine.errors import ExportError
from motion_composer.engine.formats import bvh
from motion_composer.engine.formats.bvh import _format_rows, format_bvh
from conftest import all_bvh_params, resolve


def _percent_rows(values: np.ndarray, decimals: np.ndarray) -> str:
    """The writer's rows as they were formatted before: ``%`` on each row."""
    row_fmt = " ".join(f"%.{d}f" for d in decimals)
    return "\n".join(row_fmt % tuple(row) for row in values.tolist())


@pytest.mark.parametrize("spec", all_bvh_params())
def test_every_clip_is_written_as_before(spec, monkeypatch):
    motion = read_bvh(resolve(spec))
    options = [{}, {"decimals": 3}, {"decimals": 9}, {"channels": "rotation"}]

    def written():
        out = []
        for o in options:
            try:
                out.append(format_bvh(motion, **o))
            except ExportError as exc:            # a moving joint cannot lose its channels
                out.append(str(exc))
        return out

    now = written()
    monkeypatch.setattr(bvh, "_format_rows", _percent_rows)
    assert now == written()


TRICKY = [0.0, -0.0, 0.5, -0.5, 1.5, 2.5, 0.0078125, -0.0078125, 2.5e-7, -2.5e-7, 5e-7, -5e-7,
          4.9999999999e-7, 1.0000005, 0.9999995, -999.9999995, 2.675, -2.675, 0.1234565,
          0.1234575, 1e-300, -1e-300, 1 / 3, -2 / 3, 123456789.123456789, 1e9, -1e9,
          4503599627370495.5, 2.0 ** 52, 9007199254740993.0, 1.7976931348623157e308]


@pytest.mark.parametrize("decimals", [0, 1, 3, 6, 7, 10, 15, 23, 30])
def test_tricky_values(decimals):
    values = np.array([TRICKY, TRICKY[::-1]])
    columns = np.full(values.shape[1], decimals)
    assert _format_rows(values, columns) == _percent_rows(values, columns)


def test_near_ties_and_mixed_precision():
    rng = np.random.default_rng(20261201)
    k = rng.integers(-10 ** 9, 10 ** 9, size=(200, 12))
    ties = (k + 0.5) / 1e6                                   # halves at 6 decimals, rounded
    close = (k + 0.5 + rng.normal(scale=1e-9, size=k.shape)) / 1e6
    wide = rng.normal(scale=50.0, size=(200, 12)) * 10.0 ** rng.integers(-8, 9, size=(200, 12))
    values = np.concatenate([ties, close, wide], axis=1)
    columns = rng.choice([6, 7, 10], size=values.shape[1])
    assert _format_rows(values, columns) == _percent_rows(values, columns)
    assert _format_rows(values[:1, :1], columns[:1]) == _percent_rows(values[:1, :1], columns[:1])


@pytest.mark.parametrize("block", [1, 5, 12, 1000])
def test_rows_formatted_a_block_at_a_time(block, monkeypatch):
    """Blocks of rows that end anywhere, around rows that hold a near tie (written with %),
    give the same text: every separator in place, none doubled."""
    monkeypatch.setattr(bvh, "_FORMAT_VALUES", block)
    rng = np.random.default_rng(20261202)
    values = rng.normal(scale=300.0, size=(40, 6)) * 10.0 ** rng.integers(-3, 4, size=(40, 6))
    values[[0, 7, 8, 21, 39], 2] = 0.0000125                # a tie at 6 decimals, rounded
    values[[3, 4], 5] = -0.0
    for columns in (np.full(6, 6), np.array([0, 3, 6, 7, 1, 12])):
        assert _format_rows(values, columns) == _percent_rows(values, columns)
