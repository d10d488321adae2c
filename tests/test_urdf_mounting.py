"""Other URDFs: a Y-up model stands along world Z, a fixed base follows the root pose sent, leaf links take the
URDF's shapes (issue #18, item 7). The URDF is tests/urdf_text.py's own small Y-up humanoid."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.link_shapes import ShapeError, leaf_geometry, prepare_urdf
from clusterfem_ros.config import ConfigError, SceneConfig
from clusterfem_ros.scene import Scene
from clusterfem_ros.skeleton.humanoid import humanoid_urdf
from clusterfem_ros.skeleton.kinematics import Skeleton
from clusterfem_ros.skeleton.mounting import UP_AXES, MountError, mount_urdf, up_rotation

from .urdf_text import FOOT_CYLINDER, HAND_BOX, HEAD_SPHERE, y_up_humanoid


def _y_up_scene(folder) -> tuple[Scene, list[str]]:
    path = folder / "y_up.urdf"
    path.write_text(y_up_humanoid())
    config = SceneConfig().with_values({"skeleton.source": "urdf_file", "skeleton.urdf_file": str(path),
                                        "skeleton.up_axis": "y", "body.target_tets": 3000,
                                        "body.flesh": "uniform",   # capsules of body.bone_radius around the shapes
                                        "body.skin": "voxel"})     # sizes measured on the voxel grid
    notes = []
    return Scene.build(config, progress=notes.append), notes


@pytest.fixture(scope="module")
def y_up(tmp_path_factory):
    """A Y-up scene for the tests that only look at its rest state."""
    return _y_up_scene(tmp_path_factory.mktemp("urdf"))


def _spacing(vertices: np.ndarray) -> float:
    """The voxel spacing of a voxelized body: the smallest step between its vertices' x coordinates."""
    xs = np.unique(np.round(vertices[:, 0], 9))
    return float(np.diff(xs).min())


