"""A built-in walk for the default humanoid, so the demo runs without external data.

``procedural_walk(duration_s)`` samples a smooth periodic gait at ``rate_hz`` into a ``JointTrajectory``
over ``default_humanoid`` joint names (radians, metres). With phase phi = 2 pi t / period:

* hips swing +-``hip_amplitude`` in opposition (hip flexion is negative pitch), knees flex up to
  ``knee_amplitude`` in mid swing (a raised-cosine pulse, so every curve is C-infinity), ankles keep the
  feet roughly level, toes bend at push-off; arms swing against the legs, elbows stay bent;
* the pelvis moves forward along +X at ``speed`` m/s, yaws and rolls a little, and its height follows
  the lower (stance) foot: root_z = -(leg length - smooth max of the two hip-to-ankle heights), with a
  log-sum-exp smooth max (``softness`` m) so the bob stays differentiable.

The gait is exactly periodic in every joint except root_x, which advances ``speed * period`` per
cycle; the trajectory's ``cycle_offset`` carries that advance, so ``sample(t, loop=True)`` loops
seamlessly when ``duration_s`` is a whole number of periods (``gait_period(speed)``).
"""
from __future__ import annotations

import numpy as np

from .humanoid import SHIN, THIGH
from .trajectory import JointTrajectory


def gait_period(speed: float, stride_length: float | None = None) -> float:
    """Seconds per gait cycle (two steps): stride length / speed, stride 0.75 + 0.45 * speed m by default."""
    stride = 0.75 + 0.45 * speed if stride_length is None else stride_length
    return float(stride / speed)


def _pulse(phi: np.ndarray, centre: float, sharpness: float = 3.0) -> np.ndarray:
    """Raised-cosine bump in [0, 1], peaking at phase ``centre``, periodic in phi."""
    return ((1.0 + np.cos(phi - centre)) / 2.0) ** sharpness


def _smooth_max(a: np.ndarray, b: np.ndarray, softness: float) -> np.ndarray:
    m = np.maximum(a, b)
    return m + softness * np.log(np.exp((a - m) / softness) + np.exp((b - m) / softness)) - softness * np.log(2.0)


def walk_pose(t: np.ndarray, speed: float = 1.0, period: float | None = None, hip_amplitude: float = 0.35,
              knee_amplitude: float = 0.75, arm_amplitude: float = 0.3, softness: float = 0.005) -> dict[str, np.ndarray]:
    """Joint name -> positions (T,) of the walk at times t (T,); joints not listed stay at 0."""
    t = np.asarray(t, dtype=np.float64)
    T = gait_period(speed) if period is None else float(period)
    phi = 2.0 * np.pi * t / T
    q: dict[str, np.ndarray] = {}
    heights = []
    for s, shift in (("l", 0.0), ("r", np.pi)):
        ph = phi + shift
        hip = -hip_amplitude * np.sin(ph) - 0.05                  # slight forward lean of the thighs
        knee = 0.08 + knee_amplitude * _pulse(ph, -0.5)           # flexed in mid swing (leg moving forward)
        ankle = -0.6 * (hip + knee) + 0.15 * _pulse(ph, 2.6, 2.0)
        q[f"{s}_hip_pitch"], q[f"{s}_knee_pitch"], q[f"{s}_ankle_pitch"] = hip, knee, ankle
        q[f"{s}_toe_pitch"] = -0.3 * _pulse(ph, 2.3, 4.0)
        q[f"{s}_shoulder_pitch"] = arm_amplitude * np.sin(ph)
        q[f"{s}_elbow_pitch"] = -0.35 - 0.15 * (1.0 + np.sin(ph + np.pi))
        heights.append(THIGH * np.cos(hip) + SHIN * np.cos(hip + knee))
    q["root_x"] = speed * t
    q["root_z"] = _smooth_max(heights[0], heights[1], softness) - (THIGH + SHIN)
    q["root_yaw"] = 0.06 * np.sin(phi)
    q["root_roll"] = 0.03 * np.sin(phi)
    q["chest_yaw"] = -0.10 * np.sin(phi)
    q["root_pitch"] = np.full_like(t, 0.04)
    q["neck_pitch"] = np.full_like(t, -0.04)
    return q


def procedural_walk(duration_s: float, rate_hz: float = 120.0, speed: float = 1.0, *, period: float | None = None,
                    names: list[str] | None = None, **gait) -> JointTrajectory:
    """The walk as a trajectory over ``names`` (default: every default-humanoid joint), see the module docstring."""
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s = {duration_s!r} must be a positive time in seconds")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz = {rate_hz!r} must be a positive frequency")
    if not (np.isfinite(speed) and speed > 0):
        raise ValueError(f"speed = {speed!r} must be a positive walking speed in m/s")
    if names is None:
        from .humanoid import default_humanoid
        names = default_humanoid().joint_names
    n = int(np.ceil(duration_s * rate_hz - 1e-9))
    t = np.arange(n + 1) / rate_hz
    t[-1] = min(t[-1], duration_s) if n > 0 else t[-1]
    pose = walk_pose(t, speed, period, **gait)
    unknown = sorted(set(pose) - set(names))
    if unknown:
        raise ValueError(f"the walk drives joints {unknown} that are not in names: pass the default humanoid's joints")
    positions = np.column_stack([pose.get(j, np.zeros_like(t)) for j in names])
    offset = np.zeros(len(names))
    if "root_x" in names:               # looping carries the distance walked, not a jump back
        k = names.index("root_x")
        offset[k] = positions[-1, k] - positions[0, k]
    revolute = np.array([j not in ("root_x", "root_y", "root_z") for j in names])
    return JointTrajectory(t, names, positions, revolute=revolute, cycle_offset=offset)
