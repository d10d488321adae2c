"""The jelly man with a smooth skin: the voxel body's surface vertices moved onto a blended union of its capsules.

The shape is the one ``jelly_body`` voxelizes (a capsule around every bone that has a radius, and a leaf link's
own URDF shapes), with a round fillet in the crease where a bone meets its parent: ``SmoothCapsules.depth`` is,
for each point, the smallest of the bones' signed distances and of every (parent, child) pair's smooth minimum
(``smooth_min``, quadratic, radius ``blend`` times the pair's smaller radius times ``crease_blend``, which grows
from 0 where the two capsules' normals agree to 1 where they are opposite). A smooth minimum of constant radius
would swell every joint, straight ones too, where the two distances are equal all round, and put that flesh
across the joints, where the bones' rigid motions crush it (``python -m pytest -s tests/test_smooth_body.py``
prints the blended shape's volume over the plain union's). Limbs stay apart: a point is
measured only against the bones its own bone may touch (``jelly_body.bone_hops`` <= ``glue_hops``), so a hand
hanging by a thigh is never pulled onto the thigh's skin, and no fillet joins bones that are not parent and
child.

``smooth_jelly_man_mesh`` keeps the voxel body's vertices and tets (same count, same connectivity) and moves
only vertices: each surface vertex by Newton steps onto the zero level of the depth of its own bone's
neighbourhood, the interior vertices by a few relaxation sweeps that spread those moves inward. A move that
would leave a tet thinner than ``min_altitude`` times its voxel altitude (the explicit step's critical length)
is halved at that tet's vertices until no tet is, so the stable step stays near the voxel body's; then a few
rounds of relaxing the interior (each vertex to its neighbours' mean) make room for the surface moves that
were held back, which are tried again under the same floor.

Arrays: points (k, 3) [m]; depth (k,) [m], negative inside.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fem.mesh.tet_mesh import TetMesh, boundary_triangles

BLEND = 1.0                 # fillet radius at a joint, as a share of the smaller capsule radius of the pair
MIN_ALTITUDE = 0.7          # no tet's smallest altitude below this share of its voxel altitude
NEWTON_STEPS = 8
RELAX_SWEEPS = 4
HALVINGS = 30
ROUNDS = 6
RELAX_RINGS = 1


def smooth_min(a: np.ndarray, b: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Quadratic smooth minimum: min(a, b) where |a - b| >= k, else lowered by up to k / 4 (C1 across)."""
    k = np.maximum(np.asarray(k, dtype=np.float64), 1e-12)
    h = np.clip(1.0 - np.abs(a - b) / k, 0.0, 1.0)
    return np.minimum(a, b) - 0.25 * k * h * h


def crease_blend(n_a: np.ndarray, n_b: np.ndarray) -> np.ndarray:
    """(...) the share of the fillet radius a point gets from the unit normals (..., 3) of two bones' flesh
    there: (1 - cos) / 2 of the angle between them. Where two capsules run on in one line (a straight joint)
    their normals agree and the smooth minimum would only swell the joint into a ring; in the crease of a bent
    joint they part and the fillet fills it (a gradient-weighted blend, as in Gourmel et al. 2013)."""
    return 0.5 * (1.0 - np.clip(np.einsum("...j,...j->...", n_a, n_b), -1.0, 1.0))


