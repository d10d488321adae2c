"""Surface mesh -> tetrahedra with fTetWild (pytetwild), sized by a tet count, cached on disk.

A character or a soft cover comes as a triangle surface (OBJ, STL, PLY, glTF...), read with trimesh.
fTetWild meshes it robustly (open seams, self-intersections and near-closed surfaces are wrapped by its
envelope) and its licence (MPL-2.0) suits the package; TetGen is faster on clean input but AGPL and
refuses self-intersecting surfaces (see benchmarks/mesher_compare.py for the comparison).

fTetWild takes an edge length, not a count, and keeps the surface's detail, so the count is reached in
two ways: the surface is first decimated (fast-simplification) to about ``FACES_PER_TET`` faces per
requested tet, and the edge length starts from the volume of a regular tet of the body's volume / target.
A coarse decimation can thin a wrist or an ankle until the mesher cuts it: where the tets come in pieces one of
which lies within ``SPLIT_EDGES`` tet edges of the largest (``near_pieces``: the hands of mesh2motion's A-pose
at 1500 tets, 750 faces), the surface is meshed again from twice as many faces, up to the whole surface.
The edge length is then corrected by the cube root of the count ratio until the count is within
``tolerance``. fTetWild is not repeatable: on a capsule, 40 runs at one edge length gave 344 to 683 tets,
18 % of them more than 20 % from the median of 438 (``python -m benchmarks.mesher_compare --repeat 40``).
Near the right edge length a miss is mostly that noise, and the next run is a fresh draw, so the search
has ``MAX_ATTEMPTS`` runs rather than the three or four a repeatable mesher would need.

The result (in the file's own units and axes) is cached in ``cache_dir`` (default ``$CLUSTERFEM_CACHE`` or
``~/.cache/clusterfem_ros``) under a key made of the file's sha256, the group, the meshing parameters and
the mesher's version; files are written to a temporary name and renamed, so a crash never leaves half a
cache entry.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .tet_mesh import MeshError, TetMesh, orient, remove_unreferenced, tet_pieces

FACES_PER_TET = 0.5         # surface faces kept per requested tet before meshing
FIRST_EDGE_FACTOR = 1.12    # fTetWild gives ~40 % more tets than volume / regular-tet volume: start longer
MAX_ATTEMPTS = 12           # fTetWild runs before giving up (see the module docstring)
CACHE_FORMAT = 2            # bump when the cached content or the way it is made changes
SPLIT_EDGES = 2.0           # a piece of the tets this many edge lengths from the largest was cut off it


class SurfaceError(MeshError):
    """A surface file that cannot become a volume mesh; the message names the file and the way out."""


@dataclass(frozen=True)
class TetResult:
    mesh: TetMesh               # in the surface file's units and axes
    min_dihedral_deg: float     # smallest dihedral angle of any tet [deg]
    min_radius_ratio: float     # smallest 3 r_in / r_circ (1 = regular tet, 0 = flat)
    attempts: int               # mesher runs it took (0 when read from the cache)
    seconds: float              # wall time of the meshing (of the cache read on a hit)
    cached: bool
    cache_file: Path | None


def cache_dir() -> Path:
    return Path(os.environ.get("CLUSTERFEM_CACHE") or Path.home() / ".cache" / "clusterfem_ros")


def _obj_groups(path: Path) -> dict:
    from trimesh.exchange.obj import load_obj
    with open(path, "rb") as f:
        return load_obj(f, split_groups=True, group_material=False, maintain_order=False,
                        skip_materials=True)["geometry"]


def pick_group(path: str | Path) -> tuple[str, str]:
    """(group, one line saying why) for ``body.surface_group: auto``: the whole file ('') unless it is an OBJ of
    several groups whose largest (by faces) is a closed surface, as a body with its helper and clothing groups is
    (MakeHuman's 'body' beside 'helper-tights', the eyes, ...): that group. A model split into parts (a head, a
    trunk, ...) has no closed largest part holding the rest, and is read whole."""
    import trimesh
    path = Path(path)
    if path.suffix.lower() != ".obj" or not path.is_file():
        return "", "body.surface_group auto: the whole file (not an OBJ)"
    try:
        parts = _obj_groups(path)
    except Exception:                # trimesh raises many types: read_surface reports the file's problem
        return "", "body.surface_group auto: the whole file"
    if len(parts) <= 1:
        return "", "body.surface_group auto: the whole file (one group)"
    sizes = sorted(((len(p["faces"]), name) for name, p in parts.items()), reverse=True)
    faces, name = sizes[0]
    closed = trimesh.Trimesh(vertices=parts[name]["vertices"], faces=parts[name]["faces"], process=True).is_watertight
    others = ", ".join(f"{n} {k}" for k, n in sizes[1:4]) + (" ..." if len(sizes) > 4 else "")
    if not closed:
        return "", (f"body.surface_group auto: the whole file (its largest of {len(parts)} groups, {name!r}, is not "
                    "a closed surface)")
    return name, (f"body.surface_group auto: group {name!r}, the largest of the file's {len(parts)} groups ({faces} "
                  f"faces, closed; then {others}): set body.surface_group to choose another, or '' for the whole file")


def read_surface(path: str | Path, group: str = "") -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3) float64, triangles (t, 3) int64) of a surface file; ``group``: one OBJ group only."""
    import trimesh
    path = Path(path)
    if not path.is_file():
        raise SurfaceError(f"surface file {str(path)!r} does not exist: give body.surface_file the path of a "
                           "triangle mesh (.obj, .stl, .ply, .glb)")
    try:
        if group:
            if path.suffix.lower() != ".obj":
                raise SurfaceError(f"body.surface_group = {group!r} picks an OBJ group, but {str(path)!r} is not an "
                                   "OBJ file: leave body.surface_group empty")
            parts = _obj_groups(path)
            if group not in parts:
                raise SurfaceError(f"{str(path)!r} has no group {group!r}; its groups are "
                                   f"{', '.join(sorted(parts)[:20])}{' ...' if len(parts) > 20 else ''}")
            m = trimesh.Trimesh(vertices=parts[group]["vertices"], faces=parts[group]["faces"], process=True)
        else:
            m = trimesh.load(str(path), force="mesh", process=True)
    except SurfaceError:
        raise
    except Exception as exc:  # trimesh raises many types for files it cannot parse
        raise SurfaceError(f"cannot read {str(path)!r} as a surface mesh ({type(exc).__name__}: {exc}): give an "
                           "OBJ, STL, PLY or glTF triangle mesh") from exc
    v = np.asarray(getattr(m, "vertices", np.empty((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(m, "faces", np.empty((0, 3))), dtype=np.int64)
    if v.ndim != 2 or len(v) < 4 or f.ndim != 2 or len(f) < 4:
        raise SurfaceError(f"{str(path)!r} holds no triangle surface ({len(v)} vertices, {len(f)} triangles): "
                           "give a closed or nearly closed triangle mesh")
    if not np.isfinite(v).all():
        raise SurfaceError(f"{str(path)!r} has non-finite vertex coordinates: fix the file")
    return v, f


def tet_quality(vertices: np.ndarray, tets: np.ndarray) -> tuple[float, float]:
    """(smallest dihedral angle [deg], smallest radius ratio 3 r_in / r_circ) over all tets."""
    x = vertices[tets]                                                   # (m, 4, 3)
    faces = ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))                 # opposite vertex 0..3, outward
    n = np.stack([np.cross(x[:, b] - x[:, a], x[:, c] - x[:, a]) for a, b, c in faces], axis=1)
    area2 = np.linalg.norm(n, axis=2)                                    # 2 * face areas
    unit = n / np.maximum(area2, 1e-300)[..., None]
    cos = [-(unit[:, i] * unit[:, j]).sum(1) for i in range(4) for j in range(i + 1, 4)]
    dihedral = np.degrees(np.arccos(np.clip(np.stack(cos, 1), -1.0, 1.0)))
    e = x[:, 1:] - x[:, :1]
    vol6 = np.abs(np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])))
    r_in = vol6 / np.maximum(area2.sum(1), 1e-300)                       # 3 V / total area
    # circumcentre c - x0 solves 2 e_k . y = |e_k|^2
    y = np.linalg.solve(2.0 * e, np.einsum("mkj,mkj->mk", e, e)[..., None])[..., 0]
    r_circ = np.linalg.norm(y, axis=1)
    return float(dihedral.min()), float((3.0 * r_in / r_circ).min())


