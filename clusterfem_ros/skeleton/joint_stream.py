"""``JointStreamInterpolator``: joint samples arriving at any rate in, q(t) and v(t) at physics times out.

``push(stamp_s, q, v=None)`` stores a sample; ``sample(t)`` interpolates linearly between the samples
bracketing t. Revolute angles are unwrapped on arrival (each new angle is moved by a multiple of 2 pi
to within pi of the previous one), so 179 deg -> -179 deg passes through 180 deg, never through 0; the
stored angles are continuous and may leave [-pi, pi]. The three angles of a ball joint (``balls``, below)
are stored as the triple of their rotation nearest the previous one, (a, b, c) or (a + pi, pi - b, c + pi),
so a sender flipping between the two never makes the interpolation swing. Between samples v is the slope of the
interpolating segment (the finite difference of the bracketing samples), message velocities or not: the pose
and the velocity the body is driven with must agree. Interpolated message velocities would not: on samples
50 ms apart (a player's timer late on a loaded host) a fast toe's would lie far from its segment's slope, and
the binding's damping would tear the foot's flesh from its bone. Message velocities carry the pose on after the
newest sample (``horizon``) and are checked against ``max_joint_speed``.

No wild extrapolation: after the newest sample the pose moves on with the newest velocity for at most
``horizon`` seconds (default 0: held), then is held with v = 0. Before the oldest sample it is held.

``push`` returns the problems found as (kind, message). Rejected (kinds in ``FATAL``): a sample not
newer than the newest (``out_of_order``), older than newest - ``max_age`` (``stale``), newer than newest
+ ``max_future`` (``future``; or than ``now`` + max_future when the caller passes its clock), of the wrong shape or non-finite (``bad_sample``). A stream that really
restarted (a replayed bag, a clock jump) is not locked out: ``restart_after`` consecutive rejected
samples with increasing stamps restart the stream from the last of them, if it passes the range checks
(reported as ``restart``). A prismatic jump between consecutive samples larger than ``teleport_distance``
and faster than ``teleport_speed`` is accepted but reported (``teleport``) and interpolation does not sweep
across it: the older samples are dropped. Both, because a sender that stalled (a player's timer starved for half
a second on a loaded host) resumes as far on as its root walked meanwhile: a long jump over a long gap is motion.

Range checks (rejected, counted by the caller; both limits are optional):

* ``root_range``: the prismatic joints (the root's translation in our URDFs) further than
  ``max_root_distance`` [m] from the origin. Never accepted later: a body that far away is a broken
  publisher or a scene that needs a larger limit, not motion.
* ``joint_speed``: a joint moving faster than ``max_joint_speed`` [rad/s or m/s] since the accepted sample
  that last moved it (unwrapped angles; a prismatic teleport is reported as one instead), or a
  reported velocity above it. Capture glitches (a thigh flipping 175 deg in one frame) are dropped. Three
  revolute joints that form one ball joint (``balls``: (B, 3) joint indices, their axes (B, 3, 3), R = R(axis0,
  q0) R(axis1, q1) R(axis2, q2); ``Skeleton.ball_joints``) are checked as a rotation: the geodesic angle of
  R_prev^T R_new, so Euler channels trading angle near gimbal lock, or flipping to the other triple of the same
  rotation, are no speed. So that
  real motion faster than the limit can never lock the stream out, a sample still rejected for speed
  ``max_age`` seconds after the first rejection of that run restarts the stream from it (``restart``; the
  body is re-placed on the skeleton).

What the stream took in decides alone what it does with the next sample: every push stores the sample it was
given or nothing (``took_last``), and a refused sample changes only the bookkeeping that may later restart the
stream. So the samples taken in, pushed again in order with ``taken=True`` (a recording read back: refused here,
a sample was one the stream restarted on), give the same stored samples, the same problems and the same
``sample(t)``, without the refused samples (which a recording does not keep).

Arrays: q, v (n,) float64 [rad, m, rad/s, m/s]; stamps float seconds. The buffer holds at most
``capacity`` samples.
"""
from __future__ import annotations

