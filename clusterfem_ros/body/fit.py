"""A surface mesh and a skeleton brought together: the bind pose, the fit of the mesh onto it, the checks.

A character mesh is modelled in some pose (the *bind pose*: often a T- or A-pose), in its own units and
axes (Y up is common). The skeleton is posed in that pose (``bind_configuration``: the URDF's zero pose,
or the first frame of the BVH the player plays, with named joints set to given angles), and the mesh is
carried into the skeleton's world frame at that pose by ``x = scale R x_file + offset`` (``Fit``):

- ``R`` takes the file's up / forward axes to ROS (Z up, X forward; ``skeleton.bvh.axes_to_ros``);
- ``scale`` is ``unit`` (metres per file unit) in mode ``manual``; in mode ``auto`` it makes the
  skeleton span ``HEIGHT_RATIO`` of the mesh's height, and it must stay within a factor of
  ``MAX_UNIT_ERROR`` of ``unit`` (a larger factor is a units mistake, refused);
- ``offset`` is given in ``manual``; ``auto`` first puts the centre of the mesh's bounding box on the
  centre of the skeleton's, then (``refine_fit``) moves and scales the mesh by least squares so that
  points along every bone lie at least ``INSIDE_MARGIN`` under the skin (a bounding box is pulled off
  centre by arms, feet and belly).

``bones_outside`` then names every bone whose segment leaves the body by more than a tolerance, so a
wrong fit or bind pose is refused with the bone and the distance instead of binding garbage.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import ClusterFemError

HEIGHT_RATIO = 0.93     # a human skeleton (toe tips to head end) spans about this much of the body's height
MAX_UNIT_ERROR = 2.0    # auto scale may differ from the declared unit by at most this factor
BONE_SAMPLES = 5        # points checked along each bone segment, ends included
INSIDE_MARGIN = 0.01    # [m] how deep under the skin auto fit wants the bones
MESH_UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "inch": 0.0254}   # the units modelling tools write


class FitError(ClusterFemError, ValueError):
    """A bind pose or fit that does not put the skeleton inside the mesh; the message names the way out."""


@dataclass(frozen=True)
class Fit:
    rotation: np.ndarray    # (3, 3) file axes -> ROS axes
    scale: float            # metres per file unit
    offset: np.ndarray      # (3,) [m]

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.offset

    def inverse(self, points: np.ndarray) -> np.ndarray:
        """File coordinates of world points: the inverse of ``apply``."""
        return (np.asarray(points, dtype=np.float64) - self.offset) @ self.rotation / self.scale

    def describe(self) -> str:
        return (f"scale {self.scale:.5g} m per file unit, offset ({', '.join(f'{x:.3f}' for x in self.offset)}) m, "
                f"file axes -> ROS {np.round(self.rotation).astype(int).tolist()}")


def _unknown_names(kind: str, names: Sequence[str], known: Sequence[str], where: str) -> None:
    bad = [n for n in names if n not in known]
    if bad:
        hints = [f"{n!r}" + (f" (did you mean {close[0]!r}?)" if (close := difflib.get_close_matches(n, known, 1))
                             else "") for n in bad]
        raise FitError(f"{where} names {kind} the skeleton does not have: {', '.join(hints)}; its {kind} are "
                       f"{', '.join(known[:12])}{' ...' if len(known) > 12 else ''}")


def bind_configuration(skeleton, pose: str = "neutral", joints: Sequence[str] = (), angles: Sequence[float] = (),
                       bvh_file: str = "", bvh_unit="auto", bvh_up: str = "auto") -> np.ndarray:
    """The skeleton's configuration q (nq,) in the pose the mesh was modelled in.

    ``pose``: 'neutral' (the URDF's zero pose) or 'first_frame' (frame 0 of ``bvh_file``, a capture of
    this skeleton: its T-pose for the CMU files; any file kind a motion source registered a reader for,
    skeleton/capture_frames.py; read in ``bvh_unit`` with up axis ``bvh_up``, 'auto' as the player finds them); then each of ``joints`` is set to its entry of
    ``angles`` [rad, or m for a prismatic joint].
    """
    if len(joints) != len(angles):
        raise FitError(f"skeleton.bind_joints has {len(joints)} names but skeleton.bind_angles {len(angles)} "
                       "values: give one angle [rad] per joint")
    q = skeleton.neutral().copy()
    if pose == "first_frame":
        if not bvh_file:
            raise FitError("skeleton.bind_pose = 'first_frame' needs skeleton.bind_bvh: the BVH file the player "
                           "plays (its frame 0 is the pose the mesh was modelled in)")
        from ..skeleton.capture_frames import read_frames
        try:
            traj = read_frames(find_data_file(str(bvh_file), what="skeleton.bind_bvh"), bvh_unit, bvh_up)
        except ValueError as exc:
            raise FitError(f"skeleton.bind_bvh: {exc}") from None
        missing = [n for n in skeleton.joint_names if n not in traj.names]
        if missing:
            raise FitError(f"skeleton.bind_bvh {str(bvh_file)!r} is a capture of another skeleton: it has no joint "
                           f"{', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}; play a capture with its "
                           "joint names, or bind on a capture of the played skeleton (skeleton.bind_bvh, with "
                           "bind_joints / bind_angles for that skeleton), or skeleton.bind_pose 'neutral'")
        q0 = traj.positions[0]
        q = np.array([q0[traj.names.index(n)] for n in skeleton.joint_names])
    elif pose != "neutral":
        raise FitError(f"skeleton.bind_pose = {pose!r}: choose 'neutral' or 'first_frame'")
    _unknown_names("joints", list(joints), list(skeleton.joint_names), "skeleton.bind_joints")
    for name, a in zip(joints, angles):
        q[skeleton.joint_names.index(name)] = float(a)
    return q


def fit_mesh(vertices: np.ndarray, starts: np.ndarray, ends: np.ndarray, mode: str = "auto", unit: float = 1.0,
             up: str = "Z", forward: str = "X", offset: Sequence[float] = (0.0, 0.0, 0.0),
             triangles: np.ndarray | None = None, rotation: np.ndarray | None = None) -> Fit:
    """The placement of a mesh (file units and axes) on a skeleton's bone segments (world, bind pose);
    ``triangles`` (the closed surface over ``vertices``) lets ``auto`` refine it (``refine_fit``); ``rotation``
    (3, 3), when given, takes the file's axes to the world instead of ``up`` / ``forward``."""
    from ..skeleton.bvh import axes_to_ros
    try:
        R = axes_to_ros(up, forward) if rotation is None else np.asarray(rotation, dtype=np.float64)
    except ValueError as exc:
        raise FitError(f"skeleton.fit_up / skeleton.fit_forward: {exc}") from None
    if not (np.isfinite(unit) and unit > 0):
        raise FitError(f"body.surface_unit = {unit!r}: give the metres per file unit (1 for metres, 0.01 for cm)")
    x = np.asarray(vertices, dtype=np.float64) @ R.T * unit
    bones = np.vstack([starts, ends])
    lo, hi, blo, bhi = x.min(0), x.max(0), bones.min(0), bones.max(0)
    height, bone_height = hi[2] - lo[2], bhi[2] - blo[2]
    if not (height > 0 and bone_height > 0):
        raise FitError(f"the mesh ({height:.3g} m) or the skeleton ({bone_height:.3g} m) has no height along ROS Z: "
                       "check skeleton.fit_up (the file's up axis)")
    auto = bone_height / (HEIGHT_RATIO * height)
    if not 1.0 / MAX_UNIT_ERROR <= auto <= MAX_UNIT_ERROR:
        raise FitError(unit_mismatch(height, bone_height / HEIGHT_RATIO, unit))
    if mode == "manual":
        return Fit(R, float(unit), np.asarray(offset, dtype=np.float64))
    if mode != "auto":
        raise FitError(f"skeleton.fit = {mode!r}: choose 'auto' or 'manual'")
    s = unit * auto
    centre = 0.5 * (lo + hi) * auto
    fit = Fit(R, float(s), 0.5 * (blo + bhi) - centre)
    return fit if triangles is None else refine_fit(fit, vertices, triangles, starts, ends)


