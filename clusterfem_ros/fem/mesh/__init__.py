"""Tetrahedral meshes: the array convention and its checks (tet_mesh.py), element quality (tet_quality.py), meshes
from voxels and the paper's shapes (voxel_mesh.py), surfaces to tets with fTetWild (tetrahedralize.py) and mesh
files through meshio (mesh_io.py). Vertices are ``(n, 3) float64``, tets ``(m, 4)`` integer, positively
oriented."""
from .tet_mesh import MeshError, TetMesh  # noqa: F401
