"""A soft cover on a robot: the volumes of its links' own shapes with a skin around them, voxelized into
tetrahedra, each part bound to its own link.

Shapes: each link's ``<collision>`` geometry (``source='collision'``; a link without any takes its
``<visual>`` one), or the other way round with ``source='visual'``: meshes (STL, OBJ, DAE... through trimesh,
scaled and placed by their ``<origin>``), boxes, cylinders, spheres and capsules, all as triangle surfaces.
A link that is not a bone of the skeleton (a frame, a helper) gives its shapes to the bone it hangs on by
fixed joints; shapes beyond a movable joint from any bone are left out, named in the notes. A rigid body
without any shape (a URDF drawn without shapes, or links left bare) gets a capsule of ``bare_radius``
(body.bone_radius) around each of its bones' segments that has a length, named in the notes.

Why voxels (a signed-distance shell) rather than fTetWild: robot meshes are often open, self-intersecting
or made of several overlapping pieces; a voxel shell needs none of them to be closed, costs a second, and
gives the tet count asked for directly. Each link's surface is sampled densely (``spacing``; at most
``MAX_SAMPLES`` in all), the distance of every voxel centre to it taken from a k-d tree; the voxels within
``max(thickness, 0.87 h)`` of the surface form a closed shell (0.87 h: half a voxel diagonal, so the shell has
no gaps), and the shell's holes filled (``ndimage.binary_fill_holes``) give the link's solid: its volume plus a
skin of ``thickness``.
The voxel spacing ``h`` is chosen so the cover has about ``target_tets`` tets (five per voxel).
All links share one lattice of voxels, but only the voxels of each link's own box (its shapes and the reach around
them) are looked at, and the solid ones kept by their lattice key: the cost follows the links' shapes, not the
robot's bounding box, so links 100 m apart cost what links side by side do. Past ``MAX_VOXELS`` voxels looked at
(or ``MAX_AXIS_VOXELS`` along one axis of the lattice) the cover is refused in one line: ``UrdfRefused``
('cover_too_large') naming the robot's extent, the count, the limit and the way out.

Links of different rigid bodies are never glued: a voxel belongs to the link it lies in (else the nearest),
links joined by fixed joints form one rigid body, and where voxels of two rigid bodies touch (share a
corner), the voxel of the larger body is left out, so the small links keep their cover where the spacing
allows (of two equal ones, one) and every part moves with its own link. A rigid body whose voxels all go is named in the notes.

Each vertex carries its bone and its depth: its distance to its link's surface, negative inside a closed
(watertight) shape; ``link_binding`` (body/) turns them into the binding: the vertices on or in the link
held firmly, the skin's held softly.

Arrays: vertices (n, 3) [m] in the skeleton's rest pose q = 0; ``bone`` (n,) skeleton bone index;
``depth`` (n,) [m].
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..fem.mesh.tet_mesh import TetMesh
from ..fem.mesh.voxel_mesh import cells_mesh
from .link_shapes import find_mesh_file, search_folders, urdf_floats
from .mounting import rpy_matrix
from .urdf_check import MAX_TRIANGLES, UrdfRefused

SOURCES = ("collision", "visual")
SHELL = 0.5 * np.sqrt(3.0)       # a voxel whose centre is within half its diagonal of a surface touches it
SAMPLE_DENSITY = 1.5             # surface samples per spacing^2 of area
# surface samples of one cover (~100 MB with their k-d trees): example-robot-data's robots take at most 2.3 M
# (romeo_laas_small) at extent / 300; a URDF of 1,000 small shaped links would take 400,000 per link there (17 GB)
MAX_SAMPLES = 4_000_000
# voxels one cover looks at, at one spacing tried (the sum of its links' boxes, never the robot's whole box): ~50 B
# each (one link, a 10 m bar on the space diagonal: 2.35 M voxels, 107 MB). example-robot-data's robots look at
# most 62,000 at 4,800 tets (simple_humanoid_classical), 392,000 at body.target_tets' ceiling 400,000 (kinova)
MAX_VOXELS = 4_000_000
# voxels along one axis of the lattice the links lie in: TetMesh.validate tolerates a volume of 1e-14 (the mesh's
# extent)^3 as round-off, which past ~25,000 voxels along an axis passes a voxel's corner tet (h^3 / 6); 16,384
# voxels of 13 mm (4,800 tets on three 5 cm boxes) span 213 m
MAX_AXIS_VOXELS = 16_384


@dataclass(frozen=True)
class CoverPart:
    """One link's shapes in the world at rest, as surface samples, with the bone and rigid body they go with."""
    link: str
    bone: int                   # skeleton bone index
    body: int                   # rigid body index (bones joined by fixed joints share it)
    points: np.ndarray          # (k, 3) surface samples [m]
    meshes: list                # trimesh.Trimesh in the world, for the inside test
    lo: np.ndarray              # (3,) bounding box of the surface [m]
    hi: np.ndarray


