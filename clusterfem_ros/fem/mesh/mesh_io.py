"""Real meshes through meshio (.msh, .vtk, .vtu, .mesh and the rest meshio reads)."""
from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from .tet_mesh import MeshError, TetMesh, orient as orient_tets


def read_mesh(path: str | Path, orient: bool = False, scale: float = 1.0) -> TetMesh:
    """Read the linear tetrahedra of a volume mesh file; validate it.

    ``orient=True`` flips negatively oriented tets instead of refusing them; ``scale`` converts units
    (e.g. 0.001 for a file in millimetres).
    """
    path = Path(path)
    if not path.exists():
        raise MeshError(f"mesh file {str(path)!r} does not exist")
    try:
        m = meshio.read(str(path))
    except (Exception, SystemExit) as exc:  # meshio raises many types, and exits on some bad .msh files
        why = f"meshio gave up (exit status {exc.code})" if isinstance(exc, SystemExit) else f"{exc}"
        raise MeshError(f"cannot read mesh file {str(path)!r} as {path.suffix or 'a mesh'}: {why}; export it "
                        "again as a Gmsh 2.2/4.1 .msh, .vtu or .vtk volume mesh") from None
    blocks = [c.data for c in m.cells if c.type == "tetra"]
    if not blocks:
        kinds = sorted({c.type for c in m.cells}) or ["none"]
        raise MeshError(f"{str(path)!r} has no tetrahedra (cell types: {', '.join(kinds)}): "
                        "a volume mesh of linear tets is needed (tetgen, gmsh -3, fTetWild)")
    mesh = TetMesh(np.asarray(m.points, dtype=np.float64)[:, :3] * scale, np.concatenate(blocks))
    if orient:
        mesh = orient_tets(mesh)
    return mesh.validate()


def write_mesh(path: str | Path, mesh: TetMesh) -> None:
    """Write a tet mesh in the format given by the file extension."""
    meshio.write_points_cells(str(path), mesh.vertices, [("tetra", mesh.tets)])
