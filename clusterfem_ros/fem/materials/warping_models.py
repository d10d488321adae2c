"""The warping models by name, declared (``MaterialDeclaration``: a name, the flags the set-up checks read, and
where its ``MaterialModel`` is, loaded when a body first runs it), and the acknowledgement the per-vertex one
needs. No numba, no scipy: the scene configuration (config.py) takes its choices and cross-checks from these
declarations and gives the integrators' refusals. A new scene-selectable model is one module holding its
``MaterialModel`` and one ``declare_material`` call. A scene's default,
'auto', stands for 'neohookean' on the clustered method and 'element' on the others (``auto_model``).

'element' (the integrators' default): per-element corotation (element_warping.py), the gradient of an energy,
so symplectic Euler keeps a shadow energy bounded (while no element is inverted: benchmarks/stability_table.py)
and damping only removes energy. 'vertex': the paper's per-vertex warping (eq. 10, symmetrised; warping.py).
Its force is not the gradient of any energy, and where neighbouring rotations differ sharply (a vertex torn
away and held, an inverting sliver) it feeds energy in: on the stability table it grew without bound in runs at
the scene's default damping too, and nothing known at set-up predicts which runs. So it is refused unless the
caller acknowledges that (``allow_unbounded_warping=True``; scene parameter
``physics.allow_unbounded_warping``), and then it runs as before, with one UnboundedWarpingWarning per process.
'neohookean': no rotation at all, the stable Neo-Hookean energy (fem/materials/neohookean.py), smooth through inversion,
where the corotated energy is not; on the clustered explicit method only (``explicit_only_refusal``). The
'element' model on an explicit method without any damping is refused too unless acknowledged
(``undamped_corotation_refusal``): undamped, the explicit step gains energy where its elements invert, and
keeps gaining while they stay inverted; damping removed that gain on every hard case, and the implicit step
damps it numerically.
"""
from __future__ import annotations

from dataclasses import dataclass

from ...registries import Registry


@dataclass(frozen=True)
class MaterialDeclaration:
    """A material model a scene may choose (``warping_model``), as the configuration checks it: its flags are its
    ``MaterialModel``'s (``MaterialModel.declaration`` takes them from here); ``implementation``
    ('package.module:Class') is imported when a body first runs it (fem/materials/registry.material_model)."""
    name: str
    implementation: str
    description: str = ""
    bounded: bool = True                        # False: refused unless acknowledged (vertex_refusal)
    undamped_explicit_refused: bool = False     # refused on an explicit method without damping, unacknowledged
    clustered_only: bool = False                # only the clustered explicit method runs it (explicit_only_refusal)
    needs_stretch_plan: bool = False            # refused with physics.plan_stretch false (stretch_plan_refusal)


DECLARED = Registry("material model")


def declare_material(declaration: MaterialDeclaration) -> MaterialDeclaration:
    """Make ``declaration.name`` a scene's choice of warping_model (a name already taken is refused); returns it."""
    return DECLARED.register(declaration.name, declaration)


_REGISTRY = "clusterfem_ros.fem.materials.registry"
for _declaration in (
        MaterialDeclaration("element", f"{_REGISTRY}:ElementCorotated",
                            "per-element corotation: the gradient of an energy", undamped_explicit_refused=True),
        MaterialDeclaration("vertex", f"{_REGISTRY}:VertexWarped", "the paper's per-vertex stiffness warping "
                            "(eq. 10, symmetrised): no energy of its own", bounded=False),
        MaterialDeclaration("neohookean", f"{_REGISTRY}:NeoHookean", "stable Neo-Hookean elements: no rotation, an "
                            "energy smooth through inversion", clustered_only=True, needs_stretch_plan=True)):
    declare_material(_declaration)
DECLARED.seal()
WARPING_MODELS = DECLARED.names()            # what a scene may choose: every declared model (a live view)
AUTO = "auto"                                # the scene's default: ``auto_model`` picks one of WARPING_MODELS
ACKNOWLEDGEMENT = "physics.allow_unbounded_warping"   # the scene parameter; integrators: allow_unbounded_warping


