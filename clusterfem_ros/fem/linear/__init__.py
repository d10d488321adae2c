"""Linear elasticity on tetrahedra: the material (Young's modulus, Poisson's ratio, Rayleigh damping; material.py)
and, vectorised over the elements, shape gradients, element stiffness blocks, the assembled K and the lumped mass
(assembly.py). Every force model starts from these."""
from .material import Material, ParameterError  # noqa: F401