@dataclass(frozen=True)
class SmoothCapsules:
    """The blended union of a body's capsules (see the module docstring). Bones are the capsules' order in
    ``jelly_body.humanoid_capsules``; ``shapes`` are ``link_shapes.PlacedShape`` whose ``bone`` indexes them."""
    starts: np.ndarray          # (nb, 3)
    ends: np.ndarray            # (nb, 3)
    radii: np.ndarray           # (nb,)
    parents: np.ndarray         # (nb,) nearest ancestor with a capsule, -1 at a root
    may_touch: np.ndarray       # (nb, nb) bool: bones that may share flesh (and whose depths a point compares)
    shapes: tuple = ()
    blend: float = BLEND

    def bone_depths(self, points: np.ndarray, normals: bool = False):
        """(k, nb) signed distance of every point to every bone's flesh (its capsule, or its shapes if nearer);
        with ``normals`` also (k, nb, 3) the unit gradient of each (central differences on a shape)."""
        x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        d = self.ends - self.starts
        L2 = np.einsum("bj,bj->b", d, d)
        rel = x[:, None, :] - self.starts[None]
        t = np.clip(np.einsum("kbj,bj->kb", rel, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        off = rel - t[..., None] * d[None]                       # from the nearest point of each axis
        dist = np.linalg.norm(off, axis=2)
        out = dist - self.radii[None]
        grad = off / np.maximum(dist, 1e-300)[..., None] if normals else None
        if self.shapes:
            from .link_shapes import shape_depth
            for shape in self.shapes:
                depth = shape_depth(x, shape)
                nearer = depth < out[:, shape.bone]
                out[:, shape.bone] = np.where(nearer, depth, out[:, shape.bone])
                if normals and nearer.any():
                    eps = 1e-6
                    g = np.stack([shape_depth(x[nearer] + eps * e, shape) - shape_depth(x[nearer] - eps * e, shape)
                                  for e in np.eye(3)], axis=1) / (2 * eps)
                    grad[nearer, shape.bone] = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
        return (out, grad) if normals else out

    def bone_of(self, points: np.ndarray) -> np.ndarray:
        """(k,) the bone each point lies deepest in."""
        return np.argmin(self.bone_depths(points), axis=1)

    def depth(self, points: np.ndarray, bones: np.ndarray) -> np.ndarray:
        """(k,) signed distance-like depth of each point to the skin of the neighbourhood of ``bones`` (k,):
        the bones that bone may touch, with a fillet in the crease of each of their joints (``crease_blend``)."""
        D, G = self.bone_depths(points, normals=True)
        allowed = self.may_touch[np.asarray(bones, dtype=np.int64)]
        D = np.where(allowed, D, 1.0e3)                          # far: never the minimum, never blended
        out = D.min(axis=1)
        child = np.flatnonzero(self.parents >= 0)
        if child.size:
            parent = self.parents[child]
            r = np.stack([self.radii[parent], self.radii[child]])
            r = np.where(r > 0, r, r.max(axis=0))                # a shaped leaf (radius 0) takes its parent's
            k = self.blend * r.min(axis=0)[None] * crease_blend(G[:, parent], G[:, child])
            out = np.minimum(out, smooth_min(D[:, parent], D[:, child], k).min(axis=1))
        return out

    def project(self, points: np.ndarray, bones: np.ndarray, max_move: float) -> np.ndarray:
        """(k, 3) the points moved onto depth 0 by Newton steps along the depth's gradient (central
        differences), each step at most ``max_move`` [m]."""
        x = np.array(points, dtype=np.float64).reshape(-1, 3)
        eps = 1e-5
        for _ in range(NEWTON_STEPS):
            f = self.depth(x, bones)
            g = np.stack([(self.depth(x + eps * e, bones) - self.depth(x - eps * e, bones)) / (2 * eps)
                          for e in np.eye(3)], axis=1)
            step = -f[:, None] * g / np.maximum((g * g).sum(axis=1, keepdims=True), 1e-12)
            n = np.linalg.norm(step, axis=1, keepdims=True)
            x += step * np.minimum(1.0, max_move / np.maximum(n, 1e-300))
        return x


def min_altitudes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m,) each tet's smallest altitude, 3 V / (largest face area), signed like its volume [m]."""
    p = vertices[tets]
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    six_v = np.einsum("ij,ij->i", a, np.cross(b, c))
    faces = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))
    area2 = np.max([np.linalg.norm(np.cross(p[:, j] - p[:, i], p[:, k] - p[:, i]), axis=1) for i, j, k in faces],
                   axis=0)
    return six_v / np.maximum(area2, 1e-300)


def edge_length(mesh: TetMesh) -> float:
    """The voxel edge h of a voxel mesh (the median of its tets' shortest edges) [m]."""
    p = mesh.vertices[mesh.tets]
    e = [np.linalg.norm(p[:, i] - p[:, j], axis=1) for i in range(4) for j in range(i + 1, 4)]
    return float(np.median(np.min(e, axis=0)))


def vertex_bones(mesh: TetMesh, shape: SmoothCapsules) -> np.ndarray:
    """(n,) each vertex's bone: that of the deepest tet around it (a tet's bone: the one its centre lies deepest
    in), so a vertex of a limb's voxels is measured against that limb's skin."""
    centres = mesh.vertices[mesh.tets].mean(axis=1)
    depths = shape.bone_depths(centres)
    bone = np.argmin(depths, axis=1)
    order = np.argsort(-depths[np.arange(len(bone)), bone])         # shallowest first, deepest written last
    out = np.full(mesh.n_vertices, -1, dtype=np.int64)
    for corner in range(4):
        out[mesh.tets[order, corner]] = bone[order]
    return out


def smooth_capsules_of(spec, glue_hops: int | None = 2, blend: float = BLEND,
                       q: np.ndarray | None = None) -> SmoothCapsules:
    """The blended capsule shape of ``spec`` (a ``HumanoidSpec``) in configuration ``q`` (None: q = 0), from
    ``jelly_body``'s capsules and leaf shapes."""
    from .jelly_body import bone_hops, humanoid_capsules, leaf_shapes_placed
    s, e, r, parents = humanoid_capsules(spec, with_parents=True, q=q)
    may_touch = np.ones((len(r), len(r)), dtype=bool) if glue_hops is None else bone_hops(parents) <= glue_hops
    return SmoothCapsules(s, e, r, parents, may_touch, tuple(leaf_shapes_placed(spec, q)), float(blend))


