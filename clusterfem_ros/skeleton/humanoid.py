"""The default humanoid (the paper's "jelly man" skeleton): a URDF generated in code, 48 degrees of freedom.

Standing at q = 0: about 1.75 m tall (top of the head flesh), feet on z = 0, Z up, facing +X, arms
hanging about 30 deg out from the body (so arm flesh and torso flesh stay apart). Degrees of freedom:

* root (6): ``root_x``, ``root_y``, ``root_z`` (prismatic, metres from the standing pose), then
  ``root_yaw`` (Z), ``root_pitch`` (Y), ``root_roll`` (X): R = Rz Ry Rx;
* spine (10): ``abdomen_{yaw,pitch,roll}``, ``chest_{yaw,pitch,roll}``, ``neck_{pitch,yaw}``, ``head_{pitch,roll}``;
* per arm (9): ``{s}_clavicle_{yaw,roll}``, ``{s}_shoulder_{pitch,roll,yaw}``, ``{s}_elbow_{pitch,yaw}``,
  ``{s}_wrist_{pitch,roll}``;  per leg (7): ``{s}_hip_{yaw,roll,pitch}``, ``{s}_knee_pitch``,
  ``{s}_ankle_{pitch,roll}``, ``{s}_toe_pitch``; s = ``l`` (+Y side) or ``r``.

Axes: roll about the link's X, pitch about Y, yaw about Z; all link frames are world-aligned at q = 0
except the upper arms (tilted by the arm's rest abduction). A positive pitch swings a limb that points
down backwards (-X), so hip flexion and elbow flexion are negative pitch, knee flexion positive.
``bone_radius`` gives each bone's capsule radius [m] for the flesh (``jelly_body``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .mounting import FREE_ROOT
from .urdf_builder import AXES, UrdfBuilder

PELVIS_HEIGHT = 0.95        # m, pelvis origin at q = 0
ARM_ABDUCTION = 0.5         # rad, rest angle of the upper arms away from the body
THIGH, SHIN, UPPER_ARM, FOREARM = 0.43, 0.41, 0.29, 0.25


@dataclass(frozen=True)
class HumanoidSpec:
    urdf: str
    bone_radius: dict[str, float] = field(default_factory=dict)   # bone link name -> capsule radius [m]
    height: float = 1.75                                          # m, standing, flesh included
    leaf_shapes: dict = field(default_factory=dict)              # leaf link -> link_shapes.LinkShape list

    @property
    def joint_names(self) -> list[str]:
        from .kinematics import Skeleton
        return Skeleton.from_urdf_string(self.urdf).joint_names


def _joints(prefix: str, axes: str) -> list[tuple[str, str, tuple]]:
    """Revolute chain entries from a compact spec: "yaw pitch roll" -> [(prefix_yaw, revolute, Z axis), ...]."""
    axis_of = {"roll": AXES["x"], "pitch": AXES["y"], "yaw": AXES["z"]}
    return [(f"{prefix}_{a}", "revolute", axis_of[a]) for a in axes.split()]


def humanoid_urdf() -> str:
    """URDF text of the default humanoid (see the module docstring)."""
    b = UrdfBuilder("jelly_man")
    b.link("world", helper=True)
    mass = {"pelvis": 11.0, "abdomen": 8.0, "chest": 16.0, "neck": 1.0, "head": 5.0, "clavicle": 1.0,
            "upper_arm": 2.0, "forearm": 1.2, "hand": 0.5, "thigh": 8.0, "shin": 3.5, "foot": 1.0, "toes": 0.2}
    for n in ("pelvis", "abdomen", "chest", "neck", "head"):
        b.link(n, mass[n])
    b.chain("world", "pelvis", FREE_ROOT, xyz=(0, 0, PELVIS_HEIGHT))
    b.chain("pelvis", "abdomen", _joints("abdomen", "yaw pitch roll"), xyz=(0, 0, 0.12))
    b.chain("abdomen", "chest", _joints("chest", "yaw pitch roll"), xyz=(0, 0, 0.18))
    b.chain("chest", "neck", _joints("neck", "pitch yaw"), xyz=(0, 0, 0.23))
    b.chain("neck", "head", _joints("head", "pitch roll"), xyz=(0, 0, 0.10))
    b.tip("head", (0, 0, 0.07))
    for s, sign in (("l", 1.0), ("r", -1.0)):
        for n in ("clavicle", "upper_arm", "forearm", "hand", "thigh", "shin", "foot", "toes"):
            b.link(f"{s}_{n}", mass[n])
        b.chain("chest", f"{s}_clavicle", _joints(f"{s}_clavicle", "yaw roll"), xyz=(0, sign * 0.03, 0.19))
        b.chain(f"{s}_clavicle", f"{s}_upper_arm", _joints(f"{s}_shoulder", "pitch roll yaw"),
                xyz=(0, sign * 0.17, 0), rpy=(sign * ARM_ABDUCTION, 0, 0))
        b.chain(f"{s}_upper_arm", f"{s}_forearm", _joints(f"{s}_elbow", "pitch yaw"), xyz=(0, 0, -UPPER_ARM))
        b.chain(f"{s}_forearm", f"{s}_hand", _joints(f"{s}_wrist", "pitch roll"), xyz=(0, 0, -FOREARM))
        b.tip(f"{s}_hand", (0, 0, -0.14))
        b.chain("pelvis", f"{s}_thigh", _joints(f"{s}_hip", "yaw roll pitch"), xyz=(0, sign * 0.09, -0.03))
        b.chain(f"{s}_thigh", f"{s}_shin", _joints(f"{s}_knee", "pitch"), xyz=(0, 0, -THIGH))
        b.chain(f"{s}_shin", f"{s}_foot", _joints(f"{s}_ankle", "pitch roll"), xyz=(0, 0, -SHIN))
        b.chain(f"{s}_foot", f"{s}_toes", _joints(f"{s}_toe", "pitch"), xyz=(0.13, 0, -0.045))
        b.tip(f"{s}_toes", (0.05, 0, 0))
    return b.to_string()


BONE_RADIUS = {"pelvis": 0.12, "abdomen": 0.12, "chest": 0.13, "neck": 0.05, "head": 0.10,
               "clavicle": 0.045, "upper_arm": 0.05, "forearm": 0.04, "hand": 0.035,
               "thigh": 0.07, "shin": 0.05, "foot": 0.035, "toes": 0.03}


def default_humanoid() -> HumanoidSpec:
    """The default humanoid: its URDF and a capsule radius per bone (see the module docstring)."""
    radius = {}
    for n, r in BONE_RADIUS.items():
        if n in ("pelvis", "abdomen", "chest", "neck", "head"):
            radius[n] = r
        else:
            radius[f"l_{n}"] = radius[f"r_{n}"] = r
    return HumanoidSpec(humanoid_urdf(), radius, height=float(PELVIS_HEIGHT + 0.12 + 0.18 + 0.23 + 0.10 + 0.07
                                                              + BONE_RADIUS["head"]))


__all__ = ["HumanoidSpec", "default_humanoid", "humanoid_urdf"]
