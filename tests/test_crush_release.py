"""The crush release (body/crush_release.py): a bound vertex's gains fall where its bones' targets crush the elements
that span bones, and nowhere else; the folded joint keeps more of its volume; off, the driver is what it was."""
import numpy as np
import pytest

from clusterfem_ros.body import LevelGains, SkeletonDriver, bind_to_skeleton
from clusterfem_ros.body.crush_release import crush_release, release_gains
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from clusterfem_ros.fem.model import build_model
from tests import naive
from tests.test_body_support import ChainSkeleton, Motion, box_body
from tests.test_folded_joint import ANGLE, H, HOLD, RAMP, _fold

SK = ChainSkeleton()
MESH = box_body()
GAINS = LevelGains((4.0e4, 4.0e3), (400.0, 120.0))


def _binding():
    q, v = Motion().qv(0.0)
    s, e = SK.bone_segments(q)
    P = SK.forward(q, v)
    return bind_to_skeleton(MESH.vertices, s, e, (0.031, 0.09), rest_rotation=P.rotation,
                            rest_translation=P.translation)


BINDING = _binding()


def test_the_spanning_elements_are_those_bound_to_two_bones_or_more():
    order = np.arange(MESH.n_vertices)
    c = crush_release(BINDING, MESH.tets, MESH.vertices, order, 0.5)
    bones = BINDING.bone[MESH.tets]
    spanning = (bones != bones[:, :1]).any(axis=1)
    assert c.rows.shape == (int(spanning.sum()), 4) and 0 < c.rows.shape[0] < MESH.n_tets
    np.testing.assert_array_equal(np.sort(c.rows, axis=1), np.sort(MESH.tets[spanning], axis=1))
    np.testing.assert_array_equal(c.touched, np.unique(MESH.tets[spanning]))
    assert crush_release(BINDING, MESH.tets, MESH.vertices, order, 0.0) is None
    with pytest.raises(ValueError, match="must be in"):
        crush_release(BINDING, MESH.tets, MESH.vertices, order, 1.0)


def test_elements_on_a_held_bone_are_never_released():
    """A bone named held (a finger: digit_bones) keeps its spanning elements' vertices at their gains: no element
    with a corner on it is in the release; holding every bone leaves nothing to release."""
    order = np.arange(MESH.n_vertices)
    bones = BINDING.bone[MESH.tets]
    spanning = (bones != bones[:, :1]).any(axis=1)
    held = int(bones[spanning].max())                                   # a bone some spanning elements reach
    c = crush_release(BINDING, MESH.tets, MESH.vertices, order, 0.5, held_bones=np.array([held]))
    keep = spanning & ~(bones == held).any(axis=1)
    assert 0 < c.rows.shape[0] == int(keep.sum()) < int(spanning.sum())
    np.testing.assert_array_equal(np.sort(c.rows, axis=1), np.sort(MESH.tets[keep], axis=1))
    assert crush_release(BINDING, MESH.tets, MESH.vertices, order, 0.5,
                         held_bones=np.arange(BINDING.n_bones)) is None


def test_a_human_skeleton_s_fingers_and_toes_are_the_held_bones():
    """The CMU walk's skeleton: its finger and toe bones by role, and nothing else; a chain that is no human holds
    none."""
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.scene_setup import digit_bones
    from clusterfem_ros.skeleton.bone_roles import label_skeleton
    from clusterfem_ros.skeleton.kinematics import Skeleton
    from tests.shared_data import walk_clip
    skeleton = Skeleton.from_urdf_string(load_motion("bvh", walk_clip()).urdf)
    roles = label_skeleton(skeleton).roles
    held = digit_bones(skeleton)
    assert len(held) >= 4 and {roles[k] for k in held} == {"finger", "toe"}
    assert sorted(held) == [k for k, r in enumerate(roles) if r in ("finger", "toe")]