def snap_to_shape(mesh: TetMesh, shape: SmoothCapsules, min_altitude: float = MIN_ALTITUDE) -> tuple[TetMesh, dict]:
    """The mesh with its surface vertices on ``shape``'s skin and its interior relaxed (module docstring);
    returns (mesh, facts: surface vertices, their depth after, voxel edge, smallest altitude share, vertex bones)."""
    x0 = mesh.vertices
    tets = mesh.tets
    surface = np.unique(boundary_triangles(mesh))
    vertex_bone = vertex_bones(mesh, shape)
    alt0 = min_altitudes(x0, tets)
    spacing = edge_length(mesh)
    move = np.zeros_like(x0)
    move[surface] = shape.project(x0[surface], vertex_bone[surface], max_move=0.5 * spacing) - x0[surface]
    # interior vertices follow: Jacobi sweeps of the mean of their neighbours' moves, the surface held
    interior = np.ones(mesh.n_vertices, dtype=bool)
    interior[surface] = False
    edges = np.concatenate([tets[:, [i, j]] for i in range(4) for j in range(4) if i != j])
    count = np.bincount(edges[:, 0], minlength=mesh.n_vertices).astype(float)
    for _ in range(RELAX_SWEEPS):
        mean = np.zeros_like(move)
        np.add.at(mean, edges[:, 0], move[edges[:, 1]])
        move[interior] = (mean / np.maximum(count, 1.0)[:, None])[interior]
    x = _held_above(x0, x0 + move, tets, min_altitude * alt0)
    target = x0 + move
    # the rounds relax only the interior within RELAX_RINGS tets of the surface: the flesh near the bones, which
    # the innermost binding level holds, keeps its voxel positions
    near = np.zeros(mesh.n_vertices, dtype=bool)
    near[surface] = True
    for _ in range(RELAX_RINGS):
        near[np.unique(tets[near[tets].any(axis=1)])] = True
    relaxable = interior & near
    for _ in range(ROUNDS):
        # make room: each interior vertex to its neighbours' mean, then the surface again towards its target
        mean = np.zeros_like(x)
        np.add.at(mean, edges[:, 0], x[edges[:, 1]])
        relaxed = x.copy()
        relaxed[relaxable] = (mean / np.maximum(count, 1.0)[:, None])[relaxable]
        x = _held_above(x, relaxed, tets, min_altitude * alt0)
        wanted = x.copy()
        wanted[surface] = target[surface]
        x = _held_above(x, wanted, tets, min_altitude * alt0)
    out = TetMesh(x, tets.copy()).validate()
    share = float(np.min(min_altitudes(x, tets) / alt0))
    after = shape.depth(x[surface], vertex_bone[surface])
    return out, {"surface_vertices": int(surface.size), "depth_after": after,
                 "spacing": spacing, "min_altitude_share": share, "vertex_bone": vertex_bone}


def _held_above(x: np.ndarray, wanted: np.ndarray, tets: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """``x`` moved towards ``wanted``, the move halved at the vertices of every tet whose smallest altitude would
    fall below ``floor`` (m,) until none does (``x`` itself must meet the floor)."""
    move = wanted - x
    scale = np.ones(len(x))
    for _ in range(HALVINGS):
        thin = min_altitudes(x + scale[:, None] * move, tets) < floor
        if not thin.any():
            return x + scale[:, None] * move
        scale[np.unique(tets[thin])] *= 0.5
    scale[np.unique(tets[min_altitudes(x + scale[:, None] * move, tets) < floor])] = 0.0
    return x + scale[:, None] * move


def smooth_jelly_man_meshes(spec, target_tets: int = 5000, glue_hops: int | None = 2, blend: float = BLEND,
                            min_altitude: float = MIN_ALTITUDE, q: np.ndarray | None = None,
                            axis_consistent: bool = False) -> tuple[TetMesh, TetMesh]:
    """(smooth body, the voxel body it was moved from): ``jelly_body.jelly_man_mesh`` (same tets, same vertex
    count) with its skin on the blended capsules, built in configuration ``q`` (None: q = 0). The voxel body is
    the reference of the smooth one's mass scaling (fem/mass_scaling.py)."""
    from .jelly_body import jelly_man_mesh
    voxels = jelly_man_mesh(spec, target_tets=target_tets, glue_hops=glue_hops, q=q, axis_consistent=axis_consistent)
    mesh, _ = snap_to_shape(voxels, smooth_capsules_of(spec, glue_hops, blend, q), min_altitude)
    return mesh, voxels


def smooth_jelly_man_mesh(spec, target_tets: int = 5000, glue_hops: int | None = 2, blend: float = BLEND,
                          min_altitude: float = MIN_ALTITUDE, q: np.ndarray | None = None,
                          axis_consistent: bool = False) -> TetMesh:
    """The smooth body of ``smooth_jelly_man_meshes``."""
    return smooth_jelly_man_meshes(spec, target_tets, glue_hops, blend, min_altitude, q, axis_consistent)[0]
