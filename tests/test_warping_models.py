"""The per-vertex warping model is refused at set-up unless acknowledged; acknowledged, it runs and warns once."""
import warnings

import numpy as np
import pytest

from clusterfem_ros import config
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.fem.stability import StabilityError
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from clusterfem_ros.fem.materials.warping_models import ACKNOWLEDGEMENT, UnboundedWarpingWarning
from clusterfem_ros.scene_build import integrator_choice

METHODS = ("clustered", "standard_explicit", "implicit_direct", "implicit_cg")


@pytest.fixture(scope="module")
def model():
    mesh = box_mesh((0.2, 0.05, 0.05), (4, 1, 1))
    return build_model(mesh, Material(E=1e5), fixed=np.isclose(mesh.vertices[:, 0], 0.0))


@pytest.mark.parametrize("method", METHODS)
def test_vertex_warping_is_refused_at_set_up_with_the_reason_and_the_ways_out(model, method):
    with pytest.raises(StabilityError) as err:
        make_integrator(method, model, warp=True, warping_model="vertex")
    text = str(err.value)
    assert "warping_model = 'vertex'" in text and "not the gradient of an energy" in text
    assert "'element'" in text and ACKNOWLEDGEMENT in text and "allow_unbounded_warping=True" in text


@pytest.mark.parametrize("method", METHODS)
def test_acknowledged_vertex_warping_runs_and_warns(model, method):
    with pytest.warns(UnboundedWarpingWarning, match="not bounded"):
        integ = make_integrator(method, model, warp=True, warping_model="vertex", allow_unbounded_warping=True)
    assert integ.warping_model == "vertex" and "vertex" in integ.name
    state = State.rest(model)
    for _ in range(5):
        integ.step(state, Control(), 1e-3)
    assert np.isfinite(state.u).all() and state.u[:, 2].min() < 0.0       # it sags under gravity


def test_the_warning_is_given_once_per_process_under_the_default_filter(model):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        for method in METHODS:
            make_integrator(method, model, warp=True, warping_model="vertex", allow_unbounded_warping=True)
    assert [w.category for w in caught] == [UnboundedWarpingWarning]


def test_no_refusal_without_warping_or_with_the_element_model(model):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        make_integrator("clustered", model, warp=False, warping_model="vertex")     # nothing is warped
        make_integrator("clustered", model, warp=True, warping_model="element")


def test_the_scene_config_refuses_vertex_warping_unless_acknowledged():
    with pytest.raises(config.ConfigError, match=f"warping_model = 'vertex'.*{ACKNOWLEDGEMENT}: true"):
        config.from_mapping({"warping_model": "vertex"})
    ok = config.from_mapping({"warping_model": "vertex", ACKNOWLEDGEMENT: True})
    assert ok.physics.allow_unbounded_warping is True
    assert integrator_choice(ok)[1]["allow_unbounded_warping"] is True
    for other in ({"warping": False}, {"method": "modal"}):        # no per-vertex force is ever made
        assert config.from_mapping({"warping_model": "vertex", **other})["warping_model"] == "vertex"
    assert config.SceneConfig().physics.allow_unbounded_warping is False
    assert integrator_choice(config.SceneConfig())[1]["allow_unbounded_warping"] is False


def test_auto_runs_neohookean_on_the_clustered_method_and_element_where_that_cannot_run():
    """The scene's default 'auto': the Neo-Hookean elements on method 'clustered'; the per-element corotation on
    the methods without a Neo-Hookean step, with an error budget (it chooses among points measured with
    'element') and without the stretch plan (which the Neo-Hookean step needs, and is refused without)."""
    default = config.SceneConfig()
    assert default["warping_model"] == "auto" and default.method == "clustered"
    assert default.warping_model == "neohookean"
    assert integrator_choice(default)[1]["warping_model"] == "neohookean"
    for other in ({"method": "standard_explicit"}, {"method": "implicit_direct"}, {"method": "implicit_cg"},
                  {"budget.max_error_mm": 5.0}, {"physics.plan_stretch": False}):
        assert default.with_values(other).warping_model == "element", other
    with pytest.raises(config.ConfigError, match="'neohookean' with physics.plan_stretch false.*plan_stretch true"):
        config.from_mapping({"warping_model": "neohookean", "physics.plan_stretch": False})
    assert config.from_mapping({"warping_model": "element", "physics.plan_stretch": False}).warping_model == "element"


def test_a_recording_keeps_the_model_auto_ran(tmp_path):
    """What the node writes beside a bag (SceneConfig.resolved): the model by name (and the pressure's kappa), so
    the replay runs them whatever the defaults become; everything else as given."""
    c = config.SceneConfig().with_values(body__kind="torus", skeleton__source="none")
    f = tmp_path / "scene.yaml"
    f.write_text(config.scene_file_text(c.resolved()))
    back = config.load_scene_file(f)
    assert back["warping_model"] == "neohookean"
    assert back["material.volume_stiffness"] == 0.0     # 'auto' on a torus: none (tests/test_volume_pressure.py)
    auto = ("warping_model", "material.volume_stiffness")
    assert {k: v for k, v in back.values.items() if k not in auto} == \
        {k: v for k, v in c.values.items() if k not in auto}


def test_undamped_corotated_elements_on_an_explicit_method_are_refused_unless_acknowledged():
    """The 'element' model on an explicit method with neither mass nor stiffness damping: refused at set-up,
    naming the ways out; runs when acknowledged, with any damping, on the implicit methods, and the default
    ('auto': Neo-Hookean on the clustered method) runs undamped."""
    mesh = box_mesh((0.2, 0.05, 0.05), (4, 1, 1))
    undamped = build_model(mesh, Material(E=1e5, xi=0.0, zeta=0.0), fixed=np.isclose(mesh.vertices[:, 0], 0.0))
    for method in ("clustered", "standard_explicit"):
        with pytest.raises(StabilityError, match=f"'element' on the explicit method '{method}' without damping"
                                                 f".*'neohookean'.*damping.*{ACKNOWLEDGEMENT}: true"):
            make_integrator(method, undamped, warp=True, warping_model="element")
        make_integrator(method, undamped, warp=True, warping_model="element", allow_unbounded_warping=True)
        make_integrator(method, undamped)                                      # linear: no rotation
    make_integrator("implicit_direct", undamped, warp=True, warping_model="element")
    make_integrator("clustered", undamped, warp=True, warping_model="neohookean")
    for damping in ({"xi": 0.5, "zeta": 0.0}, {"xi": 0.0, "zeta": 1e-5}):
        damped = build_model(mesh, Material(E=1e5, **damping), fixed=np.isclose(mesh.vertices[:, 0], 0.0))
        make_integrator("clustered", damped, warp=True, warping_model="element")
    still = {"material.mass_damping": 0.0, "material.stiffness_damping": 0.0}
    with pytest.raises(config.ConfigError, match="'element' on the explicit method 'clustered' without damping"):
        config.from_mapping({**still, "warping_model": "element"})
    with pytest.raises(config.ConfigError, match="'standard_explicit' without damping"):
        config.from_mapping({**still, "method": "standard_explicit"})              # 'auto' is 'element' there
    assert config.from_mapping({**still}).warping_model == "neohookean"
    assert config.from_mapping({**still, "warping_model": "element", ACKNOWLEDGEMENT: True})
    assert config.from_mapping({**still, "method": "implicit_direct"}).warping_model == "element"