def _mesher_version() -> str:
    from importlib.metadata import version
    return f"pytetwild {version('pytetwild')}, fast_simplification {version('fast_simplification')}"


def _mesh_once(v: np.ndarray, f: np.ndarray, edge: float, diag: float) -> TetMesh:
    import pytetwild
    # the envelope (how far the tet surface may stray from the input) grows with the edge length, so a
    # coarse body is not forced to keep every wrinkle of the surface
    eps = float(np.clip(0.1 * edge / diag, 1e-3, 2e-2))
    # fTetWild writes a debug file (__tracked_surface.stl) into the working directory: give it a scratch one
    here = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="clusterfem_ftetwild_") as scratch:
        os.chdir(scratch)
        try:
            tv, tt = pytetwild.tetrahedralize(v, f.astype(np.int32), edge_length_abs=float(edge), epsilon=eps,
                                              num_threads=1)
        finally:
            os.chdir(here)
    if len(tt) == 0:
        return TetMesh(np.asarray(tv, dtype=np.float64).reshape(-1, 3), np.empty((0, 4), dtype=np.int64))
    return remove_unreferenced(orient(TetMesh(tv, tt)))


def _steer_edge(run: Callable[[int, float], TetMesh], edge: float, target_tets: int,
                tolerance: float) -> tuple[TetMesh, int]:
    """(the mesh whose count is nearest ``target_tets``, the attempts made): ``run(attempt, edge)`` meshes
    at ``edge``, and the edge is corrected by the cube root of the count ratio, until a count is within
    ``tolerance`` or ``MAX_ATTEMPTS`` runs are used."""
    best = None
    for attempt in range(1, MAX_ATTEMPTS + 1):
        mesh = run(attempt, edge)
        n = mesh.n_tets
        if best is None or abs(n / target_tets - 1) < abs(best.n_tets / target_tets - 1):
            best = mesh
        if abs(n / target_tets - 1) <= tolerance:
            break
        edge *= (n / target_tets) ** (1.0 / 3.0)
    return best, attempt


