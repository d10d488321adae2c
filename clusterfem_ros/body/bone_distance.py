"""How far bound vertices are from the segments of their bones, in a posed skeleton: the output check that a
surface vertex was not torn from its bone (``Scene.bone_distance``), run after every batch of steps and on
every state handed to the outputs.

The distance is to the bone's segment (start -> end, as in the binding, body/binding.py), placed by the
pose: a = R c0 + p, b = R c1 + p, with (c0, c1) the segment's ends in the bone's local frame
(``Binding.axis_local``). The vertex loop is a numba kernel (it keeps the GIL: numba_config.HOLDS_GIL):
numpy's gathers and einsums over the 1411 surface vertices of the jelly man took 0.2 ms, as long as the step
they check.
"""
from __future__ import annotations

import numba
import numpy as np

from ..numba_config import HOLDS_GIL


@numba.njit(**HOLDS_GIL)
def _segment_distances(rest, u, vertices, bone, start, axis, out):
    """out[k] = distance of rest[i] + u[i] (i = vertices[k]) to the segment start[b] + s axis[b], s in [0, 1],
    b = bone[i]; a zero-length segment is its start point."""
    for k in range(vertices.shape[0]):
        i = vertices[k]
        b = bone[i]
        x0 = rest[i, 0] + u[i, 0] - start[b, 0]
        x1 = rest[i, 1] + u[i, 1] - start[b, 1]
        x2 = rest[i, 2] + u[i, 2] - start[b, 2]
        d0, d1, d2 = axis[b, 0], axis[b, 1], axis[b, 2]
        length2 = d0 * d0 + d1 * d1 + d2 * d2
        s = (x0 * d0 + x1 * d1 + x2 * d2) / length2 if length2 > 0.0 else 0.0
        s = min(max(s, 0.0), 1.0)
        e0, e1, e2 = x0 - s * d0, x1 - s * d1, x2 - s * d2
        out[k] = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


def segment_distances(rest: np.ndarray, u: np.ndarray, vertices: np.ndarray, bone: np.ndarray,
                      rotation: np.ndarray, translation: np.ndarray, axis_local: np.ndarray) -> np.ndarray:
    """(k,) distance [m] of each vertex ``rest[i] + u[i]``, i in ``vertices`` (k,), to the segment of its bone
    ``bone[i]``, with the bones placed at ``rotation`` (nb, 3, 3) and ``translation`` (nb, 3) and their segments'
    ends ``axis_local`` (nb, 2, 3) in the bones' local frames."""
    start = np.einsum("bij,bj->bi", rotation, axis_local[:, 0]) + translation
    axis = np.einsum("bij,bj->bi", rotation, axis_local[:, 1]) + translation - start
    out = np.empty(vertices.shape[0])
    _segment_distances(rest, u, vertices, bone, start, axis, out)
    return out
