"""How far an end bone's segment reaches into a surface body: on to the skin, less the flesh around its end.

A capture's skeleton ends its chains where its makers chose: a head end site a few centimetres above the head
joint or at the crown, a hand's at the wrist or the knuckles, a foot's at the ball or the toe tip. A
character's flesh goes on to its own skin, so the flesh beyond such an end (the top of a large head, the
fingers of a hand whose finger bones are left unbound) would hang off a point, far from any bone, held by
nothing but the elements. An *end bone* is a bone that binds flesh while none of its descendants does (found
from the tree, not from names). Its segment is carried on along its own direction to the point where that
ray leaves the surface, less the depth of its original end under the skin: the segment's end then lies as far
inside the tip of the flesh as it lay inside its sides, as a capsule's does. A bone of zero length, or whose
end is not inside the surface, keeps its segment.

Only the binding and the output check use the reach (body/binding.py ``Binding.axis_local``); the skeleton,
its kinematics and what is drawn of it keep the capture's bones.
"""
from __future__ import annotations

import numpy as np

MIN_REACH = 1e-3        # [m] extensions shorter than this are not made (nor reported)


def end_bones(parent: np.ndarray, binds: np.ndarray) -> np.ndarray:
    """(nb,) bool: the bones that bind flesh (``binds``) while none of their descendants does. ``parent`` (nb,) is
    each bone's parent bone (-1 for a root)."""
    parent = np.asarray(parent, dtype=np.int64)
    binds = np.asarray(binds, dtype=bool)
    below = np.zeros(parent.size, dtype=bool)            # some descendant binds flesh
    for b in np.flatnonzero(binds):
        p = parent[b]
        while p >= 0 and not below[p]:
            below[p] = True
            p = parent[p]
    return binds & ~below


def reach_to_skin(starts: np.ndarray, ends: np.ndarray, which: np.ndarray, vertices: np.ndarray,
                  triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ends (nb, 3), reach (nb,) [m]): the segments' ends with each bone of ``which`` carried on along its
    direction until it lies as deep under the tip of the closed surface (``vertices``, ``triangles``) as its own
    end lies under the skin, and how far each end moved (0 for the others)."""
    import trimesh
    starts = np.asarray(starts, dtype=np.float64)
    out = np.array(ends, dtype=np.float64)
    reach = np.zeros(len(out))
    axis = out - starts
    length = np.linalg.norm(axis, axis=1)
    cand = np.flatnonzero(np.asarray(which, dtype=bool) & (length > 0))
    if cand.size == 0:
        return out, reach
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(triangles, dtype=np.int64),
                           process=False)
    depth = trimesh.proximity.signed_distance(mesh, out[cand])          # > 0 inside
    cand, depth = cand[depth > 0], depth[depth > 0]
    if cand.size == 0:
        return out, reach
    direction = axis[cand] / length[cand, None]
    hits, ray, _ = mesh.ray.intersects_location(out[cand], direction, multiple_hits=True)
    for k, b in enumerate(cand):
        t = np.einsum("ij,j->i", hits[ray == k] - out[b], direction[k])
        t = t[t > 1e-9]
        if t.size == 0:
            continue
        step = float(t.min()) - float(depth[k])
        if step > MIN_REACH:
            out[b] += step * direction[k]
            reach[b] = step
    return out, reach


def describe(names, reach: np.ndarray) -> str:
    """One log line: which end bones reach on into their flesh, and how far."""
    moved = [f"{names[b]} +{100 * reach[b]:.1f} cm" for b in np.flatnonzero(reach > 0)]
    if not moved:
        return "end bones: every one ends within its flesh's depth of the skin (none carried on)"
    return ("end bones carried on to their flesh's depth under the skin, for the binding and the bone-distance "
            f"check (the skeleton keeps its bones): {', '.join(moved)}")
