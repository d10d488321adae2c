"""The soft body around a skeleton: capsules around the bones, voxelized into tetrahedra (the jelly man).

``capsule_inside(points, starts, ends, radii)`` is the union of capsules (segment start -> end, radius r)
as a point test. ``jelly_man_mesh(spec, target_tets)`` voxelizes that union around the humanoid's
rest pose (q = 0) with ``fem.voxel_mesh.voxelize`` (five tets per voxel), choosing the voxel spacing
by bisection so the tet count is as near ``target_tets`` as the grid allows (the paper's jelly man has
4822). Arrays: points (k, 3), starts/ends (nb, 3) [m], radii (nb,) [m].

Limbs are not glued: every voxel belongs to the bone whose capsule it lies deepest in, and two voxels that
touch (share a vertex) may belong to bones at most ``glue_hops`` apart in the skeleton's tree (a bone, its
parent and grandparent, its siblings). Where the capsules of farther bones meet at rest (hands hanging
against the thighs, an arm crossing the chest), the voxels on both sides of the contact are left out, so
no tet joins them and they move apart freely; pieces this cuts off from the body are dropped.
"""
from __future__ import annotations

import numba
import numpy as np
from scipy import ndimage

from ..numba_config import SERIAL


@numba.njit(**SERIAL)
def _inside_any(x, s, d, L2, r2, out):
    """out[k] <- whether point k is within any capsule; per point the bones in order, stopping at the first
    that holds it. The arithmetic of each bone's test is the einsum form's, term by term (tests/naive.py)."""
    for k in range(x.shape[0]):
        for b in range(s.shape[0]):
            q0, q1, q2 = x[k, 0] - s[b, 0], x[k, 1] - s[b, 1], x[k, 2] - s[b, 2]
            t = min(max((q0 * d[b, 0] + q1 * d[b, 1] + q2 * d[b, 2]) / L2[b], 0.0), 1.0)
            q0, q1, q2 = q0 - t * d[b, 0], q1 - t * d[b, 1], q2 - t * d[b, 2]
            if q0 * q0 + q1 * q1 + q2 * q2 <= r2[b]:
                out[k] = True
                break


