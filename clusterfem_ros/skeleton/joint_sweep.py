"""A smooth joint-space motion through each joint's range, read from a URDF: what a robot plays when nobody
recorded its motion (``mocap_player -p source:=joint_sweep -p file:=<URDF>``).

Every movable joint of the URDF moves on one period ``period`` [s], so the motion loops without a seam:

- revolute and prismatic joints with a range ``[lower, upper]``: ``c + a sin(2 pi t / T + phase)``, where
  ``a = fraction (upper - lower) / 2`` and the centre ``c`` is the rest value 0 moved into ``[lower + a,
  upper - a]`` (a sweep around the pose the body is built in, wherever the range allows it), so the
  motion never leaves the range; the phases are spread over the joints so they do not all peak at once;
- continuous joints (and revolute joints whose limits enclose a whole turn): a whole turn and back,
  ``pi (1 - cos(2 pi t / T))``;
- mimic joints follow their master: ``multiplier q_master + offset`` (also when the master is swept
  after them in the file);
- fixed (and floating or planar) joints are not played; a revolute or prismatic joint without a range
  (``lower >= upper``) is held at 0, named in ``JointSweep.notes``.

``joint_sweep(xml)`` returns the trajectory sampled at ``rate_hz`` over one period (Catmull-Rom between
samples, JointTrajectory) and the start-up notes.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from .trajectory import JointTrajectory

PLAYED = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class SweptJoint:
    name: str
    kind: str                   # revolute, continuous or prismatic
    lower: float                # [rad or m]; -inf / inf for a continuous joint
    upper: float
    mimic: tuple[str, float, float] | None     # (master, multiplier, offset)


@dataclass(frozen=True)
class JointSweep:
    trajectory: JointTrajectory
    joints: list[SweptJoint]
    notes: list[str]


def _number(text: str | None, default: float, where: str) -> float:
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"URDF {where} = {text!r}: give a number") from None
    if not np.isfinite(value):
        raise ValueError(f"URDF {where} = {text!r}: give a finite number")
    return value


def swept_joints(xml: str) -> list[SweptJoint]:
    """The URDF's revolute, continuous and prismatic joints in file order, with their ranges and mimic tags."""
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as exc:
        raise ValueError(f"the URDF is not well-formed XML ({exc})") from None
    out = []
    for j in root.findall("joint"):
        kind, name = j.get("type"), j.get("name")
        if kind not in PLAYED or name is None:
            continue
        lim = j.find("limit")
        if kind == "continuous":
            lo, hi = -np.inf, np.inf
        else:
            lo = _number(lim.get("lower") if lim is not None else None, 0.0, f"joint {name!r} <limit lower>")
            hi = _number(lim.get("upper") if lim is not None else None, 0.0, f"joint {name!r} <limit upper>")
        m = j.find("mimic")
        mimic = None
        if m is not None and m.get("joint"):
            mimic = (m.get("joint"), _number(m.get("multiplier"), 1.0, f"joint {name!r} <mimic multiplier>"),
                     _number(m.get("offset"), 0.0, f"joint {name!r} <mimic offset>"))
        out.append(SweptJoint(name, kind, lo, hi, mimic))
    return out


def joint_sweep(xml: str, fraction: float = 0.6, period: float = 8.0, rate_hz: float = 100.0) -> JointSweep:
    """The sweep of the module docstring: each ranged joint through ``fraction`` of its range, once per ``period``."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"joint sweep fraction = {fraction!r}: give a share of each joint's range in (0, 1]")
    if not (np.isfinite(period) and period > 0 and np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"joint sweep period = {period!r} s, rate = {rate_hz!r} Hz: give positive numbers")
    joints = swept_joints(xml)
    if not joints:
        raise ValueError("the URDF has no revolute, continuous or prismatic joint: there is nothing to sweep")
    notes = []
    t = np.linspace(0.0, period, int(np.ceil(period * rate_hz)) + 1)
    phase = 2.0 * np.pi * t / period
    q = np.zeros((t.size, len(joints)))
    index = {j.name: k for k, j in enumerate(joints)}
    free = [j for j in joints if j.mimic is None or j.mimic[0] not in index]
    held = []
    for n, j in enumerate(free):
        k = index[j.name]
        if j.mimic is not None:
            notes.append(f"joint {j.name!r} mimics {j.mimic[0]!r}, which the URDF has not as a movable joint: swept "
                         "on its own")
        span = j.upper - j.lower
        if j.kind == "continuous" or (j.kind == "revolute" and span >= 2.0 * np.pi):
            q[:, k] = np.pi * (1.0 - np.cos(phase))
        elif span > 0:
            a = 0.5 * fraction * span
            c = min(max(0.0, j.lower + a), j.upper - a)
            q[:, k] = c + a * np.sin(phase + 2.0 * np.pi * n / max(len(free), 1))
        else:
            held.append(j.name)
    for _ in range(len(joints)):            # chains of mimics settle in at most as many passes as joints
        for j in joints:
            if j.mimic is not None and j.mimic[0] in index:
                master, multiplier, offset = j.mimic
                q[:, index[j.name]] = multiplier * q[:, index[master]] + offset
    if held:
        notes.append(f"joints without a range (lower >= upper) are held at 0: {', '.join(held)}")
    revolute = np.array([j.kind != "prismatic" for j in joints])
    traj = JointTrajectory(t, [j.name for j in joints], q, revolute=revolute)
    return JointSweep(traj, joints, notes)