@dataclass(frozen=True)
class RobotCover:
    mesh: TetMesh
    bone: np.ndarray            # (n,) bone of each vertex
    depth: np.ndarray           # (n,) distance to its link's surface, negative inside a closed shape [m]
    spacing: float              # voxel edge h [m]
    thickness: float            # the skin as built: max(thickness asked, 0.87 h) [m]
    notes: list[str] = field(default_factory=list)


def _geometry(element: ET.Element, link: str, source: str, search: list[Path]):
    """One <collision>/<visual> element as a trimesh in its link's frame, or (None, why not)."""
    import trimesh
    o = element.find("origin")
    xyz = urdf_floats(o.get("xyz", "0 0 0") if o is not None else "0 0 0", 3, f"link {link!r} shape origin xyz", True)
    rpy = urdf_floats(o.get("rpy", "0 0 0") if o is not None else "0 0 0", 3, f"link {link!r} shape origin rpy", True)
    g = element.find("geometry")
    geo = g[0] if g is not None and len(g) else None
    where = f"link {link!r} <{source}>"
    if geo is None:
        return None, f"{where} has no geometry"
    if geo.tag == "box":
        m = trimesh.creation.box(extents=urdf_floats(geo.get("size"), 3, f"{where} box size"))
    elif geo.tag in ("cylinder", "capsule"):
        r = urdf_floats(geo.get("radius"), 1, f"{where} {geo.tag} radius")[0]
        length = urdf_floats(geo.get("length"), 1, f"{where} {geo.tag} length")[0]
        m = (trimesh.creation.cylinder(radius=r, height=length, sections=24) if geo.tag == "cylinder"
             else trimesh.creation.capsule(height=length, radius=r, count=[12, 12]))
    elif geo.tag == "sphere":
        m = trimesh.creation.icosphere(subdivisions=2, radius=urdf_floats(geo.get("radius"), 1, f"{where} sphere radius")[0])
    elif geo.tag == "mesh":
        name = geo.get("filename", "")
        path = find_mesh_file(name, search)
        if path is None:
            return None, f"{where} mesh {name!r} not found"
        try:
            m = trimesh.load(path, force="mesh")
        except Exception as exc:  # trimesh raises many kinds for unreadable files
            return None, f"{where} mesh {path.name!r} cannot be read ({exc})"
        if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
            return None, f"{where} mesh {path.name!r} has no triangles"
        scale = urdf_floats(geo.get("scale", "1 1 1"), 3, f"{where} mesh scale", signed=True)   # -1: mirrored
        if not scale.all():
            return None, f"{where} mesh {path.name!r} has scale {geo.get('scale')!r}: a zero flattens it"
        m = m.copy()
        m.apply_transform(np.diag(np.append(scale, 1.0)))     # trimesh keeps the faces outward under a mirror
    else:
        return None, f"{where} has a <{geo.tag}>, not a mesh, box, cylinder, sphere or capsule"
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rpy_matrix(*rpy), xyz
    m.apply_transform(T)
    return m, ""


def link_geometry(xml: str, source: str = "collision", search: list[Path] | None = None,
                  max_triangles: int = MAX_TRIANGLES):
    """({link: [trimesh in the link frame]}, notes): each link's shapes from ``source``, else from the other.
    UrdfRefused ('too_many_triangles') as soon as the shapes read pass ``max_triangles`` triangles in all (a
    primitive counts its triangulation's: a sphere 320, a box 12)."""
    if source not in SOURCES:
        raise ValueError(f"cover shapes source = {source!r}: choose one of {', '.join(SOURCES)}")
    root = ET.fromstring(xml)
    search = search if search is not None else search_folders()
    order = (source,) + tuple(s for s in SOURCES if s != source)
    out, problems, triangles = {}, [], 0
    for link in root.findall("link"):
        name = link.get("name")
        for s in order:
            found = []
            for e in link.findall(s):
                m, why = _geometry(e, name, s, search)
                if m is not None:
                    found.append(m)
                    triangles += len(m.faces)
                    if triangles > max_triangles:
                        raise UrdfRefused(
                            "too_many_triangles",
                            f"the URDF's link shapes have more than {max_triangles:,} triangles (body.cover_max_"
                            f"triangles; {triangles:,} read up to link {name!r}, <{s}>): a robot cover holds them all "
                            "while it is built; refused; simplify the meshes or raise body.cover_max_triangles if "
                            "this robot is real")
                else:
                    problems.append(why)
            if found:
                out[name] = found
                break
    notes = [f"shapes left out: {'; '.join(problems)}"] if problems else []
    return out, notes


