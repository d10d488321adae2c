"""The fetched humanoid meshes of tests/data/character_meshes.yaml: where each file is (checked by sha256), what its
geometry says it is, and whether the project's mesher makes tets of it.

    python -m benchmarks.characters [--tets 5000] [--only NAME ...] [--walk BVH ...] [--duration 3]

prints, per manifest entry, the body measured from the surface (up axis, forward axis, height, unit, arms'
angle to the body axis, pose) beside what the manifest states, then meshes it as ``body.kind: surface`` does
(fem/mesh/tetrahedralize.surface_to_tets, ``body.target_tets`` = --tets) into an empty cache folder: tets,
seconds, the smallest dihedral angle and radius ratio, or the error. With ``--walk``, each mesh then takes the
place of MakeHuman's in config/character_walk.yaml (its file: ``walk_overrides``; group, unit and axes 'auto'),
bound by ``skeleton.bind_pose: auto`` on each capture's own skeleton and played by it for --duration simulated
seconds as the clip soak plays it (benchmarks/clip_soak.headless_soak: looped as the player loops it): resets,
withheld states, worst distance of a published vertex to its bone, worst volume error, and the bind's report
per limb (the largest distance of the limb's bones from the middle of the mesh's limb), or the error that
refused the build; then a table of them all. Times depend on the machine and its load.

``find_mesh(entry)`` looks for the entry's ``file`` in ``meshes/`` of each data folder
(clusterfem_ros/data_dirs.py: ``$CLUSTERFEM_DATA``, ``../shared/data`` beside the checkout, the user data folder); ``missing_message`` names the
file and the manifest entry to fetch it from. ``measure_body`` reads the body's axes and unit from its shape alone, as the
scene's ``auto`` does (clusterfem_ros/body/mesh_frame.py), and its pose from the arms' angle.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clusterfem_ros.body.mesh_frame import UNITS as MESH_FRAME_UNITS, measure_frame
from clusterfem_ros.fem.stability import StabilityError

REPO = Path(__file__).resolve().parents[1]
MANIFEST = REPO / "tests" / "data" / "character_meshes.yaml"
AXES = "XYZ"
MANIFEST_UNIT = {"inch": "in"}                  # the manifest's names of body/mesh_frame.UNITS that differ
UNITS = {MANIFEST_UNIT.get(name, name): metres for name, metres in MESH_FRAME_UNITS.items()}   # manifest names
T_POSE_MIN_DEG, A_POSE_MIN_DEG = 70.0, 30.0     # the arms' angle to the body axis: T above, arms down below A
SURFACE_SAMPLES = 20000                         # points spread over the surface (by area) to find the arms in


@dataclass(frozen=True)
class CharacterMesh:
    name: str
    file: str
    group: str
    repository: str
    commit: str
    path: str
    sha256: str
    bytes: int
    licence: str
    attribution: str
    source: str
    format: str
    pose: str
    arm_angle_deg: float
    unit: str
    metres_per_unit: float
    up: str
    forward: str
    lateral: str
    height: float
    vertices: int
    faces: int
    watertight: bool


def load_manifest(path: Path = MANIFEST) -> list[CharacterMesh]:
    import yaml
    doc = yaml.safe_load(Path(path).read_text())
    return [CharacterMesh(**entry) for entry in doc["meshes"]]


def mesh_dirs() -> list[Path]:
    """Where the meshes are looked for, in order."""
    from clusterfem_ros.data_dirs import data_roots
    return [root / "meshes" for root in data_roots()]


def find_mesh(entry: CharacterMesh) -> Path | None:
    """The entry's file if present with the manifest's sha256 (a file with another hash raises ValueError)."""
    from .clips import find_fetched
    return find_fetched(mesh_dirs(), entry.file, entry, MANIFEST)


def missing_message(entry: CharacterMesh) -> str:
    where = " or ".join(str(d) for d in mesh_dirs()) + ("" if os.environ.get("CLUSTERFEM_DATA") else
                                                         " (or $CLUSTERFEM_DATA/meshes)")
    return (f"character mesh {entry.file} not found in {where}: it is {entry.path} at commit {entry.commit} of "
            f"{entry.repository} (entry '{entry.name}' of {MANIFEST.relative_to(REPO)})")


@dataclass(frozen=True)
class BodyShape:
    lateral: str            # 'X', 'Y' or 'Z'
    up: str                 # '+Y', '-Z', ...: feet to head
    forward: str            # the way the face looks
    height: float           # along up, file units
    unit: str               # a key of UNITS (as the manifest names them), '' when no unit gives a human height
    arm_angle_deg: float    # the arms' mean angle to the body axis (nan: no arm stands out from the trunk)
    pose: str               # 'T', 'A' or 'arms-down'
    watertight: bool

    def describe(self) -> str:
        pose = "arms down" if self.pose == "arms-down" else f"{self.pose}-pose"
        return (f"up {self.up}, forward {self.forward}, height {self.height:.4g} {self.unit or '(no unit fits)'}, "
                f"arms {self.arm_angle_deg:.1f} deg from the body axis: {pose}")


def _plus(axis: str) -> str:
    """'Y' -> '+Y', '-Z' -> '-Z': the manifest's spelling of a signed axis."""
    return axis if axis.startswith("-") else "+" + axis


