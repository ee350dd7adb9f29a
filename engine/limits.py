"""The range of the numbers the engine takes from files and settings.

A number must be finite *and* of a magnitude the computations can carry: ``1e308`` is finite,
but it overflows to infinity once scaled to metres, squared in a norm or turned into an angle,
and every frame downstream becomes NaN. No real file or setting comes near
:data:`MAX_MAGNITUDE` (a kilometre in millimetres is ``1e6``; ten thousand turns in degrees
``3.6e6``), and below it products, squares and sums of a few thousand stay far from overflow.
Readers and validators refuse what lies outside with a typed error naming the file and line
or the field; :func:`problem` words the reason.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["MAX_MAGNITUDE", "MAX_FRAME_TIME", "SCALE_RANGE", "problem", "all_usable"]

#: the largest magnitude of a number read from a file or given as a setting (any unit)
MAX_MAGNITUDE = 1e9

#: the metres per file unit a length scale may be, from a micrometre to a kilometre: outside,
#: a skeleton collapses to a point or leaves the range above
SCALE_RANGE = (1e-6, 1e3)

#: the longest frame time accepted, seconds (a tenth of a frame per second)
MAX_FRAME_TIME = 10.0


def problem(value: float) -> str | None:
    """What is wrong with the number ``value``, in words for an error message, or ``None``
    when it is usable (finite and at most :data:`MAX_MAGNITUDE` in magnitude)."""
    if not math.isfinite(value):
        return "not a finite number"
    if abs(value) > MAX_MAGNITUDE:
        return (f"{value:g} is beyond the range accepted (magnitude at most "
                f"{MAX_MAGNITUDE:g})")
    return None


def all_usable(values) -> bool:
    """Whether every number of the array ``values`` (any shape) is finite and at most
    :data:`MAX_MAGNITUDE` in magnitude."""
    return bool(np.all(np.abs(np.asarray(values, dtype=float)) <= MAX_MAGNITUDE))   # NaN: False
