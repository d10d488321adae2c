"""Skeleton constraint kinds (the paper's eqs. 7-9) as attachment targets for ``fem.model.Control``.

Conventions. A bone pose is the placement x = R c + p of bone-local points c (``rotation`` (nb, 3, 3),
``translation`` (nb, 3)) and its spatial velocity Phi = (omega, v) (``twist`` (nb, 6)), world-aligned,
with v the velocity of the bone origin p. With r = R c = x - p, a point fixed on the bone moves with

    x' = omega x r + v = (-[r]x  I) Phi                                  (eq. 7)
    x'' = (-[r]x  I) Phi' + omega x (omega x r)                          (eq. 8 + the centripetal term)

The paper's eq. 8 keeps only the first term; for a bone spinning at constant omega about its origin
Phi' = 0 and the point's acceleration is all centripetal, so the term is added here. Phi' is a finite
difference supplied by the caller (see ``driver.SkeletonDriver``). Eq. 9's force m_i x''_i is the
attachment's feed-forward ``m_i a*``; the attachment adds m_i (kp (u* - u) + kd (v* - v)) so bound
vertices do not drift (the paper notes none; an acceleration-only force drifts in position).

Targets are *displacements* from rest (u* = x* - X), as ``Attachments`` expects.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence

import numba
import numpy as np

from ..numba_config import HOLDS_GIL


class PoseLike(Protocol):
    """What the constraints read from ``skeleton.kinematics.BonePoses``."""
    rotation: np.ndarray        # (nb, 3, 3)
    translation: np.ndarray     # (nb, 3)
    twist: np.ndarray           # (nb, 6) = (omega, v), world-aligned at the bone origin


def check_poses(poses: PoseLike, n_bones: int, bone_names: Sequence[str] | None = None,
                what: str = "bone poses") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate shapes and finiteness; return (R, p, twist) as float64 arrays.

    Raises ValueError naming the first bone with a non-finite rotation, translation or twist.
    """
    out = []
    for name, shape in (("rotation", (n_bones, 3, 3)), ("translation", (n_bones, 3)), ("twist", (n_bones, 6))):
        a = np.asarray(getattr(poses, name), dtype=np.float64)
        if a.shape != shape:
            raise ValueError(f"{what}: {name} has shape {a.shape}, expected {shape} (the binding has {n_bones} bones)")
        if np.isfinite(a).all():
            out.append(a)
            continue
        bad = ~np.isfinite(a.reshape(n_bones, -1)).all(axis=1)
        if bad.any():
            b = int(np.flatnonzero(bad)[0])
            label = bone_names[b] if bone_names is not None else f"bone {b}"
            raise ValueError(f"{what}: {name} of {label} (index {b}) is not finite ({int(bad.sum())} bones "
                             "affected): check the joint state and the trajectory feeding the skeleton")
        out.append(a)
    return out[0], out[1], out[2]


@numba.njit(**HOLDS_GIL)
def rigid_motion(R, p, twist, dtwist, bone, local, x, v, a):
    """Kernel of ``rigid_point_motion``: fills x, v, a (k, 3); arrays and scalars only."""
    for k in range(bone.shape[0]):
        b = bone[k]
        r0 = R[b, 0, 0] * local[k, 0] + R[b, 0, 1] * local[k, 1] + R[b, 0, 2] * local[k, 2]
        r1 = R[b, 1, 0] * local[k, 0] + R[b, 1, 1] * local[k, 1] + R[b, 1, 2] * local[k, 2]
        r2 = R[b, 2, 0] * local[k, 0] + R[b, 2, 1] * local[k, 1] + R[b, 2, 2] * local[k, 2]
        w0, w1, w2 = twist[b, 0], twist[b, 1], twist[b, 2]
        c0, c1, c2 = w1 * r2 - w2 * r1, w2 * r0 - w0 * r2, w0 * r1 - w1 * r0          # omega x r
        al0, al1, al2 = dtwist[b, 0], dtwist[b, 1], dtwist[b, 2]
        x[k, 0], x[k, 1], x[k, 2] = r0 + p[b, 0], r1 + p[b, 1], r2 + p[b, 2]
        v[k, 0], v[k, 1], v[k, 2] = c0 + twist[b, 3], c1 + twist[b, 4], c2 + twist[b, 5]
        a[k, 0] = al1 * r2 - al2 * r1 + dtwist[b, 3] + w1 * c2 - w2 * c1
        a[k, 1] = al2 * r0 - al0 * r2 + dtwist[b, 4] + w2 * c0 - w0 * c2
        a[k, 2] = al0 * r1 - al1 * r0 + dtwist[b, 5] + w0 * c1 - w1 * c0


