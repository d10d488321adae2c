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

from ..fem.mesh.tet_mesh import TetMesh, boundary_triangles, tet_pieces
from ..fem.mesh.tetrahedralize import TetResult, surface_to_tets
from .auto_bind import auto_bind_pose, bones_to_unbind, rest_configuration
from .limb_bridges import bridge_tets, cut_bridges
from .mesh_frame import resolve_frame
from .fit import Fit, FitError, bind_configuration, bone_outside_distances, find_data_file, fit_mesh, surface_depth

MANIFEST = "config/character_data.md"


@dataclass(frozen=True)
class SurfaceBody:
    mesh: TetMesh           # [m], in the skeleton's world frame at the bind pose
    bind_q: np.ndarray      # (nq,) the skeleton's bind configuration
    depth: np.ndarray       # (n,) [m] every vertex's distance to the body's surface
    fit: Fit
    tets: TetResult         # the tets in file units, with their quality and cache facts
    unbound: tuple[str, ...] = ()   # bones without flesh: fingers, toes, root helpers outside it, head parts (auto)
    limb_distances: dict | None = None   # bind_pose 'auto': auto_bind.limb_report's {(side, kind): (mean, max) [m]}


def build_surface_body(config, skeleton, progress: Callable[[str], None] | None = None) -> SurfaceBody:
    """The surface body the scene's body.* and skeleton.* parameters describe (``config``: a config.SceneConfig,
    read through its typed sections), on ``skeleton``. With skeleton.bind_pose 'auto' the bind pose is found from
    the mesh and the skeleton (body/auto_bind.py) and the finger and toe bones outside the mesh bind no flesh."""
    say = progress or (lambda _: None)
    b, s = config.body, config.skeleton
    path = find_data_file(b.surface_file, MANIFEST)
    auto = s.bind_pose == "auto"
    if auto:
        if s.bind_joints:
            raise FitError(f"skeleton.bind_joints {list(s.bind_joints)} set joints on top of skeleton.bind_pose "
                           "'neutral' or 'first_frame'; 'auto' finds every limb's angle from the mesh: leave "
                           "bind_joints / bind_angles empty or choose 'neutral' / 'first_frame'")
        q_rest, why = rest_configuration(skeleton, s.bind_bvh, s.bvh_unit, s.bvh_up)
        say(why)
    else:
        q = bind_configuration(skeleton, s.bind_pose, s.bind_joints, s.bind_angles, s.bind_bvh, s.bvh_unit,
                               s.bvh_up)
    tets = surface_to_tets(path, b.target_tets, group=b.surface_group, progress=progress)
    triangles = boundary_triangles(tets.mesh)
    unit, up, forward, read = resolve_frame(tets.mesh.vertices, triangles, b.surface_unit, s.fit_up, s.fit_forward)
    if read:
        say(read)
    say(f"fitting {path.name} on the skeleton ({'bind pose from the mesh, ' if auto else ''}{s.fit})")
    unbound: list[str] = []
    distances = None
    if auto:
        if s.fit != "auto":
            raise FitError("skeleton.bind_pose 'auto' places the mesh itself: set skeleton.fit 'auto' (or choose "
                           "skeleton.bind_pose 'neutral' / 'first_frame' for skeleton.fit 'manual')")
        found = auto_bind_pose(skeleton, q_rest, tets.mesh.vertices, triangles, unit, up, forward, say=say)
        q, fit, distances = found.q, found.fit, found.distances
        say(found.report)
    else:
        fit = fit_mesh(tets.mesh.vertices, *skeleton.bone_segments(q), s.fit, unit, up, forward, s.fit_offset,
                       triangles=triangles)
    starts, ends = skeleton.bone_segments(q)
    say(f"fitted {path.name} on the skeleton: {fit.describe()}")
    mesh = TetMesh(fit.apply(tets.mesh.vertices), tets.mesh.tets).validate()    # R proper, scale > 0: tets keep sign
    out = bone_outside_distances(mesh.vertices, triangles, starts, ends)
    if auto:
        unbound = bones_to_unbind(found.roles, dict(zip(skeleton.bone_names, out)), parent=skeleton.bone_parent,
                                  ends=ends)
        say(f"bones left without flesh (finger, toe and root-helper bones outside the mesh, the head's side parts: "
            f"their flesh follows the hand, foot, pelvis or head): "
            f"{', '.join(_unbound_why(n, out[skeleton.bone_names.index(n)]) for n in unbound)}"
            if unbound else "every bone binds flesh (no finger, toe or root-helper bone outside the mesh, no side "
                            "part of the head)")
        mesh, triangles = _cut_limb_bridges(mesh, triangles, starts, ends, found.roles,
                                            np.array([n not in unbound for n in skeleton.bone_names]), say)
    outside = sorted(((n, float(d)) for n, d in zip(skeleton.bone_names, out)
                      if d > s.fit_tolerance and n not in unbound), key=lambda p: -p[1])
    if outside:
        listed = ", ".join(f"{name} ({d * 100:.1f} cm outside)" for name, d in outside)
        raise FitError(f"{len(outside)} of {len(starts)} bones leave the body of {path.name} by more than "
                       f"skeleton.fit_tolerance = {s.fit_tolerance:g} m: {listed}. The bind pose "
                       "(skeleton.bind_pose / bind_joints / bind_angles) or the fit (skeleton.fit, fit_up, "
                       "fit_forward, body.surface_unit) does not match the mesh")
    depth = surface_depth(mesh.vertices, mesh.vertices, triangles)
    say(f"surface body: {mesh.n_tets} tets / {mesh.n_vertices} vertices, min dihedral "
        f"{tets.min_dihedral_deg:.1f} deg, min radius ratio {tets.min_radius_ratio:.3f}")
    return SurfaceBody(mesh, q, depth, fit, tets, tuple(unbound), distances)


def _cut_limb_bridges(mesh: TetMesh, triangles: np.ndarray, starts: np.ndarray, ends: np.ndarray, roles,
                      binds: np.ndarray, say) -> tuple[TetMesh, np.ndarray]:
    """(mesh, its boundary triangles) without the tets that join the left and right limbs (body/limb_bridges.py),
    one line saying how many were cut."""
    bridges = bridge_tets(mesh.vertices, mesh.tets, starts, ends, roles, binds)
    if not bridges.any():
        return mesh, triangles
    share = float(mesh.volumes()[bridges].sum() / mesh.volumes().sum())
    cut = cut_bridges(mesh, bridges)
    say(f"cut {int(bridges.sum())} tets ({share:.1%} of the body's volume) joining flesh of the left and right "
        "limbs: the mesh's limbs touch or lie closer than its tets are wide")
    return cut, boundary_triangles(cut)


def _unbound_why(name: str, out: float) -> str:
    return f"{name} ({100 * out:.1f} cm out)" if out > 0.0 else f"{name} (a part of the head)"


def unbound_islands(tets: np.ndarray, n_vertices: int, driven: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(vertex count, vertex indices) of every connected piece of the tet mesh with no driven vertex."""
    n, label = tet_pieces(n_vertices, tets)
    hit = np.zeros(n, dtype=bool)
    hit[label[driven]] = True
    return [(int((label == k).sum()), np.flatnonzero(label == k)) for k in np.flatnonzero(~hit)]
