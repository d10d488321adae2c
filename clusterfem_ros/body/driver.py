"""``SkeletonDriver``: bone poses in, one ``Control`` per physics step out (the paper's eqs. 7-9).

Call ``control(poses_t, dt)`` once per step, before ``integrator.step(state, control, dt)``. The driver
keeps the previous twists to differentiate Phi = (omega, v):

* ``difference="backward"`` (default, streaming): the 3-point one-sided formula
  Phi'(t) ~ (3 Phi_t - 4 Phi_{t-1} + Phi_{t-2}) / 2h (non-uniform spacing handled), O(h^2) at t; it
  needs no future pose. The first two steps fall back to (Phi_t - Phi_{t-1}) / h and to Phi' = 0.
* ``difference="central"`` (a known trajectory): pass ``next_poses`` (the poses at t + dt) and get
  Phi'(t) ~ (Phi_{t+1} - Phi_{t-1}) / 2h, O(h^2). The paper's eq. 9 prints this with 1/h instead of
  1/(2h): that would double the feed-forward acceleration, so we read it as a typo and use 2h (the test
  ``test_body_constraints`` checks the O(h^2) error against the exact centripetal acceleration).

A streaming driver (backward differences, bound points only: the node's) makes each step's targets from the
third on in one compiled pass (``_bone_targets``), with the numpy path's operations in its order, so the same
bits (tests/test_body_constraints.py).

Gains per level come from ``LevelGains``; ``kinematic=True`` prescribes the innermost level exactly
(``Control.prescribed_*``) and drives the outer levels with attachments. The driver only produces
forces and targets, so it works unchanged with or without stiffness warping.
"""
from __future__ import annotations

import math
from typing import Sequence

import numba
import numpy as np

from ..fem.model import Attachments, Control, State
from .binding import Binding
from .crush_release import crush_release, release_gains
from .constraints import (LevelGains, rigid_motion, LineConstraint, PointConstraint, PoseLike, check_poses, line_set,
                          line_set_targets, point_targets, rigid_point_motion)
from ..numba_config import HOLDS_GIL

DIFFERENCES = ("backward", "central")


def _derivative_backward(f: list[np.ndarray], gaps: list[float]) -> np.ndarray:
    """d/dt at the last of the samples f (oldest first), spaced by gaps; order len(f) - 1 (at most 2)."""
    if len(f) == 1:
        return np.zeros_like(f[0])
    if len(f) == 2:
        return (f[1] - f[0]) / gaps[0]
    h1, h2 = gaps[-2], gaps[-1]
    return (f[-3] * h2 / (h1 * (h1 + h2)) - f[-2] * (h1 + h2) / (h1 * h2)
            + f[-1] * (h1 + 2.0 * h2) / (h2 * (h1 + h2)))


@numba.njit(**HOLDS_GIL)
def _bone_targets(R, p, twist, f0, f1, h1, h2, bone, local, rest, dtwist, x, u, v, a):
    """One compiled pass for the streaming step's targets: Phi' by ``_derivative_backward``'s 3-point formula
    from the history (f0, f1) and the new twist, then the bound points' rigid motion (``rigid_motion``), then
    u = x - rest. The same float operations in the same order as those numpy calls, so the same bits. Returns
    False (having filled nothing) if a pose or twist value is not finite: check_poses then names the bone."""
    for b in range(R.shape[0]):
        for i in range(3):
            if not (np.isfinite(p[b, i]) and np.isfinite(R[b, i, 0]) and np.isfinite(R[b, i, 1])
                    and np.isfinite(R[b, i, 2])):
                return False
        for i in range(6):
            if not np.isfinite(twist[b, i]):
                return False
    c0, c1, c2 = h1 * (h1 + h2), h1 * h2, h2 * (h1 + h2)
    s1, s2 = h1 + h2, h1 + 2.0 * h2
    for b in range(R.shape[0]):
        for i in range(6):
            dtwist[b, i] = (f0[b, i] * h2 / c0 - f1[b, i] * s1 / c1) + twist[b, i] * s2 / c2
    rigid_motion(R, p, twist, dtwist, bone, local, x, v, a)
    for k in range(x.shape[0]):
        for i in range(3):
            u[k, i] = x[k, i] - rest[k, i]
    return True


def _derivative_central(fm: np.ndarray, f0: np.ndarray, fp: np.ndarray, hb: float, hf: float) -> np.ndarray:
    """d/dt at the middle sample for back/forward gaps hb, hf; (fp - fm) / 2h when hb = hf."""
    return (hb * hb * fp - hf * hf * fm - (hb * hb - hf * hf) * f0) / (hb * hf * (hb + hf))


