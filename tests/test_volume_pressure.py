"""The whole volume's pressure (fem/volume_pressure.py): its volume is the tets' signed volume, its force the
gradient of its energy, zero at rest and in rigid motion, without net force or torque; its mode's rate is the
one it plans with, a kappa too stiff for the step is lowered and said, and on a squeezed bar it keeps the volume
the elements alone give up."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.fem.integrators.clustered_explicit import ClusteredExplicit
from clusterfem_ros.fem.linear.material import Material, ParameterError
from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from clusterfem_ros.fem.model import Attachments, Control, State, build_model
from clusterfem_ros.fem.volume_pressure import MAX_OMEGA_H, volume_pressure
from clusterfem_ros.scene import Scene

MATERIAL = Material(E=3e4, nu=0.3, rho=1000.0, xi=1.0, zeta=1e-5)
H = 1e-3


def bar(material=MATERIAL):
    return build_model(box_mesh((0.4, 0.1, 0.1), (8, 2, 2)), material, gravity=(0.0, 0.0, 0.0))


def wobble(model, scale, seed=0):
    """A displacement of ``scale`` m in every vertex, random but smooth enough to keep every tet positive."""
    rng = np.random.default_rng(seed)
    return scale * rng.standard_normal(model.rest.shape)


def test_the_enclosed_volume_is_the_tets_total_signed_volume():
    model = bar()
    p = volume_pressure(model, 1.0, H)
    u = wobble(model, 0.003) - 0.1 * (model.rest - model.rest.mean(axis=0))
    assert p.volume(np.zeros_like(u)) == pytest.approx(p.rest_volume, rel=1e-13)
    assert p.volume(u) == pytest.approx(signed_volumes(model.rest + u, model.mesh.tets).sum(), rel=1e-12)
    assert p.volume(u) < 0.8 * p.rest_volume          # the squeeze is a real change of volume


def test_the_force_is_minus_the_gradient_of_its_energy():
    model = bar()
    p = volume_pressure(model, 1.0, H)
    u = wobble(model, 0.003, seed=1) - 0.05 * (model.rest - model.rest.mean(axis=0))
    f = p.force(u).copy()
    assert np.abs(f).max() > 0
    rng = np.random.default_rng(2)
    for _ in range(5):
        d = rng.standard_normal(u.shape)
        eps = 1e-6
        slope = (p.energy(u + eps * d) - p.energy(u - eps * d)) / (2 * eps)
        assert -slope == pytest.approx(float(np.sum(f * d)), rel=1e-6)


def test_zero_at_rest_and_in_rigid_motion_and_no_net_force_or_torque():
    model = bar()
    p = volume_pressure(model, 1.0, H)
    squeezed = p.force(-0.05 * (model.rest - model.rest.mean(axis=0))).copy()
    scale = np.abs(squeezed).max()
    assert np.abs(p.force(np.zeros_like(model.rest))).max() <= 1e-12 * scale
    R = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    moved = model.rest @ R.T + np.array([3.0, -2.0, 5.0])
    assert np.abs(p.force(moved - model.rest)).max() <= 1e-9 * scale
    u = wobble(model, 0.004, seed=3) - 0.05 * (model.rest - model.rest.mean(axis=0))
    f = p.force(u).copy()
    x = model.rest + u
    assert np.abs(f.sum(axis=0)).max() <= 1e-12 * np.abs(f).sum()
    assert np.abs(np.cross(x, f).sum(axis=0)).max() <= 1e-12 * np.abs(f).sum() * np.abs(x).max()


def test_the_mode_rate_is_the_rayleigh_quotient_of_its_stiffness():
    model = bar()
    p = volume_pressure(model, 3.0, H)
    p.volume(np.zeros_like(model.rest))
    d = p._grad / 6.0 / model.mass[:, None]           # the mode: M^-1 dV/dx (the buffer holds 6 dV/dx)
    eps = 1e-7
    stiffness = -float(np.sum(p.force(eps * d) * d)) / eps
    assert stiffness / float(np.sum(model.mass[:, None] * d * d)) == pytest.approx(p.mode_rate(model.mass), rel=1e-5)


def test_a_kappa_too_stiff_for_the_step_is_lowered_and_said():
    model = bar()
    w_unit = np.sqrt(volume_pressure(model, 1.0, H).mode_rate(model.mass))
    asked = 4.0 * (MAX_OMEGA_H / (w_unit * H)) ** 2            # omega h = 2 MAX_OMEGA_H
    p = volume_pressure(model, asked, H)
    assert p.asked == asked and p.kappa[0] == pytest.approx(asked / 4.0, rel=1e-12)
    assert np.sqrt(p.mode_rate(model.mass)) * H == pytest.approx(MAX_OMEGA_H, rel=1e-9)
    assert "lowered on 1 of 1 pieces" in p.summary(H, model.mass)
    kept = volume_pressure(model, asked / 8.0, H)
    assert (kept.kappa == asked / 8.0).all() and "lowered" not in kept.summary(H, model.mass)


def test_off_builds_nothing_and_a_bad_value_is_refused():
    model = bar()
    assert volume_pressure(model, 0.0, H) is None
    for bad in (-1.0, float("nan")):
        with pytest.raises(ParameterError, match="material.volume_stiffness"):
            volume_pressure(model, bad, H)
    for bad in (-2.0, "stiff", float("nan"), True):
        with pytest.raises(ValueError, match="volume_stiffness"):
            SceneConfig().with_values({"material.volume_stiffness": bad})


def test_auto_runs_it_on_flesh_on_a_skeleton_and_a_recording_keeps_the_number():
    """'auto' (the default) is kappa 2 on the jelly man and a character's surface, 0 on the other kinds; the
    recorded scene (SceneConfig.resolved) holds the number, so a replay runs the same pressure whatever 'auto'
    becomes; 'AUTO' in any case and a number both pass."""
    kinds = {"jelly_man": 2.0, "surface": 2.0, "sphere": 0.0, "cube": 0.0, "torus": 0.0, "mesh": 0.0,
             "robot_cover": 0.0}
    files = {"body.surface_file": "man.obj", "body.mesh_file": "man.msh"}    # checked when built, not here
    for kind, kappa in kinds.items():
        config = SceneConfig().with_values(files, body__kind=kind)
        assert config.material.volume_stiffness == kappa, kind
        assert config.resolved()["material.volume_stiffness"] == kappa
    assert SceneConfig().with_values({"material.volume_stiffness": "AUTO"})["material.volume_stiffness"] == "auto"
    assert SceneConfig().with_values({"material.volume_stiffness": 3}).material.volume_stiffness == 3.0


def test_each_piece_keeps_its_own_volume():
    a, b = box_mesh((0.4, 0.1, 0.1), (8, 2, 2)), box_mesh((0.1, 0.1, 0.1), (2, 2, 2))
    far = b.vertices + np.array([1.0, 0.0, 0.0])
    from clusterfem_ros.fem.mesh.tet_mesh import TetMesh
    mesh = TetMesh(np.vstack([a.vertices, far]), np.vstack([a.tets, b.tets + a.n_vertices]))
    model = build_model(mesh, MATERIAL, gravity=(0.0, 0.0, 0.0))
    p = volume_pressure(model, 1.0, H)
    assert p.rest_volumes.size == 2
    assert sorted(p.rest_volumes) == pytest.approx(sorted([a.volumes().sum(), b.volumes().sum()]), rel=1e-12)
    u = np.zeros_like(model.rest)
    big = np.arange(a.n_vertices)
    u[big] = -0.1 * (a.vertices - a.vertices.mean(axis=0))          # squeeze the bar, leave the cube
    f = p.force(u)
    assert np.abs(f[a.n_vertices:]).max() <= 1e-12 * np.abs(f[big]).max()     # the cube's volume is its own
    v = p.volumes(u)
    assert sorted(v) == pytest.approx(sorted([signed_volumes(model.rest + u, a.tets).sum(),
                                              b.volumes().sum()]), rel=1e-12)


def squeezed_bar_volume(kappa: float) -> float:
    """V / V0 of the bar with its two end faces held 5 % closer together, settled (no gravity, damped; far below
    the squeeze that buckles it)."""
    model = bar(Material(E=3e4, nu=0.3, rho=1000.0, xi=20.0, zeta=1e-4))
    ends = np.flatnonzero(np.isclose(model.rest[:, 0], 0.0) | np.isclose(model.rest[:, 0], 0.4))
    target = np.zeros((ends.size, 3))
    target[:, 0] = np.where(np.isclose(model.rest[ends, 0], 0.0), 0.01, -0.01)
    att = Attachments(ends, target, np.zeros_like(target), np.zeros_like(target),
                      np.full(ends.size, 4e4), np.full(ends.size, 400.0))
    p = volume_pressure(model, kappa, H)
    integrator = ClusteredExplicit(model)
    state = State.rest(model)
    for _ in range(3000):
        f = None if p is None else p.force(state.u).copy()
        integrator.step(state, Control(f_ext=f, attachments=att), H)
    assert np.isfinite(state.u).all() and np.abs(state.v).max() < 1e-3       # settled
    return float(signed_volumes(model.rest + state.u, model.mesh.tets).sum() / model.mesh.volumes().sum())


def test_on_a_squeezed_bar_it_keeps_the_volume_the_elements_give_up():
    alone, held = squeezed_bar_volume(0.0), squeezed_bar_volume(4.0)
    assert alone < 0.99                                   # nu = 0.3 gives up a real share of the volume
    # a (1 + kappa) times stiffer whole-volume mode: the loss falls to about 1 / (1 + kappa) of it
    assert 1.0 - held < 0.35 * (1.0 - alone)
    assert held < 1.0                                     # it keeps volume, it does not inflate


def test_the_scene_builds_it_only_when_asked_and_says_so():
    base = SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False)
    assert base["material.volume_stiffness"] == "auto" and base.material.volume_stiffness == 0.0
    assert Scene.build(base).pressure is None             # 'auto' on a paper shape: the elements alone
    assert Scene.build(base.with_values({"material.volume_stiffness": 0})).pressure is None
    said = []
    scene = Scene.build(base.with_values({"material.volume_stiffness": 2.0}), progress=said.append)
    assert scene.pressure is not None and (scene.pressure.kappa == 2.0).all()
    assert any(line.startswith("volume pressure: kappa 2") for line in said)


def test_a_recording_made_before_auto_replays_without_the_pressure(tmp_path):
    """A recording's scene file without material.volume_stiffness was made when none ran: the replay's reading
    (config.RECORDED_BEFORE) gives 0, a plain scene file the default 'auto'; a recorded number is kept."""
    from clusterfem_ros.config import RECORDED_BEFORE, load_scene_file, scene_file_text
    old = tmp_path / "old.yaml"
    old.write_text("clusterfem:\n  ros__parameters:\n    physics:\n      clock: input\n")
    assert load_scene_file(old, absent=RECORDED_BEFORE).material.volume_stiffness == 0.0
    assert load_scene_file(old).material.volume_stiffness == 2.0
    new = tmp_path / "new.yaml"
    new.write_text(scene_file_text(SceneConfig().resolved()))
    assert load_scene_file(new, absent=RECORDED_BEFORE)["material.volume_stiffness"] == 2.0
