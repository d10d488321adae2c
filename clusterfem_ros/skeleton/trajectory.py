"""``JointTrajectory``: timed joint positions by name, sampled at any time (BVH, key frames, the built-in walk).

Arrays: ``times`` (T,) strictly increasing [s]; ``positions`` (T, n) [rad for revolute joints, m for
prismatic]; ``names`` the n joint names. Revolute columns are unwrapped along time at construction
(``np.unwrap``: no step larger than pi), so interpolation never takes the long way round.

``sample(t)`` returns (q (n,), v (n,)): ``interpolation="catmull_rom"`` (default) is a C1 cubic Hermite
spline with tangents (p[k+1] - p[k-1]) / (t[k+1] - t[k-1]) (one-sided at the ends), so v is continuous;
``"linear"`` is piecewise linear (v piecewise constant). Outside [t0, t_end] the ends are held with v = 0,
unless ``loop=True``: time wraps with period ``duration`` and each completed loop adds
``cycle_offset`` (n,) to q (e.g. the root's forward advance per cycle, so a walk loops seamlessly).
``with_seam`` makes any trajectory loop that way (a capture's end blended into its start).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

INTERPOLATIONS = ("catmull_rom", "linear")


class JointTrajectory:
    def __init__(self, times: np.ndarray, names: Sequence[str], positions: np.ndarray, *,
                 revolute: np.ndarray | None = None, interpolation: str = "catmull_rom",
                 cycle_offset: np.ndarray | None = None):
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        p = np.array(positions, dtype=np.float64)
        self.names = list(names)
        n = len(self.names)
        if p.ndim != 2 or p.shape != (t.size, n):
            raise ValueError(f"positions has shape {p.shape}, expected ({t.size}, {n}): one row per time, "
                             "one column per joint name")
        if t.size < 1:
            raise ValueError("a trajectory needs at least one sample")
        if not (np.isfinite(t).all() and np.isfinite(p).all()):
            k = int(np.argwhere(~np.isfinite(np.column_stack([t, p])))[0, 0])
            raise ValueError(f"sample {k} (t = {t[k]}) has a non-finite time or position: fix the source")
        if t.size > 1 and not (np.diff(t) > 0).all():
            k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
            raise ValueError(f"times must increase: sample {k} has t = {t[k]} after t = {t[k - 1]}")
        if len(set(self.names)) != n:
            raise ValueError(f"joint names repeat in {self.names}: give each joint once")
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation = {interpolation!r}: choose one of {INTERPOLATIONS}")
        self.revolute = np.zeros(n, bool) if revolute is None else np.asarray(revolute, dtype=bool).reshape(-1)
        if self.revolute.shape != (n,):
            raise ValueError(f"revolute mask has shape {self.revolute.shape}, expected ({n},)")
        if self.revolute.any() and t.size > 1:
            p[:, self.revolute] = np.unwrap(p[:, self.revolute], axis=0)
        self.cycle_offset = np.zeros(n) if cycle_offset is None else np.asarray(cycle_offset, float).reshape(n)
        self.times, self.positions, self.interpolation = t, p, interpolation
        self._tangents = self._catmull_rom_tangents()

    def _catmull_rom_tangents(self) -> np.ndarray:
        t, p = self.times, self.positions
        m = np.zeros_like(p)
        if t.size >= 2:
            m[1:-1] = (p[2:] - p[:-2]) / (t[2:] - t[:-2])[:, None]
            m[0] = (p[1] - p[0]) / (t[1] - t[0])
            m[-1] = (p[-1] - p[-2]) / (t[-1] - t[-2])
        if self.closed:         # periodic: the tangent at the seam sees both sides
            m[0] = m[-1] = (p[1] - (p[-2] - self.cycle_offset)) / (t[1] - t[0] + t[-1] - t[-2])
        return m

    @property
    def closed(self) -> bool:
        """True when the last sample equals the first plus ``cycle_offset`` (a seamless loop; periodic tangents)."""
        p = self.positions
        return p.shape[0] >= 3 and bool(np.allclose(p[-1], p[0] + self.cycle_offset, rtol=0, atol=1e-9))

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def sample(self, t: float, loop: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(q (n,), v (n,)) at time t [s] (see the module docstring for the end and loop rules)."""
        t0, T = self.times[0], self.duration
        offset = 0.0
        if loop and T > 0:
            cycles = np.floor((t - t0) / T)
            t = t - cycles * T
            offset = cycles
        if t <= t0 or self.times.size == 1:
            return self.positions[0] + offset * self.cycle_offset, (
                self._tangents[0].copy() if (loop and t >= t0 and T > 0) else np.zeros(self.n_joints))
        if t >= self.times[-1]:
            return self.positions[-1] + offset * self.cycle_offset, np.zeros(self.n_joints)
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        h = self.times[k + 1] - self.times[k]
        s = (t - self.times[k]) / h
        p0, p1 = self.positions[k], self.positions[k + 1]
        if self.interpolation == "linear":
            return p0 + s * (p1 - p0) + offset * self.cycle_offset, (p1 - p0) / h
        m0, m1 = self._tangents[k] * h, self._tangents[k + 1] * h
        s2, s3 = s * s, s * s * s
        q = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1
        dq = (6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * m0 + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * m1
        return q + offset * self.cycle_offset, dq / h

    def with_seam(self, blend_s: float, carry: np.ndarray | None = None) -> "JointTrajectory":
        """The trajectory made to loop without a jump (``closed``): columns in ``carry`` (n,) bool (e.g. the root's
        horizontal position) continue from where a loop ends (``cycle_offset`` = end - start); revolute columns
        keep whole turns (a pirouette does not unwind); what is left of the end-to-start difference is spread
        over the last ``blend_s`` seconds with a smooth (C1) ramp, so the last sample equals the first plus the
        offset. A trajectory that is already closed is returned as it is."""
        if self.closed or self.times.size < 3:
            return self
        if not (np.isfinite(blend_s) and blend_s > 0):
            raise ValueError(f"loop blend {blend_s!r} s: give a positive time (the seam is spread over it)")
        n = self.n_joints
        carry = np.zeros(n, bool) if carry is None else np.asarray(carry, dtype=bool).reshape(n)
        p = self.positions.copy()
        jump = p[-1] - p[0]
        offset = np.where(carry, jump, 0.0)
        offset[self.revolute] = 2 * np.pi * np.round(jump[self.revolute] / (2 * np.pi))
        gap = p[0] + offset - p[-1]
        s = np.clip((self.times - (self.times[-1] - blend_s)) / blend_s, 0.0, 1.0)
        p += (s * s * (3 - 2 * s))[:, None] * gap[None, :]
        p[-1] = p[0] + offset                       # exactly closed despite round-off
        return JointTrajectory(self.times, self.names, p, revolute=self.revolute, interpolation=self.interpolation,
                               cycle_offset=offset)

    def resample(self, rate_hz: float) -> "JointTrajectory":
        """The same motion sampled uniformly at ``rate_hz`` from t0 to the end (last sample at the end)."""
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz = {rate_hz!r} must be a positive frequency")
        n = max(int(np.floor(self.duration * rate_hz + 1e-9)), 0)
        times = self.times[0] + np.arange(n + 1) / rate_hz
        if times[-1] < self.times[-1] - 1e-12:
            times = np.append(times, self.times[-1])
        q = np.array([self.sample(t)[0] for t in times])
        return JointTrajectory(times, self.names, q, revolute=self.revolute, interpolation=self.interpolation,
                               cycle_offset=self.cycle_offset)

    def select(self, names: Sequence[str]) -> "JointTrajectory":
        """The trajectory of a subset / reordering of its joints (KeyError naming a missing joint)."""
        idx = []
        for n in names:
            if n not in self.names:
                raise KeyError(f"joint {n!r} is not in this trajectory (it has {self.n_joints} joints)")
            idx.append(self.names.index(n))
        return JointTrajectory(self.times, list(names), self.positions[:, idx], revolute=self.revolute[idx],
                               interpolation=self.interpolation, cycle_offset=self.cycle_offset[idx])