class SkeletonDriver:
    """Turns bone poses into constraint targets for the bound vertices of one body.

    ``rest_vertices`` (n, 3) are the body's rest positions (``FemModel.rest``). ``points`` / ``lines`` add
    point and line constraints (line constraints need ``state`` in ``control``). A vertex in several
    constraints gets the sum of their forces; a prescribed vertex ignores forces. The outermost
    ``sliding_levels`` levels are held by line constraints along their bones (free to slide along the axis,
    the paper's line constraints) with their level's gains, the others by points on the bones; their slide
    stops at their bone's ends (LineConstraint.within_bone). With ``crush_floor`` > 0 the gains of the points held
    fall where the targets crush the body's elements ``tets`` (m, 4) that span bones, none of them one of
    ``crush_held`` (body/crush_release.py).
    """

    def __init__(self, binding: Binding, rest_vertices: np.ndarray, gains: LevelGains | None = None, *,
                 kinematic: bool = False, difference: str = "backward",
                 points: Sequence[PointConstraint] = (), lines: Sequence[LineConstraint] = (),
                 bone_names: Sequence[str] | None = None, sliding_levels: int = 0,
                 tets: np.ndarray | None = None, crush_floor: float = 0.0, crush_held: np.ndarray | None = None):
        rest = np.asarray(rest_vertices, dtype=np.float64)
        if rest.shape != (binding.level.size, 3):
            raise ValueError(f"rest_vertices has shape {rest.shape}, but the binding is for "
                             f"{binding.level.size} vertices: bind the same mesh you simulate")
        if difference not in DIFFERENCES:
            raise ValueError(f"difference = {difference!r}: choose 'backward' (streaming) or 'central' "
                             "(needs next_poses)")
        self.gains = LevelGains.default(binding.n_levels) if gains is None else gains
        if self.gains.n_levels != binding.n_levels:
            raise ValueError(f"{self.gains.n_levels} levels of gains for a binding with {binding.n_levels} levels")
        L = binding.n_levels
        if not (isinstance(sliding_levels, (int, np.integer)) and 0 <= sliding_levels <= L):
            raise ValueError(f"sliding_levels = {sliding_levels!r}: give a whole number of levels in [0, {L}]")
        if kinematic and sliding_levels == L:
            raise ValueError(f"sliding_levels = {L} would let the innermost level slide, but kinematic=True "
                             "prescribes it: slide fewer levels or turn the kinematic core off")
        if bone_names is not None and len(bone_names) != binding.n_bones:
            raise ValueError(f"{len(bone_names)} bone names for {binding.n_bones} bones")
        n, nb = rest.shape[0], binding.n_bones
        for c in list(points) + list(lines):
            if not 0 <= c.vertex < n:
                raise ValueError(f"{type(c).__name__} vertex {c.vertex} is outside [0, {n - 1}]")
            if c.bone is not None and not 0 <= c.bone < nb:
                raise ValueError(f"{type(c).__name__} on vertex {c.vertex}: bone {c.bone} is outside [0, {nb - 1}]")
        self.binding = binding
        self.rest = rest
        self.kinematic = bool(kinematic)
        self.difference = difference
        self.points = tuple(points)
        self.lines = tuple(lines)
        self.bone_names = list(bone_names) if bone_names is not None else None
        order = np.argsort(binding.level + (binding.level < 0) * (binding.n_levels + 1), kind="stable")
        self.bound = order[binding.level[order] >= 0]            # bound vertices, innermost level first
        lev = binding.level[self.bound]
        self._kp = np.asarray(self.gains.kp)[lev]
        self._kd = np.asarray(self.gains.kd)[lev]
        if crush_floor and tets is None:
            raise ValueError(f"crush_floor = {crush_floor!r} needs the body's elements: pass tets")
        self.crush = None if tets is None else crush_release(binding, tets, rest, self.bound, crush_floor, crush_held)
        self._kp0, self._kd0 = self._kp, self._kd                # the levels' gains; _kp, _kd: this step's
        if self.crush is not None:
            self._kp, self._kd = self._kp0.copy(), self._kd0.copy()
            self._ratio = np.empty(self.bound.size)
        self._n_inner = int((lev == 0).sum())                    # level 0 is the prefix bound[:n_inner]
        self._n_held = int((lev < L - sliding_levels).sum())     # held at points: bound[:n_held]; then sliding
        self._bone_b = np.ascontiguousarray(binding.bone[self.bound])
        self._local_b = np.ascontiguousarray(binding.local[self.bound])
        self._rest_b = rest[self.bound]
        self._twists: list[np.ndarray] = []
        self._gaps: list[float] = []
        self._last_dt: float | None = None
        self.target_u = np.zeros((self.bound.size, 3))          # last bone targets, displacements
        self.target_v = np.zeros((self.bound.size, 3))
        self.target_a = np.zeros((self.bound.size, 3))
        slide = self.bound[self._n_held:]
        index = np.concatenate([[c.vertex for c in self.lines], slide]).astype(np.int64)
        self._line_set = None if index.size == 0 else line_set(
            index, np.concatenate([[c.bone for c in self.lines], binding.bone[slide]]),
            np.concatenate([[c.kp for c in self.lines], self._kp[self._n_held:]]),
            np.concatenate([[c.kd for c in self.lines], self._kd[self._n_held:]]),
            rest, binding.axis_local, binding.rest_rotation, binding.rest_translation,
            np.concatenate([[c.within_bone for c in self.lines], np.ones(slide.size, bool)]))
        self._sliding = slice(len(self.lines), None)            # the sliding levels' rows of _line_set
        self._slide_axis = np.zeros((slide.size, 3))            # world axes of the sliding vertices' bones
        # The streaming step (_streaming_targets): backward differences, bound points only. Its attachments'
        # index and gains are the same arrays every step, with their maxima (Attachments.gain_max: the integrator
        # plans its sub-steps from them). Writable like the general path's: a read-only array is another type to
        # numba, and the step would be compiled again for it.
        self._streaming = difference == "backward" and not self.points and self._line_set is None
        self._attached_from = self._n_inner if self.kinematic else 0   # kinematic: level 0 is prescribed, not attached
        k0 = self._attached_from
        self._att_const = tuple(np.ascontiguousarray(c[k0:]) for c in (self.bound, self._kp, self._kd))
        kp, kd = self._att_const[1:]
        self._gain_max = (float(kp.max()), float(kd.max())) if kp.size else None
        self._x = np.empty((self.bound.size, 3))
        self._dtwist = np.empty((binding.n_bones, 6))

    def reset(self) -> None:
        """Forget the twist history (after a jump in the trajectory); the next steps use lower-order differences."""
        self._twists, self._gaps, self._last_dt = [], [], None

    def _poses(self, poses: PoseLike, what: str):
        return check_poses(poses, self.binding.n_bones, self.bone_names, what)

    def twist_rate(self, twist: np.ndarray, dt: float, next_twist: np.ndarray | None) -> np.ndarray:
        """Phi'(t) (nb, 6) from the history and the new twist; appends (a copy of) the new twist to the history."""
        if self.difference == "central" and next_twist is None:
            raise ValueError("difference='central' needs next_poses (the bone poses at t + dt); pass them "
                             "or use difference='backward'")
        twist = np.array(twist, dtype=np.float64)          # the skeleton may reuse its output buffers
        if self._last_dt is not None:
            self._twists.append(twist)
            self._gaps.append(self._last_dt)
        else:
            self._twists, self._gaps = [twist], []
        self._twists, self._gaps = self._twists[-3:], self._gaps[-2:]
        self._last_dt = dt
        if self.difference == "central":
            if len(self._twists) == 1:
                return (next_twist - twist) / dt
            return _derivative_central(self._twists[-2], twist, next_twist, self._gaps[-1], dt)
        return _derivative_backward(self._twists, self._gaps)

    def control(self, poses: PoseLike, dt: float, *, next_poses: PoseLike | None = None,
                state: State | None = None, f_ext: np.ndarray | None = None) -> Control:
        """The Control for the step [t, t + dt] given the bone poses at t (and at t + dt for 'central').

        ``state`` (the body's state at t) is needed only by line constraints. Raises ValueError on
        non-finite poses, naming the bone.
        """
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt = {dt!r} s must be a positive finite step")
        if (self._streaming and next_poses is None and len(self._twists) >= 2 and self._last_dt is not None
                and self._streaming_targets(poses, float(dt))):
            return self._control_of(self._bound_attachments(), f_ext)
        R, p, twist = self._poses(poses, "bone poses")
        next_twist = None
        if next_poses is not None:
            next_twist = self._poses(next_poses, "next bone poses")[2]
        dtwist = self.twist_rate(twist, float(dt), next_twist)
        b = self.binding
        n = self.bound.size
        x, v, a = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        rigid_motion(np.ascontiguousarray(R), np.ascontiguousarray(p), np.ascontiguousarray(twist),
                      np.ascontiguousarray(dtwist), self._bone_b, self._local_b, x, v, a)
        self._release(x)
        self.target_u = x - self._rest_b
        self.target_v, self.target_a = v, a

        k0 = self._attached_from
        k1 = self._n_held
        parts = [(self.bound[k0:k1], self.target_u[k0:k1], v[k0:k1], a[k0:k1], self._kp[k0:k1], self._kd[k0:k1])]
        if self.points:
            parts.append(point_targets(self.points, self.rest, (b.rest_rotation, b.rest_translation,
                                                                R, p, twist, dtwist)))
        if self._line_set is not None:
            if state is None:
                raise ValueError("line constraints need the body's current state: call control(..., state=state)")
            parts.append(line_set_targets(self._line_set, R, p, twist, dtwist, self.rest + state.u, state.v))
            sliding = self._sliding
            self._slide_axis = np.einsum("kij,kj->ki", R[self._line_set.bone[sliding]], self._line_set.axis[sliding])
        for j in range(1, len(parts)):                      # point and line targets are world positions
            parts[j] = (parts[j][0], parts[j][1] - self.rest[parts[j][0]]) + tuple(parts[j][2:])
        if len(parts) == 1:                                 # bound points only: held at points, none sliding
            return self._control_of(self._bound_attachments(), f_ext)
        return self._control_of(Attachments(*[np.concatenate([q[i] for q in parts]) for i in range(6)]), f_ext)

    def _streaming_targets(self, poses: PoseLike, dt: float) -> bool:
        """The targets of a streaming step (backward differences with two twists of history, bound points only)
        in one compiled pass, ``_bone_targets``: the numbers of the general path in ``control``, without its
        dozen numpy calls. False (nothing changed) for poses that are not float64 arrays of the binding's shapes
        or not finite: ``control`` then takes the general path, which converts them or names the bad bone."""
        nb = self.binding.n_bones
        try:
            R, p, twist = poses.rotation, poses.translation, poses.twist
            if not (R.shape == (nb, 3, 3) and p.shape == (nb, 3) and twist.shape == (nb, 6)
                    and R.dtype == p.dtype == twist.dtype == np.float64
                    and R.flags.c_contiguous and p.flags.c_contiguous and twist.flags.c_contiguous):
                return False
        except AttributeError:
            return False
        n = self.bound.size
        u, v, a = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        if not _bone_targets(R, p, twist, self._twists[-2], self._twists[-1], self._gaps[-1], self._last_dt,
                             self._bone_b, self._local_b, self._rest_b, self._dtwist, self._x, u, v, a):
            return False
        self._release(self._x)
        self._twists = [self._twists[-2], self._twists[-1], twist.copy()]     # the history twist_rate keeps
        self._gaps = [self._gaps[-1], self._last_dt]
        self._last_dt = dt
        self.target_u, self.target_v, self.target_a = u, v, a
        return True

    def _release(self, x: np.ndarray) -> None:
        """This step's gains from the targets ``x`` (bound rows, world) when the crush release is on (in place: the
        attachments carry the same arrays every step)."""
        c = self.crush
        if c is not None:
            release_gains(x, c.rows, c.v0, c.touched, c.floor, self._kp0, self._kd0, self._kp, self._kd, self._ratio)

    def _bound_attachments(self) -> Attachments:
        """The bound points' attachments at the last targets (level 0 left out if kinematic), with the driver's
        constant index and gains and their maxima: the same arrays every step."""
        k0 = self._attached_from
        index, kp, kd = self._att_const
        return Attachments(index, self.target_u[k0:], self.target_v[k0:], self.target_a[k0:], kp, kd, self._gain_max)

    def _control_of(self, attachments: Attachments, f_ext: np.ndarray | None) -> Control:
        """The step's Control: the attachments, and with ``kinematic`` level 0 prescribed at the last targets."""
        control = Control(f_ext=f_ext, attachments=attachments)
        if self.kinematic:
            k0 = self._n_inner
            control.prescribed_index = self.bound[:k0]
            control.prescribed_u = self.target_u[:k0]
            control.prescribed_v = self.target_v[:k0]
        return control

    def rigid_state(self, poses: PoseLike, t: float = 0.0) -> State:
        """Every vertex (bound or free) carried rigidly by its nearest bone: a start without a jump.

        Starting a moving skeleton from ``State.rest`` yanks the bound vertices at the first step; start
        from this state instead (u = R c + p - X, v = omega x (x - p) + v for each vertex's bone).
        """
        R, p, twist = self._poses(poses, "bone poses")
        b = self.binding
        x, v, _ = rigid_point_motion(R, p, twist, np.zeros_like(twist), b.bone, b.local)
        return State(x - self.rest, v, float(t))

    def tracking_error(self, state: State) -> np.ndarray:
        """(L,) max |u - u*| per level [m], against the targets of the last ``control`` call (same time t); for
        a sliding level, without the slide along the bone's axis that stays within the bone."""
        d = state.u[self.bound] - self.target_u
        tail, axis = d[self._n_held:], self._slide_axis
        if tail.size:
            ls = self._line_set
            slide = np.clip(np.einsum("ki,ki->k", tail, axis), ls.slide_min[self._sliding], ls.slide_max[self._sliding])
            tail -= slide[:, None] * axis
        err = np.linalg.norm(d, axis=1)
        lev = self.binding.level[self.bound]
        return np.array([err[lev == k].max() if (lev == k).any() else 0.0 for k in range(self.binding.n_levels)])
