"""A URDF checked as a bounded tree before anything else reads it (mounting, shapes, Pinocchio).

Pinocchio's URDF reader (urdfdom, then its own recursive tree walk) trusts its input: a joint whose parent
and child are the same link, or a chain of 10,000 links, crashes the process (segmentation fault), and a
chain of 1,000 links or a star of 10,000 grew the node past 20 GB. So every URDF text the scene uses passes
``check_urdf`` first, whose work is linear in the text's size and whose memory is bounded by ``max_bytes``:

* the text: at most ``max_bytes`` bytes (UTF-8), well-formed XML without a ``<!DOCTYPE>`` (a URDF has no
  use for one; refusing it refuses every entity trick, internal or external, before any expansion), XML
  elements nested at most ``XML_MAX_NESTING`` deep, root element ``<robot>``; the parse stops at the first
  element past a limit, so a huge description costs no more than a small one;
* the counts: at most ``max_links`` links, ``max_joints`` joints and ``max_meshes`` ``<mesh>`` references;
* the tree: unique link and joint names; every joint names a type, a parent and a child link that exist,
  parent != child (no self-loop), no link is the child of two joints, exactly one root link (no joint's
  child), every link reached from it (no cycle), at most ``max_depth`` joints from the root to any link
  (a ``<mimic>`` naming no other joint is no danger: Pinocchio and skeleton/joint_limits.py ignore it, as
  real robots have them: example-robot-data's alex_psyonic_hands).

After these checks, Pinocchio builds a tree of at most ``max_joints`` joints and ``max_depth`` levels:
tests/test_urdf_check.py builds the largest descriptions the defaults accept in a child process and measures
its peak memory, and the node path is measured by benchmarks/hostile_urdf.py. The parameters' own upper
bounds (``CEILING``) stay below what Pinocchio survives, and ``kinematics.Skeleton`` checks every text it is
given against them (``SKELETON_LIMITS``: a prepared URDF has up to twice the links, skeleton/link_shapes.py),
so no caller can hand Pinocchio a self-loop, a cycle or a 10,000-deep chain.

A refusal is ``UrdfRefused``: one line naming the link or joint, what is wrong, and the parameter to raise
(``skeleton.max_*``) when a limit was hit; ``kind`` names the class of problem for the node's counts.

The defaults fit every robot of example-robot-data 6.0.0 (the largest: tiago_dual, 211 KB, 130 links,
129 meshes; the deepest: tiago, 21 joints from its root) and the skeletons this package writes from BVH
captures (up to 6 scalar joints per captured joint, so a 12-bone finger chain is ~75 deep) with margin.
"""
from __future__ import annotations

import pyexpat
import xml.etree.ElementTree as ET
from collections import deque
from dataclasses import dataclass

from ..errors import ClusterFemError

# triangles of the shapes of one cover (body.cover_max_triangles; robot_cover.py reads it, here so that the scene
# configuration has the default without importing the cover's meshing): ~0.6 kB each held while the cover is built (a
# 56,264-triangle STL named 17 times, 0.96 M, took 642 MB; 35 times, 1.97 M, 1,142 MB). example-robot-data's
# URDFs have at most 0.4 M collision triangles (so101) and 1.03 M visual ones (b1-z1, the only one past this)
MAX_TRIANGLES = 1_000_000
DEFAULT_MAX_BYTES = 2_000_000
DEFAULT_MAX_LINKS = 1000
DEFAULT_MAX_JOINTS = 1000
DEFAULT_MAX_DEPTH = 128
DEFAULT_MAX_MESHES = 2000
# the highest limits the parameters allow (config.PARAMS): Pinocchio 4.1 segfaults building a chain between 2,000
# and 4,000 joints deep (its recursion), and its build time grows with the square of the links (a star of
# 10,000: 14 s, 0.5 GB; of 1,000: 0.5 s)
CEILING_BYTES, CEILING_LINKS, CEILING_DEPTH, CEILING_MESHES = 20_000_000, 2000, 1000, 100_000
XML_MAX_NESTING = 64            # URDFs nest 7 deep at most (robot/link/visual/geometry/mesh, gazebo plugins)
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
_SHOWN = 4                      # names quoted in one line


class UrdfError(ClusterFemError, ValueError):
    """A URDF that cannot become a skeleton; the message names the element and the way out."""


class UrdfRefused(UrdfError):
    """A URDF refused before any parser but ours read it; ``kind`` names the class (for the node's counts)."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class UrdfLimits:
    """How large a URDF may be (config: skeleton.max_urdf_bytes, max_links, max_joints, max_depth, max_meshes)."""
    max_bytes: int = DEFAULT_MAX_BYTES
    max_links: int = DEFAULT_MAX_LINKS
    max_joints: int = DEFAULT_MAX_JOINTS
    max_depth: int = DEFAULT_MAX_DEPTH
    max_meshes: int = DEFAULT_MAX_MESHES

    @classmethod
    def of(cls, skeleton_section) -> "UrdfLimits":
        """The limits a config's skeleton section sets."""
        s = skeleton_section
        return cls(s.max_urdf_bytes, s.max_links, s.max_joints, s.max_depth, s.max_meshes)

    def prepared(self) -> "UrdfLimits":
        """The limits of a URDF these limits accepted once the scene prepared it (skeleton/link_shapes.py): the
        mounting adds at most 8 links and joints above the root, the shapes a tip below each leaf link."""
        return UrdfLimits(2 * self.max_bytes + 10_000, 2 * self.max_links + 8, 2 * self.max_joints + 8,
                          self.max_depth + 8, self.max_meshes)


