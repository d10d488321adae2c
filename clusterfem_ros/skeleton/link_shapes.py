"""The flesh of a URDF's leaf links (head, hands, feet) from the URDF's own shapes.

A jelly body is capsules around the bones; a leaf link (a bone with no child joint) has no length, so its
capsule would be a ball of ``body.bone_radius``. ``leaf_geometry`` gives it the URDF's ``<collision>``
shapes instead, else its ``<visual>`` ones: box, cylinder (along its Z), sphere, capsule (a cylinder of
``length`` along Z with half-spheres), or a mesh, taken as its bounding box (trimesh) when the file is
found, each placed by its ``<origin>``. A leaf without any usable shape keeps the ball; one warning names
those leaves.

Each shaped leaf also gets a tip link (``<leaf>_tip``, see ``urdf_builder``) at the far end of its shapes'
main axis, so the bone has a segment through its flesh for binding (else a foot's flesh would bind to the
shin, whose end is the ankle) and for the skeleton markers.

Arrays: a shape's ``rotation`` (3, 3) and ``translation`` (3,) place shape-local points in its link's frame
(``LinkShape``) or in the world (``PlacedShape``); ``half`` (3,) are the box half-sizes, or (r, r, half
length) of a cylinder or capsule, or (r, r, r) of a sphere [m].
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ClusterFemError
from .mounting import rpy_matrix
from .robot_data import package_file
from .urdf_builder import HELPER_MASS, TIP_SUFFIX, UrdfBuilder

KINDS = ("box", "cylinder", "sphere", "capsule")


class ShapeError(ClusterFemError, ValueError):
    """A URDF shape attribute that is not a number of the right count; the message names the link and the text."""


@dataclass(frozen=True)
class LinkShape:
    link: str
    kind: str                   # one of KINDS (a mesh is a box)
    rotation: np.ndarray        # (3, 3) shape frame in the link frame
    translation: np.ndarray     # (3,) [m]
    half: np.ndarray            # (3,) [m], see the module docstring
    source: str                 # 'collision', 'visual' or 'mesh bounding box'


@dataclass(frozen=True)
class PlacedShape:
    bone: int                   # index of its bone among the body's capsules
    kind: str
    rotation: np.ndarray        # (3, 3) shape frame in the world
    translation: np.ndarray     # (3,) [m]
    half: np.ndarray            # (3,) [m]


@dataclass(frozen=True)
class LeafGeometry:
    urdf: str                                       # the URDF with a tip link per shaped leaf
    shapes: dict[str, list[LinkShape]]             # leaf link -> its shapes
    warnings: list[str] = field(default_factory=list)


def urdf_floats(text: str | None, count: int, where: str, signed: bool = False) -> np.ndarray:
    """``count`` finite numbers (non-negative unless ``signed``) from a URDF attribute; ShapeError naming it."""
    try:
        out = np.array([float(x) for x in (text or "").split()])
    except ValueError:
        out = np.zeros(0)
    if out.shape != (count,) or not np.isfinite(out).all() or (not signed and (out < 0).any()):
        sign = "" if signed else " non-negative"
        raise ShapeError(f"URDF {where} = {text!r}: give {count} finite{sign} number(s)")
    return out


def find_mesh_file(name: str, search: list[Path]) -> Path | None:
    """The mesh a URDF names (a path, file://path or package://<package>/<path>): the installed package's file
    (robot_data.package_file), the path itself, or under a search folder by its path, or by its path less
    leading folders (the package's own layout)."""
    installed = package_file(name)
    if installed is not None:
        return installed
    rest = name.split("://", 1)[1] if "://" in name else name
    if Path(rest).is_absolute():
        return Path(rest) if Path(rest).is_file() else None
    parts = Path(rest).parts
    for root in search:
        for k in range(len(parts)):
            p = root.joinpath(*parts[k:])
            if p.is_file():
                return p
    return None


def _shape(link: str, element: ET.Element, source: str, search: list[Path]) -> tuple[LinkShape | None, str]:
    """One <collision>/<visual> element as a LinkShape, or None and why not."""
    o = element.find("origin")
    xyz = urdf_floats(o.get("xyz", "0 0 0") if o is not None else "0 0 0", 3, f"link {link!r} shape origin xyz", True)
    rpy = urdf_floats(o.get("rpy", "0 0 0") if o is not None else "0 0 0", 3, f"link {link!r} shape origin rpy", True)
    R = rpy_matrix(*rpy)
    g = element.find("geometry")
    geo = g[0] if g is not None and len(g) else None
    where = f"link {link!r} <{source}>"
    if geo is None:
        return None, f"{where} has no geometry"
    if geo.tag == "box":
        return LinkShape(link, "box", R, xyz, 0.5 * urdf_floats(geo.get("size"), 3, f"{where} box size"), source), ""
    if geo.tag in ("cylinder", "capsule"):
        r = urdf_floats(geo.get("radius"), 1, f"{where} {geo.tag} radius")[0]
        length = urdf_floats(geo.get("length"), 1, f"{where} {geo.tag} length")[0]
        return LinkShape(link, geo.tag, R, xyz, np.array([r, r, 0.5 * length]), source), ""
    if geo.tag == "sphere":
        r = urdf_floats(geo.get("radius"), 1, f"{where} sphere radius")[0]
        return LinkShape(link, "sphere", R, xyz, np.full(3, r), source), ""
    if geo.tag == "mesh":
        name = geo.get("filename", "")
        path = find_mesh_file(name, search)
        if path is None:
            return None, f"{where} mesh {name!r} not found"
        import trimesh
        try:
            lo, hi = np.asarray(trimesh.load(path, force="mesh").bounds, dtype=np.float64)
        except Exception as exc:  # trimesh raises many kinds for unreadable files
            return None, f"{where} mesh {str(path)!r} cannot be read ({exc})"
        scale = urdf_floats(geo.get("scale", "1 1 1"), 3, f"{where} mesh scale")
        lo, hi = lo * scale, hi * scale
        return LinkShape(link, "box", R, xyz + R @ (0.5 * (lo + hi)), 0.5 * (hi - lo), "mesh bounding box"), ""
    return None, f"{where} has a <{geo.tag}>, not box, cylinder, sphere, capsule or mesh"


def leaf_links(root: ET.Element) -> list[str]:
    """Links that are bones (not helpers, not tips) and parent no joint."""
    parents = {p.get("link") for p in root.findall("joint/parent")}
    out = []
    for link in root.findall("link"):
        n = link.get("name")
        m = link.find("inertial/mass")
        try:
            helper = m is not None and float(m.get("value", "1")) <= HELPER_MASS
        except ValueError:              # the Skeleton names a mass that is not a number
            helper = False
        if n not in parents and not helper and not n.endswith(TIP_SUFFIX):
            out.append(n)
    return out


def search_folders(urdf_file: str | Path | None = None) -> list[Path]:
    """Where meshes are looked for: the URDF file's folder and its parent, then the data folders
    (clusterfem_ros.data_dirs: $CLUSTERFEM_DATA, ../shared/data of a checkout, the user data folder)."""
    from ..data_dirs import data_roots
    out = []
    if urdf_file:
        here = Path(urdf_file).resolve().parent
        out += [here, here.parent]
    return out + data_roots()


def _tip(shapes: list[LinkShape]) -> np.ndarray:
    """The far end (from the link origin) of the shapes' main axes: a box's longest axis shortened by its
    smallest half-size, a cylinder's or capsule's Z, a sphere's centre."""
    ends = []
    for s in shapes:
        if s.kind == "box":
            a = int(np.argmax(s.half))
            reach = s.half[a] - s.half.min()
        elif s.kind == "sphere":
            a, reach = 2, 0.0
        else:
            a, reach = 2, s.half[2] - (s.half[0] if s.kind == "cylinder" else 0.0)
        axis = s.rotation[:, a] * max(reach, 0.0)
        ends += [s.translation + axis, s.translation - axis]
    ends = np.array(ends)
    return ends[np.argmax(np.linalg.norm(ends, axis=1))]


def leaf_geometry(xml: str, search: list[Path] | None = None) -> LeafGeometry:
    """Shapes for the URDF's leaf links, and the URDF with a tip per shaped leaf (see the module docstring)."""
    root = ET.fromstring(xml)
    search = search if search is not None else search_folders()
    shapes: dict[str, list[LinkShape]] = {}
    plain, problems = [], []
    names = {x.get("name") for x in root.findall("link")}
    b = UrdfBuilder("tips")
    for leaf in leaf_links(root):
        element = root.find(f"link[@name={leaf!r}]")
        found: list[LinkShape] = []
        why_not = []
        for source in ("collision", "visual"):
            for e in element.findall(source):
                shape, why = _shape(leaf, e, source, search)
                if shape is not None:
                    found.append(shape)
                else:
                    why_not.append(why)
            if found:
                break
        if not found:
            plain.append(leaf)
            problems += why_not
            continue
        shapes[leaf] = found
        tip = _tip(found)
        if np.linalg.norm(tip) > 1e-6 and leaf + TIP_SUFFIX not in names:
            b.tip(leaf, tip)
    warnings = []
    if plain:
        warnings.append(f"leaf links without a usable collision or visual shape keep a ball of body.bone_radius: "
                        f"{', '.join(plain)}" + (f" ({'; '.join(problems)})" if problems else ""))
    for element in ET.fromstring(b.to_string()):
        root.append(element)
    return LeafGeometry(ET.tostring(root, encoding="unicode") if shapes else xml, shapes, warnings)


def place_shapes(shapes: dict[str, list[LinkShape]], bone_names: list[str], rotation: np.ndarray,
                 translation: np.ndarray, bone_index: dict[str, int]) -> list[PlacedShape]:
    """The shapes in the world, with their bone's world pose (rotation (nb, 3, 3), translation (nb, 3) in
    ``bone_names`` order); ``bone_index`` maps a bone name to its index among the body's capsules."""
    out = []
    for link, items in shapes.items():
        b = bone_names.index(link)
        for s in items:
            out.append(PlacedShape(bone_index[link], s.kind, rotation[b] @ s.rotation,
                                   rotation[b] @ s.translation + translation[b], s.half))
    return out


def shape_depth(points: np.ndarray, shape: PlacedShape) -> np.ndarray:
    """(k,) how far points lie outside the shape (negative inside; exact inside and for spheres and capsules,
    a lower bound outside boxes and cylinders) [m]."""
    local = (np.asarray(points, dtype=np.float64) - shape.translation) @ shape.rotation
    h = shape.half
    if shape.kind == "box":
        return np.max(np.abs(local) - h, axis=1)
    if shape.kind == "sphere":
        return np.linalg.norm(local, axis=1) - h[0]
    radial = np.hypot(local[:, 0], local[:, 1])
    if shape.kind == "cylinder":
        return np.maximum(radial - h[0], np.abs(local[:, 2]) - h[2])
    beyond = np.maximum(np.abs(local[:, 2]) - h[2], 0.0)
    return np.hypot(radial, beyond) - h[0]


def shapes_inside(points: np.ndarray, shapes: list[PlacedShape]) -> np.ndarray:
    """(k,) bool: True where a point lies in any of the shapes."""
    out = np.zeros(len(points), dtype=bool)
    for s in shapes:
        out |= shape_depth(points, s) <= 0.0
    return out


@dataclass(frozen=True)
class PreparedUrdf:
    urdf: str                                   # what the skeleton, the body and the markers are made from
    leaf_shapes: dict[str, list[LinkShape]]     # {} unless leaf geometry was asked for and found
    notes: list[str]                            # start-up lines: the root chosen, then any warnings


def prepare_urdf(xml: str, up_axis: str = "z", root_joint: str = "auto", leaf_shapes: bool = False,
                 urdf_file: str | Path | None = None) -> PreparedUrdf:
    """The URDF as the scene uses it: mounted (``mounting.mount_urdf``) and, with ``leaf_shapes``
    (a jelly body), its leaf links' shapes and tips (``leaf_geometry``; meshes searched from ``urdf_file``'s
    folder). The one place the scene and the bag renderer turn a URDF into the skeleton they draw."""
    from .mounting import mount_urdf
    mounted = mount_urdf(xml, up_axis, root_joint)
    notes = [mounted.note]
    if not leaf_shapes:
        return PreparedUrdf(mounted.urdf, {}, notes)
    try:
        leaves = leaf_geometry(mounted.urdf, search_folders(urdf_file))
    except ET.ParseError:
        return PreparedUrdf(mounted.urdf, {}, notes)        # the Skeleton names the XML error
    notes += [f"warning: {w}" for w in leaves.warnings]
    if leaves.shapes:
        notes.append("leaf links shaped by the URDF: " + ", ".join(
            f"{link} ({', '.join(s.kind + ' from ' + s.source for s in items)})" for link, items in leaves.shapes.items()))
    return PreparedUrdf(leaves.urdf, leaves.shapes, notes)
