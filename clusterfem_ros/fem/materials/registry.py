"""The material models by name: the linear one, per-element corotation ('element'), the paper's per-vertex
warping ('vertex') and stable Neo-Hookean elements ('neohookean'), each a ``MaterialModel``
(fem/materials/material_model.py says what the integrators ask of one). ``register`` adds a model; the names
a scene may choose are the declared ones (fem/materials/warping_models.DECLARED, which config.py reads without
numba): a declared model not registered yet is loaded from its declaration's module when first asked for."""
from __future__ import annotations

import numpy as np

from ..kernels.cluster_force_kernel import cluster_args, scratch
from ..kernels.cluster_slices import host_slices
from ...registries import Registry, load_object
from ..model import FemModel
from .assembled_warp import AssembledWarp
from .corotational import ElementCorotation
from .element_warping import ElementFrames, element_e_parallel, element_e_serial, element_force, element_rotations
from .material_model import ClusteredParts, MaterialModel, StandardParts
from .stress import compute_stress
from .neohookean import (energy as neohookean_energy, neohookean_e_parallel, neohookean_e_serial,
                         neohookean_e_unplanned_parallel, neohookean_e_unplanned_serial)
from .warping import VertexFrames, vertex_rotations, warped_e_parallel, warped_e_serial, warped_force
from .warping_models import DECLARED

# the implicit step with per-vertex rotations held misses the dR/dx coupling through the volumetric stiffness,
# which grows as 1 / (1 - 2 nu): it diverged at every step size tried above this
VERTEX_IMPLICIT_MAX_NU = 0.49


def _element_parts(model: FemModel, kernels: tuple, suffix: str) -> ClusteredParts:
    """An element model's clustered parts: its element data (ElementFrames) and its force pass's builds; w holds
    x0 + u + zeta v by vertex, e the gathered rows."""
    frames = ElementFrames.from_model(model)
    return ClusteredParts(frames, (frames.elems, frames.gather, frames.rest, frames.work), frames.w, frames.e,
                          kernels, suffix)


class Linear(MaterialModel):
    name = "linear"
    description = "linear elasticity: the assembled K, the paper's clustered force (warping: false)"
    rotation_invariant = False          # the volume grows under rotation: what warping removes

    def clustered(self, model: FemModel) -> ClusteredParts:
        slices = host_slices(model.clusters)
        w, f = scratch(slices)          # w: rows of 3 and one more (4-wide loads); f: the sweep's K w rows
        return ClusteredParts(None, cluster_args(slices), w, f, None, "")

    def standard(self, model: FemModel) -> None:
        return None

    def energy_function(self, model: FemModel):
        return model.elastic_energy

    def stress(self, model: FemModel, u: np.ndarray):
        """The linear stress of the strain (sym grad u), unrotated."""
        return compute_stress(model, u, corotated=False)


class ElementCorotated(MaterialModel):
    declaration = DECLARED["element"]
    suffix = "_warp"
    stretch_energy = "corotated"

    def clustered(self, model: FemModel) -> ClusteredParts:
        return _element_parts(model, (element_e_serial, element_e_parallel), "_element")

    def standard(self, model: FemModel) -> StandardParts:
        frames = ElementFrames.from_model(model)
        corotation = ElementCorotation(model)

        def implicit_terms(u, v, R):
            Kw = corotation.rotated_stiffness(R)                           # PSD, translation invariant
            return Kw, element_force(model, u, v, frames).reshape(-1), Kw

        return StandardParts(frames, lambda u: element_rotations(model, u, frames),
                             lambda u, v, R: corotation.force(u, v, R), implicit_terms)

    def energy_function(self, model: FemModel):
        return ElementCorotation(model).energy