@pytest.mark.parametrize("axis", UP_AXES)
def test_every_up_axis_is_turned_onto_world_z(axis):
    sign = -1.0 if axis.startswith("-") else 1.0
    up = sign * np.eye(3)["xyz".index(axis[-1])]
    R = up_rotation(axis)
    np.testing.assert_allclose(R @ up, [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_a_y_up_urdf_stands_along_world_z_with_its_left_on_plus_y(y_up):
    scene, notes = y_up
    extent = np.ptp(scene.model.rest, axis=0)
    print(f"extent x, y, z: {extent}")
    assert extent[2] > 2.5 * max(extent[0], extent[1])         # 1.65 m tall, 0.28 deep, 0.6 wide
    sk = scene.skeleton
    starts, ends = sk.bone_segments(sk.neutral())
    head, foot = sk.bone_names.index("head"), sk.bone_names.index("left_foot")
    assert ends[head][2] - starts[foot][2] > 1.4                 # head above the feet, along z
    assert starts[sk.bone_names.index("left_hand")][1] == pytest.approx(0.25)   # ISB left (-z) is our left (+y)
    assert any("up axis y" in n for n in notes)


def test_a_y_up_body_under_gravity_with_bones_held_still_stays_upright(tmp_path):
    scene, _ = _y_up_scene(tmp_path)
    sk = scene.skeleton
    x0 = scene.positions().copy()
    for k in range(51):                                         # 0.5 s of a still pose at 100 Hz
        assert scene.push_joint_state(10.0 + k / 100, sk.joint_names, sk.neutral()) == []
        scene.advance_to(10.0 + k / 100)
    x = scene.positions()
    sag = x0.mean(axis=0) - x.mean(axis=0)
    print(f"centroid moved {sag} m after 0.5 s; extent {np.ptp(x, axis=0)}")
    assert scene.sim_time == pytest.approx(10.5)
    assert np.isfinite(x).all()
    assert np.ptp(x[:, 2]) == pytest.approx(np.ptp(x0[:, 2]), rel=0.02)   # still as tall
    assert abs(sag[2]) < 0.01 and np.abs(sag[:2]).max() < 0.005           # held by its bones, not lying down


def test_leaf_links_get_the_sizes_of_their_collision_shapes(y_up):
    scene, notes = y_up
    x, h = scene.model.rest, _spacing(scene.model.rest)
    print(f"voxel spacing {h:.4f} m")
    hand = x[(x[:, 2] < -0.08 - 0.05 - h) & (np.abs(x[:, 1] - 0.25) < HAND_BOX[2] / 2 + h)]   # below the forearm
    assert np.ptp(hand[:, 0]) == pytest.approx(HAND_BOX[0], abs=h)   # ISB x: forward
    assert np.ptp(hand[:, 1]) == pytest.approx(HAND_BOX[2], abs=h)   # ISB z: sideways
    assert hand[:, 2].min() == pytest.approx(-0.08 - HAND_BOX[1], abs=h)
    foot = x[(x[:, 0] > 0.05 + h) & (x[:, 1] > 0) & (x[:, 2] < -0.8)]              # ahead of the shin's capsule: the cylinder only
    assert foot[:, 0].max() == pytest.approx(0.07 + FOOT_CYLINDER[1] / 2, abs=h)
    assert np.ptp(foot[:, 1]) == pytest.approx(2 * FOOT_CYLINDER[0], abs=h)
    assert np.ptp(foot[:, 2]) == pytest.approx(2 * FOOT_CYLINDER[0], abs=h)
    head = x[x[:, 2] > 0.5 + 0.05 + h]                           # above the chest's capsule: the sphere only
    assert head[:, 2].max() == pytest.approx(0.6 + HEAD_SPHERE, abs=h)
    assert np.ptp(head[:, 0]) == pytest.approx(2 * HEAD_SPHERE, abs=h)
    assert any("head (sphere from collision)" in n for n in notes)     # collision before the visual box


def test_a_fixed_base_urdf_with_the_free_root_follows_the_root_sent(tmp_path):
    scene, notes = _y_up_scene(tmp_path)
    assert any("skeleton root: free" in n for n in notes)
    sk = scene.skeleton
    t0 = 20.0
    q = sk.neutral()
    scene.push_joint_state(t0, sk.joint_names, q)
    scene.advance_to(t0)
    c0 = scene.positions().mean(axis=0)
    ix, iz = sk.joint_index("root_x"), sk.joint_index("root_z")
    for k in range(1, 41):                              # 0.4 m forward and 0.1 m up in 0.4 s
        q = sk.neutral()
        q[ix], q[iz] = 0.01 * k, 0.0025 * k
        assert scene.push_joint_state(t0 + k / 100, sk.joint_names, q) == []
        scene.advance_to(t0 + k / 100)
    for k in range(41, 61):                             # then held for 0.2 s
        scene.push_joint_state(t0 + k / 100, sk.joint_names, q)
        scene.advance_to(t0 + k / 100)
    moved = scene.positions().mean(axis=0) - c0
    print(f"centroid moved {moved} m for a root move of (0.4, 0, 0.1) m")
    np.testing.assert_allclose(moved, [0.4, 0.0, 0.1], atol=0.01)


def test_bad_up_axis_and_root_joint_values_are_refused_naming_the_choices():
    with pytest.raises(ConfigError, match=r"skeleton.up_axis = 'w': choose one of z, y, x, -z, -y, -x"):
        SceneConfig().with_values({"skeleton.up_axis": "w"})
    with pytest.raises(ConfigError, match=r"skeleton.root_joint = 'floating': choose one of auto, free, fixed"):
        SceneConfig().with_values({"skeleton.root_joint": "floating"})
    with pytest.raises(MountError, match=r"skeleton.up_axis = 'up'.*choose one of z, y"):
        mount_urdf(y_up_humanoid(), "up")


def test_a_urdf_with_its_own_root_is_unchanged_by_default_and_free_refuses_a_name_clash():
    urdf = humanoid_urdf()
    mounted = mount_urdf(urdf)
    assert mounted.urdf is urdf and mounted.root == "own"
    assert prepare_urdf(urdf, leaf_shapes=True).urdf is urdf      # the default scene's skeleton, bit for bit
    with pytest.raises(MountError, match=r"already has \['root_pitch', 'root_roll', 'root_x'.*'fixed'"):
        mount_urdf(urdf, root_joint="free")
    fixed = mount_urdf(y_up_humanoid(), "y", "fixed")
    assert fixed.root == "fixed" and Skeleton.from_urdf_string(fixed.urdf).joint_names[0] == "left_hip"


def test_own_root_joints_move_the_model_in_its_own_axes_under_the_up_axis_rotation():
    mounted = mount_urdf(humanoid_urdf(), "y")          # taken as Y up: its root joints stay, the model is turned
    assert mounted.root == "own"
    sk = Skeleton.from_urdf_string(mounted.urdf)
    q = sk.neutral()
    q[sk.joint_index("root_y")] = 0.3                                   # the model's up is the world's z
    moved = sk.forward(q).translation - sk.forward(sk.neutral()).translation
    np.testing.assert_allclose(moved, np.tile([0, 0, 0.3], (sk.n_bones, 1)), atol=1e-12)


def test_leaves_without_shapes_keep_the_ball_with_one_warning_and_a_mesh_is_its_bounding_box(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    (tmp_path / "pkg" / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(2.0, 4.0, 6.0)).export(tmp_path / "pkg" / "meshes" / "hand.stl")
    urdf = y_up_humanoid()
    mesh = ('<visual><origin xyz="0 -0.1 0"/><geometry><mesh filename="package://pkg/meshes/hand.stl" '
            'scale="0.01 0.02 0.01"/></geometry></visual>')
    missing = '<visual><geometry><mesh filename="package://pkg/meshes/none.stl"/></geometry></visual>'
    start = urdf.index('<link name="left_hand">')
    end = urdf.index("</link>", start)
    urdf = urdf[:start] + '<link name="left_hand">' + mesh + urdf[end:]
    start = urdf.index('<link name="right_hand">')
    end = urdf.index("</link>", start)
    urdf = urdf[:start] + '<link name="right_hand">' + missing + urdf[end:]
    geo = leaf_geometry(urdf, [tmp_path])
    (shape,) = geo.shapes["left_hand"]
    assert shape.kind == "box" and shape.source == "mesh bounding box"
    np.testing.assert_allclose(shape.half, [0.01, 0.04, 0.03], atol=1e-12)
    np.testing.assert_allclose(shape.translation, [0, -0.1, 0], atol=1e-12)
    assert "right_hand" not in geo.shapes and len(geo.warnings) == 1
    assert "right_hand" in geo.warnings[0] and "none.stl" in geo.warnings[0] and "body.bone_radius" in geo.warnings[0]
    sk = Skeleton.from_urdf_string(geo.urdf)
    starts, ends = sk.bone_segments(sk.neutral())
    b = sk.bone_names.index("left_hand")
    assert np.linalg.norm(ends[b] - starts[b]) == pytest.approx(0.1 + 0.04 - 0.01)   # a tip through the box
    b = sk.bone_names.index("right_hand")
    assert np.linalg.norm(ends[b] - starts[b]) == 0.0                                 # the ball's bone: a point


def test_virtual_links_between_the_axes_of_one_joint_are_not_bones():
    urdf = y_up_humanoid().replace(
        '<joint name="neck" type="revolute"><parent link="chest"/><child link="head"/>'
        '<origin xyz="0 0.25 0" rpy="0 0 0"/>',
        '<link name="neck_virtual"/><joint name="neck_z" type="revolute"><parent link="chest"/>'
        '<child link="neck_virtual"/><origin xyz="0 0.25 0"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        '<joint name="neck" type="revolute"><parent link="neck_virtual"/><child link="head"/>'
        '<origin xyz="0 0 0" rpy="0 0 0"/>')
    sk = Skeleton.from_urdf_string(urdf)
    assert "neck_virtual" not in sk.bone_names and "neck_z" in sk.joint_names
    assert sk.bone_parent[sk.bone_names.index("head")] == sk.bone_names.index("chest")


def test_a_shape_with_a_bad_size_is_refused_naming_the_link_and_the_text():
    urdf = y_up_humanoid().replace(f'<box size="{HAND_BOX[0]} {HAND_BOX[1]} {HAND_BOX[2]}"/>', '<box size="0.1 0.2"/>', 1)
    with pytest.raises(ShapeError, match=r"link 'left_hand' <collision> box size = '0.1 0.2': give 3 finite non-negative"):
        leaf_geometry(urdf, [])


def test_the_renderer_draws_the_scene_s_urdf_file_found_under_clusterfem_data_mounted_as_the_node_did(
        tmp_path, monkeypatch):
    from clusterfem_ros.bag_frames import _skeleton_urdf
    (tmp_path / "urdf").mkdir()
    (tmp_path / "urdf" / "y.urdf").write_text(y_up_humanoid())
    monkeypatch.setenv("CLUSTERFEM_DATA", str(tmp_path))
    config = SceneConfig().with_values({"skeleton.source": "urdf_file", "skeleton.urdf_file": "urdf/y.urdf",
                                        "skeleton.up_axis": "y", "body.target_tets": 500})
    drawn = _skeleton_urdf(config, humanoid_urdf(), tmp_path / "bag")     # a player latched the humanoid too
    built = Scene.build(config)
    assert drawn == built.urdf_xml and "left_hand_tip" in drawn and "root_x" in drawn


def test_the_human_of_example_robot_data_stands_with_mesh_shaped_leaves_and_a_free_root():
    """The real URDF, where config/urdf_data.md says to put it (skipped when it is not there)."""
    from clusterfem_ros.body.fit import FitError, find_data_file
    try:
        path = find_data_file("urdf/human_description/robots/human.urdf")
    except FitError:
        pytest.skip("urdf/human_description is not under $CLUSTERFEM_DATA or ../shared/data (config/urdf_data.md)")
    notes = []
    scene = Scene.build(SceneConfig().with_values({"skeleton.source": "urdf_file", "skeleton.urdf_file": str(path),
                                                   "skeleton.up_axis": "y", "body.target_tets": 2000}),
                        progress=notes.append)
    extent = np.ptp(scene.model.rest, axis=0)
    print(f"extent {extent}", *notes[:3], sep="\n")
    # upright: 1.82 m tall, 0.64 m across the hanging arms' flesh (y: its left side), 0.35 m front to back
    assert extent[2] > 1.6 and extent[2] > 2.5 * extent[1] and extent[1] > extent[0]
    said = {n.split(":")[0]: n for n in notes}                   # each log line by its subject
    assert said["skeleton root"].startswith("skeleton root: free")
    for leaf in ("left_foot", "right_foot", "left_hand", "right_hand", "middle_head"):
        assert f"{leaf} (box from mesh bounding box" in said["leaf links shaped by the URDF"]
    assert not any(n.startswith("warning") for n in notes)
    assert not any("virtual" in n for n in scene.skeleton.bone_names)      # 18 bones, the virtual links are frames
    assert scene.skeleton.n_bones == 18 and scene.skeleton.nq == 42


def test_the_shipped_human_scene_file_reads_and_names_its_data():
    from pathlib import Path

    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.motion import load_player_section
    root = Path(__file__).resolve().parents[1]
    c = load_scene_file(root / "config" / "human_urdf.yaml")
    assert (c["skeleton.source"], c["skeleton.up_axis"], c["skeleton.root_joint"]) == ("urdf_file", "y", "auto")
    assert load_player_section(root / "config" / "human_urdf.yaml") == {"source": "builtin_walk"}
    assert c["skeleton.urdf_file"] in (root / "config" / "urdf_data.md").read_text()


def test_a_floating_root_joint_is_replaced_by_the_free_root_and_made_fixed_when_asked():
    urdf = y_up_humanoid().replace(
        '<link name="pelvis">', '<link name="world"/><joint name="base" type="floating"><parent link="world"/>'
        '<child link="pelvis"/><origin xyz="0 1 0"/></joint><link name="pelvis">')
    with pytest.raises(NotImplementedError, match="floating"):
        Skeleton.from_urdf_string(urdf)
    free = mount_urdf(urdf, "y")
    assert free.root == "free" and "floating joint base made fixed" in free.note
    sk = Skeleton.from_urdf_string(free.urdf)
    assert sk.joint_names[:6] == ["root_x", "root_y", "root_z", "root_yaw", "root_pitch", "root_roll"]
    np.testing.assert_allclose(sk.forward(sk.neutral()).translation[sk.bone_names.index("pelvis")], [0, 0, 1],
                               atol=1e-12)                               # the joint's origin, turned Y up
    assert sk.bone_names[0] == "pelvis"                                  # 'world' is a frame, no flesh
    fixed = mount_urdf(urdf, "z", "fixed")
    assert fixed.root == "fixed" and Skeleton.from_urdf_string(fixed.urdf).joint_names[0] == "left_hip"


@pytest.mark.parametrize("kind, half, inside, outside", [
    ("box", (0.1, 0.2, 0.3), (0.09, -0.19, 0.29), (0.11, 0.0, 0.0)),
    ("cylinder", (0.1, 0.1, 0.3), (0.07, 0.07, 0.29), (0.08, 0.08, 0.0)),       # r = 0.113 > 0.1
    ("capsule", (0.1, 0.1, 0.3), (0.0, 0.0, 0.39), (0.0, 0.0, 0.41)),           # the half-sphere's top at 0.4
    ("sphere", (0.1, 0.1, 0.1), (0.0, 0.057, 0.08), (0.06, 0.06, 0.06))])
def test_a_placed_shape_holds_the_points_inside_it_and_not_those_outside(kind, half, inside, outside):
    from clusterfem_ros.skeleton.link_shapes import PlacedShape, shape_depth, shapes_inside
    from clusterfem_ros.skeleton.mounting import rpy_matrix
    R, p = rpy_matrix(0.3, -0.2, 1.1), np.array([1.0, 2.0, 3.0])
    shape = PlacedShape(0, kind, R, p, np.array(half))
    points = p + np.array([inside, outside]) @ R.T                 # shape-local points, placed like the shape
    np.testing.assert_array_equal(shapes_inside(points, [shape]), [True, False])
    assert shape_depth(p[None], shape)[0] == pytest.approx(-min(half[:2]) if kind != "box" else -min(half))