def tetrahedralize_surface(vertices: np.ndarray, faces: np.ndarray, target_tets: int, tolerance: float = 0.2,
                           progress: Callable[[str], None] | None = None, source: str = "the surface") -> TetResult:
    """Tets filling the surface, their count within ``tolerance`` of ``target_tets`` (see the module docstring)."""
    say = progress or (lambda _: None)
    t0 = time.perf_counter()
    v0, f0 = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    keep = int(max(200, FACES_PER_TET * target_tets))
    attempts = 0
    while True:
        result, edge = _tetrahedralize_decimated(v0, f0, keep, target_tets, tolerance, say, source, t0)
        attempts += result.attempts
        near = near_pieces(result.mesh, edge)
        if not near or keep >= len(f0):
            return replace(result, attempts=attempts)
        keep = min(2 * keep, len(f0))
        say(f"the tets of {source} came in {near + 1} pieces within {SPLIT_EDGES:g} tet edges of each other (a "
            f"thin limb cut where the surface was decimated): meshing again from {keep} of its {len(f0)} "
            "triangles")


def near_pieces(mesh: TetMesh, edge: float) -> int:
    """How many pieces of the tets (connected through shared vertices), other than the largest, come within
    SPLIT_EDGES x ``edge`` of the largest: parts the mesher cut off the body rather than parts apart in the
    surface."""
    from scipy.spatial import cKDTree
    if mesh.n_tets == 0:
        return 0
    k, label = tet_pieces(mesh.n_vertices, mesh.tets)
    if k == 1:
        return 0
    main = int(np.argmax(np.bincount(label)))
    gap, _ = cKDTree(mesh.vertices[label == main]).query(mesh.vertices[label != main],
                                                         distance_upper_bound=SPLIT_EDGES * edge)
    return int(np.unique(label[label != main][np.isfinite(gap)]).size)


def _tetrahedralize_decimated(v0: np.ndarray, f0: np.ndarray, keep: int, target_tets: int, tolerance: float, say,
                              source: str, t0: float) -> tuple[TetResult, float]:
    """(tetrahedralize_surface's result from the surface decimated to ``keep`` faces, the edge length it took)."""
    import fast_simplification
    import trimesh
    v, f = v0, f0
    if len(f) > keep:
        v, f = fast_simplification.simplify(v, f, target_reduction=1.0 - keep / len(f))
        say(f"decimated {source} from {len(f0)} to {len(f)} triangles for ~{target_tets} tets")
    surf = trimesh.Trimesh(v, f, process=False)
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    # an open surface has no volume of its own: half its bounding box is the guess for the first edge length
    volume = abs(float(surf.volume)) if surf.is_watertight else 0.5 * float(np.prod(np.ptp(v, axis=0)))
    if not volume > 1e-12 * diag ** 3:
        raise SurfaceError(f"{source} encloses no volume (it is flat: an open sheet, not a shell); the mesher cannot "
                           "close it: give the surface of a solid")
    edge = FIRST_EDGE_FACTOR * (volume * 6.0 * np.sqrt(2.0) / target_tets) ** (1.0 / 3.0)

    edges = {}

    def run(attempt: int, edge: float) -> TetMesh:
        say(f"fTetWild attempt {attempt}: edge length {edge:.4g} (file units), aiming at {target_tets} tets ...")
        mesh = _mesh_once(v, f, edge, diag)
        say(f"fTetWild attempt {attempt}: {mesh.n_tets} tets ({time.perf_counter() - t0:.1f} s so far)")
        if mesh.n_tets == 0:
            raise SurfaceError(f"fTetWild found no inside in {source}: it is an open surface (a sheet, not a shell) "
                               "the mesher cannot close; close its holes or give a solid's surface")
        edges[id(mesh)] = edge
        return mesh

    best, attempt = _steer_edge(run, edge, target_tets, tolerance)
    if abs(best.n_tets / target_tets - 1) > tolerance:
        raise SurfaceError(f"{source}: fTetWild gave {best.n_tets} tets, not within {tolerance:.0%} of "
                           f"body.target_tets = {target_tets}, after {MAX_ATTEMPTS} attempts: the surface has more "
                           "detail than that count can hold; ask for more tets")
    tet_volume = float(best.volumes().sum())
    if surf.is_watertight and abs(tet_volume / volume - 1.0) > 0.25:
        raise SurfaceError(f"{source}: the tets hold {tet_volume:.4g} but the surface encloses {volume:.4g} "
                           "(file units^3): fTetWild could not close it the way it was meant; repair the surface")
    best.validate()
    dihedral, ratio = tet_quality(best.vertices, best.tets)
    return TetResult(best, dihedral, ratio, attempt, time.perf_counter() - t0, False, None), edges[id(best)]


