"""scene_setup: the parts a scene runs, set up from the chosen parts; the scene's constructor builds nothing."""
import numpy as np
import pytest

from clusterfem_ros.config import ConfigError, SceneConfig
from clusterfem_ros.fem.mesh.tet_mesh import MeshError
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
from clusterfem_ros.scene import Scene
from clusterfem_ros.scene_build import scene_parts
from clusterfem_ros.scene_setup import set_up, warm_up
from clusterfem_ros.skeleton.procedural_walk import procedural_walk

SPHERE = paper_mesh("sphere").vertices
CAP = [float(SPHERE[:, 0].mean()), float(SPHERE[:, 1].mean()), float(SPHERE[:, 2].max())]   # the top's centre


def _walk(scene: Scene, seconds: float = 0.2) -> None:
    """The built-in walk's samples, 120 Hz, through take_joint_state on the input clock."""
    walk = procedural_walk(seconds, names=scene.skeleton.joint_names)
    for t, q in zip(walk.times, walk.positions):
        scene.take_joint_state(50.0 + t, walk.names, q, None, received=50.0 + t)


CASES = {
    "walking jelly man": dict(body__target_tets=700, physics__clock="input", warping=False),
    "walking warped jelly man": dict(body__target_tets=700, physics__clock="input", warping=True),
    "anchored sphere": dict(skeleton__source="none", body__kind="sphere", body__fix_bottom=False, warping=False,
                            anchors__points=CAP, anchors__radius=0.05),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_warming_up_leaves_nothing_behind_in_the_scene_but_the_warm_start_of_the_rotations(case):
    """Scenes set up from the same parts, warmed up once (as Scene.build does), twice with other step counts, or
    not at all, step to the same states (the walk, or 150 steps of a sphere hanging from its anchors): the
    warm-up steps a throw-away state and resets the driver's history. Bit for bit without warping; with element
    warping to round-off only, because each element's last rotation (fem/materials/element_warping.py, the polar
    iteration's warm start) is kept from the warm-up's last step."""
    parts = scene_parts(SceneConfig().with_values(**CASES[case]))
    states = []
    for warm_ups in ((), (40,), (3, 11)):
        running = set_up(parts)
        scene = Scene(running)
        for steps in warm_ups:
            warm_up(running, lambda state: scene._control(0.0, state), scene.h, steps=steps)
        if scene.skeleton is not None:
            _walk(scene)
        else:
            scene.advance_to(0.0)
            scene.advance_to(150 * scene.h)
        assert scene.steps_done >= 150 and scene.output_problem() is None
        states.append((scene.state.u.copy(), scene.state.v.copy()))
    assert np.abs(states[0][0]).max() > 1e-4                      # the body moved
    atol = 1e-13 if parts.config.warping else 0.0
    for u, v in states[1:]:
        np.testing.assert_allclose(u, states[0][0], atol=atol, rtol=0.0)
        np.testing.assert_allclose(v, states[0][1], atol=1e3 * atol, rtol=0.0)


def test_world_anchors_without_a_skeleton_hold_their_vertices_at_rest_with_the_configured_gains():
    config = SceneConfig().with_values(skeleton__source="none", body__kind="sphere", body__fix_bottom=False,
                                       warping=False, anchors__points=CAP, anchors__radius=0.05,
                                       anchors__kp=2.5e4, anchors__kd=150.0)
    running = set_up(scene_parts(config))
    assert running.skeleton is running.binding is running.driver is running.joints is running.stream is None
    near = np.flatnonzero(np.linalg.norm(running.model.rest - CAP, axis=1) <= 0.05)
    att = running.anchored
    assert sorted(att.index.tolist()) == sorted(a.vertex for a in running.anchors) == near.tolist()
    np.testing.assert_array_equal(att.target_u, 0.0)
    assert (att.kp == 2.5e4).all() and (att.kd == 150.0).all()


def test_the_surface_the_outputs_show_is_the_boundary_renumbered():
    running = set_up(scene_parts(SceneConfig().with_values(skeleton__source="none", body__kind="cube")))
    tris, verts, local = running.triangles, running.surface_vertices, running.surface_triangles
    np.testing.assert_array_equal(verts[local], tris)
    assert np.array_equal(verts, np.unique(tris)) and local.max() == verts.size - 1


def test_the_set_up_says_the_tet_quality_and_refuses_a_degenerate_tet_with_the_way_out():
    """One log line with the worst quality and the slivers; a mesh with a flat tet is refused at set-up, naming
    the parameter that accepts it, and runs with it."""
    said = []
    running = set_up(scene_parts(SceneConfig().with_values(skeleton__source="none", body__kind="cube")), said.append)
    q = running.model.quality
    assert [line for line in said if line.startswith("tet quality") and f"worst {q.worst:.3g}" in line
            and f"{q.slivers} sliver" in line]
    config = SceneConfig().with_values(skeleton__source="none", body__kind="cube", body__min_tet_quality=0.9)
    with pytest.raises(MeshError, match=r"tet \d+ has quality .*body.min_tet_quality"):
        set_up(scene_parts(config))


_LOOP_LOADS_NOTHING = r"""
import sys
import numba
import numpy as np
import clusterfem_ros
from clusterfem_ros.config import ConfigError, SceneConfig
from clusterfem_ros.scene import Scene
from clusterfem_ros.skeleton.procedural_walk import procedural_walk

def dispatchers():  # every compiled function of the package, also those a module keeps in tuples (a step's builds)
    found = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("clusterfem_ros"):
            for attr, obj in vars(module).items():
                for k, o in enumerate(obj if isinstance(obj, tuple) else (obj,)):
                    if isinstance(o, numba.core.registry.CPUDispatcher):
                        found[f"{name}.{attr}[{k}]"] = o
    return found

def record_calls(found, called):  # module attributes: what Python code calls by global name (not the step builds)
    for key, d in found.items():
        name, rest = key.rsplit(".", 1)
        attr = rest.split("[")[0]
        module = sys.modules[name]
        if isinstance(vars(module)[attr], tuple):
            continue
        def wrapper(*a, _d=d, _key=key, **kw):
            called.add(_key)
            return _d(*a, **kw)
        setattr(module, attr, wrapper)

def walk_on(scene, walk, part):
    for t, q in zip(walk.times[part], walk.positions[part]):
        scene.take_joint_state(50.0 + t, walk.names, q, None, received=50.0 + t)
        scene.advance_to(50.0 + t + 1e-3 * 8)
        assert scene.output_problem() is None

scene = Scene.build(SceneConfig().with_values(body__target_tets=700, warping=True))
found = dispatchers()
before = {k: len(d.signatures) for k, d in found.items()}
walk = procedural_walk(0.3, names=scene.skeleton.joint_names)
half = walk.times.size // 2
walk_on(scene, walk, slice(0, half))
after = {k: len(d.signatures) for k, d in found.items()}
new = sorted(k for k in after if after[k] > before.get(k, 0))
print("LOADED IN THE LOOP:", new)
called = set()       # the second half with the calls recorded (wrappers: nothing may compile now)
record_calls(found, called)
walk_on(scene, walk, slice(half, None))
print("CALLED FROM PYTHON:", sorted(called))
print("RELEASE THE GIL:", sorted(k for k in called if found[k].targetoptions.get("nogil")))
"""


@pytest.fixture(scope="module")
def step_loop_run():
    """The script above in a fresh process (nothing loaded before the build): its output."""
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", _LOOP_LOADS_NOTHING], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def test_a_built_scene_has_loaded_every_kernel_its_step_loop_calls(step_loop_run):
    """Scene.build loads (on a machine's first start: compiles) every compiled function the physics thread's loop
    calls: the step's, the driver's, the kinematics' and the output checks'. One it misses is compiled in the
    loop, and the node's first run stalls a second and drops its inputs. A fresh process, so nothing is loaded
    before the build."""
    assert "LOADED IN THE LOOP: []" in step_loop_run, step_loop_run[-2000:]


def test_the_step_loop_lets_the_gil_go_only_in_the_integrator_step(step_loop_run):
    """The compiled functions the physics thread's loop calls from Python between its steps (kinematics, the
    driver's targets, the stretch bound, the output checks) keep the GIL: a thread that lets it go for a few
    microseconds then waits its turn to get it back, behind the executor and every other body's physics thread
    (numba_config.HOLDS_GIL). Only the integrator's step (its builds are held by the integrator, not called by
    a global name, so they are not recorded here) lets it go. The loop must call some compiled functions, or
    the recording missed them."""
    called = step_loop_run.split("CALLED FROM PYTHON:")[1].splitlines()[0]
    assert "tree_forward" in called and "_bone_targets" in called, step_loop_run[-2000:]
    assert "RELEASE THE GIL: []" in step_loop_run, step_loop_run[-2000:]


def slid_cube(config, skeleton, urdf_xml, leaf_shapes, progress):
    """The builder of the toy body kind below: the paper's cube, slid 1 m along x."""
    from clusterfem_ros import scene_build
    from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
    mesh = paper_mesh("cube", config.body.scale)
    mesh = type(mesh)(mesh.vertices + [1.0, 0.0, 0.0], mesh.tets)
    return scene_build.SceneParts(config, mesh, np.zeros(mesh.n_vertices, dtype=bool), skeleton, urdf_xml)


def test_body_kinds_are_declared_and_a_new_kind_builds_a_scene_by_being_declared():
    """Every body.kind a scene may choose is declared (body_kinds.py) and builds through scene_build.body_kind;
    a kind of one's own (this module's ``slid_cube``) is chosen, checked and built by one declaration alone:
    the configuration offers it and refuses it without the skeleton it declares it needs."""
    from clusterfem_ros import body_kinds, config as config_module, scene_build
    from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
    assert tuple(body_kinds.BODY_DECLARATIONS) == tuple(config_module.BODIES) == tuple(
        next(p for p in config_module.PARAMS if p.name == "body.kind").choices)
    assert all(scene_build.body_kind(name).declaration is d for name, d in body_kinds.BODY_DECLARATIONS.items())
    toy = body_kinds.declare_body_kind(body_kinds.BodyDeclaration("slid_cube", f"{__name__}:slid_cube"))
    try:
        config = SceneConfig().with_values({"skeleton.source": "none", "body.kind": "slid_cube"})
        assert "slid_cube" in config_module.BODIES
        parts = scene_build.scene_parts(config)
        cube = paper_mesh("cube", config.body.scale).vertices
        assert np.array_equal(parts.mesh.vertices, cube + [1.0, 0.0, 0.0]) and not parts.fixed.any()
        with pytest.raises(ValueError, match="taken"):
            body_kinds.declare_body_kind(toy)
    finally:
        body_kinds.BODY_DECLARATIONS.unregister("slid_cube")
        scene_build.BODY_KINDS.pop("slid_cube", None)
    with pytest.raises(ConfigError, match="choose one of"):
        SceneConfig().with_values({"skeleton.source": "none", "body.kind": "slid_cube"})
    needy = body_kinds.declare_body_kind(body_kinds.BodyDeclaration("needy", f"{__name__}:slid_cube",
                                                                    needs_skeleton=True))
    try:
        with pytest.raises(ConfigError, match="'needy' is built around a skeleton"):
            SceneConfig().with_values({"skeleton.source": "none", "body.kind": needy.name})
    finally:
        body_kinds.BODY_DECLARATIONS.unregister("needy")


def test_a_body_kind_whose_builder_does_not_load_is_refused_naming_it():
    from clusterfem_ros import body_kinds, scene_build
    body_kinds.declare_body_kind(body_kinds.BodyDeclaration("lost", "no_such_module:build"))
    try:
        with pytest.raises(ValueError, match="'no_such_module:build' does not load"):
            scene_build.body_kind("lost")
    finally:
        body_kinds.BODY_DECLARATIONS.unregister("lost")


def test_mass_scaling_is_set_up_for_one_sub_step_within_its_share_and_says_what_it_added():
    """physics.mass_scaling > 0: the model carries the added mass, within the share, and the integrator plans with
    it (a longer critical step, one log line with the count and the share); 0: nothing added, nothing said."""
    base = dict(skeleton__source="none", body__kind="cube", warping=False)
    plain = set_up(scene_parts(SceneConfig().with_values(**base)))
    h0 = plain.integrator.critical_step()
    assert plain.model.added_mass is None
    said = []
    step = 2.0 * h0            # safety 0.8: 3 sub-steps unscaled; the goal is one
    running = set_up(scene_parts(SceneConfig().with_values(**base, physics__step=step, physics__mass_scaling=0.02)),
                     said.append)
    added = running.model.added_mass
    share = float(added.sum() / plain.model.mass.sum())
    assert 0.0 < share <= 0.02 + 1e-9
    np.testing.assert_allclose(running.model.mass - added, plain.model.mass)
    assert running.integrator.critical_step() > h0
    line = [s for s in said if s.startswith("mass scaling")]
    assert len(line) == 1 and f"{int((added > 0).sum())} vertices" in line[0] and f"{share:.2%}" in line[0]