def unit_mismatch(mesh_height: float, skeleton_height: float, unit: float) -> str:
    """The message for a mesh (``mesh_height`` [m] at body.surface_unit ``unit``) and a skeleton (its stature [m] in
    the capture's unit) of different sizes, naming the input whose height is no human's: the mesh's unit when the
    mesh is not a standing human's height, else the capture's when the skeleton is not, else both."""
    from ..skeleton.bvh_placement import HEIGHT_RANGE, STANDING_HEIGHT
    lo, hi = HEIGHT_RANGE
    sizes = (f"the mesh is {mesh_height / skeleton_height:.3g} times the size of its skeleton (the mesh "
             f"{mesh_height:.4g} m tall at body.surface_unit = {unit:g} m per file unit, the skeleton "
             f"{skeleton_height:.4g} m)")
    if not lo <= mesh_height <= hi:
        file_height = mesh_height / unit
        name = min(MESH_UNITS, key=lambda n: abs(np.log(file_height * MESH_UNITS[n] / STANDING_HEIGHT)))
        metres = MESH_UNITS[name]
        return (f"{sizes}: a standing human is {lo:g} to {hi:g} m tall, so the mesh's unit is wrong; set "
                f"body.surface_unit {metres:g} ({name}: the mesh {mesh_height / unit * metres:.2f} m tall)")
    if not lo <= skeleton_height <= hi:
        return (f"{sizes}: a standing human is {lo:g} to {hi:g} m tall, so the capture's unit is wrong; set the "
                "player's 'unit' (skeleton.bvh_unit) to the unit of the BVH file, or 'auto'")
    return (f"{sizes}: check body.surface_unit (the mesh's unit) and the player's 'unit' (skeleton.bvh_unit, the "
            "capture's): one of them is wrong")


