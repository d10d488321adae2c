"""A skeleton from a URDF: scalar joints by name, bones, and their world poses and twists (Pinocchio).

``Skeleton`` wraps a fixed pinocchio ``Model`` (built only from a text that passed ``urdf_check.check_urdf``);
``forward``, ``bone_segments`` and ``link_placements`` compute placements and twists with the numba kernel from the
model's constants. Pinocchio's scratch ``Data`` is made only by ``pinocchio_data`` (``forward_pinocchio``, the tests'
reference), and refused when it would pass ``max_data_bytes``: its size grows with the cube of the joints (pinocchio
4.1, a child's VmHWM, star and chain alike: 68 MB at 100 joints, 513 MB at 200, 4.0 GB at 400; a 999-link star
that passes the default URDF limits would need ~60 GB). No scene or node path makes it. Its configuration is *scalar*:
one entry per revolute, continuous or prismatic joint, in ``joint_names`` order (pinocchio's q order),
so a ``sensor_msgs/JointState`` maps onto it by name; ``nq == nv``. A continuous joint's angle is
turned into pinocchio's (cos, sin) pair internally.

Floating base: the URDF's root joints define it. Our generated URDFs use 3 prismatic + 3 revolute
scalar root joints. A ``floating``, ``planar`` or spherical joint raises ``NotImplementedError``
(it has no scalar name per degree of freedom; replace it by scalar joints: a scene does so, skeleton/mounting.py
makes a floating joint fixed and adds scalar root joints).

Bones (``bone_names``) are the URDF links except helpers and tips (see ``urdf_builder``): a link whose
``<inertial>`` mass is <= 1e-6 kg is a helper between the scalar joints of one multi-axis joint, and so is a
link with neither inertia nor shapes whose child joints all sit at its origin (a 'virtual' link), or that is
named 'world'; a leaf link named ``*_tip`` on a fixed joint marks the end of its parent bone.
A bone's segment runs from its origin to its tip if it has one, else to the origin of its farthest child
bone, else it has zero length.

Array conventions: q, v (n,) float64 [rad, m, rad/s, m/s]; rotation (nb, 3, 3) and translation (nb, 3)
place bone-local points in the world, x = R c + p [m]; twist (nb, 6) = (omega, v) [rad/s, m/s] in
world-aligned axes, v the velocity of the bone origin, so a point x on the bone moves with
x' = omega x (x - p) + v (``point_velocity``; the paper's eq. 7).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from .fk_kernel import tree_forward
from .urdf_builder import HELPER_MASS, TIP_SUFFIX
from .urdf_check import SKELETON_LIMITS, UrdfError, UrdfLimits, check_urdf, read_urdf_file

SCALAR_KINDS = ("revolute", "continuous", "prismatic")
# pinocchio 4.1's Data for nv scalar joints, fitted to its measured peak (benchmarks/pinocchio_data_size.py)
DATA_BYTES_CUBIC, DATA_BYTES_QUADRATIC = 63.0, 880.0
MAX_DATA_BYTES = 256 * 2 ** 20      # ~157 joints; example-robot-data's largest robot (tiago_dual, 101) needs 68 MB


def data_bytes(nv: int) -> float:
    """Pinocchio's Data size for ``nv`` scalar joints [bytes], from the fit above (within 2 % from 100 to 400)."""
    return DATA_BYTES_CUBIC * nv ** 3 + DATA_BYTES_QUADRATIC * nv ** 2


@dataclass(frozen=True)
class BonePoses:
    """World placement and spatial velocity of every bone (see the module docstring for conventions)."""
    rotation: np.ndarray        # (nb, 3, 3)
    translation: np.ndarray     # (nb, 3) [m]
    twist: np.ndarray           # (nb, 6) = (omega [rad/s], v of the origin [m/s]), world-aligned