from bisect import bisect_right
from collections import deque
from typing import Sequence

import numba
import numpy as np

from ..errors import ClusterFemError
from ..numba_config import HOLDS_GIL

FATAL = frozenset({"out_of_order", "stale", "future", "bad_sample", "root_range", "joint_speed"})


class StaleSample(ClusterFemError, ValueError):
    """Raised by ``push_or_raise`` for a rejected sample; ``kind`` is one of ``FATAL``."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles mapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


@numba.njit(**HOLDS_GIL)
def _range_measures(q, v, prev, revolute, prismatic, moved_at, stamp, max_speed):
    """What the range checks compare, in one compiled pass (a dozen numpy calls took 46 us a sample): the
    prismatic joints' distance from the origin; the joint with the largest reported |v| (0 without v); the
    prismatic joints' jump from ``prev``; and the joint k whose step from ``prev`` (angles wrapped to
    [-pi, pi)) most exceeds max_speed times the time since the sample that last moved it, with that step and
    time (the first such joint)."""
    root = 0.0
    jump = 0.0
    for k in range(q.shape[0]):
        if prismatic[k]:
            root += q[k] * q[k]
            jump += (q[k] - prev[k]) * (q[k] - prev[k])
    fastest = 0
    for k in range(v.shape[0]):
        if abs(v[k]) > abs(v[fastest]):
            fastest = k
    worst, kw, step_k, dt_k = -np.inf, 0, 0.0, 0.0
    for k in range(q.shape[0]):
        d = q[k] - prev[k]
        if revolute[k]:
            d = (d + np.pi) % (2.0 * np.pi) - np.pi
        step = abs(d)
        dt = stamp - moved_at[k]
        excess = step - max_speed * dt
        if excess > worst:
            worst, kw, step_k, dt_k = excess, k, step, dt
    return np.sqrt(root), fastest, np.sqrt(jump), kw, step_k, dt_k


@numba.njit(**HOLDS_GIL)
def _nearest_ball_triples(q, prev, balls):
    """In place: each ball joint's angles in q re-expressed as the triple of the same rotation nearest ``prev``: of
    (a, b, c) and (a + pi, pi - b, c + pi) (three orthogonal axes), each shifted by whole turns."""
    two_pi = 2.0 * np.pi
    best = np.empty(3)
    cand = np.empty(3)
    for b in range(balls.shape[0]):
        best_cost = np.inf
        for twin in range(2):
            for i in range(3):
                x = q[balls[b, i]]
                if twin:
                    x = np.pi - x if i == 1 else x + np.pi
                p = prev[balls[b, i]]
                cand[i] = x + two_pi * np.round((p - x) / two_pi)
            cost = abs(cand[0] - prev[balls[b, 0]]) + abs(cand[1] - prev[balls[b, 1]]) + \
                abs(cand[2] - prev[balls[b, 2]])
            if cost < best_cost:
                best_cost = cost
                best[:] = cand
        for i in range(3):
            q[balls[b, i]] = best[i]


@numba.njit(**HOLDS_GIL)
def _axis_rotation(axis, angle):
    c, s_ = np.cos(angle), np.sin(angle)
    x, y, z = axis[0], axis[1], axis[2]
    t = 1.0 - c
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = t * x * x + c, t * x * y - s_ * z, t * x * z + s_ * y
    R[1, 0], R[1, 1], R[1, 2] = t * x * y + s_ * z, t * y * y + c, t * y * z - s_ * x
    R[2, 0], R[2, 1], R[2, 2] = t * x * z - s_ * y, t * y * z + s_ * x, t * z * z + c
    return R


@numba.njit(**HOLDS_GIL)
def _ball_measures(q, prev, balls, axes, moved_at, stamp, max_speed):
    """The ball joint b whose turn from ``prev`` (the geodesic angle of R_prev^T R_q) most exceeds max_speed times
    the time since the sample that last moved it, with that angle and time (the first such ball)."""
    worst, kb, angle_k, dt_k = -np.inf, 0, 0.0, 0.0
    for b in range(balls.shape[0]):
        Ra = np.eye(3)
        Rb = np.eye(3)
        last = moved_at[balls[b, 0]]
        for i in range(3):
            j = balls[b, i]
            Ra = Ra @ _axis_rotation(axes[b, i], prev[j])
            Rb = Rb @ _axis_rotation(axes[b, i], q[j])
            last = max(last, moved_at[j])
        c = (np.sum(Ra * Rb) - 1.0) / 2.0
        angle = np.arccos(min(1.0, max(-1.0, c)))
        dt = stamp - last
        excess = angle - max_speed * dt
        if excess > worst:
            worst, kb, angle_k, dt_k = excess, b, angle, dt
    return kb, angle_k, dt_k


class JointStreamInterpolator:
    """Bounded buffer of joint samples with unwrapped linear interpolation (see the module docstring)."""

    FATAL = FATAL

    def __init__(self, joint_names: Sequence[str], revolute: np.ndarray | None = None, *, max_age: float = 1.0,
                 max_future: float = 0.5, teleport_distance: float = 0.5, teleport_speed: float = 10.0,
                 prismatic: np.ndarray | None = None,
                 horizon: float = 0.0, capacity: int = 256, restart_after: int = 3,
                 max_root_distance: float = float("inf"), max_joint_speed: float = float("inf"),
                 balls: tuple[np.ndarray, np.ndarray] | None = None):
        self.joint_names = list(joint_names)
        n = len(self.joint_names)
        idx, axes = (np.zeros((0, 3), np.int64), np.zeros((0, 3, 3))) if balls is None else balls
        self.balls = np.ascontiguousarray(idx, dtype=np.int64).reshape(-1, 3)
        self.ball_axes = np.ascontiguousarray(axes, dtype=np.float64).reshape(-1, 3, 3)
        if self.balls.size and (self.balls.min() < 0 or self.balls.max() >= n or
                                self.ball_axes.shape[0] != self.balls.shape[0]):
            raise ValueError(f"balls: {self.balls.shape[0]} joint triples within 0..{n - 1} with one axis each "
                             f"expected, got indices up to {self.balls.max()} and {self.ball_axes.shape[0]} axes")
        self._in_ball = np.zeros(n, bool)
        self._in_ball[self.balls.reshape(-1)] = True
        self.revolute = np.ones(n, bool) if revolute is None else np.asarray(revolute, dtype=bool).reshape(-1)
        self.prismatic = ~self.revolute if prismatic is None else np.asarray(prismatic, dtype=bool).reshape(-1)
        for name, m in (("revolute", self.revolute), ("prismatic", self.prismatic)):
            if m.shape != (n,):
                raise ValueError(f"{name} mask has shape {m.shape}, expected ({n},) for {n} joints")
        for name, val in (("max_age", max_age), ("max_future", max_future), ("teleport_distance", teleport_distance),
                          ("horizon", horizon)):
            if not (np.isfinite(val) and val >= 0):
                raise ValueError(f"{name} = {val!r} must be a finite time/distance >= 0")
        for name, val in (("max_root_distance", max_root_distance), ("max_joint_speed", max_joint_speed),
                          ("teleport_speed", teleport_speed)):
            if not val > 0:
                raise ValueError(f"{name} = {val!r} must be > 0 (inf: no limit)")
        if capacity < 2 or restart_after < 1:
            raise ValueError(f"capacity = {capacity} must be >= 2 and restart_after = {restart_after} >= 1")
        self.max_age, self.max_future = float(max_age), float(max_future)
        self.teleport_distance, self.horizon = float(teleport_distance), float(horizon)
        self.teleport_speed = float(teleport_speed)
        self.restart_after = int(restart_after)
        self.max_root_distance, self.max_joint_speed = float(max_root_distance), float(max_joint_speed)
        self._speeding_since: float | None = None     # stamp of the first sample of a run rejected for speed
        self._moved_at = np.zeros(n)                  # per joint: stamp of the sample that last changed it
        self._t: deque[float] = deque(maxlen=capacity)
        self._q: deque[np.ndarray] = deque(maxlen=capacity)
        self._v: deque[np.ndarray | None] = deque(maxlen=capacity)
        self._rejected: list[float] = []              # stamps of the consecutive samples refused for their time
        self.took_last = False                        # the last push stored its sample
        self.teleports = 0
        self.revision = 0                             # changes whenever the samples held change (sample's input)

    # -- state ---------------------------------------------------------------------------------------
    @property
    def ready(self) -> bool:
        return len(self._t) > 0

    @property
    def newest(self) -> float | None:
        """Stamp [s] of the newest accepted sample (None before the first)."""
        return self._t[-1] if self._t else None

    def __len__(self) -> int:
        return len(self._t)

    # -- input ---------------------------------------------------------------------------------------
    def _teleport(self, jump: float, dt: float) -> bool:
        """A prismatic jump of ``jump`` [m] over ``dt`` [s] since the newest sample is a teleport."""
        return jump > self.teleport_distance and jump > self.teleport_speed * dt

    def _clear(self) -> None:
        self._t.clear(), self._q.clear(), self._v.clear()
        self.revision += 1

    def _store(self, stamp: float, q: np.ndarray, v: np.ndarray | None, problems: list) -> None:
        if self._t:
            prev = self._q[-1]
            q = q.copy()
            q[self.revolute] = prev[self.revolute] + wrap_angle(q[self.revolute] - prev[self.revolute])
            if self.balls.shape[0]:
                _nearest_ball_triples(q, prev, self.balls)
            jump, dt = float(np.linalg.norm(q[self.prismatic] - prev[self.prismatic])), stamp - self._t[-1]
            if self.prismatic.any() and self._teleport(jump, dt):
                self.teleports += 1
                problems.append(("teleport", f"prismatic joints jumped {jump:.3g} m in {dt:.3g} s "
                                             f"(> teleport_distance {self.teleport_distance:g} m, faster than "
                                             f"teleport_speed {self.teleport_speed:g} m/s): not "
                                             "interpolated across; older samples dropped"))
                self._clear()
            self._moved_at[q != prev] = stamp
        else:
            self._moved_at[:] = stamp
        self._t.append(stamp)
        self._q.append(q)
        self._v.append(v)
        self.revision += 1
        self.took_last = True

    def push(self, stamp_s: float, q: np.ndarray, v: np.ndarray | None = None,
             now: float | None = None, taken: bool = False) -> list[tuple[str, str]]:
        """Offer one sample; returns the problems found as (kind, message), empty when all is well.
        ``took_last`` says whether it was stored.

        ``now`` [s], the receiver's clock on the stamps' time base, makes the future check absolute
        (stamp > now + max_future); without it the check is relative to the newest sample, which also
        rejects the first sample after a pause longer than max_future (until ``restart_after`` agree).
        ``taken``: the sample is known to have been taken in by a stream that saw the same samples taken in
        (a recording's, whose refused samples were left out): if this stream refuses it, the other one had
        restarted on it, and so does this one.
        """
        stamp = float(stamp_s)
        q = np.asarray(q, dtype=np.float64).reshape(-1)
        v = None if v is None else np.asarray(v, dtype=np.float64).reshape(-1)
        self.took_last = False
        problems = self._judge_and_store(stamp, q, v, now)
        if taken and not self.took_last and not any(k == "bad_sample" for k, _ in problems):
            self._rejected, self._speeding_since = [], None
            self._clear()
            self._store(stamp, q, v, problems)
            problems.append(("restart", "a sample taken in by the recorded stream is refused here: the recorded "
                                        "stream restarted on it, so this one does"))
        return problems

    def _judge_and_store(self, stamp: float, q: np.ndarray, v: np.ndarray | None,
                         now: float | None) -> list[tuple[str, str]]:
        n = len(self.joint_names)
        if q.shape != (n,) or (v is not None and v.shape != (n,)):
            return [("bad_sample", f"sample has {q.size} positions / {None if v is None else v.size} velocities, "
                                   f"expected {n}: map it through JointMap first")]
        if not (np.isfinite(stamp) and np.isfinite(q).all() and (v is None or np.isfinite(v).all())):
            bad = int(np.flatnonzero(~np.isfinite(q))[0]) if not np.isfinite(q).all() else -1
            what = f"joint {self.joint_names[bad]!r} = {q[bad]}" if bad >= 0 else f"stamp {stamp} or a velocity"
            return [("bad_sample", f"sample rejected: {what} is not finite; send finite values")]
        problems: list[tuple[str, str]] = []
        if now is not None and stamp > float(now) + self.max_future:
            return [("future", f"stamp {stamp:.6f} s is {stamp - float(now):.3g} s ahead of the clock "
                               f"(max_future {self.max_future:g} s): sample dropped")]
        if self._t:
            newest = self._t[-1]
            kind = None
            if stamp < newest - self.max_age:
                kind, text = "stale", f"stamp {stamp:.6f} s is {newest - stamp:.3g} s older than the newest " \
                                      f"(max_age {self.max_age:g} s): sample dropped"
            elif stamp <= newest:
                kind, text = "out_of_order", f"stamp {stamp:.6f} s is not newer than the newest {newest:.6f} s: " \
                                             "sample dropped; publish in stamp order"
            elif now is None and stamp > newest + self.max_future:
                kind, text = "future", f"stamp {stamp:.6f} s is {stamp - newest:.3g} s ahead of the newest " \
                                       f"(max_future {self.max_future:g} s): sample dropped"
            if kind is not None:
                if self._rejected and stamp <= self._rejected[-1]:
                    self._rejected.clear()
                self._rejected.append(stamp)
                del self._rejected[:-self.restart_after]          # bounded: a run waiting for a sample in range
                if len(self._rejected) < self.restart_after:
                    return [(kind, text)]
                limit = self._range_problem(stamp, q, v, alone=True)
                if limit is not None:                  # the restart waits for a sample in range
                    return [(kind, text), limit]
                count, first = len(self._rejected), self._rejected[0]
                self._rejected, self._speeding_since = [], None
                self._clear()
                self._store(stamp, q, v, problems)
                return [(kind, text), ("restart", f"{count} consecutive samples from {first:.6f} s agree with each "
                                                  "other: the stream restarts from the last of them")]
        self._rejected.clear()
        limit = self._range_problem(stamp, q, v)
        if limit is not None:
            if limit[0] == "root_range" or self._speeding_since is None or stamp - self._speeding_since < self.max_age:
                if limit[0] == "joint_speed" and self._speeding_since is None:
                    self._speeding_since = stamp
                return [limit]
            problems += [limit, ("restart", f"joint speeds above max_joint_speed {self.max_joint_speed:g} for "
                                            f"{stamp - self._speeding_since:.3g} s (>= max_age {self.max_age:g} s): "
                                            "the stream restarts from this sample; raise the limit if this motion "
                                            "is real")]
            self._clear()
        self._speeding_since = None
        self._store(stamp, q, v, problems)
        return problems

    def _range_problem(self, stamp: float, q: np.ndarray, v: np.ndarray | None,
                       alone: bool = False) -> tuple[str, str] | None:
        """The ``root_range`` or ``joint_speed`` problem of a sample that passed the time checks, or None
        (``alone``: as the first of an empty stream, only its root and its reported velocities)."""
        prev = self._q[-1] if self._t and not alone else q
        root, fastest, jump, k, step, dt = _range_measures(q, np.zeros(0) if v is None else v, prev,
                                                           self.revolute, self.prismatic, self._moved_at_free(),
                                                           stamp, self.max_joint_speed)
        if root > self.max_root_distance:
            return ("root_range", f"root is {root:.4g} m from the origin (max_root_distance "
                                  f"{self.max_root_distance:g} m): sample dropped; fix the publisher or raise "
                                  "input.max_root_distance")
        if v is not None and abs(v[fastest]) > self.max_joint_speed:
            return ("joint_speed", f"joint {self.joint_names[fastest]!r} reports velocity {v[fastest]:.4g} "
                                   f"(max_joint_speed {self.max_joint_speed:g}): sample dropped")
        if self._t and not alone and np.isfinite(self.max_joint_speed):
            if self._teleport(jump, stamp - self._t[-1]):
                return None                      # a teleport: reported by _store, the body is re-placed
            # per joint, the time since the sample that last moved it: split publishers (arms and legs in
            # separate messages microseconds apart) each move their own joints over their own period
            if step > self.max_joint_speed * dt:
                return ("joint_speed", f"joint {self.joint_names[k]!r} moved {step:.4g} in {dt:.3g} s "
                                       f"({step / dt:.4g}/s > max_joint_speed {self.max_joint_speed:g}): "
                                       "sample dropped as a capture glitch")
            if self.balls.shape[0]:
                b, angle, dt = _ball_measures(q, prev, self.balls, self.ball_axes, self._moved_at, stamp,
                                              self.max_joint_speed)
                if angle > self.max_joint_speed * dt:
                    names = "/".join(self.joint_names[j] for j in self.balls[b])
                    return ("joint_speed", f"ball joint {names} turned {angle:.4g} rad in {dt:.3g} s "
                                           f"({angle / dt:.4g} rad/s > max_joint_speed {self.max_joint_speed:g}): "
                                           "sample dropped as a capture glitch")
        return None

    def _moved_at_free(self) -> np.ndarray:
        """Per joint, when it last moved; joints of ball joints are checked as rotations (-inf: never too fast)."""
        if not self.balls.shape[0]:
            return self._moved_at
        out = self._moved_at.copy()
        out[self._in_ball] = -np.inf
        return out

    def load_kernels(self) -> None:
        """Load (on a machine's first start: compile) the range checks' compiled pass, so the first sample does
        not stall the step loop (scene_setup.warm_up)."""
        z = np.zeros(len(self.joint_names))
        _range_measures(z, z, z, self.revolute, self.prismatic, self._moved_at, 0.0, 1.0)
        _ball_measures(z, z, np.zeros((1, 3), np.int64), np.ones((1, 3, 3)) / np.sqrt(3), np.zeros(3), 0.0, 1.0)
        _nearest_ball_triples(np.zeros(3), np.zeros(3), np.zeros((1, 3), np.int64))

    def push_or_raise(self, stamp_s: float, q: np.ndarray, v: np.ndarray | None = None,
                      now: float | None = None) -> list[tuple[str, str]]:
        """Like ``push`` but raises ``StaleSample`` for a rejected sample."""
        problems = self.push(stamp_s, q, v, now)
        for kind, text in problems:
            if kind in FATAL and not any(k == "restart" for k, _ in problems):
                raise StaleSample(kind, text)
        return problems

    # -- output --------------------------------------------------------------------------------------
    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(q (n,), v (n,)) at time t [s]; see the module docstring for the hold / horizon rules."""
        if not self._t:
            raise RuntimeError("no joint sample yet: push one before sampling (check .ready)")
        times = self._t
        n = len(times)
        if t >= times[-1]:
            q_last = self._q[-1]
            v_last = self._v[-1]
            if v_last is None:
                v_last = (q_last - self._q[-2]) / (times[-1] - times[-2]) if n >= 2 else np.zeros_like(q_last)
            dt = t - times[-1]
            if dt <= self.horizon:
                return q_last + dt * v_last, v_last.copy()
            return q_last + self.horizon * v_last, np.zeros_like(q_last)
        if t <= times[0]:
            return self._q[0].copy(), np.zeros_like(self._q[0])
        k = bisect_right(times, t) - 1        # on the deque itself: copying its 256 stamps cost 10 us a step
        t0, t1 = times[k], times[k + 1]
        s = (t - t0) / (t1 - t0)
        q0, q1 = self._q[k], self._q[k + 1]
        q = q0 + s * (q1 - q0)
        return q, (q1 - q0) / (t1 - t0)