def capsule_inside(points: np.ndarray, starts: np.ndarray, ends: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(k,) bool: True where a point lies within any capsule (distance to its segment <= its radius).

    Compiled: the jelly man's voxelization tests ~20 grids of up to ~10^5 points against 21 bones, which took
    1.4-1.8 s of a 2.2-3.3 s node start in numpy (the (k, nb, 3) temporaries of the einsum form)."""
    x = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    s = np.ascontiguousarray(starts, dtype=np.float64).reshape(-1, 3)
    e = np.ascontiguousarray(ends, dtype=np.float64).reshape(-1, 3)
    r = np.ascontiguousarray(radii, dtype=np.float64).reshape(-1)
    if not (s.shape == e.shape and r.shape == (s.shape[0],)):
        raise ValueError(f"capsules: starts {s.shape}, ends {e.shape}, radii {r.shape} must describe the same "
                         "number of bones ((nb, 3), (nb, 3), (nb,))")
    if not (np.isfinite(r).all() and (r >= 0).all()):
        raise ValueError(f"capsule radii {r.tolist()} must be finite and >= 0 metres")
    d = e - s
    L2 = np.einsum("bj,bj->b", d, d)
    out = np.zeros(x.shape[0], dtype=bool)
    _inside_any(x, s, d, np.where(L2 > 0, L2, 1.0), r * r, out)
    return out


def nearest_capsule(points: np.ndarray, starts: np.ndarray, ends: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(k,) index of the capsule each point lies deepest in (smallest distance to its segment minus its radius)."""
    x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d = ends - starts
    L2 = np.einsum("bj,bj->b", d, d)
    out = np.empty(x.shape[0], dtype=np.int64)
    for a in range(0, x.shape[0], 20000):                       # (chunk, nb, 3) temporaries stay small
        rel = x[a:a + 20000, None, :] - starts[None]
        t = np.clip(np.einsum("kbj,bj->kb", rel, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        depth = np.linalg.norm(rel - t[..., None] * d[None], axis=2) - radii[None]
        out[a:a + 20000] = np.argmin(depth, axis=1)
    return out


def axis_conflicts(points: np.ndarray, starts: np.ndarray, ends: np.ndarray, label: np.ndarray,
                   may_touch: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """(k,) bool: points that lie nearer the axis of a bone they may not touch than the axis of their own bone
    ``label`` (k,), or less than ``margin[own, other]`` (nb, nb) farther. The binding takes each vertex to the
    nearest bone axis; such a point, in a thick bone's flesh beside a thin limb (a pelvis beside a hanging
    forearm), would follow the limb."""
    x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d = ends - starts
    L2 = np.einsum("bj,bj->b", d, d)
    out = np.zeros(x.shape[0], dtype=bool)
    for a in range(0, x.shape[0], 20000):
        rel = x[a:a + 20000, None, :] - starts[None]
        t = np.clip(np.einsum("kbj,bj->kb", rel, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        dist = np.linalg.norm(rel - t[..., None] * d[None], axis=2)
        lab = label[a:a + 20000]
        own = dist[np.arange(lab.size), lab]
        out[a:a + 20000] = ((dist <= own[:, None] + margin[lab]) & ~may_touch[lab]).any(axis=1)
    return out


def bone_hops(parent: np.ndarray) -> np.ndarray:
    """(nb, nb) number of parent-child steps between bones in the tree given by ``parent`` (nb,) (-1: a root;
    bones of different roots are ``nb`` apart)."""
    parent = np.asarray(parent, dtype=np.int64)
    nb = parent.size
    hops = np.full((nb, nb), nb, dtype=np.int64)
    for b in range(nb):
        chain, c, k = {}, b, 0
        while c >= 0 and c not in chain:
            chain[c], c, k = k, parent[c], k + 1
        for o in range(nb):
            c, k = o, 0
            while c >= 0 and c not in chain and k <= nb:
                c, k = parent[c], k + 1
            if c >= 0 and c in chain:
                hops[b, o] = chain[c] + k
    return hops


def separate_limbs(mask: np.ndarray, label: np.ndarray, may_touch: np.ndarray) -> np.ndarray:
    """The voxel mask (nx, ny, nz) without the voxels that share a vertex with a voxel of a bone they may not
    touch (``may_touch`` (nb, nb) bool, ``label`` (nx, ny, nz) bone per voxel), and without the pieces that
    this cuts off from the largest connected part."""
    mask = np.asarray(mask, dtype=bool)
    drop = np.zeros_like(mask)
    n = mask.shape
    for off in [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) > (0, 0, 0)]:
        a = tuple(slice(max(-o, 0), n[ax] - max(o, 0)) for ax, o in enumerate(off))     # voxel
        b = tuple(slice(max(o, 0), n[ax] - max(-o, 0)) for ax, o in enumerate(off))     # its neighbour at off
        bad = mask[a] & mask[b] & ~may_touch[label[a], label[b]]
        drop[a] |= bad
        drop[b] |= bad
    kept = mask & ~drop
    parts, count = ndimage.label(kept, structure=np.ones((3, 3, 3), dtype=bool))
    if count > 1:
        kept = parts == 1 + int(np.argmax(np.bincount(parts.ravel())[1:]))
    return kept


def humanoid_capsules(spec, with_parents: bool = False, q: np.ndarray | None = None):
    """(starts, ends, radii) of the bones of ``spec`` (a ``HumanoidSpec``) that have a radius, at rest (or in the
    configuration ``q``, the body's bind pose); with ``with_parents``, also (nb,) the index among them of each one's
    nearest ancestor that has a radius (-1)."""
    from .kinematics import Skeleton
    sk = Skeleton.from_urdf_string(spec.urdf)
    s, e = sk.bone_segments(sk.neutral() if q is None else q)
    keep = [b for b, n in enumerate(sk.bone_names) if n in spec.bone_radius]
    missing = sorted(set(spec.bone_radius) - set(sk.bone_names))
    if missing:
        raise ValueError(f"bone_radius names bones {missing} that the URDF does not have: fix the spec")
    if not keep:
        raise ValueError("no bone has a radius in spec.bone_radius: give at least one capsule radius")
    caps = s[keep], e[keep], np.array([spec.bone_radius[sk.bone_names[b]] for b in keep])
    if not with_parents:
        return caps
    index = {b: k for k, b in enumerate(keep)}
    parents = []
    for b in keep:
        p = int(sk.bone_parent[b])
        while p >= 0 and p not in index:
            p = int(sk.bone_parent[p])
        parents.append(index.get(p, -1))
    return caps + (np.array(parents, dtype=np.int64),)


def leaf_shapes_placed(spec, q: np.ndarray | None = None) -> list:
    """The world placements at rest (q = 0, or the configuration ``q``) of ``spec.leaf_shapes``
    (link_shapes.PlacedShape), each with the index of its bone among ``humanoid_capsules(spec)``; [] when the spec
    has none."""
    if not getattr(spec, "leaf_shapes", None):
        return []
    from .link_shapes import place_shapes
    from .kinematics import Skeleton
    sk = Skeleton.from_urdf_string(spec.urdf)
    poses = sk.forward(sk.neutral() if q is None else q)
    kept = [n for n in sk.bone_names if n in spec.bone_radius]
    return place_shapes(spec.leaf_shapes, sk.bone_names, poses.rotation, poses.translation,
                        {n: k for k, n in enumerate(kept)})


def _label(points: np.ndarray, s, e, r, shapes: list) -> np.ndarray:
    """``nearest_capsule``, with the leaf shapes competing by their depth (link_shapes.shape_depth)."""
    label = nearest_capsule(points, s, e, r)
    if not shapes:
        return label
    from .link_shapes import shape_depth
    d = e[label] - s[label]
    L2 = np.einsum("kj,kj->k", d, d)
    t = np.clip(np.einsum("kj,kj->k", points - s[label], d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    best = np.linalg.norm(points - s[label] - t[:, None] * d, axis=1) - r[label]
    for shape in shapes:
        depth = shape_depth(points, shape)
        closer = depth < best
        label[closer], best[closer] = shape.bone, depth[closer]
    return label


def jelly_man_mesh(spec, target_tets: int = 5000, max_iterations: int = 24, glue_hops: int | None = 2,
                   q: np.ndarray | None = None, axis_consistent: bool = False):
    """Tet mesh of the capsules of ``spec`` (and of its leaf shapes, if it has ``leaf_shapes``) with about
    ``target_tets`` tets (nearest count found by bisection); voxels of bones more than ``glue_hops`` apart never
    touch (None: every touching voxel is glued). ``q``: the skeleton's configuration to build it in (None: q = 0).
    ``axis_consistent``: also leave out the voxels nearer the axis of a bone they may not touch than their own
    bone's axis, or within a voxel of it for bones 4 or more hops apart (their corners are the vertices bound;
    ``axis_conflicts``), for bodies whose radii differ much from bone to bone on skeletons with limbs against the
    trunk at rest (nearer bones keep the margin 0: a clavicle beside the head must not be cut off)."""
    from ..fem.mesh.voxel_mesh import grid_mesh, voxel_centres
    if not (isinstance(target_tets, (int, np.integer)) and target_tets >= 50):
        raise ValueError(f"target_tets = {target_tets!r}: give a whole number >= 50")
    s, e, r, parents = humanoid_capsules(spec, with_parents=True, q=q)
    shapes = leaf_shapes_placed(spec, q)
    hops = bone_hops(parents)
    may_touch = None if glue_hops is None else hops <= glue_hops
    far = hops >= 4
    lo = np.minimum(s, e).min(axis=0) - r.max()
    hi = np.maximum(s, e).max(axis=0) + r.max()
    for shape in shapes:                        # the shape's bounding box in the world
        half = shape.half + (np.array([0.0, 0.0, shape.half[0]]) if shape.kind == "capsule" else 0.0)
        reach = np.abs(shape.rotation) @ half
        lo, hi = np.minimum(lo, shape.translation - reach), np.maximum(hi, shape.translation + reach)

    def inside(p: np.ndarray) -> np.ndarray:
        out = capsule_inside(p, s, e, r)
        if shapes:
            from .link_shapes import shapes_inside
            out |= shapes_inside(p, shapes)
        return out

    # volume of the union by a coarse voxel count -> first guess of the spacing (5 tets per voxel)
    h0 = float(np.min(hi - lo)) / 40.0
    n = np.maximum(np.ceil((hi - lo) / h0).astype(int), 1)
    g = [lo[a] + (np.arange(n[a]) + 0.5) * h0 for a in range(3)]
    volume = inside(np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)).sum() * h0 ** 3
    guess = (5.0 * volume / target_tets) ** (1.0 / 3.0)
    a, b = guess / 2.0, guess * 2.0             # count(a) > target > count(b), checked below
    best = None
    cache: dict[float, object] = {}

    def mesh(h: float):
        if h not in cache:
            centres, n = voxel_centres(lo, hi, h)
            mask = inside(centres).reshape(n)
            if may_touch is not None:
                label = np.zeros(mask.size, dtype=np.int64)
                inside_ = mask.ravel()
                label[inside_] = _label(centres[inside_], s, e, r, shapes)
                if axis_consistent:
                    keep = inside_.copy()
                    keep[inside_] = ~axis_conflicts(centres[inside_], s, e, label[inside_], may_touch,
                                                    np.where(far, h, 0.0))
                    mask = keep.reshape(n)
                mask = separate_limbs(mask, label.reshape(n), may_touch)
            cache[h] = grid_mesh(mask, lo, np.full(3, h))
        return cache[h]

    for _ in range(max_iterations):
        h = 0.5 * (a + b)
        m = mesh(h)
        if best is None or abs(m.n_tets - target_tets) < abs(best.n_tets - target_tets):
            best = m
        if m.n_tets == target_tets or (b - a) < 1e-4 * guess:
            break
        if m.n_tets > target_tets:
            a = h
        else:
            b = h
    return best


def voxel_bones(spec, mesh, q: np.ndarray | None = None, voxels=None) -> np.ndarray:
    """(n, nb) bool, nb the skeleton's bones (those without flesh never set): for each vertex of ``mesh`` (a
    ``jelly_man_mesh`` of ``spec``), the bones of the voxels around it, each voxel labelled as ``jelly_man_mesh``
    labelled it when it kept voxels of bones that may not touch apart (the capsule or leaf shape its centre lies
    deepest in). Every tet of the grid's split spans its whole voxel, so a tet's voxel centre is the middle of its
    bounding box. Binding a vertex only to these keeps a limb's flesh on its own bone where another bone passes
    close at rest (a robot's hand folded beside its forearm, an arm hanging beside the pelvis): the nearest segment
    alone would give part of one limb's tets to the other, and a label read anywhere else in the voxel (its tets'
    centroids) can name a bone the voxel was kept apart from. ``q``: the configuration the mesh was built in (None:
    q = 0); ``voxels``: the voxel mesh ``mesh`` shares its tets with when its vertices were moved (the smooth skin;
    None: ``mesh`` itself)."""
    from .kinematics import Skeleton
    s, e, r = humanoid_capsules(spec, q=q)
    grid = mesh if voxels is None else voxels
    if grid.tets.shape != mesh.tets.shape or not np.array_equal(grid.tets, mesh.tets):
        raise ValueError("voxels has other tets than mesh: pass the voxel mesh the body was made from")
    corners = grid.vertices[grid.tets]
    centre = 0.5 * (corners.min(axis=1) + corners.max(axis=1))
    label = _label(centre, s, e, r, leaf_shapes_placed(spec, q))
    names = Skeleton.from_urdf_string(spec.urdf).bone_names
    bone = np.array([b for b, n in enumerate(names) if n in spec.bone_radius])   # capsule -> skeleton bone
    out = np.zeros((mesh.n_vertices, len(names)), dtype=bool)
    out[mesh.tets.ravel(), np.repeat(bone[label], 4)] = True
    return out