def rigid_bodies(xml: str, bone_names: list[str]) -> tuple[dict[str, int], dict[int, int]]:
    """({link: the bone it is rigidly fixed to (fixed joints only), for the links that have one},
    {bone: its rigid body index}): bones joined by fixed joints (through any links) share a rigid body."""
    root = ET.fromstring(xml)
    parent: dict[str, tuple[str, str]] = {}
    for j in root.findall("joint"):
        p, c = j.find("parent"), j.find("child")
        if p is not None and c is not None:
            parent[c.get("link")] = (p.get("link"), j.get("type"))
    index = {n: b for b, n in enumerate(bone_names)}

    def top(link: str) -> str:
        """The highest link reached from ``link`` through fixed joints only."""
        seen = set()
        while link in parent and parent[link][1] == "fixed" and link not in seen:
            seen.add(link)
            link = parent[link][0]
        return link

    def bone_of(link: str) -> int | None:
        """``link``'s bone: itself, else the nearest bone above it through fixed joints, else below it."""
        seen, c = set(), link
        while c not in seen:
            seen.add(c)
            if c in index:
                return index[c]
            if c not in parent or parent[c][1] != "fixed":
                break
            c = parent[c][0]
        return None

    links = [x.get("name") for x in root.findall("link")]
    owner = {n: b for n in links if (b := bone_of(n)) is not None}
    tops: dict[str, int] = {}
    body = {}
    for n, b in index.items():
        body[b] = tops.setdefault(top(n), len(tops))
    return owner, body


def bone_capsules(xml: str, skeleton, geometry: dict, radius: float) -> dict:
    """{link: [capsule]} in the link frame around the segment of every bone whose rigid body has no shape and whose
    segment has a length (a URDF drawn without shapes, or links left bare)."""
    import trimesh
    owner, body = rigid_bodies(xml, skeleton.bone_names)
    shaped = {body[owner[link]] for link in geometry if link in owner}
    poses = skeleton.forward(skeleton.neutral())
    starts, ends = skeleton.bone_segments(skeleton.neutral())
    out = {}
    for b, name in enumerate(skeleton.bone_names):
        d = poses.rotation[b].T @ (ends[b] - starts[b])
        length = float(np.linalg.norm(d))
        if body[b] in shaped or length < 1e-6:
            continue
        m = trimesh.creation.capsule(height=length, radius=radius, count=[12, 12])
        T = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / length)
        T[:3, 3] = poses.rotation[b].T @ (starts[b] - poses.translation[b]) + 0.5 * d
        out[name] = [m.apply_transform(T)]
    return out


def cover_parts(xml: str, skeleton, geometry: dict, spacing: float, max_samples: int = MAX_SAMPLES
                ) -> tuple[list[CoverPart], list[str]]:
    """The shapes of ``geometry`` placed at the skeleton's rest pose (its own kinematics, ``link_placements``:
    no pinocchio Data, whose size grows with the cube of the joints), sampled every ``spacing`` [m], or wider
    where ``max_samples`` samples in all would not reach (said in a note)."""
    import trimesh
    owner, body = rigid_bodies(xml, skeleton.bone_names)
    known = set(skeleton.link_names)
    placed = [link for link in geometry if link in owner and link in known]
    away = [link for link in geometry if link not in owner or link not in known]
    notes = [f"links on no bone through fixed joints have no cover: {', '.join(away)}"] if away else []
    area = sum(float(m.area) for link in placed for m in geometry[link])
    wide = float(np.sqrt(SAMPLE_DENSITY * area / max_samples))
    if wide > spacing:
        notes.append(f"surface samples {wide * 1e3:.2g} mm apart, not {spacing * 1e3:.2g} mm: {area:.3g} m^2 of "
                     f"shapes in {max_samples:,} samples (robot_cover.MAX_SAMPLES)")
        spacing = wide
    R, p = skeleton.link_placements(skeleton.neutral(), placed)
    parts = []
    for k, link in enumerate(placed):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[k], p[k]
        world = [m.copy().apply_transform(T) for m in geometry[link]]
        points = []
        for m in world:
            count = int(min(max(m.area / spacing ** 2 * SAMPLE_DENSITY, 50), 400000))
            points += [np.asarray(m.vertices), np.asarray(trimesh.sample.sample_surface(m, count, seed=0)[0])]
        points = np.concatenate(points)
        b = owner[link]
        parts.append(CoverPart(link, b, body[b], points, world, points.min(axis=0), points.max(axis=0)))
    return parts, notes


