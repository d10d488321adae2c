"""One integrator by its method's name, for the scene, the benchmarks and the tests."""
from __future__ import annotations

from ..model import FemModel
from .base import Integrator
from .clustered_explicit import ClusteredExplicit
from .modal import ModalIntegrator
from .standard_explicit import StandardExplicit
from .standard_implicit import StandardImplicit


def make_integrator(method: str, model: FemModel, **options) -> Integrator:
    """'clustered', 'standard_explicit', 'implicit_direct', 'implicit_cg' or 'modal' (options per class)."""
    if method == "clustered":
        return ClusteredExplicit(model, **options)
    if method == "standard_explicit":
        return StandardExplicit(model, **options)
    if method == "implicit_direct":
        return StandardImplicit(model, solver="direct", **options)
    if method == "implicit_cg":
        return StandardImplicit(model, solver="cg", **options)
    if method == "modal":
        return ModalIntegrator(model, **options)
    raise ValueError(f"unknown method {method!r}: choose clustered, standard_explicit, implicit_direct, "
                     "implicit_cg or modal")
