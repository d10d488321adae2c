"""Every registered material model on every method that runs it, by its contract (fem/materials/material_model.py):
its force is the gradient of its energy, a rigid motion is force-free, a small strain gives the linear force,
and a model only some methods run is refused by the others. A model is tested here by being registered: the
toy St. Venant-Kirchhoff model below is one module's worth of numpy and a ``register`` call."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.assembly import shape_gradients
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.materials import registry
from clusterfem_ros.fem.materials.corotational import deformation_gradients
from clusterfem_ros.fem.materials.material_model import MaterialModel, StandardParts
from clusterfem_ros.fem.materials.warping_models import DECLARED, MaterialDeclaration, declare_material
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.fem.stability import StabilityError

METHODS = ("clustered", "standard_explicit", "implicit_direct")
H = 1e-7            # a step this short is one sub-step whose velocity is h M^-1 f(u) to O(h^2)


class StVenantKirchhoff(MaterialModel):
    """Psi = mu E:E + lambda/2 tr(E)^2, E = (F^T F - I) / 2: rotation invariant, not stable under inversion; a
    numpy force for the standard methods only (the toy of this test, not a model of the package)."""
    name = "toy_stvk"
    suffix = "_toy_stvk"

    def _gradients(self, model, u):
        g, vol = model.rest_gradients
        return deformation_gradients(g, model.mesh.tets, u), g, vol

    def energy_function(self, model):
        lam, mu = model.material.lame

        def energy(u):
            F, _, vol = self._gradients(model, u)
            E = 0.5 * (np.einsum("eai,eaj->eij", F, F) - np.eye(3))
            return float(vol @ (mu * np.einsum("eij,eij->e", E, E) + 0.5 * lam * np.trace(E, axis1=1, axis2=2) ** 2))
        return energy

    def standard(self, model):
        lam, mu = model.material.lame
        tets = model.mesh.tets

        def force(u, v, R):
            F, g, vol = self._gradients(model, u)
            E = 0.5 * (np.einsum("eai,eaj->eij", F, F) - np.eye(3))
            P = F @ (2.0 * mu * E + lam * np.trace(E, axis1=1, axis2=2)[:, None, None] * np.eye(3))
            fc = -np.einsum("e,eab,ecb->eca", vol, P, g)
            f = np.zeros_like(u)
            np.add.at(f, tets.reshape(-1), fc.reshape(-1, 3))
            return f - model.material.xi * model.mass[:, None] * v

        # the linearly implicit step with the rest stiffness K (a valid, if first-order, scheme)
        return StandardParts(None, None, force,
                             lambda u, v, R: (model.K, force(u, v, R).reshape(-1), model.K))


@pytest.fixture(scope="module", autouse=True)
def toy():
    registry.register(StVenantKirchhoff())
    yield
    registry.unregister("toy_stvk")


@pytest.fixture(scope="module")
def model():
    return build_model(box_mesh((0.2, 0.1, 0.1), (4, 2, 2)), Material(E=3e4, nu=0.3, rho=1000.0, xi=0.0, zeta=0.0),
                       gravity=(0.0, 0.0, 0.0))


def _models():
    return [m for m in registry.MODELS] + ["toy_stvk"]


def _integrator(method, model, name):
    warp = name != "linear"
    return make_integrator(method, model, warp=warp, warping_model=name if warp else "element",
                           allow_unbounded_warping=True)


def _force(integ, model, u):
    """f(u) at rest velocity, read from one short step: v1 = h M^-1 f(u0)."""
    state = State.rest(model)
    state.u[:] = u
    integ.step(state, Control(), H)
    return model.mass[:, None] * state.v / H


def _runs(method, name):
    model = registry.MODELS.get(name)
    return model is not None and not (model.clustered_only and method != "clustered") and not (
        method == "clustered" and type(model).clustered is MaterialModel.clustered)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", _models())
def test_the_force_is_minus_the_gradient_of_the_energy(model, method, name):
    material = registry.MODELS[name]
    if not _runs(method, name) or not material.has_energy:
        pytest.skip(f"{name} does not run on {method}" if not _runs(method, name) else f"{name} has no energy")
    rng = np.random.default_rng(11)
    u = 0.01 * rng.standard_normal((model.n_vertices, 3))
    f = _force(_integrator(method, model, name), model, u)
    energy = material.energy_function(model)
    for _ in range(3):
        d = rng.standard_normal(u.shape)
        eps = 1e-6
        slope = (energy(u + eps * d) - energy(u - eps * d)) / (2 * eps)
        assert -np.vdot(f, d) == pytest.approx(slope, rel=2e-5, abs=1e-9 * np.abs(f).sum()), (name, method)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", _models())
def test_a_rigid_motion_is_force_free_and_a_small_strain_gives_the_linear_force(model, method, name):
    if not _runs(method, name):
        pytest.skip(f"{name} does not run on {method}")
    material = registry.MODELS[name]
    integ = _integrator(method, model, name)
    x0 = model.rest
    turn = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix() if material.rotation_invariant else np.eye(3)
    rigid = (x0 - x0.mean(0)) @ turn.T + x0.mean(0) + [0.05, -0.02, 0.1] - x0
    scale = np.abs(_force(_integrator(method, model, "linear"), model, 1e-3 * x0)).max()
    assert np.abs(_force(integ, model, rigid)).max() < 1e-8 * scale, (name, method)
    rng = np.random.default_rng(5)
    small = 1e-7 * rng.standard_normal(x0.shape)
    linear = -(model.K @ small.reshape(-1)).reshape(-1, 3)
    got = _force(integ, model, small)
    assert np.abs(got - linear).max() < 1e-4 * np.abs(linear).max(), (name, method)


@pytest.mark.parametrize("method", METHODS[1:])
def test_a_model_only_the_clustered_method_runs_is_refused_by_the_others_saying_so(model, method):
    for name, material in registry.MODELS.items():
        if material.clustered_only:
            with pytest.raises(ValueError, match=f"runs on method 'clustered' only.*{method}"):
                _integrator(method, model, name)


def test_a_model_without_a_clustered_step_is_refused_by_the_clustered_method(model):
    with pytest.raises(ValueError, match="toy_stvk.*no clustered explicit step"):
        _integrator("clustered", model, "toy_stvk")


def test_every_name_a_scene_may_choose_has_a_model_and_a_name_is_registered_once():
    from clusterfem_ros.fem.materials.warping_models import WARPING_MODELS
    assert set(WARPING_MODELS) <= set(registry.MODELS)
    with pytest.raises(ValueError, match="taken"):
        registry.register(StVenantKirchhoff())
    with pytest.raises(ValueError, match="choose one of"):
        registry.material_model(True, "no_such_model")


@pytest.mark.parametrize("name", _models())
def test_the_stress_of_a_rigid_motion_is_zero_and_of_a_small_strain_the_linear_one(model, name):
    material = registry.MODELS[name]
    x0 = model.rest
    turn = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix() if material.rotation_invariant else np.eye(3)
    rigid = (x0 - x0.mean(0)) @ turn.T + x0.mean(0) + [0.05, -0.02, 0.1] - x0
    small = 1e-6 * np.random.default_rng(9).standard_normal(x0.shape)
    linear = registry.LINEAR.stress(model, small).element_von_mises
    assert linear.max() > 0
    assert material.stress(model, rigid).element_von_mises.max() < 1e-9 * model.material.E
    assert np.allclose(material.stress(model, small).element_von_mises, linear, rtol=1e-4, atol=1e-12 * linear.max())


TOY_DECLARATION = MaterialDeclaration("toy_declared", f"{__name__}:DeclaredStVenantKirchhoff",
                                      "a declared toy St. Venant-Kirchhoff model", undamped_explicit_refused=True)


class DeclaredStVenantKirchhoff(StVenantKirchhoff):
    """The toy model made a scene's choice: its declaration is all the configuration reads."""
    declaration = TOY_DECLARATION
    suffix = "_toy_declared"