class VertexWarped(MaterialModel):
    declaration = DECLARED["vertex"]
    suffix = "_warp_vertex"
    stretch_energy = "corotated"
    has_energy = False

    def clustered(self, model: FemModel) -> ClusteredParts:
        frames = VertexFrames.from_model(model)
        # w: rows of 3 and one more; e: the sweep's rows, as K w's
        return ClusteredParts(frames, (frames.gradients, frames.slices, frames.rest, frames.work), frames.w,
                              frames.e, (warped_e_serial, warped_e_parallel), "")

    def standard(self, model: FemModel) -> StandardParts:
        frames = VertexFrames.from_model(model)
        assembled = AssembledWarp(model)

        def implicit_terms(u, v, R):
            # K_w = R K R^T: PSD; the force's Jacobian: translation invariant
            return assembled.rotated(R), warped_force(model, u, v, frames).reshape(-1), assembled.jacobian(R)

        return StandardParts(frames, lambda u: vertex_rotations(model, u, frames),
                             lambda u, v, R: assembled.force(R, u, v), implicit_terms, VERTEX_IMPLICIT_MAX_NU)

    def energy_function(self, model: FemModel):
        """Its force is no energy's gradient: the linear energy of the same displacement stands in."""
        return model.elastic_energy


class NeoHookean(MaterialModel):
    declaration = DECLARED["neohookean"]
    suffix = "_neohookean"
    stretch_energy = "neohookean"

    def clustered(self, model: FemModel) -> ClusteredParts:
        parts = _element_parts(model, (neohookean_e_serial, neohookean_e_parallel), "_neohookean")
        parts.bound = lambda: parts.frames.rot_lanes       # the step plans from the bounds its first force leaves
        parts.later_e = (neohookean_e_unplanned_serial, neohookean_e_unplanned_parallel)    # no bounds after it
        return parts

    def energy_function(self, model: FemModel):
        return lambda u: neohookean_energy(model, u)


MODELS = Registry("material model")


def register(model: MaterialModel) -> MaterialModel:
    """Add ``model`` under its name (a name already taken is refused); returns it. A declared name's model must
    carry that declaration's flags (ValueError naming the flag that differs)."""
    d = DECLARED.get(model.name)
    if d is not None:
        differ = [f for f in MaterialModel.FLAGS if getattr(model, f) != getattr(d, f)]
        if differ:
            raise ValueError(f"material model {model.name!r}: its {', '.join(differ)} differ from its declaration "
                             "(fem/materials/warping_models.py): set declaration = DECLARED[name] on its class")
    return MODELS.register(model.name, model)


unregister = MODELS.unregister
LINEAR = register(Linear())
for _model in (ElementCorotated(), VertexWarped(), NeoHookean()):
    register(_model)
MODELS.seal()
assert set(DECLARED.built_in) <= set(MODELS), "every built-in name a scene may choose has its model"


def _load(name: str) -> MaterialModel:
    """The declared model ``name``, its module imported and the model registered on first use."""
    if name not in MODELS:
        found = load_object(DECLARED[name].implementation)
        model = found() if isinstance(found, type) else found
        if model.name != name:
            raise ValueError(f"material model declared as {name!r} loads {DECLARED[name].implementation!r}, named "
                             f"{model.name!r}: give its class declaration = DECLARED[{name!r}]")
        register(model)
    return MODELS[name]


def material_model(warp: bool, name: str) -> MaterialModel:
    """The model an integrator runs: the linear one without ``warp``, else the one registered (or declared) as
    ``name`` (ValueError naming the choices for any other)."""
    if (name not in MODELS and name not in DECLARED) or name == "linear":
        choices = [m for m in dict.fromkeys((*MODELS, *DECLARED)) if m != "linear"]
        raise ValueError(f"warping_model = {name!r}: choose one of {', '.join(choices)}"
                         " ('element': per-element corotation, conservative; 'vertex': the paper's per-vertex "
                         "warping, for comparison; 'neohookean': stable Neo-Hookean elements, smooth through "
                         "inversion, method 'clustered' only)")
    return _load(name) if warp else LINEAR
