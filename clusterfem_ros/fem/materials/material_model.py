"""The contract of a material model: what an element's elastic force is, as every integrator asks it.

A model is an object (``MaterialModel``) registered by name (fem/materials/registry.py); a scene's
``warping_model`` names one, and ``warping: false`` runs the linear one. The integrators never compare a
model's name: they ask the object

- ``check``: whether a set-up may run it (its energy bounded by the work put in, damping, the method);
- ``clustered``: the arrays and compiled force pass the clustered explicit step runs around
  (``ClusteredParts``; fem/integrators/clustered_explicit.py builds the step from them), and, for a model whose
  step is planned from its first force's tangent bounds, where those bounds are;
- ``standard``: its force, rotations and stiffness for the standard explicit and implicit methods
  (``StandardParts``), or a refusal for a model only the clustered method runs;
- ``stretch_energy``: which stretch bound plans its explicit sub-steps (fem/materials/stretch.py);
- ``energy_function``: its elastic energy of a body, which /diagnostics reports;
- ``stress``: the stress of a state, which the node colours the surface by and publishes.

Adding a model a scene may choose: one module with a ``MaterialModel`` subclass whose ``declaration`` is its
``MaterialDeclaration`` (fem/materials/warping_models.py: the name and flags the configuration checks without
loading it), and one ``declare_material`` call; fem/materials/registry.material_model imports the module when a
body first runs the model. A model no scene names (a test's) is one ``register`` call. The parametrised tests
over the registry (tests/test_material_models.py) then test it.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..model import FemModel
from ..stability import StabilityError
from .stress import StressField, compute_stress
from .warping_models import (MaterialDeclaration, UnboundedWarpingWarning, explicit_only_refusal,
                             unbounded_refusal, undamped_corotation_refusal)


@dataclass
class ClusteredParts:
    """What the clustered explicit step of one body runs around, for one model."""
    frames: object                  # the model's per-body data (ElementFrames, VertexFrames) or None (linear)
    model_args: tuple               # the force pass's leading arguments (the step passes them through)
    w: np.ndarray                   # the pass's input rows (workspace)
    e: np.ndarray                   # the pass's output rows: K w, or its warped counterpart (workspace)
    warped_e: tuple | None          # (serial, threaded) builds of the warped pass, called as
                                    #   warped_e(*model_args, u, w, work); None: the linear cluster sweep
    build_suffix: str               # names this model's step builds apart in numba's cache
    bound: Callable[[], np.ndarray] | None = None
    # ^ the element tangent bounds by lane that the first force leaves (ElementFrames.rot_lanes, the bounds in its
    #   first LANES columns, negative where inverted): the step makes its first force before it plans (the
    #   Neo-Hookean plan, StretchPlan.element_factor); None: planned from the state (stretch.factor)
    later_e: tuple | None = None
    # ^ (serial, threaded) builds of the pass for a step's later sub-steps, which nothing plans from (the
    #   Neo-Hookean pass without its bounds: the same forces); None: warped_e


@dataclass
class StandardParts:
    """The model's force on the assembled (reference) methods, in numpy and scipy."""
    frames: object
    rotations: Callable[[np.ndarray], np.ndarray] | None                 # u -> its rotations R; None: it has none
    explicit_force: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]   # (u, v, R) -> f (n, 3)
    implicit_terms: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple]
    # ^ (u, v, R) -> (K_s, f, H): the stiffness of the linearly implicit system (PSD), the elastic-damping force
    #   (3n,), and the force's Jacobian by v's positions (the step subtracts h H v)
    implicit_max_nu: float | None = None        # the implicit step refuses a larger Poisson's ratio


class MaterialModel:
    """One material model; subclasses set the class attributes (a ``declaration`` sets the name, description and
    flags) and implement what they support."""
    declaration: MaterialDeclaration | None = None
    name: str = ""                  # the registry's key (a scene's warping_model)
    suffix: str = ""                # an integrator's name with it: 'clustered' + suffix
    description: str = ""
    bounded: bool = True            # False: its energy can grow without bound (refused unless acknowledged)
    undamped_explicit_refused: bool = False     # refused on an explicit method without any damping
    clustered_only: bool = False    # only the clustered explicit method runs it
    stretch_energy: str | None = None           # StretchPlan energy ('corotated', 'neohookean'); None: none
    rotation_invariant: bool = True             # a rigid rotation of the rest shape is force-free
    has_energy: bool = True                     # its force is the gradient of energy_function's energy
    needs_stretch_plan: bool = False            # a scene refuses it with physics.plan_stretch false

    FLAGS = ("name", "description", "bounded", "undamped_explicit_refused", "clustered_only", "needs_stretch_plan")

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        d = cls.__dict__.get("declaration")
        if d is not None:                       # the declaration's name and flags are the class's, set once
            for flag in cls.FLAGS:
                setattr(cls, flag, getattr(d, flag))

    def check(self, allow_unbounded: bool = False, method: str = "clustered", material=None) -> None:
        """Refuse a set-up this model may not run: StabilityError for an unbounded model not acknowledged and
        (given the explicit method's ``material``) for a model refused undamped, ValueError for a method that
        does not run it. An acknowledged unbounded model warns: once per process under Python's default warning
        filter (one call site, one message per model)."""
        if not self.bounded:
            if not allow_unbounded:
                raise StabilityError(unbounded_refusal(self.name))
            warnings.warn(f"warping_model = {self.name!r} runs with allow_unbounded_warping: its energy is not "
                          "bounded by the work put in (fem/materials/warping_models.py)", UnboundedWarpingWarning,
                          stacklevel=1)
        if (material is not None and self.undamped_explicit_refused and not allow_unbounded
                and float(material.xi) == 0.0 and float(material.zeta) == 0.0):
            raise StabilityError(undamped_corotation_refusal(method, self.name))
        if self.clustered_only and method != "clustered":
            raise ValueError(explicit_only_refusal(self.name, method))

    def clustered(self, model: FemModel) -> ClusteredParts:
        raise ValueError(f"material model {self.name!r} has no clustered explicit step: run it on method "
                         "'standard_explicit' or 'implicit_direct'")

    def standard(self, model: FemModel) -> StandardParts | None:
        """None: the linear force of the assembled K (the methods' own path)."""
        raise ValueError(explicit_only_refusal(self.name, "standard"))

    def stress(self, model: FemModel, u: np.ndarray) -> StressField:
        """The stress of displacement u [Pa]: the linear stress of each element's strain measured in its rotated
        frame (fem/materials/stress.py, corotated), which every warped model here reports; the small-strain
        stress of the Neo-Hookean model as well."""
        return compute_stress(model, u, corotated=True)

    def energy_function(self, model: FemModel) -> Callable[[np.ndarray], float]:
        """u -> the body's elastic energy [J] (what a body needs for it made once, here)."""
        raise NotImplementedError(f"material model {self.name!r} has no energy")
