"""How a URDF's base is put into the world: its up axis turned onto world Z, and a free root where it has none.

The world is Z up with gravity along -Z. A URDF drawn Y up (the ISB convention of biomechanical models)
would lie along world Y with gravity sideways; ``skeleton.up_axis`` names the URDF's up axis, and
``mount_urdf`` puts a fixed joint above the URDF's root link whose rotation turns that axis onto world Z
(Y up: +90 deg about X, so the model's forward X stays forward and its right +Z becomes -Y, left +Y).

A URDF whose root link hangs on nothing (a fixed base) cannot follow a moving root. A ``floating`` joint (six
degrees of freedom without a scalar name each, which a JointState cannot address) is made fixed, so such a
URDF counts as a fixed base. With
``skeleton.root_joint`` 'free' (or 'auto' and a URDF without any prismatic joint, so nothing in it can
translate), the root link gets the built-in humanoid's root joints ``FREE_ROOT``: three prismatic joints
along world X, Y, Z and yaw (Z), pitch (Y), roll (X) revolute joints, R = Rz Ry Rx, the same names and the
same meaning as the players send for the humanoid (and the same path through the joint map and the
stream's teleport and range checks). The up-axis rotation sits below them, so the root pose is in world
axes. A URDF that has its own root joints (prismatic joints, as the BVH skeletons have) keeps them
('auto' or 'fixed'); the up-axis rotation then sits above them, so they move the model in its own axes.

Everything is done on the URDF text, once, before the ``Skeleton`` is made: body building, binding, the
markers and the renderer's skeleton all read the same text and agree. A Z-up URDF that needs no root is
returned unchanged (the same string).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from ..errors import ClusterFemError
from .urdf_builder import AXES, UrdfBuilder

UP_AXES = ("z", "y", "x", "-z", "-y", "-x")
ROOT_JOINTS = ("auto", "free", "fixed")
FREE_ROOT = (("root_x", "prismatic", AXES["x"]), ("root_y", "prismatic", AXES["y"]),
             ("root_z", "prismatic", AXES["z"]), ("root_yaw", "revolute", AXES["z"]),
             ("root_pitch", "revolute", AXES["y"]), ("root_roll", "revolute", AXES["x"]))
WORLD_LINK = "clusterfem_world"
BASE_LINK = "clusterfem_base"
MOUNT_JOINT = "clusterfem_up_axis"
_RPY = {"z": (0.0, 0.0, 0.0), "y": (np.pi / 2, 0.0, 0.0), "x": (0.0, -np.pi / 2, 0.0),
        "-z": (np.pi, 0.0, 0.0), "-y": (-np.pi / 2, 0.0, 0.0), "-x": (0.0, np.pi / 2, 0.0)}


class MountError(ClusterFemError, ValueError):
    """An up axis or root joint choice that cannot be applied; the message names the value and the choices."""


@dataclass(frozen=True)
class MountedUrdf:
    urdf: str           # the URDF text the skeleton is made from
    root: str           # 'free' (root joints added), 'own' (the URDF's root joints kept) or 'fixed'
    note: str           # one line for the start-up log: what was chosen and why


def rpy_matrix(r: float, p: float, y: float) -> np.ndarray:
    """(3, 3) rotation of a URDF ``rpy`` (roll about X, then pitch about Y, then yaw about Z: R = Rz Ry Rx)."""
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def up_rotation(up_axis: str) -> np.ndarray:
    """(3, 3) rotation taking the URDF's ``up_axis`` onto world +Z (the mounting joint's rpy)."""
    if up_axis not in _RPY:
        raise MountError(f"skeleton.up_axis = {up_axis!r}: choose one of {', '.join(UP_AXES)} (the URDF's axis "
                         "that points up when the model stands)")
    return rpy_matrix(*_RPY[up_axis])


def _root_link(root: ET.Element) -> str:
    children = {c.get("link") for c in root.findall("joint/child")}
    roots = [link.get("name") for link in root.findall("link") if link.get("name") not in children]
    if len(roots) != 1:
        raise MountError(f"the URDF has {len(roots)} root links ({roots[:4]}): a skeleton needs exactly one link "
                         "that is no joint's child")
    return roots[0]


def mount_urdf(xml: str, up_axis: str = "z", root_joint: str = "auto") -> MountedUrdf:
    """The URDF with its up axis turned onto world Z and, where asked, a free root (see the module docstring)."""
    up_rotation(up_axis)                                    # names a bad up axis
    if root_joint not in ROOT_JOINTS:
        raise MountError(f"skeleton.root_joint = {root_joint!r}: choose one of {', '.join(ROOT_JOINTS)} (auto: a "
                         "free root when the URDF cannot translate)")
    try:
        tree = ET.fromstring(xml)
    except ET.ParseError:
        return MountedUrdf(xml, "fixed", "")                # the Skeleton names the XML error
    floating = [j for j in tree.findall("joint") if j.get("type") == "floating"]
    for j in floating:                  # six degrees of freedom without scalar names: the free root replaces them
        j.set("type", "fixed")
    own = any(j.get("type") == "prismatic" for j in tree.findall("joint"))
    free = root_joint == "free" or (root_joint == "auto" and not own)
    if free:
        names = {j.get("name") for j in tree.findall("joint")} | {x.get("name") for x in tree.findall("link")}
        clash = sorted(names & ({n for n, _, _ in FREE_ROOT} | {WORLD_LINK, BASE_LINK, MOUNT_JOINT}))
        if clash:
            raise MountError(f"skeleton.root_joint = {root_joint!r} adds the root joints {[n for n, _, _ in FREE_ROOT]}, "
                             f"but the URDF already has {clash}: set skeleton.root_joint to 'fixed' (keep its own root)")
    root = "free" if free else ("own" if own else "fixed")
    why = ("the URDF's own root joints move the root" if own else
           "the URDF cannot translate: the body stays where the URDF's root link is")
    if not free and up_axis == "z" and not floating:
        return MountedUrdf(xml, root, f"skeleton root: {root} ({why}); up axis z")
    if free or up_axis != "z":
        old_root = _root_link(tree)
        if free:
            why = f"added {', '.join(n for n, _, _ in FREE_ROOT)} above {old_root!r}" + (
                " (skeleton.root_joint auto: the URDF has no prismatic joint)" if root_joint == "auto" else "")
        b = UrdfBuilder("mount")
        b.link(WORLD_LINK, helper=True)
        top = WORLD_LINK
        if free:
            b.link(BASE_LINK, helper=True)
            b.chain(WORLD_LINK, BASE_LINK, FREE_ROOT)
            top = BASE_LINK
        b.joint(MOUNT_JOINT, "fixed", top, old_root, rpy=_RPY[up_axis])
        for element in list(ET.fromstring(b.to_string())):
            tree.append(element)
    if floating:
        why += f"; floating joint{'s' if len(floating) > 1 else ''} {', '.join(j.get('name') for j in floating)} made fixed"
    note = f"skeleton root: {root} ({why}); up axis {up_axis}" + (
        f": the URDF's {up_axis} axis turned onto world z" if up_axis != "z" else "")
    return MountedUrdf(ET.tostring(tree, encoding="unicode"), root, note)
