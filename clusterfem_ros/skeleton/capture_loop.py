"""A capture looped without artefacts: joints blended as rotations, the root's heading and position carried on.

``CaptureLoop(trajectory, balls, root_ball, root_position, up, blend_s)`` plays ``trajectory`` (a capture's
``JointTrajectory``, Euler channels as revolute columns) in loops:

* **Seam.** Over the last ``blend_s`` seconds every ball joint (three rotation columns about three different
  axes, ``balls``: (columns, file axes in order, e.g. "ZYX")) is turned from its captured rotation towards the
  rotation it starts the clip with, by a slerp of the end's remaining gap with a smooth (C1) ramp, and its
  Euler triple re-extracted nearest to the previous frame's: the body never passes through poses the clip
  does not have (blending each Euler channel on its own can lay a standing body flat). Other columns are
  ramped linearly to their start (whole turns kept).
* **Carry.** The root (``root_ball``; ``root_position``: its position columns and their file axes) ends the
  clip somewhere else, facing another way. Loop k is the clip moved by the rigid motion M^k, M turning by the
  change of heading over the clip (the twist of R_end R_start^T about ``up``, the file's up axis) about the
  start and moving it to where the clip ends horizontally: a walk keeps walking, a clip that ends facing away
  goes on facing away. The root's height is blended back to its start (a loop does not climb).

``sample(t, loop=True)`` returns the joint values of loop floor((t - t0) / duration) (each loop's root triples
continue the previous loop's); ``sample(t)`` without loop is the blended clip. Rotations are in the capture
file's frame; positions in metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .euler import euler_nearest
from .trajectory import JointTrajectory


@dataclass(frozen=True)
class Ball:
    columns: tuple[int, int, int]       # trajectory columns of the three rotation channels, in chain order
    order: str                          # their file axes, e.g. "ZYX": R = Rz Ry Rx


def _rotations(q: np.ndarray, ball: Ball) -> Rotation:
    return Rotation.from_euler(ball.order, q[:, list(ball.columns)])


def twist(R: Rotation, axis: np.ndarray) -> np.ndarray:
    """Angle [rad] of the twist of R about ``axis`` (unit): R's turn about the axis (its heading when up)."""
    x, y, z, w = np.moveaxis(np.atleast_2d(R.as_quat()), -1, 0)
    return 2.0 * np.arctan2(np.stack([x, y, z], -1) @ axis, w)