def test_a_declared_model_is_a_scene_choice_checked_by_its_flags_and_loaded_when_first_run(model):
    """One declaration makes a model a scene's choice: the configuration offers it, refuses it where its flags
    say (undamped on an explicit method), and the integrator loads its module on first use."""
    from clusterfem_ros.config import PARAMS, ConfigError, SceneConfig
    declare_material(TOY_DECLARATION)
    try:
        assert "toy_declared" in next(p for p in PARAMS if p.name == "warping_model").choices
        assert "toy_declared" not in registry.MODELS                        # declared, not loaded
        scene = {"method": "standard_explicit", "warping_model": "toy_declared"}
        assert SceneConfig().with_values(scene).warping_model == "toy_declared"
        with pytest.raises(ConfigError, match="warping_model = 'toy_declared' on the explicit method"):
            SceneConfig().with_values({**scene, "material.mass_damping": 0.0, "material.stiffness_damping": 0.0})
        with pytest.raises(StabilityError, match="'toy_declared' on the explicit method"):    # undamped model
            make_integrator("standard_explicit", model, warp=True, warping_model="toy_declared")
        integ = make_integrator("standard_explicit", model, warp=True, warping_model="toy_declared",
                                allow_unbounded_warping=True)
        assert isinstance(registry.MODELS["toy_declared"], StVenantKirchhoff) and integ.name.endswith("_toy_declared")
        u = 0.01 * np.random.default_rng(2).standard_normal((model.n_vertices, 3))
        assert np.allclose(_force(integ, model, u), registry.MODELS["toy_stvk"].standard(model).explicit_force(
            u, np.zeros_like(u), None), rtol=1e-4, atol=1e-9)
    finally:
        DECLARED.unregister("toy_declared")
        registry.MODELS.pop("toy_declared", None)
    with pytest.raises(ConfigError, match="choose one of"):
        SceneConfig().with_values(warping_model="toy_declared")


def test_a_model_registered_under_a_declared_name_must_carry_its_flags():
    class Impostor(MaterialModel):
        name = "neohookean"             # the declared name, without its declaration's flags
    with pytest.raises(ValueError, match="'neohookean': its description, clustered_only, needs_stretch_plan differ"):
        registry.register(Impostor())


def test_the_scene_configuration_reads_the_declarations_without_numba():
    """config.py checks a scene against the declarations alone: no kernel is compiled or imported for it."""
    import subprocess
    import sys
    code = ("import sys, clusterfem_ros.config as c; c.SceneConfig().with_values(method='implicit_direct'); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'pinocchio')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