def _bone_points(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    w = np.linspace(0.0, 1.0, BONE_SAMPLES)
    return (starts[:, None, :] * (1 - w)[None, :, None] + ends[:, None, :] * w[None, :, None]).reshape(-1, 3)


def refine_fit(fit: Fit, vertices: np.ndarray, triangles: np.ndarray, starts: np.ndarray, ends: np.ndarray,
               scale: bool = True) -> Fit:
    """``fit`` with its offset and (``scale``) its scale moved (least squares) so that the bone points lie
    INSIDE_MARGIN inside."""
    import trimesh
    from scipy.optimize import least_squares
    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    pts = _bone_points(starts, ends)
    free = 4 if scale else 3

    def outside(p: np.ndarray) -> np.ndarray:
        scale, offset = fit.scale * np.exp(p[3] if free == 4 else 0.0), fit.offset + p[:3]
        local = (pts - offset) @ fit.rotation / scale                  # bone points in the file's frame
        depth = trimesh.proximity.signed_distance(mesh, local) * scale  # > 0 inside [m]
        return np.maximum(INSIDE_MARGIN - depth, 0.0)

    r = least_squares(outside, np.zeros(free), diff_step=1e-3, max_nfev=60)
    return Fit(fit.rotation, float(fit.scale * np.exp(r.x[3] if free == 4 else 0.0)), fit.offset + r.x[:3])


def bone_outside_distances(surface_vertices: np.ndarray, triangles: np.ndarray, starts: np.ndarray,
                           ends: np.ndarray) -> np.ndarray:
    """(nb,) [m] how far the farthest of BONE_SAMPLES points along each bone lies outside the closed surface
    (negative: every point inside, by that depth)."""
    import trimesh
    mesh = trimesh.Trimesh(surface_vertices, triangles, process=False)
    pts = _bone_points(starts, ends)
    signed = trimesh.proximity.signed_distance(mesh, pts).reshape(len(starts), BONE_SAMPLES)   # > 0 inside
    return -signed.min(axis=1)


def bones_outside(surface_vertices: np.ndarray, triangles: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                  names: Sequence[str], tolerance: float) -> list[tuple[str, float]]:
    """(bone name, how far outside [m]) of every bone a point of whose segment lies more than ``tolerance``
    outside the closed surface (signed distance, trimesh), worst first."""
    out = bone_outside_distances(surface_vertices, triangles, starts, ends)
    bad = [(names[b], float(out[b])) for b in np.flatnonzero(out > tolerance)]
    return sorted(bad, key=lambda p: -p[1])


def surface_depth(points: np.ndarray, surface_vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distance (n,) [m] of every point to the closed surface (0 on it)."""
    import trimesh
    mesh = trimesh.Trimesh(surface_vertices, triangles, process=False)
    _, d, _ = trimesh.proximity.closest_point(mesh, np.asarray(points, dtype=np.float64))
    return np.asarray(d, dtype=np.float64)


def find_data_file(name: str, manifest: str = "", what: str = "surface file") -> Path:
    """A data file given by path, by ``package://<package>/<path>`` in an installed package
    (skeleton/robot_data.py), or by a bare name under the data folders (clusterfem_ros.data_dirs:
    $CLUSTERFEM_DATA, ../shared/data of a checkout, the user data folder); ``what`` names it in the error."""
    from ..data_dirs import data_roots
    from ..skeleton.robot_data import PACKAGE_SCHEME, package_file
    p = Path(name)
    if p.is_file():
        return p
    if name.startswith(PACKAGE_SCHEME):
        found = package_file(name)
        if found is None:
            raise FitError(f"{what} {name!r} is in no installed package: install the package that ships it (the "
                           "robot scenes use example-robot-data, pinned in requirements.lock)")
        return found
    roots = data_roots()
    for root in roots:
        if (root / name).is_file():
            return root / name
    where = ", ".join(str(r) for r in roots)
    raise FitError(f"{what} {name!r} is neither a path nor found under {where}: place it there (or set "
                   f"CLUSTERFEM_DATA to the folder holding it)" + (f"; {manifest} says where it comes from"
                                                                  if manifest else ""))
