"""How far bound vertices are from the segments of their bones, in a posed skeleton: the output check that a
surface vertex was not torn from its bone (``Scene.bone_distance``), run after every batch of steps and on
every state handed to the outputs.

The distance is to the bone's segment (start -> end, as in the binding, body/binding.py), placed by the
pose: a = R c0 + p, b = R c1 + p, with (c0, c1) the segment's ends in the bone's local frame
(``Binding.axis_local``). The vertex loop is a numba kernel (it keeps the GIL: numba_config.HOLDS_GIL):
numpy's gathers and einsums over the 1411 surface vertices of the jelly man took 0.2 ms, as long as the step
they check. The check itself (``any_beyond``) compares squared distances with the squared limits and stops
at the first vertex beyond; only then are the distances taken, to name the farthest.
"""
from __future__ import annotations

import numba
import numpy as np

from ..numba_config import HOLDS_GIL


@numba.njit(**HOLDS_GIL)
def _place_segments(rotation, translation, axis_local, start, axis):
    """start[b] <- R c0 + p, axis[b] <- (R c1 + p) - start[b]: bone b's segment placed by its pose."""
    for b in range(rotation.shape[0]):
        for i in range(3):
            a = (rotation[b, i, 0] * axis_local[b, 0, 0] + rotation[b, i, 1] * axis_local[b, 0, 1]
                 + rotation[b, i, 2] * axis_local[b, 0, 2]) + translation[b, i]
            e = (rotation[b, i, 0] * axis_local[b, 1, 0] + rotation[b, i, 1] * axis_local[b, 1, 1]
                 + rotation[b, i, 2] * axis_local[b, 1, 2]) + translation[b, i]
            start[b, i] = a
            axis[b, i] = e - a


@numba.njit(**dict(HOLDS_GIL, inline="always"))
def _squared_distance(rest, u, i, start, axis, b):
    """|x - segment|^2 for x = rest[i] + u[i] and the segment start[b] + s axis[b], s in [0, 1] (a zero-length
    segment is its start point)."""
    x0 = rest[i, 0] + u[i, 0] - start[b, 0]
    x1 = rest[i, 1] + u[i, 1] - start[b, 1]
    x2 = rest[i, 2] + u[i, 2] - start[b, 2]
    d0, d1, d2 = axis[b, 0], axis[b, 1], axis[b, 2]
    length2 = d0 * d0 + d1 * d1 + d2 * d2
    s = (x0 * d0 + x1 * d1 + x2 * d2) / length2 if length2 > 0.0 else 0.0
    s = min(max(s, 0.0), 1.0)
    e0, e1, e2 = x0 - s * d0, x1 - s * d1, x2 - s * d2
    return e0 * e0 + e1 * e1 + e2 * e2


@numba.njit(**HOLDS_GIL)
def _segment_distances(rest, u, vertices, bone, start, axis, out):
    """out[k] = distance of rest[i] + u[i] (i = vertices[k]) to the segment of its bone bone[i]."""
    for k in range(vertices.shape[0]):
        i = vertices[k]
        out[k] = np.sqrt(_squared_distance(rest, u, i, start, axis, bone[i]))


@numba.njit(**HOLDS_GIL)
def _any_beyond(rest, u, vertices, bone, start, axis, limit2):
    """Whether the squared distance of some vertex vertices[k] to its bone's segment is above limit2[k]."""
    for k in range(vertices.shape[0]):
        i = vertices[k]
        if _squared_distance(rest, u, i, start, axis, bone[i]) > limit2[k]:
            return True
    return False


def _segments(rotation: np.ndarray, translation: np.ndarray, axis_local: np.ndarray) -> tuple:
    nb = rotation.shape[0]
    start, axis = np.empty((nb, 3)), np.empty((nb, 3))
    _place_segments(rotation, translation, axis_local, start, axis)
    return start, axis


def segment_distances(rest: np.ndarray, u: np.ndarray, vertices: np.ndarray, bone: np.ndarray,
                      rotation: np.ndarray, translation: np.ndarray, axis_local: np.ndarray) -> np.ndarray:
    """(k,) distance [m] of each vertex ``rest[i] + u[i]``, i in ``vertices`` (k,), to the segment of its bone
    ``bone[i]``, with the bones placed at ``rotation`` (nb, 3, 3) and ``translation`` (nb, 3) and their segments'
    ends ``axis_local`` (nb, 2, 3) in the bones' local frames."""
    out = np.empty(vertices.shape[0])
    _segment_distances(rest, u, vertices, bone, *_segments(rotation, translation, axis_local), out)
    return out


def any_beyond(rest: np.ndarray, u: np.ndarray, vertices: np.ndarray, bone: np.ndarray, rotation: np.ndarray,
               translation: np.ndarray, axis_local: np.ndarray, limit2: np.ndarray) -> bool:
    """Whether some vertex is farther from its bone's segment than its limit (``limit2``: the limits squared,
    (k,)), arguments as ``segment_distances``: the output check's question in one pass without square roots,
    stopping at the first vertex beyond (segment_distances then says which is farthest)."""
    return bool(_any_beyond(rest, u, vertices, bone, *_segments(rotation, translation, axis_local), limit2))