def arm_angle(points: np.ndarray, lateral: int, up: int, up_sign: float) -> float:
    """The arms' mean angle [deg] to the body axis: the main direction of the surface points (evenly spread over
    the surface, not vertices: a long triangle has them at its ends only) beyond the trunk (farther than 0.2 of
    the height from the mid-plane) above the hips (higher than 0.45 of the height), each side apart; nan when a
    side has no such points."""
    v = np.asarray(points, dtype=np.float64)
    h = (v[:, up] - v[:, up].min()) if up_sign > 0 else (v[:, up].max() - v[:, up])
    height = float(h.max())
    x = v[:, lateral] - 0.5 * (v[:, lateral].min() + v[:, lateral].max())
    angles = []
    for side in (1.0, -1.0):
        sel = (side * x > 0.2 * height) & (h > 0.45 * height)
        if sel.sum() < 10:
            return float("nan")
        p = np.stack([x[sel], h[sel]], axis=1)
        p -= p.mean(axis=0)
        direction = np.linalg.eigh(p.T @ p)[1][:, -1]
        angles.append(np.degrees(np.arccos(min(1.0, abs(direction[1]) / np.linalg.norm(direction)))))
    return float(np.mean(angles))


def measure_body(vertices: np.ndarray, faces: np.ndarray) -> BodyShape:
    """The body's axes, height and unit (body/mesh_frame.measure_frame: what ``auto`` takes in the scene) and its
    pose (the arms' angle) from its surface alone."""
    import trimesh
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    frame = measure_frame(v, f)
    up, up_sign = AXES.index(frame.up.lstrip("-")), -1.0 if frame.up.startswith("-") else 1.0
    mesh = trimesh.Trimesh(v, f, process=False)
    points = np.asarray(trimesh.sample.sample_surface(mesh, SURFACE_SAMPLES, seed=0)[0])
    angle = arm_angle(points, AXES.index(frame.lateral), up, up_sign)
    pose = ("T" if angle >= T_POSE_MIN_DEG else "A" if angle >= A_POSE_MIN_DEG else "arms-down") \
        if np.isfinite(angle) else "arms-down"
    return BodyShape(frame.lateral, _plus(frame.up), _plus(frame.forward), frame.height,
                     MANIFEST_UNIT.get(frame.unit, frame.unit), angle, pose, bool(mesh.is_watertight))


def read_entry(path: Path, entry: CharacterMesh) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of the entry's file as ``body.kind: surface`` reads it."""
    from clusterfem_ros.fem.mesh.tetrahedralize import read_surface
    return read_surface(path, entry.group)