def rigid_point_motion(R: np.ndarray, p: np.ndarray, twist: np.ndarray, dtwist: np.ndarray,
                       bone: np.ndarray, local: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World position, velocity and acceleration (each (k, 3)) of points ``local`` (k, 3) fixed on bones ``bone`` (k,).

    ``R`` (nb, 3, 3), ``p`` (nb, 3), ``twist`` and ``dtwist`` = d(Phi)/dt = (alpha, a_origin) (nb, 6);
    x = R c + p, v = omega x r + v_o, a = alpha x r + a_o + omega x (omega x r) with r = R c.
    """
    bone = np.ascontiguousarray(bone, dtype=np.int64)
    local = np.ascontiguousarray(local, dtype=np.float64)
    if local.shape != (bone.size, 3):
        raise ValueError(f"local has shape {local.shape}, expected ({bone.size}, 3) for {bone.size} bone indices")
    if bone.size and (bone.min() < 0 or bone.max() >= R.shape[0]):
        raise ValueError(f"bone index {int(bone.max() if bone.max() >= R.shape[0] else bone.min())} is outside "
                         f"[0, {R.shape[0] - 1}]")
    x, v, a = np.empty((bone.size, 3)), np.empty((bone.size, 3)), np.empty((bone.size, 3))
    rigid_motion(np.ascontiguousarray(R, dtype=np.float64), np.ascontiguousarray(p, dtype=np.float64),
                  np.ascontiguousarray(twist, dtype=np.float64), np.ascontiguousarray(dtwist, dtype=np.float64),
                  bone, local, x, v, a)
    return x, v, a


@dataclass(frozen=True)
class LevelGains:
    """Stabilisation gains per binding level (level 0 innermost): ``kp`` [1/s^2], ``kd`` [1/s].

    The attachment force is m_i (a* + kp (u* - u) + kd (v* - v)): kp is a squared tracking frequency, so
    an error e under a load of g_eff m/s^2 settles at about g_eff / kp. Explicit integrators fold max kp
    into omega^2 and max kd into the damping when planning sub-steps, so very stiff gains cost sub-steps.
    """
    kp: tuple[float, ...]
    kd: tuple[float, ...]

    def __post_init__(self) -> None:
        kp, kd = tuple(float(k) for k in self.kp), tuple(float(k) for k in self.kd)
        object.__setattr__(self, "kp", kp)
        object.__setattr__(self, "kd", kd)
        if len(kp) != len(kd) or not kp:
            raise ValueError(f"LevelGains needs one kp and one kd per level, got {len(kp)} kp and {len(kd)} kd")
        for name, vals in (("kp", kp), ("kd", kd)):
            if not all(np.isfinite(v) and v >= 0 for v in vals):
                raise ValueError(f"LevelGains {name} = {vals} must be finite and >= 0")

    @classmethod
    def default(cls, n_levels: int, kp_inner: float = 4.0e4, ratio: float = 0.25) -> "LevelGains":
        """kp_k = kp_inner * ratio**k, kd_k = 2 sqrt(kp_k) (critically damped tracking of each level).

        kp_inner = 4e4 1/s^2 (200 rad/s) tracks a walking skeleton to about a millimetre and leaves the
        explicit critical step of a jelly body near 1 ms almost unchanged.
        """
        if n_levels < 1:
            raise ValueError(f"n_levels = {n_levels}: a binding has at least one level")
        kp = tuple(kp_inner * ratio ** k for k in range(n_levels))
        return cls(kp, tuple(2.0 * np.sqrt(k) for k in kp))

    @property
    def n_levels(self) -> int:
        return len(self.kp)


@dataclass(frozen=True)
class PointConstraint:
    """Vertex ``vertex`` held at a point: on bone ``bone`` at ``local`` (bone frame; default: the vertex's rest
    position in that frame), or, with ``bone=None``, at the world point ``world`` moving with ``world_velocity``."""
    vertex: int
    bone: int | None = None
    local: tuple[float, float, float] | None = None
    world: tuple[float, float, float] | None = None
    world_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    kp: float = 4.0e4
    kd: float = 400.0

    def __post_init__(self) -> None:
        if (self.bone is None) == (self.world is None):
            raise ValueError(f"point constraint on vertex {self.vertex}: give exactly one of bone= (a point on a "
                             f"bone) or world= (a world point), got bone={self.bone!r}, world={self.world!r}")
        for name, val in (("local", self.local), ("world", self.world), ("world_velocity", self.world_velocity)):
            if val is not None and not (np.shape(val) == (3,) and np.isfinite(val).all()):
                raise ValueError(f"point constraint on vertex {self.vertex}: {name} = {val!r} must be 3 finite numbers")
        if not (np.isfinite([self.kp, self.kd]).all() and self.kp >= 0 and self.kd >= 0):
            raise ValueError(f"point constraint on vertex {self.vertex}: kp = {self.kp}, kd = {self.kd} must be >= 0")


@dataclass(frozen=True)
class LineConstraint:
    """Vertex ``vertex`` kept at its rest offset from the axis of bone ``bone`` but free to slide along it.

    Implemented as an attachment whose target is re-projected every step: the target is the vertex's rest
    point in the bone frame slid along the axis to the vertex's current axial coordinate, and the target
    velocity keeps the vertex's current axial velocity relative to the bone. So the force has no axial
    component at the start of each step; inside a step it only sees the O(h^2) drift between the linear
    target motion and the vertex's, so the slide is free to first order. A vertex on the axis (offset 0)
    is the paper's line constraint.

    ``within_bone=True`` stops the slide at the bone's ends: the vertex's axial coordinate stays within the
    segment (or within its rest coordinate, if that lies beyond an end), and past an end the target is the
    end's point, held like a point constraint. The default slides along the whole line.
    """
    vertex: int
    bone: int
    kp: float = 4.0e4
    kd: float = 400.0
    within_bone: bool = False

    def __post_init__(self) -> None:
        if not (np.isfinite([self.kp, self.kd]).all() and self.kp >= 0 and self.kd >= 0):
            raise ValueError(f"line constraint on vertex {self.vertex}: kp = {self.kp}, kd = {self.kd} must be >= 0")


def point_targets(points: Sequence[PointConstraint], rest: np.ndarray, bones: tuple | None = None):
    """(index, x*, v*, a*, kp, kd) of point constraints; x*, v*, a* are world (k, 3). ``bones``: (rest_R,
    rest_p, R, p, twist, dtwist), the bones' rest and current poses and rates, needed when a point is on a
    bone; world points need none (a scene without skeleton)."""
    k = len(points)
    idx = np.array([c.vertex for c in points], dtype=np.int64)
    x, v, a = np.zeros((k, 3)), np.zeros((k, 3)), np.zeros((k, 3))
    on_bone = np.array([c.bone is not None for c in points], dtype=bool)
    if on_bone.any():
        if bones is None:
            raise ValueError(f"point constraint on vertex {points[int(np.argmax(on_bone))].vertex} is on a bone, "
                             "but no bone poses were given")
        rest_R, rest_p, R, p, twist, dtwist = bones
        sel = np.flatnonzero(on_bone)
        bone = np.array([points[i].bone for i in sel], dtype=np.int64)
        local = np.array([points[i].local if points[i].local is not None else
                          rest_R[points[i].bone].T @ (rest[points[i].vertex] - rest_p[points[i].bone])
                          for i in sel]).reshape(-1, 3)
        x[sel], v[sel], a[sel] = rigid_point_motion(R, p, twist, dtwist, bone, local)
    for i in np.flatnonzero(~on_bone):
        x[i], v[i] = points[i].world, points[i].world_velocity
    return (idx, x, v, a, np.array([c.kp for c in points], dtype=np.float64),
            np.array([c.kd for c in points], dtype=np.float64))


@dataclass(frozen=True)
class LineSet:
    """Many line constraints as arrays, built once (``line_set``), for ``line_set_targets`` every step: the
    vertex, its bone, its rest point in the bone frame and the bone's unit axis there, the gains, and the
    range of the slide (from the rest point, along the axis: -inf/inf for a whole line), (k,)."""
    index: np.ndarray           # (k,) int64
    bone: np.ndarray            # (k,) int64
    rest_local: np.ndarray      # (k, 3)
    axis: np.ndarray            # (k, 3) unit, bone frame
    kp: np.ndarray              # (k,)
    kd: np.ndarray              # (k,)
    slide_min: np.ndarray       # (k,) <= 0 [m]
    slide_max: np.ndarray       # (k,) >= 0 [m]

    def __len__(self) -> int:
        return int(self.index.size)


def line_set(index: np.ndarray, bone: np.ndarray, kp: np.ndarray, kd: np.ndarray, rest: np.ndarray,
             axis_local: np.ndarray, rest_R: np.ndarray, rest_p: np.ndarray,
             within_bone: np.ndarray | bool = False) -> LineSet:
    """The LineSet of vertices ``index`` sliding along bones ``bone`` with gains kp, kd (all (k,)); where
    ``within_bone`` (a bool or (k,)), the slide stops at the bone's ends (LineConstraint). Raises ValueError
    for a zero-length bone, which has no axis."""
    idx = np.asarray(index, dtype=np.int64).reshape(-1)
    bone = np.asarray(bone, dtype=np.int64).reshape(-1)
    axis = axis_local[bone, 1] - axis_local[bone, 0]
    length = np.linalg.norm(axis, axis=1)
    if (length <= 0).any():
        j = int(np.flatnonzero(length <= 0)[0])
        raise ValueError(f"line constraint on vertex {idx[j]}: bone {bone[j]} has zero length, "
                         "so it has no axis; use a point constraint instead")
    axis = axis / length[:, None]
    rest_local = np.einsum("kji,kj->ki", rest_R[bone], rest[idx] - rest_p[bone])
    at = np.einsum("ki,ki->k", rest_local - axis_local[bone, 0], axis)    # the rest point's axial coordinate
    within = np.broadcast_to(np.asarray(within_bone, dtype=bool), idx.shape)
    slide_min = np.where(within, np.minimum(at, 0.0) - at, -np.inf)
    slide_max = np.where(within, np.maximum(at, length) - at, np.inf)
    return LineSet(idx, bone, rest_local, axis, np.asarray(kp, dtype=np.float64).reshape(-1),
                   np.asarray(kd, dtype=np.float64).reshape(-1), slide_min, slide_max)


def line_set_targets(ls: LineSet, R: np.ndarray, p: np.ndarray, twist: np.ndarray, dtwist: np.ndarray,
                     x_now: np.ndarray, v_now: np.ndarray):
    """(index, x*, v*, a*, kp, kd) of the line constraints given the current world positions/velocities (n, 3).
    A slide past its range (LineSet.slide_min/max) is cut to it and held there like a point on the bone."""
    idx, bone, a_hat = ls.index, ls.bone, ls.axis
    c_now = np.einsum("kji,kj->ki", R[bone], x_now[idx] - p[bone])
    slide = np.einsum("ki,ki->k", c_now - ls.rest_local, a_hat)
    free = (slide >= ls.slide_min) & (slide <= ls.slide_max)
    slide = np.clip(slide, ls.slide_min, ls.slide_max)
    x, v, a = rigid_point_motion(R, p, twist, dtwist, bone, ls.rest_local + slide[:, None] * a_hat)
    a_w = np.einsum("kij,kj->ki", R[bone], a_hat)
    along = np.where(free, np.einsum("ki,ki->k", v_now[idx] - v, a_w), 0.0)
    v_rel = along[:, None] * a_w                                             # axial velocity relative to the bone
    a = a + 2.0 * np.cross(twist[bone, :3], v_rel)                          # Coriolis of the slide
    return idx, x, v + v_rel, a, ls.kp, ls.kd


def line_targets(lines: Sequence[LineConstraint], rest: np.ndarray, axis_local: np.ndarray, rest_R: np.ndarray,
                 rest_p: np.ndarray, R: np.ndarray, p: np.ndarray, twist: np.ndarray, dtwist: np.ndarray,
                 x_now: np.ndarray, v_now: np.ndarray):
    """(index, x*, v*, a*, kp, kd) of line constraints given the current world positions/velocities (n, 3)."""
    ls = line_set([c.vertex for c in lines], [c.bone for c in lines], [c.kp for c in lines], [c.kd for c in lines],
                  rest, axis_local, rest_R, rest_p, [c.within_bone for c in lines])
    return line_set_targets(ls, R, p, twist, dtwist, x_now, v_now)