@pytest.mark.parametrize("seed", [3, 17])
def test_the_kernel_matches_its_numpy_twin(seed):
    """Random targets around the rest shape (some elements crushed, some inverted, some stretched)."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(MESH.n_vertices)            # rows are the driver's order, not the vertices'
    c = crush_release(BINDING, MESH.tets, MESH.vertices, order, 0.4)
    x = MESH.vertices[order] + rng.normal(scale=0.012, size=(order.size, 3))
    kp0, kd0 = rng.uniform(1e3, 4e4, order.size), rng.uniform(50, 400, order.size)
    kp, kd = kp0.copy(), kd0.copy()
    release_gains(x, c.rows, c.v0, c.touched, c.floor, kp0, kd0, kp, kd, np.empty(order.size))
    want_kp, want_kd = naive.release_gains(x, c.rows, c.v0, c.floor, kp0, kd0)
    print(f"seed {seed}: {int((kp == 0).sum())} let go, {int(((kp > 0) & (kp < kp0)).sum())} weakened")
    assert (kp == 0).any() and ((kp > 0) & (kp < kp0)).any() and (kp == kp0).any()
    np.testing.assert_allclose(kp, want_kp, rtol=1e-12, atol=0)
    np.testing.assert_allclose(kd, want_kd, rtol=1e-12, atol=0)


def _run(floor: float, motion: Motion, steps: int, nu: float = 0.4, mesh=MESH, binding=BINDING):
    model = build_model(mesh, Material(E=3.0e4, nu=nu, rho=1000.0, xi=2.0, zeta=1.0e-4))
    integrator = make_integrator("clustered", model, warp=True, warping_model="neohookean", plan_stretch=True,
                                 safety=0.8, max_substeps=64)
    driver = SkeletonDriver(binding, mesh.vertices, GAINS, tets=mesh.tets if floor else None, crush_floor=floor)
    state = driver.rigid_state(SK.forward(*motion.qv(0.0)))
    for k in range(steps):
        integrator.step(state, driver.control(SK.forward(*motion.qv(k * H)), H), H)
    return driver, state


def test_the_folded_joint_keeps_more_of_its_volume_with_the_release():
    """j1 folded 120 deg, a thick coarse box (0.2 m across, 0.05 m voxels: a band of elements spans the two bones, as
    on the character's coarse mesh) bound whole: the release at 0.5 loses at most 0.95 of the volume the fixed gains
    lose (0.93 measured), and lets go of vertices inside the fold only, none at the straight ends."""
    mesh = box_mesh((0.66, 0.2, 0.2), (13, 4, 4), (-0.03, -0.1, -0.1))
    q, v = Motion().qv(0.0)
    s, e = SK.bone_segments(q)
    P = SK.forward(q, v)
    binding = bind_to_skeleton(mesh.vertices, s, e, (0.05, 0.2), rest_rotation=P.rotation,
                               rest_translation=P.translation)
    assert (binding.level >= 0).all()
    v0 = signed_volumes(mesh.vertices, mesh.tets).sum()
    loss = {}
    for floor in (0.0, 0.5):
        driver, state = _run(floor, _fold(), int(round((RAMP + HOLD) / H)), mesh=mesh, binding=binding)
        loss[floor] = signed_volumes(mesh.vertices + state.u, mesh.tets).sum() / v0 - 1.0
    print(f"folded {np.degrees(ANGLE):.0f} deg: V/V0 - 1 {loss[0.0]:+.2%} fixed gains, {loss[0.5]:+.2%} released")
    assert 0.95 * loss[0.0] < loss[0.5] < 0          # losses are negative: |released| < 0.95 |fixed|
    let_go = driver.bound[driver._kp == 0]
    assert let_go.size and np.abs(mesh.vertices[let_go, 0] - 0.2).max() < 0.15     # all near j1 (x = 0.2)


def test_off_or_uncrushed_the_driver_gives_the_same_bits():
    """A rigid turn of the whole chain (no fold: no element's targets crushed): the released driver's states equal
    the plain driver's bit for bit, and its gains are the levels' gains in the same arrays every step."""
    spin = Motion(phi=lambda t: 3.0 * t, dphi=lambda t: 3.0, axis=(0.0, 1.0, 0.0), T=lambda t: np.array([t, 0, 0]),
                  dT=lambda t: np.array([1.0, 0, 0]))
    plain, a = _run(0.0, spin, 60)
    released, b = _run(0.5, spin, 60)
    assert plain.crush is None and released.crush is not None
    np.testing.assert_array_equal(a.u, b.u)
    np.testing.assert_array_equal(a.v, b.v)
    np.testing.assert_array_equal(released._kp, plain._kp)
    att = released.control(SK.forward(*spin.qv(60 * H)), H).attachments
    assert np.shares_memory(att.kp, released._kp) and np.shares_memory(att.kd, released._kd)
