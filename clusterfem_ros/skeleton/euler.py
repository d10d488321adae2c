"""Euler angle triples of rotations about three different axes, kept continuous over time.

A rotation R = R1(a) R2(b) R3(c) about three different axes (intrinsic, e.g. "ZYX": R = Rz(a) Ry(b) Rx(c), the
BVH convention and scipy's upper-case one) has two triples, (a, b, c) and (a + pi, pi - b, c + pi), each up
to whole turns per angle. ``continuous_euler`` picks, frame by frame, the one nearest the previous frame's,
so a source wrapping at +-180 deg or flipping to the other triple of the same rotation makes no jump. At
gimbal lock (|cos b| < ``LOCK_COS``) the rotation fixes only a combination of a and c: a keeps its previous
value and c is solved for. ``euler_nearest`` extracts the triples of rotations that way.
"""
from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

LOCK_COS = 1e-6        # |cos b| below this: gimbal lock, only a +- c is defined by the rotation


def continuous_euler(angles: np.ndarray, order: str = "") -> np.ndarray:
    """(F, 3) Euler angles [rad] about three different axes made continuous along F: each frame's triple becomes,
    of the two triples of its rotation, (a, b, c) and (a + pi, pi - b, c + pi), each shifted by whole turns per
    channel, the one nearest (least summed change) the previous frame's. A representation flip is no jump. At
    gimbal lock (|cos b| < LOCK_COS) the rotation fixes only a combination of a and c: with the axes ``order``
    given, a keeps the previous frame's value and c is solved for."""
    a = np.asarray(angles, dtype=np.float64)
    out = a.copy()
    if a.shape[0] < 2:
        return out
    twin = a + np.array([np.pi, 0.0, np.pi])
    twin[:, 1] = np.pi - a[:, 1]
    two_pi = 2.0 * np.pi
    prev = out[0].tolist()
    rows_a, rows_t = a.tolist(), twin.tolist()
    for f in range(1, a.shape[0]):
        best, best_cost = None, np.inf
        for cand in (rows_a[f], rows_t[f]):
            shifted = [x + two_pi * round((p - x) / two_pi) for x, p in zip(cand, prev)]
            cost = sum(abs(x - p) for x, p in zip(shifted, prev))
            if cost < best_cost:
                best, best_cost = shifted, cost
        if order and abs(np.cos(best[1])) < LOCK_COS:
            best[0], best[2] = prev[0], _third_angle(rows_a[f], order, prev[0], best[1], prev[2])
        out[f] = best
        prev = best
    return out


def _third_angle(triple, order: str, a: float, b: float, near: float) -> float:
    """The angle c [rad] about ``order[2]`` with R1(a) R2(b) R3(c) equal to the rotation of ``triple``, nearest
    ``near`` by whole turns."""
    R = Rotation.from_euler(order, triple)
    rest = Rotation.from_euler(order[:2], [a, b]).inv() * R          # R3(c)
    axis = np.eye(3)["XYZ".index(order[2])]
    c = float(rest.as_rotvec() @ axis)
    return c + 2 * np.pi * round((near - c) / (2 * np.pi))




def euler_nearest(R: Rotation | np.ndarray, order: str, previous: np.ndarray) -> np.ndarray:
    """(F, 3) triples [rad] about ``order`` of the F rotations R (a ``Rotation`` or (F, 3, 3) matrices), each the
    one nearest the triple before it, the first nearest ``previous`` (3,)."""
    rot = R if isinstance(R, Rotation) else Rotation.from_matrix(R)
    with warnings.catch_warnings():          # gimbal lock: continuous_euler splits a and c as the frame before
        warnings.simplefilter("ignore", UserWarning)
        raw = rot.as_euler(order.upper())
    return continuous_euler(np.vstack([previous, np.atleast_2d(raw)]), order.upper())[1:]
