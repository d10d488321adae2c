"""Writing URDF text for generated skeletons (the built-in humanoid, BVH captures).

Conventions shared with ``kinematics.Skeleton``:

* a *bone* link carries a real ``<inertial>`` (mass > ``HELPER_MASS``);
* a *helper* link (mass ``HELPER_MASS_VALUE`` <= ``HELPER_MASS``) sits between the scalar joints of a
  multi-axis joint (a 3-axis shoulder is three revolute joints at one origin with two helpers between);
  helpers are never bones;
* a *tip* link (name ending in ``_tip``, attached by a fixed joint, no children) marks where a bone ends.

Lengths are metres, angles radians, axes unit vectors in the parent joint frame.
"""
from __future__ import annotations

from typing import Sequence
from xml.sax.saxutils import quoteattr

import numpy as np

HELPER_MASS = 1e-6          # kg: links at or below this mass are helpers, not bones
HELPER_MASS_VALUE = 1e-9    # kg: the mass written for helpers (pinocchio wants a positive inertia)
TIP_SUFFIX = "_tip"
AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _vec(v: Sequence[float]) -> str:
    return " ".join(f"{float(x):.17g}" for x in v)


class UrdfBuilder:
    """Accumulates links and joints and renders one ``<robot>`` document with ``to_string()``."""

    def __init__(self, robot_name: str):
        self.robot_name = robot_name
        self._parts: list[str] = []
        self.links: list[str] = []
        self.joints: list[str] = []

    def link(self, name: str, mass: float = 1.0, helper: bool = False) -> str:
        """Add a link: a bone (``mass`` kg, unit-ish inertia) or, with ``helper``, a massless helper."""
        if name in self.links:
            raise ValueError(f"link {name!r} is defined twice: give every link a unique name")
        m = HELPER_MASS_VALUE if helper else float(mass)
        i = m * 1e-2 if not helper else HELPER_MASS_VALUE
        self._parts.append(f'  <link name={quoteattr(name)}><inertial><mass value="{m:.9g}"/>'
                           f'<inertia ixx="{i:.9g}" iyy="{i:.9g}" izz="{i:.9g}" ixy="0" ixz="0" iyz="0"/>'
                           f'</inertial></link>')
        self.links.append(name)
        return name

    def tip(self, parent: str, xyz: Sequence[float]) -> str:
        """Add the tip link ``<parent>_tip`` at ``xyz`` in ``parent``'s frame (ends a leaf bone)."""
        name = parent + TIP_SUFFIX
        self._parts.append(f"  <link name={quoteattr(name)}/>")
        self.links.append(name)
        self.joint(name + "_fixed", "fixed", parent, name, xyz)
        return name

    def joint(self, name: str, kind: str, parent: str, child: str, xyz: Sequence[float] = (0, 0, 0),
              rpy: Sequence[float] = (0, 0, 0), axis: Sequence[float] = (1, 0, 0),
              limit: tuple[float, float] = (-np.pi, np.pi)) -> str:
        """Add one joint of type ``kind`` (revolute, continuous, prismatic, fixed) from parent to child."""
        if name in self.joints:
            raise ValueError(f"joint {name!r} is defined twice: give every joint a unique name")
        body = f'<parent link={quoteattr(parent)}/><child link={quoteattr(child)}/>' \
               f'<origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>'
        if kind != "fixed":
            body += f'<axis xyz="{_vec(axis)}"/>'
        if kind in ("revolute", "prismatic"):
            body += f'<limit lower="{limit[0]:.17g}" upper="{limit[1]:.17g}" effort="1000" velocity="100"/>'
        self._parts.append(f"  <joint name={quoteattr(name)} type={quoteattr(kind)}>{body}</joint>")
        self.joints.append(name)
        return name

    def chain(self, parent: str, child: str, joints: Sequence[tuple[str, str, Sequence[float]]],
              xyz: Sequence[float] = (0, 0, 0), rpy: Sequence[float] = (0, 0, 0),
              limit: tuple[float, float] = (-np.pi, np.pi)) -> None:
        """Connect parent to the existing link ``child`` through scalar joints at one origin.

        ``joints`` lists (name, kind, axis) applied in order from the parent; the first joint takes the
        origin ``xyz``/``rpy``, helpers ``<name>_link`` join the rest. No joints: a fixed joint.
        """
        if not joints:
            self.joint(f"{child}_fixed", "fixed", parent, child, xyz, rpy)
            return
        prev = parent
        for k, (name, kind, axis) in enumerate(joints):
            last = k == len(joints) - 1
            nxt = child if last else self.link(f"{name}_link", helper=True)
            lim = limit if kind == "revolute" else (-1e3, 1e3)
            self.joint(name, kind, prev, nxt, xyz if k == 0 else (0, 0, 0), rpy if k == 0 else (0, 0, 0), axis, lim)
            prev = nxt

    def to_string(self) -> str:
        return (f'<?xml version="1.0"?>\n<robot name={quoteattr(self.robot_name)}>\n'
                + "\n".join(self._parts) + "\n</robot>\n")