CEILING = UrdfLimits(CEILING_BYTES, CEILING_LINKS, CEILING_LINKS, CEILING_DEPTH, CEILING_MESHES)
SKELETON_LIMITS = CEILING.prepared()     # what a Skeleton checks by default: any text a scene may prepare


@dataclass(frozen=True)
class UrdfTree:
    """What the check found: the root link, link and joint counts, the deepest link's depth (joints)."""
    root: str
    n_links: int
    n_joints: int
    depth: int


def _size(text: str, limit: int) -> int:
    """The text's UTF-8 size in bytes, or a value > limit without encoding a text that cannot fit."""
    if len(text) > limit:
        return len(text)
    return len(text.encode("utf-8", "surrogatepass"))


def parse_urdf(text: str, limits: UrdfLimits = UrdfLimits()) -> ET.Element:
    """The URDF's element tree, parsed under the limits of the module docstring (UrdfRefused otherwise)."""
    if not isinstance(text, str) or not text.strip():
        raise UrdfRefused("empty", "the URDF text is empty: pass the robot_description string or a URDF file")
    size = _size(text, limits.max_bytes)
    if size > limits.max_bytes:
        raise UrdfRefused("too_large", f"the URDF has {size} bytes (skeleton.max_urdf_bytes {limits.max_bytes}): "
                                       "refused unread; raise skeleton.max_urdf_bytes if this robot is real")
    builder = ET.TreeBuilder()
    parser = pyexpat.ParserCreate()
    parser.buffer_text = True
    counts = {"link": 0, "joint": 0, "mesh": 0}
    caps = {"link": ("max_links", limits.max_links), "joint": ("max_joints", limits.max_joints),
            "mesh": ("max_meshes", limits.max_meshes)}
    nesting = [0]

    def start(tag: str, attrs: dict) -> None:
        nesting[0] += 1
        if nesting[0] > XML_MAX_NESTING:
            raise UrdfRefused("xml_nesting", f"the URDF nests XML elements more than {XML_MAX_NESTING} deep (at "
                                             f"<{tag}>, line {parser.CurrentLineNumber}): not a URDF")
        if tag in counts and (tag == "mesh" or nesting[0] == 2):
            counts[tag] += 1
            name, cap = caps[tag]
            if counts[tag] > cap:
                raise UrdfRefused(f"too_many_{tag}es" if tag == "mesh" else f"too_many_{tag}s",
                                  f"the URDF has more than {cap} <{tag}> elements (skeleton.{name} {cap}; "
                                  f"stopped reading at line {parser.CurrentLineNumber}): refused; raise "
                                  f"skeleton.{name} if this robot is real")
        builder.start(tag, attrs)

    def end(tag: str) -> None:
        nesting[0] -= 1
        builder.end(tag)

    def doctype(name, *_) -> None:
        raise UrdfRefused("doctype", f"the URDF has a <!DOCTYPE {name}> (line {parser.CurrentLineNumber}): "
                                     "a URDF needs no document type or entities; remove it")

    parser.StartElementHandler, parser.EndElementHandler = start, end
    parser.CharacterDataHandler = builder.data
    parser.StartDoctypeDeclHandler = doctype
    parser.EntityDeclHandler = doctype          # an entity outside a DOCTYPE cannot occur; kept as a second lock
    try:
        parser.Parse(text, True)
    except pyexpat.ExpatError as e:
        raise UrdfRefused("not_xml", f"the URDF is not well-formed XML ({pyexpat.ErrorString(e.code)}, line "
                                     f"{e.lineno}): check the file or the robot_description text") from None
    root = builder.close()
    if root.tag != "robot":
        raise UrdfRefused("not_robot", f"the URDF's root element is <{root.tag}>, expected <robot>")
    return root


def _names(items: list[str]) -> str:
    more = f" and {len(items) - _SHOWN} more" if len(items) > _SHOWN else ""
    return ", ".join(repr(x) for x in items[:_SHOWN]) + more