class UnboundedWarpingWarning(UserWarning):
    """The per-vertex warping model runs, acknowledged: its energy is not bounded by the work put in."""


def vertex_refusal() -> str:
    """Why ``warping_model = 'vertex'`` is refused, and the two ways out."""
    return ("warping_model = 'vertex' (the paper's per-vertex warping) is refused: its force is not the gradient "
            "of an energy and grew without bound on the stability table's torn-vertex and sliver cases, at the "
            "default damping too, which no set-up check predicts. Use warping_model 'auto' (the default), "
            "'neohookean' or 'element' (their forces are gradients of energies), or acknowledge the risk to compare "
            f"against the paper: {ACKNOWLEDGEMENT}: true (integrators: allow_unbounded_warping=True)")


def unbounded_refusal(name: str) -> str:
    """Why the unbounded model ``name`` is refused unacknowledged: ``vertex_refusal`` for 'vertex', the same ways
    out for another model declared ``bounded=False``."""
    if name == "vertex":
        return vertex_refusal()
    return (f"warping_model = {name!r} is refused: it is declared unbounded (its energy can grow beyond the work "
            "put in). Use warping_model 'auto' (the default), 'neohookean' or 'element', or acknowledge the risk: "
            f"{ACKNOWLEDGEMENT}: true (integrators: allow_unbounded_warping=True)")


def undamped_corotation_refusal(method: str, name: str = "element") -> str:
    """Why ``warping_model = name`` is refused on an explicit ``method`` without damping, and the ways out."""
    return (f"warping_model = {name!r} on the explicit method {method!r} without damping (mass_damping and "
            "stiffness_damping both 0) is refused: the corotated energy has no smooth rotation where elements "
            "invert, and there symplectic Euler gains energy for as long as they stay inverted (the stability "
            "table's undamped torn vertex: 5-8 % in 1 s, and growing). Use warping_model 'neohookean' (method "
            "'clustered'; what 'auto' runs there), give the material some damping, or acknowledge the risk: "
            f"{ACKNOWLEDGEMENT}: true (integrators: allow_unbounded_warping=True)")


def declared(name: str) -> MaterialDeclaration | None:
    """The declaration of a scene-selectable model, or None (the linear model, a test's own)."""
    return DECLARED.get(name)


def unacknowledged_undamped(name: str, warp: bool, xi: float, zeta: float, allow_unbounded: bool) -> bool:
    """True if an explicit set-up must be refused (``undamped_corotation_refusal``): a model declared
    ``undamped_explicit_refused`` ('element'), warped, with neither mass nor stiffness damping, not acknowledged."""
    d = declared(name)
    return (warp and d is not None and d.undamped_explicit_refused and xi == 0.0 and zeta == 0.0
            and not allow_unbounded)


def explicit_only_refusal(name: str, method: str) -> str:
    """Why ``warping_model = name`` is refused on ``method``, and the ways out."""
    return (f"warping_model = {name!r} runs on method 'clustered' only (its force has no implicit or standard "
            f"explicit step here), not on {method!r}: use method 'clustered', or warping_model 'element'")


def auto_model(method: str, error_budget: bool, plan_stretch: bool) -> str:
    """The model a scene's ``warping_model: auto`` runs: 'neohookean' on method 'clustered' (smooth through
    inversion, and the cheaper step: benchmarks/core_benchmark.py, benchmarks/stability_table.py); 'element' on
    the other methods, which do not run it, while an error budget is to choose the method (the point it chooses
    then sets warping_model: method_choice.WARPED_LABELS), and when the step is planned without the stretch
    (``stretch_plan_refusal``)."""
    return "neohookean" if method == "clustered" and not error_budget and plan_stretch else "element"


def stretch_plan_refusal(name: str) -> str:
    """Why ``warping_model = name`` is refused without the stretch plan, and the ways out."""
    return (f"warping_model = {name!r} with physics.plan_stretch false: its elements stiffen with the square of "
            "the stretch (fem/materials/stretch.py), and a step planned for the linear stiffness alone can diverge "
            "where an element is stretched: set physics.plan_stretch true, or warping_model 'element'")