def main(argv: list[str] | None = None) -> None:
    from clusterfem_ros.fem.mesh.tetrahedralize import MeshError, surface_to_tets
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tets", type=int, default=5000, help="body.target_tets (default 5000)")
    parser.add_argument("--only", nargs="*", default=None, help="manifest names to run (default: all)")
    parser.add_argument("--walk", nargs="*", type=Path, default=[], help="BVH captures to drive each character by")
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds of each walk (default 3)")
    args = parser.parse_args(argv)
    rows: list[list] = []
    for entry in load_manifest():
        if args.only and entry.name not in args.only:
            continue
        path = find_mesh(entry)
        if path is None:
            print(f"{entry.name}: absent ({missing_message(entry)})", flush=True)
            continue
        v, f = read_entry(path, entry)
        shape = measure_body(v, f)
        print(f"{entry.name} ({entry.format}, {len(v)} vertices, {len(f)} triangles, "
              f"{'closed' if shape.watertight else 'open'}): measured {shape.describe()}; manifest up {entry.up}, "
              f"forward {entry.forward}, {entry.unit}, {entry.pose}", flush=True)
        with tempfile.TemporaryDirectory(prefix="clusterfem_character_meshes_") as cache:
            t0 = time.perf_counter()
            try:
                r = surface_to_tets(path, args.tets, group=entry.group, cache=Path(cache))
            except MeshError as exc:
                print(f"  tetrahedralize ({args.tets} tets asked): FAILED after {time.perf_counter() - t0:.1f} s: "
                      f"{exc}", flush=True)
                continue
            print(f"  tetrahedralize ({args.tets} tets asked): {r.mesh.n_tets} tets, {r.mesh.n_vertices} vertices in "
                  f"{r.seconds:.1f} s ({r.attempts} fTetWild runs), min dihedral {r.min_dihedral_deg:.2f} deg, min "
                  f"radius ratio {r.min_radius_ratio:.4f}, volume {r.mesh.volumes().sum():.4g} file units^3",
                  flush=True)
            old = os.environ.get("CLUSTERFEM_CACHE")
            os.environ["CLUSTERFEM_CACHE"] = cache              # the scenes below read these tets from the cache
            try:
                for bvh in args.walk:
                    line, row = walk(path, entry, bvh, args.tets, args.duration)
                    rows.append(row)
                    print(f"  {bvh.name}: {line}", flush=True)
            finally:
                if old is None:
                    del os.environ["CLUSTERFEM_CACHE"]
                else:
                    os.environ["CLUSTERFEM_CACHE"] = old
    if rows:
        from .timing import table
        print(f"\nmesh x capture, {args.duration:g} s each at --tets {args.tets} (config/character_walk.yaml, "
              "bind_pose auto):")
        print(table(["mesh", "capture", "resets", "withheld", "worst vertex-to-bone [m]", "worst volume error",
                     "bind: bones from the limb's middle, max [cm]", "bones unbound"], rows))


def walk_overrides(path: Path, entry: CharacterMesh, tets: int) -> dict:
    """The parameters that put the entry's mesh in place of MakeHuman's in config/character_walk.yaml, as
    ``scripts/run --set`` gives them: its file; its group, unit and axes are the scene's ``auto`` (an OBJ's closed
    largest group, the unit and axes read from the shape: body/mesh_frame.py), as for a mesh of the user's."""
    return {"body.surface_file": str(path), "body.target_tets": tets}


def walk(path: Path, entry: CharacterMesh, bvh: Path, tets: int, duration: float) -> tuple[str, list]:
    """(one line, a table row): the character scene on ``path`` played by the capture ``bvh`` as
    ``python -m benchmarks.clip_soak --scene config/character_walk.yaml --set ...`` plays it (the capture's own
    skeleton, bound 'auto', looped as the player loops it) for ``duration`` s, or the error that stopped it."""
    from .character_report import DEFAULT_SCENE
    from .clip_soak import headless_soak
    t0 = time.perf_counter()
    try:
        r = headless_soak(bvh, walk_overrides(path, entry, tets), duration, DEFAULT_SCENE)
    except ValueError as exc:           # FitError, ConfigError, UrdfError: the scene refuses the input, naming it
        return (f"refused ({time.perf_counter() - t0:.0f} s): {type(exc).__name__}: {exc}",
                [entry.name, bvh.stem, "refused", "", "", "", "", ""])
    except StabilityError as exc:       # the placement's step cannot be made stable: this row fails, the run goes on
        return (f"failed ({time.perf_counter() - t0:.0f} s): {type(exc).__name__}: {exc}",
                [entry.name, bvh.stem, "failed", "", "", "", "", ""])
    limbs = ", ".join(f"{k[0]}{k[1]} {100 * v[1]:.0f}" for k, v in (r.limbs or {}).items())
    line = (f"{r.seconds:g} s played in {time.perf_counter() - t0:.0f} s: {r.resets} resets, {r.withheld} withheld, "
            f"worst volume error {r.worst_volume:.2%}, worst vertex-to-bone {r.worst_distance:.3f} m, "
            f"{r.step_ms:.2f} ms a step; bones from the limbs' middle (max, cm): {limbs or '-'}; "
            f"unbound: {', '.join(r.unbound) or 'none'}" + (f"; first reset: {r.first_problem}" if r.resets else ""))
    return line, [entry.name, bvh.stem, r.resets, r.withheld, f"{r.worst_distance:.3f}",
                  f"{100 * r.worst_volume:.1f} %", limbs or "-", len(r.unbound)]


if __name__ == "__main__":
    main()