def _file_sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _cached_group(path: Path, folder: Path, sha: str) -> tuple[str, str]:
    """``pick_group`` of the file, kept in ``folder`` by the file's sha256: an OBJ's groups take longer to parse
    (0.5 s for MakeHuman's) than its cached tets to load."""
    file = folder / f"group_{sha[:24]}.json"
    if file.is_file():
        try:
            d = json.loads(file.read_text())
            return str(d["group"]), str(d["why"])
        except (ValueError, KeyError):
            pass                                   # unreadable: chosen again below
    group, why = pick_group(path)
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".group_", suffix=".json")
    with os.fdopen(fd, "w") as out:
        json.dump({"group": group, "why": why}, out)
    os.replace(tmp, file)
    return group, why


def _key(path: Path, group: str, target_tets: int, tolerance: float, sha: str | None = None) -> str:
    h = sha or _file_sha(path)
    params = json.dumps({"file_sha256": h, "group": group, "target_tets": int(target_tets),
                         "tolerance": float(tolerance), "faces_per_tet": FACES_PER_TET,
                         "first_edge_factor": FIRST_EDGE_FACTOR, "format": CACHE_FORMAT,
                         "mesher": _mesher_version()}, sort_keys=True)
    return hashlib.sha256(params.encode()).hexdigest()[:24]


def surface_to_tets(path: str | Path, target_tets: int, group: str = "", tolerance: float = 0.2,
                    cache: Path | None = None, progress: Callable[[str], None] | None = None) -> TetResult:
    """Read a surface file and tetrahedralize it, or load the tets of an earlier identical request; ``group``
    'auto': ``pick_group``'s, said in one line."""
    say = progress or (lambda _: None)
    path = Path(path)
    if not path.is_file():
        raise SurfaceError(f"surface file {str(path)!r} does not exist: give body.surface_file the path of a "
                           "triangle mesh (.obj, .stl, .ply, .glb)")
    folder = Path(cache) if cache is not None else cache_dir()
    sha = _file_sha(path)
    if group == "auto":
        group, why = _cached_group(path, folder, sha)
        say(why)
    file = folder / f"tets_{_key(path, group, target_tets, tolerance, sha)}.npz"
    if file.is_file():
        t0 = time.perf_counter()
        with np.load(file) as d:
            mesh = TetMesh(d["vertices"], d["tets"]).validate()
            dihedral, ratio = float(d["min_dihedral_deg"]), float(d["min_radius_ratio"])
        say(f"tets of {path.name} read from the cache {file} ({mesh.n_tets} tets)")
        return TetResult(mesh, dihedral, ratio, 0, time.perf_counter() - t0, True, file)
    say(f"tetrahedralizing {path.name} (~{target_tets} tets; cached after this first time in {folder})")
    v, f = read_surface(path, group)
    result = tetrahedralize_surface(v, f, target_tets, tolerance, progress, source=repr(str(path)))
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tets_", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as out:
            np.savez(out, vertices=result.mesh.vertices, tets=result.mesh.tets,
                     min_dihedral_deg=result.min_dihedral_deg, min_radius_ratio=result.min_radius_ratio)
        os.replace(tmp, file)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    say(f"{result.mesh.n_tets} tets in {result.seconds:.1f} s, min dihedral {result.min_dihedral_deg:.1f} deg, "
        f"min radius ratio {result.min_radius_ratio:.3f}; cached in {file}")
    return TetResult(result.mesh, result.min_dihedral_deg, result.min_radius_ratio, result.attempts,
                     result.seconds, False, file)
