"""``body.kind: surface``: a character's triangle surface made into a tet body sitting on its skeleton.

The steps, each refusing bad input with the value and the way out (nothing half-built is returned):
find the file (a path, or under $CLUSTERFEM_DATA / ../shared/data), pose the skeleton in the bind pose,
tetrahedralize the surface (fTetWild, cached: fem/mesh/tetrahedralize.py), fit the tets onto the skeleton
(body/fit.py), check that every bone lies inside, and measure each vertex's depth under the skin for
the relative binding levels. ``unbound_islands`` finds pieces of the body no bone or anchor reaches.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..fem.mesh.tet_mesh import TetMesh, boundary_triangles
from ..fem.mesh.tetrahedralize import TetResult, surface_to_tets
from .fit import Fit, FitError, bind_configuration, bones_outside, find_data_file, fit_mesh, surface_depth

MANIFEST = "config/character_data.md"


@dataclass(frozen=True)
class SurfaceBody:
    mesh: TetMesh           # [m], in the skeleton's world frame at the bind pose
    bind_q: np.ndarray      # (nq,) the skeleton's bind configuration
    depth: np.ndarray       # (n,) [m] every vertex's distance to the body's surface
    fit: Fit
    tets: TetResult         # the tets in file units, with their quality and cache facts


def build_surface_body(config, skeleton, progress: Callable[[str], None] | None = None) -> SurfaceBody:
    """The surface body the scene's body.* and skeleton.* parameters describe (``config``: a config.SceneConfig,
    read through its typed sections), on ``skeleton``."""
    say = progress or (lambda _: None)
    b, s = config.body, config.skeleton
    path = find_data_file(b.surface_file, MANIFEST)
    q = bind_configuration(skeleton, s.bind_pose, s.bind_joints, s.bind_angles, s.bind_bvh, s.bvh_unit, s.bvh_up)
    starts, ends = skeleton.bone_segments(q)
    tets = surface_to_tets(path, b.target_tets, group=b.surface_group, progress=progress)
    triangles = boundary_triangles(tets.mesh)
    say(f"fitting {path.name} on the skeleton ({s.fit})")
    fit = fit_mesh(tets.mesh.vertices, starts, ends, s.fit, b.surface_unit, s.fit_up, s.fit_forward, s.fit_offset,
                   triangles=triangles)
    say(f"fitted {path.name} on the skeleton: {fit.describe()}")
    mesh = TetMesh(fit.apply(tets.mesh.vertices), tets.mesh.tets).validate()    # R proper, scale > 0: tets keep sign
    outside = bones_outside(mesh.vertices, triangles, starts, ends, skeleton.bone_names, s.fit_tolerance)
    if outside:
        listed = ", ".join(f"{name} ({d * 100:.1f} cm outside)" for name, d in outside)
        raise FitError(f"{len(outside)} of {len(starts)} bones leave the body of {path.name} by more than "
                       f"skeleton.fit_tolerance = {s.fit_tolerance:g} m: {listed}. The bind pose "
                       "(skeleton.bind_pose / bind_joints / bind_angles) or the fit (skeleton.fit, fit_up, "
                       "fit_forward, body.surface_unit) does not match the mesh")
    depth = surface_depth(mesh.vertices, mesh.vertices, triangles)
    say(f"surface body: {mesh.n_tets} tets / {mesh.n_vertices} vertices, min dihedral "
        f"{tets.min_dihedral_deg:.1f} deg, min radius ratio {tets.min_radius_ratio:.3f}")
    return SurfaceBody(mesh, q, depth, fit, tets)


def unbound_islands(tets: np.ndarray, n_vertices: int, driven: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(vertex count, vertex indices) of every connected piece of the tet mesh with no driven vertex."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    rows = np.repeat(tets[:, 0], 3)
    cols = tets[:, 1:].reshape(-1)
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n_vertices, n_vertices))
    n, label = connected_components(graph, directed=False)
    hit = np.zeros(n, dtype=bool)
    hit[label[driven]] = True
    return [(int((label == k).sum()), np.flatnonzero(label == k)) for k in np.flatnonzero(~hit)]