def check_tree(root: ET.Element, limits: UrdfLimits = UrdfLimits()) -> UrdfTree:
    """The ``<robot>`` element checked as a tree (see the module docstring); UrdfRefused names what is wrong."""
    links: list[str] = []
    seen: set[str] = set()
    for link in root.findall("link"):
        name = link.get("name")
        if not name:
            raise UrdfRefused("unnamed", "a URDF <link> has no name: name every link")
        if name in seen:
            raise UrdfRefused("duplicate_name", f"URDF link {name!r} is defined twice: give every link a unique name")
        seen.add(name)
        links.append(name)
    if not links:
        raise UrdfRefused("no_link", "the URDF has no <link>: a skeleton needs at least one")
    parent_of: dict[str, str] = {}          # child link -> parent link
    joint_of: dict[str, str] = {}           # child link -> joint
    children: dict[str, list[str]] = {}
    joint_names: set[str] = set()
    for j in root.findall("joint"):
        name, kind = j.get("name"), j.get("type")
        p, c = j.find("parent"), j.find("child")
        parent, child = (p.get("link") if p is not None else None), (c.get("link") if c is not None else None)
        if not name or not kind or not parent or not child:
            raise UrdfRefused("joint_incomplete", f"URDF joint {name!r} lacks a name, type, parent link or child "
                                                  "link: give all four")
        if name in joint_names:
            raise UrdfRefused("duplicate_name", f"URDF joint {name!r} is defined twice: give every joint a unique name")
        joint_names.add(name)
        if kind not in JOINT_TYPES:
            raise UrdfRefused("joint_type", f"URDF joint {name!r} has type {kind!r}: use one of {', '.join(JOINT_TYPES)}")
        if parent == child:
            raise UrdfRefused("self_loop", f"URDF joint {name!r} has link {parent!r} as both parent and child: a "
                                           "joint connects two different links; fix the URDF")
        for role, link in (("parent", parent), ("child", child)):
            if link not in seen:
                raise UrdfRefused("missing_link", f"URDF joint {name!r} names {role} link {link!r}, which is not "
                                                  "defined: add the <link> or fix the name")
        if child in parent_of:
            raise UrdfRefused("two_parents", f"URDF link {child!r} is the child of two joints ({joint_of[child]!r} and "
                                             f"{name!r}): a link has one parent joint in a tree; fix the URDF")
        parent_of[child], joint_of[child] = parent, name
        children.setdefault(parent, []).append(child)
    roots = [n for n in links if n not in parent_of]
    if len(roots) != 1:
        if not roots:
            raise UrdfRefused("cycle", f"every URDF link is some joint's child: the joints form a cycle (through "
                                       f"{_names(_cycle_from(links[0], parent_of))}); a skeleton is a tree")
        raise UrdfRefused("roots", f"the URDF has {len(roots)} root links ({_names(roots)}): a skeleton needs "
                                   "exactly one link that is no joint's child; join them with joints")
    depth = {roots[0]: 0}
    deepest = 0
    todo = deque([roots[0]])
    while todo:                             # breadth first: depth is the number of joints from the root
        link = todo.popleft()
        for child in children.get(link, ()):
            d = depth[link] + 1
            if d > limits.max_depth:
                raise UrdfRefused("too_deep", f"URDF link {child!r} is {d} joints below the root {roots[0]!r} "
                                              f"(skeleton.max_depth {limits.max_depth}): refused; raise "
                                              "skeleton.max_depth if this robot is real")
            depth[child] = d
            deepest = max(deepest, d)
            todo.append(child)
    if len(depth) != len(links):
        lost = next(n for n in links if n not in depth)
        raise UrdfRefused("cycle", f"URDF links {_names(_cycle_from(lost, parent_of))} form a cycle of joints, "
                                   f"cut off from the root {roots[0]!r}: a skeleton is a tree; fix the URDF")
    return UrdfTree(roots[0], len(links), len(joint_names), deepest)


def _cycle_from(link: str, parent_of: dict[str, str]) -> list[str]:
    """The links of the cycle above ``link`` (every link is somebody's child up there)."""
    order: dict[str, int] = {}
    while link not in order and link in parent_of:
        order[link] = len(order)
        link = parent_of[link]
    return [n for n, k in order.items() if k >= order.get(link, 0)]


def read_urdf_file(path, limits: UrdfLimits = UrdfLimits()) -> str:
    """The text of a URDF file, its size checked before it is read (UrdfError naming the path otherwise)."""
    try:
        with open(path, "rb") as f:
            data = f.read(limits.max_bytes + 1)
    except OSError as e:
        raise UrdfError(f"cannot read URDF file {str(path)!r}: {e.strerror}; check the path") from e
    if len(data) > limits.max_bytes:
        raise UrdfRefused("too_large", f"URDF file {str(path)!r} has more than {limits.max_bytes} bytes "
                                       "(skeleton.max_urdf_bytes): refused unread; raise skeleton.max_urdf_bytes if "
                                       "this robot is real")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise UrdfRefused("not_xml", f"URDF file {str(path)!r} is not UTF-8 text (byte {e.start}): give the URDF "
                                     "file itself") from None


def check_urdf(text: str, limits: UrdfLimits = UrdfLimits()) -> UrdfTree:
    """``parse_urdf`` then ``check_tree``: the one call before a URDF text is used (see the module docstring)."""
    return check_tree(parse_urdf(text, limits), limits)