def point_velocity(poses: BonePoses, bone: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Velocity (k, 3) of world points ``points`` (k, 3) moving rigidly with bones ``bone`` (k,): omega x (x - p) + v."""
    bone = np.asarray(bone, dtype=np.int64)
    tw = poses.twist[bone]
    return np.cross(tw[:, :3], np.asarray(points, dtype=np.float64) - poses.translation[bone]) + tw[:, 3:]


@dataclass(frozen=True)
class _Link:
    name: str
    mass: float | None
    parent_joint: str | None
    shaped: bool = False        # has a <visual> or <collision> shape


def _parse_tree(xml: str) -> tuple[dict[str, _Link], dict[str, dict]]:
    """Links and joints of a URDF as plain data (for bones and error messages; pinocchio does the maths)."""
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as e:
        raise UrdfError(f"URDF is not well-formed XML ({e}): check the file or the robot_description text") from e
    if root.tag != "robot":
        raise UrdfError(f"URDF root element is <{root.tag}>, expected <robot>")
    joints: dict[str, dict] = {}
    child_of: dict[str, str] = {}
    for j in root.findall("joint"):
        name, kind = j.get("name"), j.get("type")
        p, c = j.find("parent"), j.find("child")
        if name is None or kind is None or p is None or c is None:
            raise UrdfError(f"URDF joint {name!r} lacks a name, type, parent or child: fix the URDF")
        o = j.find("origin")
        xyz = _numbers(o.get("xyz", "0 0 0") if o is not None else "0 0 0", f"joint {name!r} <origin xyz>")
        a = j.find("axis")
        axis = _numbers(a.get("xyz", "1 0 0") if a is not None else "1 0 0", f"joint {name!r} <axis xyz>")
        if kind in SCALAR_KINDS and not (axis.shape == (3,) and np.linalg.norm(axis) > 0):
            raise UrdfError(f"URDF joint {name!r} has axis {axis.tolist()}: give a non-zero 3-vector")
        joints[name] = {"type": kind, "parent": p.get("link"), "child": c.get("link"), "xyz": xyz,
                        "axis": axis / max(np.linalg.norm(axis), 1e-300)}
        child_of[c.get("link")] = name
    links: dict[str, _Link] = {}
    for link in root.findall("link"):
        m = link.find("inertial/mass")
        mass = None if m is None else _numbers(m.get("value", ""), f"link {link.get('name')!r} <mass value>", 1)[0]
        shaped = link.find("visual") is not None or link.find("collision") is not None
        links[link.get("name")] = _Link(link.get("name"), mass, child_of.get(link.get("name")), shaped)
    return links, joints


def _numbers(text: str, where: str, count: int = 3) -> np.ndarray:
    """``count`` finite numbers from a URDF attribute; UrdfError naming the element and the text otherwise."""
    try:
        out = np.array([float(x) for x in text.split()])
    except ValueError:
        out = None
    if out is None or out.shape != (count,) or not np.isfinite(out).all():
        raise UrdfError(f"URDF {where} = {text!r}: give {count} finite number{'s' if count > 1 else ''}")
    return out


class Skeleton:
    """Forward kinematics of a URDF skeleton by joint name (see the module docstring)."""

    def __init__(self, xml: str, limits: UrdfLimits = SKELETON_LIMITS):
        check_urdf(xml, limits)         # a bounded tree: what Pinocchio's reader crashes or swells on never reaches it
        self.urdf = xml                 # the text it was built from (joint limits and mimics: joint_limits.py)
        links, joints = _parse_tree(xml)
        for name, j in joints.items():
            if j["type"] not in SCALAR_KINDS + ("fixed",):
                raise NotImplementedError(
                    f"URDF joint {name!r} is of type {j['type']!r}: only revolute, continuous, prismatic and "
                    "fixed joints are supported; model a floating root as 3 prismatic + 3 revolute joints")
        try:
            self.model = pin.buildModelFromXML(xml)
        except (ValueError, RuntimeError) as e:
            raise UrdfError(f"pinocchio cannot build a model from this URDF: {e}") from e
        self._data = None               # pinocchio's Data, made by pinocchio_data only (see the module docstring)
        m = self.model
        self.link_names: list[str] = list(links)        # every link has a BODY frame in the model
        self.joint_names: list[str] = []
        q_index, continuous = [], []
        for jid in range(1, m.njoints):
            jm = m.joints[jid]
            if jm.nv != 1:
                raise NotImplementedError(f"joint {m.names[jid]!r} has {jm.nv} degrees of freedom: use scalar joints")
            self.joint_names.append(m.names[jid])
            q_index.append(jm.idx_q)
            continuous.append(jm.nq == 2)
        self._q_index = np.array(q_index, dtype=np.int64)
        self._continuous = np.array(continuous, dtype=bool)
        self._kinds = [joints[n]["type"] for n in self.joint_names]
        self.nq = self.nv = len(self.joint_names)

        children: dict[str, list[str]] = {n: [] for n in links}
        out_joints: dict[str, list[dict]] = {n: [] for n in links}
        for j in joints.values():
            children.setdefault(j["parent"], []).append(j["child"])
            out_joints.setdefault(j["parent"], []).append(j)

        def is_tip(n: str) -> bool:
            pj = links[n].parent_joint
            return n.endswith(TIP_SUFFIX) and not children[n] and pj is not None and joints[pj]["type"] == "fixed"

        def is_frame(n: str) -> bool:
            """A link without inertia or shapes whose child joints all sit at its origin: a frame between the
            axes of one multi-axis joint (the '*_virtual' links of biomechanical URDFs), like our helpers; or
            such a link named 'world' (the world frame a robot's base hangs on, by convention; the mounting may
            have put it under the up-axis rotation)."""
            out = out_joints[n]
            bare = links[n].mass is None and not links[n].shaped
            return bare and bool(out) and (n == "world" or all(not j["xyz"].any() for j in out))

        def is_bone(n: str) -> bool:
            mass = links[n].mass
            return not is_tip(n) and not (mass is not None and mass <= HELPER_MASS) and not is_frame(n)

        self.bone_names: list[str] = [n for n in links if is_bone(n)]
        if not self.bone_names:
            raise UrdfError("the URDF has no bone links (every link is a helper or a tip): give links real masses")
        index = {n: b for b, n in enumerate(self.bone_names)}

        def parent_bone(n: str) -> int:
            pj = links[n].parent_joint
            while pj is not None:
                p = joints[pj]["parent"]
                if p in index:
                    return index[p]
                pj = links[p].parent_joint
            return -1

        def child_targets(n: str) -> list[str]:
            """Bones (or tips) reached from n through helpers only."""
            out = []
            for c in children[n]:
                out += [c] if (c in index or is_tip(c)) else child_targets(c)
            return out

        self.bone_parent = np.array([parent_bone(n) for n in self.bone_names], dtype=np.int64)
        # the root's joints: no bone between the tree's root and them (a free root, a capture's root channels)
        self._root_joint = np.array([joints[n]["parent"] not in index and parent_bone(joints[n]["parent"]) < 0
                                     for n in self.joint_names], dtype=bool)
        self._frame = [int(m.getFrameId(n, pin.BODY)) for n in self.bone_names]
        self._ends: list[list[int]] = []
        for n in self.bone_names:
            targets = child_targets(n)
            tips = [t for t in targets if is_tip(t)]
            chosen = tips if tips else targets
            self._ends.append([int(m.getFrameId(t, pin.BODY)) for t in chosen])
        self._q_pin = pin.neutral(m)
        self._v_pin = np.zeros(m.nv)
        # constant data of the numba kernel (joint k of the kernel = pinocchio joint k + 1)
        nj = self.nq
        self._k_parent = np.array([m.parents[j] - 1 for j in range(1, m.njoints)], dtype=np.int64)
        self._k_R = np.array([m.jointPlacements[j].rotation for j in range(1, m.njoints)]).reshape(nj, 3, 3)
        self._k_p = np.array([m.jointPlacements[j].translation for j in range(1, m.njoints)]).reshape(nj, 3)
        self._k_axis = np.array([joints[n]["axis"] for n in self.joint_names]).reshape(nj, 3)
        self._k_prismatic = np.array([k == "prismatic" for k in self._kinds], dtype=np.bool_)
        self._k_fjoint = np.array([m.frames[f].parentJoint - 1 for f in self._frame], dtype=np.int64)
        self._k_fR = np.array([m.frames[f].placement.rotation for f in self._frame])
        self._k_fp = np.array([m.frames[f].placement.translation for f in self._frame])
        self._scratch = (np.zeros((nj, 3, 3)), np.zeros((nj, 3)), np.zeros((nj, 3)), np.zeros((nj, 3)))
        # the bones' end frames (tips, child bones) for bone_segments, through the same kernel
        ends = sorted({f for fs in self._ends for f in fs})
        self._e_row = {f: k for k, f in enumerate(ends)}
        self._e_joint = np.array([m.frames[f].parentJoint - 1 for f in ends], dtype=np.int64)
        self._e_R = np.array([m.frames[f].placement.rotation for f in ends]).reshape(len(ends), 3, 3)
        self._e_p = np.array([m.frames[f].placement.translation for f in ends]).reshape(len(ends), 3)

    # -- construction --------------------------------------------------------------------------------
    @classmethod
    def from_urdf_string(cls, xml: str, limits: UrdfLimits = SKELETON_LIMITS) -> "Skeleton":
        if not isinstance(xml, str) or not xml.strip():
            raise UrdfError("the URDF text is empty: pass the robot_description string or use from_urdf_file")
        return cls(xml, limits)

    @classmethod
    def from_urdf_file(cls, path: str | Path, limits: UrdfLimits = SKELETON_LIMITS) -> "Skeleton":
        return cls.from_urdf_string(read_urdf_file(path, limits), limits)

    # -- configuration ---------------------------------------------------------------------------------
    @property
    def n_bones(self) -> int:
        return len(self.bone_names)

    def neutral(self) -> np.ndarray:
        """The rest configuration (n,): every joint at 0 (the pose the URDF is drawn in)."""
        return np.zeros(self.nq)

    def revolute_mask(self) -> np.ndarray:
        """(n,) bool: True for revolute and continuous joints (angles, unwrapped when interpolating)."""
        return np.array([k != "prismatic" for k in self._kinds], dtype=bool)

    def joint_kinds(self) -> list[str]:
        return list(self._kinds)

    def ball_joints(self) -> tuple[np.ndarray, np.ndarray]:
        """((B, 3) joint indices, (B, 3, 3) unit axes): chains of three revolute joints about orthogonal axes at one
        point, each the only child of the one before (a BVH joint's three rotation channels, a floating root's
        yaw/pitch/roll), so R = R(axis0, q0) R(axis1, q1) R(axis2, q2) is one ball joint's rotation."""
        kinds, parent = self._kinds, self._k_parent
        n_children = np.bincount(parent[parent >= 0], minlength=self.nq)
        rotary = [k in ("revolute", "continuous") for k in kinds]
        found, used = [], set()
        for k1 in range(self.nq):
            chain = [k1]
            while len(chain) < 3 and n_children[chain[-1]] == 1:
                nxt = int(np.flatnonzero(parent == chain[-1])[0])
                if not rotary[nxt] or np.abs(self._k_p[nxt]).max() > 0 or \
                        np.abs(self._k_R[nxt] - np.eye(3)).max() > 1e-12:
                    break
                chain.append(nxt)
            if len(chain) < 3 or not all(rotary[k] for k in chain) or used & set(chain):
                continue
            axes = np.array([self._k_axis[k] / np.linalg.norm(self._k_axis[k]) for k in chain])
            if np.abs(axes @ axes.T - np.eye(3)).max() > 1e-9:
                continue
            found.append((chain, axes))
            used |= set(chain)
        if not found:
            return np.zeros((0, 3), np.int64), np.zeros((0, 3, 3))
        return np.array([c for c, _ in found], dtype=np.int64), np.array([a for _, a in found])

    def root_joint_mask(self) -> np.ndarray:
        """(n,) bool: the joints that move the root, with no bone above them (decided from the tree: the free
        root's or a capture's root channels); their angles wrap and their translation is bounded by
        input.max_root_distance instead of URDF limits (skeleton/joint_limits.py)."""
        return self._root_joint.copy()

    def _check(self, q: np.ndarray, v: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Contiguous float64 copies-or-views of q and v (v defaults to zeros), shapes checked (the kernel checks
        that they are finite)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        v = np.zeros(self.nv) if v is None else np.ascontiguousarray(v, dtype=np.float64)
        if q.shape != (self.nq,) or v.shape != (self.nv,):
            self._to_pin(q, v)          # raises the specific error
        return q, v

    def _to_pin(self, q: np.ndarray, v: np.ndarray | None) -> None:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.nq,):
            raise ValueError(f"q has shape {q.shape}, expected ({self.nq},): one value per joint in joint_names")
        if not np.isfinite(q).all():
            k = int(np.flatnonzero(~np.isfinite(q))[0])
            raise ValueError(f"joint {self.joint_names[k]!r} position is {q[k]} at index {k}: send a finite value")
        qi, c = self._q_index, self._continuous
        self._q_pin[qi[~c]] = q[~c]
        self._q_pin[qi[c]] = np.cos(q[c])
        self._q_pin[qi[c] + 1] = np.sin(q[c])
        if v is not None:
            v = np.asarray(v, dtype=np.float64)
            if v.shape != (self.nv,):
                raise ValueError(f"v has shape {v.shape}, expected ({self.nv},): one velocity per joint")
            if not np.isfinite(v).all():
                k = int(np.flatnonzero(~np.isfinite(v))[0])
                raise ValueError(f"joint {self.joint_names[k]!r} velocity is {v[k]} at index {k}: send a finite value")
            self._v_pin[:] = v

    # -- kinematics -------------------------------------------------------------------------------------
    def forward(self, q: np.ndarray, v: np.ndarray | None = None) -> BonePoses:
        """World poses and twists of all bones at configuration q (n,) and joint velocities v (n,) (default 0).

        Computed by the numba kernel ``fk_kernel.tree_forward`` from pinocchio's model constants; equal
        to ``forward_pinocchio`` to round-off. The returned arrays are new on every call.
        """
        qs, vs = self._check(q, v)
        nb = self.n_bones
        R, p, tw = np.empty((nb, 3, 3)), np.empty((nb, 3)), np.empty((nb, 6))
        if not tree_forward(self._k_parent, self._k_R, self._k_p, self._k_axis, self._k_prismatic, qs, vs,
                            self._k_fjoint, self._k_fR, self._k_fp, *self._scratch, R, p, tw):
            self._to_pin(qs, vs)        # a value is not finite: raises naming the joint
        return BonePoses(R, p, tw)

    @property
    def data(self) -> pin.Data:
        """Pinocchio's scratch Data, made on first use, within ``MAX_DATA_BYTES`` (``pinocchio_data``)."""
        return self.pinocchio_data()

    def pinocchio_data(self, max_data_bytes: float = MAX_DATA_BYTES) -> pin.Data:
        """Pinocchio's scratch Data (made on first use); UrdfError, before any allocation, when its size
        (``data_bytes``) would pass ``max_data_bytes``."""
        if self._data is None:
            need = data_bytes(self.nv)
            if need > max_data_bytes:
                raise UrdfError(
                    f"pinocchio's Data for {self.nv} joints would take {need / 2 ** 20:,.0f} MB, past max_data_bytes "
                    f"= {max_data_bytes / 2 ** 20:,.0f} MB (it grows with the cube of the joints): use forward, "
                    "bone_segments or link_placements, which need no Data, or raise max_data_bytes")
            self._data = self.model.createData()
        return self._data

    def forward_pinocchio(self, q: np.ndarray, v: np.ndarray | None = None,
                          max_data_bytes: float = MAX_DATA_BYTES) -> BonePoses:
        """``forward`` through pinocchio's ``forwardKinematics`` / ``getFrameVelocity`` (LOCAL_WORLD_ALIGNED), with
        its Data (``pinocchio_data``: refused past ``max_data_bytes``)."""
        d = self.pinocchio_data(max_data_bytes)
        self._to_pin(q, v if v is not None else np.zeros(self.nv))
        m = self.model
        pin.forwardKinematics(m, d, self._q_pin, self._v_pin)
        pin.updateFramePlacements(m, d)
        nb = self.n_bones
        R, p, tw = np.empty((nb, 3, 3)), np.empty((nb, 3)), np.empty((nb, 6))
        for b, f in enumerate(self._frame):
            M = d.oMf[f]
            R[b], p[b] = M.rotation, M.translation
            vel = pin.getFrameVelocity(m, d, f, pin.LOCAL_WORLD_ALIGNED)
            tw[b, :3], tw[b, 3:] = vel.angular, vel.linear
        return BonePoses(R, p, tw)

    def bone_segments(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(starts (nb, 3), ends (nb, 3)) [m]: each bone's axis at q, origin to tip / farthest child / itself
        (the end frames placed by the kernel of ``forward``)."""
        qs, vs = self._check(q, None)
        starts = self.forward(qs).translation
        ne = len(self._e_row)
        R, p, tw = np.empty((ne, 3, 3)), np.empty((ne, 3)), np.empty((ne, 6))
        tree_forward(self._k_parent, self._k_R, self._k_p, self._k_axis, self._k_prismatic, qs, vs,
                     self._e_joint, self._e_R, self._e_p, *self._scratch, R, p, tw)
        ends = starts.copy()
        for b, fs in enumerate(self._ends):
            if fs:
                cand = p[[self._e_row[f] for f in fs]]
                ends[b] = cand[np.argmax(np.linalg.norm(cand - starts[b], axis=1))]
        return starts, ends

    def link_placements(self, q: np.ndarray, links: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(rotation (k, 3, 3), translation (k, 3)): the frames of URDF links ``links`` (any link: bones, helpers,
        tips, links on fixed joints) in the world at q, x = R c + p, by the kernel of ``forward`` (equal to
        pinocchio's ``oMf`` of their BODY frames to round-off)."""
        qs, vs = self._check(q, None)
        m, frames = self.model, []
        for n in links:
            if not m.existFrame(n, pin.BODY):
                raise KeyError(f"no link {n!r} in this skeleton's URDF ({len(self.link_names)} links, e.g. "
                               f"{self.link_names[:4]})")
            frames.append(int(m.getFrameId(n, pin.BODY)))
        k = len(frames)
        joint = np.array([m.frames[f].parentJoint - 1 for f in frames], dtype=np.int64)
        fR = np.array([m.frames[f].placement.rotation for f in frames]).reshape(k, 3, 3)
        fp = np.array([m.frames[f].placement.translation for f in frames]).reshape(k, 3)
        R, p, tw = np.empty((k, 3, 3)), np.empty((k, 3)), np.empty((k, 6))
        if not tree_forward(self._k_parent, self._k_R, self._k_p, self._k_axis, self._k_prismatic, qs, vs,
                            joint, fR, fp, *self._scratch, R, p, tw):
            self._to_pin(qs, vs)        # a value is not finite: raises naming the joint
        return R, p

    def bone_joints(self) -> list[list[int]]:
        """Per bone, the joints (indices into joint_names, root-side first) between its parent bone's frame and its
        own: the joints that turn this bone relative to its parent (a BVH joint's rotation channels)."""
        out = []
        for b in range(self.n_bones):
            p = int(self.bone_parent[b])
            stop = int(self._k_fjoint[p]) if p >= 0 else -1
            chain, j = [], int(self._k_fjoint[b])
            while j >= 0 and j != stop:
                chain.append(j)
                j = int(self._k_parent[j])
            out.append(chain[::-1])
        return out

    def joint_index(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"no joint {name!r} in this skeleton ({self.nq} joints, e.g. {self.joint_names[:4]})") from None
