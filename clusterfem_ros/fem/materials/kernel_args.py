"""The checks the public force entries (warped_force, element_force, vertex_rotations, element_rotations)
make on their arguments, and their choice between a kernel's serial and threaded builds. Plain numpy.
"""
from __future__ import annotations

import numpy as np

from ..model import FemModel
from ...numba_config import PARALLEL_MIN_VERTICES


def output_rows(n: int, out: np.ndarray | None) -> np.ndarray:
    """``out`` checked as a force's (n, 3) C-contiguous float64 destination, or a new one."""
    if out is None:
        return np.empty((n, 3))
    if out.shape != (n, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous ({n}, 3) float64 array, got {out.dtype} {out.shape}")
    return out


def pick_build(n: int, threads: bool | None, serial, parallel):
    """The serial build below PARALLEL_MIN_VERTICES vertices, the threaded one from there (``threads`` forces
    a choice)."""
    use = n >= PARALLEL_MIN_VERTICES if threads is None else threads
    return parallel if use else serial


def checked_rows(model: FemModel, **arrays) -> list[np.ndarray]:
    """The arrays given by name, each as a C-contiguous float64 (n, 3) array of the model's vertices; a wrong
    shape or a non-finite entry raises ValueError naming the array."""
    out = []
    for name, a in arrays.items():
        a = np.ascontiguousarray(a, dtype=np.float64)
        if a.shape != (model.n_vertices, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({model.n_vertices}, 3) for this mesh")
        if not np.isfinite(a).all():
            raise ValueError(f"{name} has non-finite entries: the state diverged; reset it before warping")
        out.append(a)
    return out