def _inside(meshes: list, points: np.ndarray) -> np.ndarray:
    """(k,) bool: inside any of the closed meshes (open ones hold no inside)."""
    out = np.zeros(len(points), dtype=bool)
    for m in meshes:
        if m.is_watertight and len(points):
            out |= m.contains(points)
    return out


def _lattice(lo: np.ndarray, hi: np.ndarray, h: float, parts: list[CoverPart], thickness: float, target_tets: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n (3,) voxels of the lattice of spacing ``h`` from ``lo`` over [lo, hi] per axis, the boxes (p, 2, 3) of the
    voxels within reach of each part: [i0, i1)), or UrdfRefused ('cover_too_large') in one line when an axis would
    pass MAX_AXIS_VOXELS or the boxes together MAX_VOXELS."""
    reach = max(thickness, SHELL * h)
    span = hi - lo
    axes = np.ceil(span / h - 1e-9)
    ext = " x ".join(f"{v:.3g}" for v in span)
    way = (f"lower body.target_tets (now {target_tets:,}) for larger voxels, or check the URDF's link shapes and "
           "joint origins")
    if axes.max() > MAX_AXIS_VOXELS:
        raise UrdfRefused("cover_too_large", f"a robot cover over links spanning {ext} m would need {axes.max():.3g} "
                          f"voxels of {h * 1e3:.3g} mm along an axis, past the limit of {MAX_AXIS_VOXELS:,} "
                          f"(robot_cover.MAX_AXIS_VOXELS); refused; {way}")
    n = np.maximum(axes.astype(np.int64), 1)
    box = np.array([[np.floor((p.lo - reach - lo) / h), np.ceil((p.hi + reach - lo) / h)] for p in parts])
    box = np.clip(box, 0, n).astype(np.int64)
    each = np.prod(np.maximum(box[:, 1] - box[:, 0], 0), axis=1)
    if each.sum() > MAX_VOXELS:
        big = int(np.argmax(each))
        size = " x ".join(f"{v:.3g}" for v in parts[big].hi - parts[big].lo)
        raise UrdfRefused("cover_too_large", f"a robot cover over links spanning {ext} m would look at {each.sum():,} "
                          f"voxels of {h * 1e3:.3g} mm around its {len(parts)} shaped links ({each[big]:,} around link "
                          f"{parts[big].link!r}, {size} m), past the limit of {MAX_VOXELS:,} (robot_cover.MAX_VOXELS); "
                          f"refused; {way}")
    return n, box[:, 0], box[:, 1]


def _voxels(parts: list[CoverPart], trees: list, lo: np.ndarray, n: np.ndarray, i0: np.ndarray, i1: np.ndarray,
            h: float, thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """(keys (m,) sorted, part (m,)): the solid voxels of the lattice (n voxels per axis from ``lo``, spacing ``h``),
    only those of each part's box [i0, i1) looked at, each with the part it belongs to. A voxel's key is
    ``_key`` of its (i, j, k)."""
    reach = max(thickness, SHELL * h)
    keys, scores, owner = [], [], []
    for k, p in enumerate(parts):
        a, b = i0[k], i1[k]
        if (b <= a).any():
            continue
        axes = [np.arange(a[x], b[x]) for x in range(3)]
        centres = np.stack(np.meshgrid(*[lo[x] + (axes[x] + 0.5) * h for x in range(3)], indexing="ij"), -1)
        # a distance past the reach only ever counts as 'past the reach' (inf): bounding the search keeps a voxel
        # far from every sample (inside a large box) as cheap as one near them
        d, _ = trees[k].query(centres.reshape(-1, 3), distance_upper_bound=1.001 * reach)
        d = d.reshape(centres.shape[:3])
        del centres
        solid = ndimage.binary_fill_holes(d <= reach)
        # inside a link (filled, beyond the shell) ranks before any distance; else the nearest surface wins
        score = np.where(solid & (d > reach), -1.0, d)
        ijk = np.nonzero(solid)
        keys.append(_key(n, *(axes[x][ijk[x]] for x in range(3))))
        scores.append(score[solid])
        owner.append(np.full(len(keys[-1]), k, dtype=np.int64))
    if not keys:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    keys, scores, owner = np.concatenate(keys), np.concatenate(scores), np.concatenate(owner)
    # of the parts claiming a voxel, the lowest score wins; of equal scores, the first part
    order = np.lexsort((owner, scores, keys))
    keys, owner = keys[order], owner[order]
    first = np.ones(len(keys), dtype=bool)
    first[1:] = keys[1:] != keys[:-1]
    return keys[first], owner[first]


def _key(n: np.ndarray, i, j, k):
    """The lattice key of voxel (i, j, k) of a lattice of n voxels per axis: its index in the lattice padded by one
    voxel on every side, so keys sort as (i, j, k) do and the key of the neighbour (i + a, j + b, k + c) is the key
    plus (a (n[1] + 2) + b) (n[2] + 2) + c, never wrapping past an edge."""
    return ((np.asarray(i, dtype=np.int64) + 1) * (n[1] + 2) + (np.asarray(j) + 1)) * (n[2] + 2) + (np.asarray(k) + 1)


def _cells(n: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """(m, 3) voxel (i, j, k) of each key."""
    k = keys % (n[2] + 2) - 1
    j = keys // (n[2] + 2) % (n[1] + 2) - 1
    return np.stack([keys // ((n[1] + 2) * (n[2] + 2)) - 1, j, k], axis=1)


def _separate(n: np.ndarray, keys: np.ndarray, label: np.ndarray, body_of: np.ndarray) -> np.ndarray:
    """(m,) bool: the voxels ``keys`` kept, without those sharing a corner with a voxel of another rigid body: of each
    such pair the voxel of the body with more voxels goes (of equal ones, the body with the higher index)."""
    body = body_of[label]
    size = np.bincount(body, minlength=body_of.max() + 1)
    drop = np.zeros(len(keys), dtype=bool)
    for off in [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) > (0, 0, 0)]:
        shifted = keys + (off[0] * (n[1] + 2) + off[1]) * (n[2] + 2) + off[2]
        at = np.minimum(np.searchsorted(keys, shifted), len(keys) - 1)
        a = np.flatnonzero(keys[at] == shifted)                   # voxel a and its neighbour b at a + off
        b = at[a]
        ba, bb = body[a], body[b]
        clash = ba != bb
        sa, sb = size[ba], size[bb]
        drop[a[clash & ((sa > sb) | ((sa == sb) & (ba > bb)))]] = True
        drop[b[clash & ((sb > sa) | ((sa == sb) & (bb > ba)))]] = True
    return ~drop


def robot_cover(xml: str, skeleton, thickness: float = 0.02, target_tets: int = 4800, source: str = "collision",
                urdf_file: str | Path | None = None, iterations: int = 6, bare_radius: float = 0.05,
                max_triangles: int = MAX_TRIANGLES) -> RobotCover:
    """The cover of the module docstring around ``skeleton`` (built from the prepared URDF ``xml``) at rest; a rigid
    body without any shape gets capsules of ``bare_radius`` [m] around its bones' segments (bone_capsules). Shapes
    of more than ``max_triangles`` triangles in all are refused (link_geometry), and so is a cover that would look at
    more than MAX_VOXELS voxels, or MAX_AXIS_VOXELS along an axis (_lattice)."""
    if not (np.isfinite(thickness) and thickness > 0):
        raise ValueError(f"cover thickness = {thickness!r}: give a positive length in metres")
    if not (isinstance(target_tets, (int, np.integer)) and target_tets >= 50):
        raise ValueError(f"target_tets = {target_tets!r}: give a whole number >= 50")
    geometry, notes = link_geometry(xml, source, search_folders(urdf_file), max_triangles)
    capsules = bone_capsules(xml, skeleton, geometry, bare_radius)
    if capsules:
        notes.append(f"links without a shape in their rigid body get a capsule of {bare_radius:g} m around their "
                     f"bone (body.bone_radius): {', '.join(capsules)}")
        geometry = {**geometry, **capsules}
    if not geometry:
        raise ValueError("no link of this URDF has a usable collision or visual shape, and no bone has a length to "
                         "put a capsule around: a robot cover needs the links' shapes (check that the mesh files are "
                         "installed)")
    extent = max(float(np.ptp(np.concatenate([np.concatenate([np.asarray(m.bounds) for m in ms]) for ms in
                                              geometry.values()]), axis=0).max()), 1e-3)
    parts, more = cover_parts(xml, skeleton, geometry, spacing=extent / 300.0)
    notes += more
    if not parts:
        raise ValueError("no shaped link hangs on a bone of the skeleton: nothing to cover")
    body_of = np.array([p.body for p in parts])
    trees = [cKDTree(p.points) for p in parts]
    lo = np.min([p.lo for p in parts], axis=0) - thickness - 1e-3
    hi = np.max([p.hi for p in parts], axis=0) + thickness + 1e-3
    # volume of the solids at a coarse spacing -> first guess of h (5 tets per voxel), then a few secant steps on
    # log(count) against log(h): count ~ h^-3 for a volume, ~ h^-2 for a skin, the slope is measured
    # the first guess is at most 8 times the spacing ``fill`` at which the links' boxes, filled, would hold the tets
    # asked for: links far apart make the whole box's guess (its smallest side / 12) too coarse for the secant steps
    # to recover from (one voxel per link); example-robot-data's robots start at most 4.7 fill (solo8, 400,000 tets)
    boxes = float(np.sum([np.prod(p.hi - p.lo + 2.0 * thickness) for p in parts]))
    fill = (boxes / (target_tets / 5.0)) ** (1.0 / 3.0)
    h = min(float(np.min(hi - lo)) / 12.0, 8.0 * fill)
    tried: list[tuple[float, int, tuple]] = []
    for _ in range(iterations):
        n, i0, i1 = _lattice(lo, hi, h, parts, thickness, target_tets)
        keys, label = _voxels(parts, trees, lo, n, i0, i1, h, thickness)
        kept = _separate(n, keys, label, body_of) if len(keys) else np.zeros(0, dtype=bool)
        count = 5 * int(kept.sum())
        tried.append((h, count, (n, keys, label, kept)))
        if count and abs(count - target_tets) <= 0.1 * target_tets:
            break
        if len(tried) >= 2 and tried[-1][1] > 0 and tried[-2][1] > 0 and tried[-1][1] != tried[-2][1]:
            (h0, c0, _), (h1, c1, _) = tried[-2], tried[-1]
            slope = np.clip(np.log(c1 / c0) / np.log(h1 / h0), -4.0, -1.5)
        else:
            slope = -3.0
        h *= float(np.clip((target_tets / max(count, 1)) ** (1.0 / slope), 0.5, 2.0))
    h, count, (n, keys, label, kept) = min(tried, key=lambda x: abs(x[1] - target_tets) if x[1] else np.inf)
    mesh = cells_mesh(_cells(n, keys[kept]), lo, np.full(3, h))
    # each tet's voxel -> its part; a vertex takes the part of its tets (parts of one vertex share a rigid body)
    centroid = mesh.vertices[mesh.tets].mean(axis=1)
    ijk = np.floor((centroid - lo) / h).astype(np.int64)
    tet_part = label[np.searchsorted(keys, _key(n, ijk[:, 0], ijk[:, 1], ijk[:, 2]))]
    vpart = np.empty(mesh.n_vertices, dtype=np.int64)
    vpart[mesh.tets.ravel()] = np.repeat(tet_part, 4)
    bone = np.array([p.bone for p in parts])[vpart]
    depth = np.empty(mesh.n_vertices)
    for k, p in enumerate(parts):
        idx = np.flatnonzero(vpart == k)
        if idx.size:
            d, _ = trees[k].query(mesh.vertices[idx])
            depth[idx] = np.where(_inside(p.meshes, mesh.vertices[idx]), -d, d)
    covered = set(np.unique(vpart).tolist())
    bare = sorted({p.link for k, p in enumerate(parts) if k not in covered
                   and not any(q.body == p.body for j, q in enumerate(parts) if j in covered)})
    if bare:
        notes.append(f"rigid bodies too small for the voxel spacing {h * 1e3:.1f} mm keep no cover: {', '.join(bare)}")
    notes.append(f"robot cover: {mesh.n_tets} tets, {mesh.n_vertices} vertices on {len(covered)} of {len(parts)} "
                 f"shaped links, voxel {h * 1e3:.1f} mm, skin {max(thickness, SHELL * h) * 1e3:.1f} mm "
                 f"({source} shapes first)")
    return RobotCover(mesh, bone, depth, h, max(thickness, SHELL * h), notes)
