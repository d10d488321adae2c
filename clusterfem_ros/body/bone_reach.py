"""How far an end bone's segment reaches into a surface body: on to the skin, less the depth of its flesh.

A capture's skeleton ends its chains where its makers chose: a head end site a few centimetres above the head
joint or at the crown, a hand's at the wrist or the knuckles, a foot's at the ball or the toe tip; and a head
joint sits at the back of the skull, where the neck meets it. A character's flesh goes on to its own skin, so
the flesh beyond such an end (the top and the face of a large head, the fingers of a hand whose finger bones
are left unbound) would hang off a point far from any bone, held by nothing but the elements. An *end bone*
is a bone that binds flesh while none of its descendants does (found from the tree, not from names). Its
segment is carried on along its direction to the point where that ray leaves the surface, less the depth of
its end under the skin: the end then lies as far inside the tip of the flesh as inside its sides, as a
capsule's does; it is never shortened. A bone that is a stub in a lump of flesh (the centre of its own flesh,
the vertices nearest to it weighted by their share of the volume, lies deeper under the skin than the bone is
long: a head joint at the back of a large skull) is first aimed from its start through that centre, and runs
on from the centre as deep under the tip as the centre lies. A bone of zero length, or whose end is not under
the skin, keeps its segment.

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
                  triangles: np.ndarray, flesh: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ends (nb, 3), reach (nb,) [m], turn (nb,) [deg]): the segments' ends with each bone of ``which`` carried
    on until it lies as deep under the tip of the closed surface (``vertices``, ``triangles``) as it lies under
    its sides, how far each end moved and by how much its direction turned (0 for the others).

    Each bone runs on along its own direction from its end, as deep under the tip as that end lies under the
    skin, never shorter. With ``flesh`` = (points (m, 3), their weights (m,), their bone (m,)), a bone whose
    flesh's centre (the weighted mean of its points) lies beyond its start and deeper under the skin than the
    bone is long is aimed from its start through that centre and runs on from it as deep under the tip as the
    centre lies: a head joint at the back of a large head gets a segment through the head's middle."""
    import trimesh
    starts = np.asarray(starts, dtype=np.float64)
    out = np.array(ends, dtype=np.float64)
    reach, turn = np.zeros(len(out)), np.zeros(len(out))
    axis = out - starts
    length = np.linalg.norm(axis, axis=1)
    cand = np.flatnonzero(np.asarray(which, dtype=bool) & (length > 0))
    if cand.size == 0:
        return out, reach, turn
    own = _unit(axis[cand])
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(triangles, dtype=np.int64),
                           process=False)
    origin = out[cand].copy()                       # where each ray starts: the bone's end, or its flesh's centre
    direction = own.copy()
    depth = trimesh.proximity.signed_distance(mesh, origin)          # > 0 inside
    if flesh is not None:
        points, weights, bone = (np.asarray(a) for a in flesh)
        centre = np.array([np.average(points[bone == b], axis=0, weights=weights[bone == b])
                           if weights[bone == b].sum() > 0 else starts[b] for b in cand])
        centre_depth = trimesh.proximity.signed_distance(mesh, centre)
        lever = centre - starts[cand]
        # a stub in a lump of flesh: the centre beyond the start, deeper under the skin than the bone is long
        aim = (np.einsum("ij,ij->i", lever, own) > MIN_REACH) & (centre_depth > length[cand])
        origin[aim], direction[aim], depth[aim] = centre[aim], _unit(lever[aim]), centre_depth[aim]
    hits, ray, _ = mesh.ray.intersects_location(origin, direction, multiple_hits=True)
    for k, b in enumerate(cand):
        if depth[k] <= 0:
            continue
        t = np.einsum("ij,j->i", hits[ray == k] - origin[k], direction[k])
        t = t[t > 1e-9]
        if t.size == 0:
            continue
        end = origin[k] + max(float(t.min()) - float(depth[k]), 0.0) * direction[k]
        end = starts[b] + max(float((end - starts[b]) @ direction[k]), length[b]) * direction[k]   # never shorter
        moved = float(np.linalg.norm(end - out[b]))
        if moved > MIN_REACH:
            turn[b] = float(np.degrees(np.arccos(np.clip(own[k] @ direction[k], -1.0, 1.0))))
            reach[b] = float((end - starts[b]) @ direction[k]) - length[b]
            out[b] = end
    return out, reach, turn


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def describe(names, reach: np.ndarray, turn: np.ndarray) -> str:
    """One log line: which end bones reach on into their flesh, how much longer and how far turned."""
    moved = [f"{names[b]} {100 * reach[b]:+.1f} cm" + (f", turned {turn[b]:.0f} deg" if turn[b] >= 1.0 else "")
             for b in np.flatnonzero(np.abs(reach) + turn > 0)]
    if not moved:
        return "end bones: every one ends within its flesh's depth of the skin (none carried on)"
    return ("end bones carried on to their flesh's depth under the skin (a stub in a lump of flesh turned through its "
            f"centre), for the binding and the bone-distance check; the skeleton keeps its bones: {', '.join(moved)}")
