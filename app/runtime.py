"""Process-wide settings the application makes at start-up.

glibc's allocator hands large blocks (the frame arrays of a clip) back to the system when they
are freed, so the next array of the same size faults its pages in again, about 2.5 us per
4 KiB page on our machines: up to half the time of a conversion goes there. Raising the mmap
and trim thresholds keeps freed memory in the process for reuse. It is a setting of the whole
process, so the application makes it (the command line and the window), not the engine, which
may be imported by other programs.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_done = False


def tune_allocator(limit: int = 512 << 20) -> bool:
    """Keep freed blocks up to ``limit`` bytes in the process (glibc only). True if applied."""
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    ok = bool(mallopt(_M_MMAP_THRESHOLD, limit)) and bool(mallopt(_M_TRIM_THRESHOLD, 2 * limit))
    _done = ok
    return ok