class CaptureLoop(JointTrajectory):
    """A capture's trajectory that loops with a rotation-blended seam and a carried root (module docstring)."""

    def __init__(self, trajectory: JointTrajectory, balls: list[Ball], root_ball: int | None,
                 root_position: tuple[list[int], str], up: np.ndarray, blend_s: float):
        if not (np.isfinite(blend_s) and blend_s > 0):
            raise ValueError(f"loop blend {blend_s!r} s: give a positive time (the seam is spread over it)")
        t = trajectory.times
        p = trajectory.positions.copy()
        self.up = np.asarray(up, float) / np.linalg.norm(up)
        self.balls, self.root_ball = list(balls), root_ball
        self.root_cols = list(root_position[0])
        self.root_axes = np.array([np.eye(3)["XYZ".index(a)] for a in root_position[1]]).reshape(-1, 3)
        s = np.clip((t - (t[-1] - blend_s)) / blend_s, 0.0, 1.0)
        ramp = s * s * (3 - 2 * s)
        window = np.flatnonzero(ramp > 0)
        self.turn = Rotation.identity()
        if root_ball is not None and p.shape[0] >= 2:
            rb = balls[root_ball]
            R0, R1 = _rotations(p[[0, -1]], rb)
            self.turn = Rotation.from_rotvec(float(twist(R1 * R0.inv(), self.up)[0]) * self.up)
        ball_cols = {c for b in balls for c in b.columns}
        # the root's position: where loop 1 starts (Q) from where the clip starts (P0)
        x = self._root_xyz(p)
        self.start = x[0].copy()
        move = x[-1] - x[0]
        self.step = self.start + move - (move @ self.up) * self.up           # Q: horizontal end, start height
        target = p[0].copy()
        for c in range(p.shape[1]):                                          # plain columns: back to the start
            if c not in ball_cols and c not in self.root_cols:
                if trajectory.revolute[c]:
                    target[c] += 2 * np.pi * np.round((p[-1, c] - p[0, c]) / (2 * np.pi))
                p[window, c] += ramp[window] * (target[c] - p[-1, c])
        if self.root_cols:
            gap = self.step - x[-1]
            x[window] += ramp[window, None] * gap
            p[:, self.root_cols] = x @ self.root_axes.T
        if window.size and window[0] >= 1:
            for k, b in enumerate(balls):
                R = _rotations(p, b)
                goal = R[0] if k != root_ball else self.turn * R[0]
                gap = (R[-1].inv() * goal).as_rotvec()
                Rw = R[window] * Rotation.from_rotvec(ramp[window, None] * gap)
                p[window[:, None], list(b.columns)] = euler_nearest(Rw, b.order, p[window[0] - 1, list(b.columns)])
        # non-root joints end on their start rotation: each loop adds the whole turns their triples gained; a ball
        # whose end triple is the other representation of its start rotation is re-extracted in each loop instead
        self._offset = np.zeros(p.shape[1])
        for c in range(p.shape[1]):
            if trajectory.revolute[c] and c not in self.root_cols:
                self._offset[c] = 2 * np.pi * np.round((p[-1, c] - p[0, c]) / (2 * np.pi))
        self._reextract = [k for k, b in enumerate(balls) if k == root_ball or not np.allclose(
            p[-1, list(b.columns)], p[0, list(b.columns)] + self._offset[list(b.columns)], rtol=0, atol=1e-9)]
        for k in self._reextract:
            self._offset[list(balls[k].columns)] = 0.0
        super().__init__(t, trajectory.names, p, revolute=trajectory.revolute, interpolation=trajectory.interpolation)
        self._loops: dict[int, JointTrajectory] = {}      # the latest loops built
        # per loop: the row the next loop continues from (its last; its first for loops before the clip)
        self._joins: dict[int, np.ndarray] = {}

    def _root_xyz(self, p: np.ndarray) -> np.ndarray:
        """(F, 3) the root's position in the file's frame [m] (zero along axes without a column)."""
        if not self.root_cols:
            return np.zeros((p.shape[0], 3))
        return p[:, self.root_cols] @ self.root_axes

    def _moved(self, k: int) -> tuple[Rotation, np.ndarray]:
        """(A^k, Q_k): loop k's rotation and where it puts the clip's start, M^k(x) = A^k (x - P0) + Q_k."""
        A, Q = Rotation.identity(), self.start.copy()
        step = self.step - self.start
        for _ in range(abs(k)):
            if k > 0:
                Q = self.turn.apply(Q - self.start) + self.start + step
            else:
                Q = self.turn.inv().apply(Q - self.start - step) + self.start
        return self.turn ** k if k else A, Q

    def loop_trajectory(self, k: int) -> JointTrajectory:
        """The trajectory of loop k (loop 0 is the blended clip)."""
        if k == 0:
            return self
        if k in self._loops:
            return self._loops[k]
        step = 1 if k > 0 else -1
        known = max((j for j in self._joins if j * step > 0 and abs(j) < abs(k)), key=abs, default=0)
        tr = self
        for j in range(known + step, k + step, step):               # each loop continues the one before
            join = self._joins[j - step] if j != step else self.positions[-1 if step > 0 else 0]
            tr = self._build(j, join)
        return tr

    def _build(self, k: int, join: np.ndarray) -> JointTrajectory:
        A, Q = self._moved(k)
        p = self.positions.copy()
        p += k * self._offset
        if self.root_cols:
            x = A.apply(self._root_xyz(self.positions) - self.start) + Q
            p[:, self.root_cols] = x @ self.root_axes.T
        for kb in self._reextract:
            b = self.balls[kb]
            cols = list(b.columns)
            R = _rotations(self.positions, b)
            R = A * R if kb == self.root_ball else R
            if k > 0:                                            # on from the previous loop's end
                p[:, cols] = euler_nearest(R, b.order, join[cols])
            else:                                                # back from the next loop's start
                p[::-1, cols] = euler_nearest(R[::-1], b.order, join[cols])
        tr = JointTrajectory(self.times, self.names, p, revolute=self.revolute, interpolation=self.interpolation)
        self._joins[k] = p[-1] if k > 0 else p[0]
        if len(self._loops) >= 4:
            self._loops.pop(next(iter(self._loops)))
        self._loops[k] = tr
        return tr

    def sample(self, t: float, loop: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) at time t [s]; with ``loop`` the loop floor((t - t0) / duration) (see the module docstring)."""
        T = self.duration
        if not loop or T <= 0:
            return super().sample(t)
        k = int(np.floor((t - self.times[0]) / T))
        return self.loop_trajectory(k).sample(t - k * T)
