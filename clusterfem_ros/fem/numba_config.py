"""Numba flags in one place. Kernels are compiled twice from one source: serial and multi-threaded.

``prange`` is a plain ``range`` in the serial build, so the two builds cannot drift apart.
"""
from __future__ import annotations

import numba

SERIAL = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
PARALLEL = dict(SERIAL, parallel=True)

# Below this many vertices a thread pool costs more than it saves (measured by
# `python -m clusterfem_ros.bench.scaling`).
PARALLEL_MIN_VERTICES = 20000


def serial_and_parallel(fn):
    """(serial, parallel) numba builds of one kernel source."""
    return numba.njit(**SERIAL)(fn), numba.njit(**PARALLEL)(fn)
