"""The character meshes of tests/data/character_meshes.yaml: the manifest gives each one's provenance and open
licence, and each file present is what the manifest says, measured from its geometry (benchmarks/characters.py):
its up and forward axes, its height and unit, its arms' angle and pose, its counts. A mesh not present is skipped
with the file and the manifest entry to fetch it from."""
import re

import numpy as np
import pytest

from benchmarks import characters
from benchmarks.characters import UNITS, find_mesh, load_manifest, measure_body, missing_message, read_entry

MESHES = load_manifest()
OPEN_LICENCES = ("CC0", "CC BY 4.0", "MIT License", "BSD", "public domain")


def test_the_manifest_names_each_mesh_with_its_provenance_and_an_open_licence():
    """Runs without the meshes: at least three meshes from at least three repositories, in T- and A-pose, each
    with repository, commit, path, sha256, an open licence (no non-commercial or no-derivatives terms), an
    attribution, a unit the table knows with its metres, and axes that are one each of X, Y and Z."""
    assert len(MESHES) >= 3 and len({m.name for m in MESHES}) == len(MESHES)
    assert len({m.repository for m in MESHES}) >= 3
    assert {"T", "A"} <= {m.pose for m in MESHES}
    for m in MESHES:
        assert re.fullmatch(r"[0-9a-f]{40}", m.commit) and re.fullmatch(r"[0-9a-f]{64}", m.sha256), m.name
        assert "/" in m.repository and m.path and m.file.startswith(m.name + "."), m.name
        assert any(word in m.licence for word in OPEN_LICENCES), m.licence
        assert not re.search(r"\bNC\b|NonCommercial|\bND\b|NoDerivatives", m.licence), m.licence
        assert m.attribution and m.source, m.name
        assert m.pose in ("T", "A", "arms-down") and m.metres_per_unit == UNITS[m.unit], m.name
        assert re.fullmatch(r"[+-][XYZ]", m.up) and re.fullmatch(r"[+-][XYZ]", m.forward), m.name
        assert {m.up[1], m.forward[1], m.lateral} == {"X", "Y", "Z"}, m.name
        assert 1.4 <= m.height * m.metres_per_unit <= 2.1, m.name


@pytest.mark.parametrize("entry", MESHES, ids=[m.name for m in MESHES])
def test_each_mesh_is_what_the_manifest_says(entry):
    """Read as ``body.kind: surface`` reads it, the file has the manifest's counts, closedness, axes, height
    (to 0.1 %), unit (the one its height names) and pose (arms' angle to 3 deg)."""
    path = find_mesh(entry)
    if path is None:
        pytest.skip(missing_message(entry))
    v, f = read_entry(path, entry)
    assert (len(v), len(f)) == (entry.vertices, entry.faces)
    shape = measure_body(v, f)
    assert (shape.lateral, shape.up, shape.forward) == (entry.lateral, entry.up, entry.forward), shape.describe()
    assert shape.height == pytest.approx(entry.height, rel=1e-3)
    assert shape.unit == entry.unit, shape.describe()
    assert shape.arm_angle_deg == pytest.approx(entry.arm_angle_deg, abs=3.0) and shape.pose == entry.pose
    assert shape.watertight == entry.watertight


def test_a_missing_mesh_is_skipped_naming_the_manifest_and_a_changed_file_is_refused(tmp_path, monkeypatch):
    """With no mesh folder holding it, find_mesh gives None and the message names the file, where it comes from and
    the manifest entry; a file of that name with other bytes is refused, naming the manifest's sha256."""
    entry = MESHES[0]
    monkeypatch.setattr(characters, "mesh_dirs", lambda: [tmp_path])
    assert find_mesh(entry) is None
    message = missing_message(entry)
    assert entry.file in message and entry.repository in message and entry.commit in message
    assert "tests/data/character_meshes.yaml" in message and f"'{entry.name}'" in message
    (tmp_path / entry.file).write_bytes(b"not the mesh")
    with pytest.raises(ValueError, match=entry.sha256):
        find_mesh(entry)


def _stick_figure(arm_deg: float, height: float = 1.75) -> tuple[np.ndarray, np.ndarray]:
    """A closed-capsule figure in metres, Y up, facing +Z, mirror-symmetric in X: legs, trunk, head, feet pointing
    forward, and arms hanging ``arm_deg`` from the body axis (90 = T-pose)."""
    import trimesh
    H = height
    parts = []

    def capsule(a, b, r):
        a, b = np.asarray(a, float), np.asarray(b, float)
        length = float(np.linalg.norm(b - a))
        m = trimesh.creation.capsule(height=length, radius=r, count=[16, 16])
        m.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], (b - a) / length))
        m.apply_translation(0.5 * (a + b))
        parts.append(m)

    for s in (1.0, -1.0):
        capsule([s * 0.06 * H, 0.05 * H, 0.0], [s * 0.06 * H, 0.5 * H, 0.0], 0.04 * H)             # leg
        capsule([s * 0.06 * H, 0.02 * H, -0.02 * H], [s * 0.06 * H, 0.02 * H, 0.1 * H], 0.02 * H)  # foot
        shoulder = np.array([s * 0.13 * H, 0.8 * H, 0.0])
        a = np.radians(arm_deg)
        capsule(shoulder, shoulder + 0.42 * H * np.array([s * np.sin(a), -np.cos(a), 0.0]), 0.03 * H)  # arm
    capsule([0.0, 0.5 * H, 0.0], [0.0, 0.8 * H, 0.0], 0.1 * H)                                     # trunk
    head = trimesh.creation.icosphere(subdivisions=2, radius=0.06 * H)
    head.apply_translation([0.0, 0.9 * H, 0.02 * H])
    parts.append(head)
    m = trimesh.util.concatenate(parts)
    return np.asarray(m.vertices), np.asarray(m.faces)


@pytest.mark.parametrize("arm_deg, pose", [(90.0, "T"), (45.0, "A"), (5.0, "arms-down")])
@pytest.mark.parametrize("frame, scale, up, forward, lateral, unit", [
    (np.eye(3), 1.0, "+Y", "+Z", "X", "m"),
    (np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), 100.0, "+Z", "-Y", "X", "cm"),    # Z up, facing -Y, cm
    (np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), 1.0 / 0.0254, "-X", "+Z", "Y", "in"),  # head towards -X
])
def test_measure_body_reads_axes_unit_and_pose_from_the_shape(arm_deg, pose, frame, scale, up, forward, lateral, unit):
    """A stick figure of known pose, turned into other axes and scaled into other units (m, cm, inches): the axes,
    the unit its height names, the height and the arms' angle come back from its shape."""
    v, f = _stick_figure(arm_deg)
    v = scale * v @ frame.T
    shape = measure_body(v, f)
    assert (shape.up, shape.forward, shape.lateral, shape.unit, shape.pose) == (up, forward, lateral, unit, pose)
    assert shape.height * UNITS[unit] == pytest.approx(0.96 * 1.75, rel=1e-3)      # soles at 0, head top at 0.96 H
    if pose != "arms-down":
        assert shape.arm_angle_deg == pytest.approx(arm_deg, abs=3.0)


# The turns a user's file may come in: (file axes from the MakeHuman file's, up, forward, metres per unit)
TURNS = [(np.eye(3), "Y", "Z", 0.1),
         (np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), "Z", "-Y", 0.01),     # Z up, facing -Y, cm
         (np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), "-X", "Z", 0.0254),   # head towards -X, inches
         (np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]]), "-Y", "X", 1.0)]      # upside down, facing X, metres


@pytest.mark.parametrize("turn", range(len(TURNS)))
def test_the_scene_reads_a_real_mesh_s_up_facing_and_unit_in_any_axes(turn):
    """MakeHuman's body (decimetres, Y up, facing +Z) turned into other axes and scaled into other units: 'auto'
    (body/mesh_frame.resolve_frame) gives back the file's up and forward axes and its unit, and says so in one line."""
    from clusterfem_ros.body.mesh_frame import resolve_frame
    from tests.shared_data import character_mesh
    entry = next(m for m in MESHES if m.name == "makehuman_base")
    v, f = read_entry(character_mesh(), entry)
    frame, up, forward, metres = TURNS[turn]
    v = (0.1 / metres) * v @ frame.T
    unit, got_up, got_forward, line = resolve_frame(v, f, "auto", "auto", "auto")
    assert (got_up, got_forward) == (up, forward) and unit == metres, line
    assert line.startswith("surface frame read from its shape (unit, up, forward)") and "1.67 m" in line


def test_given_axes_and_units_are_kept_and_the_rest_read_against_them():
    """What the user sets is taken as set; 'auto' fills in the rest, read against a given up axis."""
    from clusterfem_ros.body.mesh_frame import resolve_frame
    v, f = _stick_figure(45.0)
    v = 100.0 * v @ np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]).T         # Z up, facing -Y, cm
    assert resolve_frame(v, f, 0.01, "Z", "-Y") == (0.01, "Z", "-Y", None)   # nothing auto: nothing read
    assert resolve_frame(v, f, "cm", "Z", "auto")[:3] == (0.01, "Z", "-Y")
    assert resolve_frame(v, f, "auto", "Z", "X")[:3] == (0.01, "Z", "X")      # a given forward is kept
    unit, up, forward, line = resolve_frame(v, f, "inch", "auto", "auto")
    assert (unit, up, forward) == (0.0254, "Z", "-Y") and "(up, forward)" in line


def test_a_frame_that_cannot_be_read_names_the_parameter_to_set():
    from clusterfem_ros.body.fit import FitError
    from clusterfem_ros.body.mesh_frame import resolve_frame
    v, f = _stick_figure(45.0)
    with pytest.raises(FitError, match=r"0\.5\d* file units tall .* set body\.surface_unit"):
        resolve_frame(0.3 * v, f, "auto", "auto", "auto")          # 0.5 units: no unit makes it a human
    assert resolve_frame(0.3 * v, f, 3.4, "auto", "auto")[0] == 3.4  # a giant's unit, given, is taken
    with pytest.raises(FitError, match="skeleton.fit_forward = 'Y' lies along the surface's up axis Y"):
        resolve_frame(v, f, "auto", "auto", "Y")
    with pytest.raises(FitError, match="body.surface_unit: unit 'furlong'"):
        resolve_frame(v, f, "furlong", "auto", "auto")


def test_the_character_scene_binds_a_turned_copy_of_its_mesh_with_nothing_declared(tmp_path, monkeypatch):
    """The shipped character scene on MakeHuman's body written Z up, facing -Y, in centimetres (a file nobody declared
    the unit or axes of): it builds, every bone inside, the file's -Y taken to the world's forward (ROS +X) and its Z
    to up, at a hundredth of a metre per unit (to the fit's own scaling). A wrong read would turn the body on its side
    or make it ten times too large, and the build would refuse the bones outside it."""
    import trimesh

    from benchmarks.clips import clip_config
    from clusterfem_ros.body.surface_body import build_surface_body
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.skeleton.kinematics import Skeleton
    from tests.shared_data import CHARACTER_SCENE, character_mesh, walk_clip
    entry = next(m for m in MESHES if m.name == "makehuman_base")
    v, f = read_entry(character_mesh(), entry)
    frame, _, _, metres = TURNS[1]
    turned = tmp_path / "makehuman_z_up_cm.obj"
    trimesh.Trimesh((0.1 / metres) * v @ frame.T, f, process=False).export(turned)
    monkeypatch.setenv("CLUSTERFEM_CACHE", str(tmp_path / "cache"))
    config = clip_config(scene=CHARACTER_SCENE).with_values(
        {"body.surface_file": str(turned), "body.surface_group": "", "body.target_tets": 1500})
    skeleton = Skeleton.from_urdf_string(load_motion("bvh", walk_clip()).urdf)
    said = []
    body = build_surface_body(config, skeleton, progress=said.append)
    assert any(s.startswith("surface frame read from its shape") and "up Z, forward -Y" in s for s in said), said
    # the bind turns the mesh about the vertical onto the skeleton's heading (body/auto_bind.py): a degree or two,
    # as fTetWild's tets differ from run to run (2.1 deg seen once); a wrong axis read is 90 deg off
    np.testing.assert_allclose(body.fit.rotation @ [0, -1, 0], [1, 0, 0], atol=0.05)
    np.testing.assert_allclose(body.fit.rotation @ [0, 0, 1], [0, 0, 1], atol=1e-9)
    assert 0.5 * metres < body.fit.scale < 2.0 * metres


def _obj(path, groups):
    """An OBJ file of named groups, each (vertices, faces)."""
    lines, base = [], 1
    for name, (v, f) in groups.items():
        lines.append(f"g {name}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in f]
        base += len(v)
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_surface_group_auto_takes_a_closed_largest_group_else_the_whole_file(tmp_path):
    """MakeHuman's OBJ: its 'body' (13378 faces, closed) beside 138 helper and joint groups with faces. A closed largest group
    is taken, an open one is not (a model split into parts is read whole), nor is a file of one group or not an OBJ;
    a group named for a file that is not an OBJ is refused, naming the parameter."""
    import trimesh

    from clusterfem_ros.fem.mesh.tetrahedralize import SurfaceError, pick_group, read_surface
    from tests.shared_data import character_mesh
    group, why = pick_group(character_mesh())
    assert group == "body" and "the largest of the file's 139 groups (13378 faces, closed" in why, why
    ball = trimesh.creation.icosphere(subdivisions=3)                          # 1280 faces, closed
    sheet = trimesh.creation.icosphere(subdivisions=4)                         # 5120 faces, its top cut off: open
    sheet.update_faces(sheet.triangles_center[:, 2] < 0.5)
    sheet.remove_unreferenced_vertices()
    assert len(sheet.faces) > len(ball.faces) and not sheet.is_watertight
    small = trimesh.creation.icosphere(subdivisions=1)
    parts = {"body": (ball.vertices, ball.faces), "eyes": (small.vertices + 3.0, small.faces)}
    assert pick_group(_obj(tmp_path / "body.obj", parts))[0] == "body"
    open_largest = {**parts, "cloth": (sheet.vertices + 6.0, sheet.faces)}
    group, why = pick_group(_obj(tmp_path / "split.obj", open_largest))
    assert group == "" and "'cloth', is not a closed surface" in why
    assert pick_group(_obj(tmp_path / "one.obj", {"only": parts["body"]}))[0] == ""
    ball.export(tmp_path / "ball.stl")
    assert pick_group(tmp_path / "ball.stl") == ("", "body.surface_group auto: the whole file (not an OBJ)")
    with pytest.raises(SurfaceError, match="body.surface_group = 'body' picks an OBJ group"):
        read_surface(tmp_path / "ball.stl", "body")


def test_the_group_chosen_is_kept_with_the_tets_and_said_on_every_start(tmp_path, monkeypatch):
    """``surface_to_tets(group='auto')`` chooses once per file (by its sha256) and says the choice every time; the
    tets are those of the group chosen, under the same cache key as when that group is named."""
    import trimesh

    from clusterfem_ros.fem.mesh import tetrahedralize as tz
    ball, small = trimesh.creation.icosphere(subdivisions=3), trimesh.creation.icosphere(subdivisions=1)
    path = _obj(tmp_path / "body.obj", {"body": (ball.vertices, ball.faces), "eyes": (small.vertices + 3.0, small.faces)})
    said = []
    first = tz.surface_to_tets(path, 300, group="auto", cache=tmp_path / "cache", progress=said.append)
    assert said[0].startswith("body.surface_group auto: group 'body'") and not first.cached

    def no_parse(_):
        raise AssertionError("the groups were parsed again")

    monkeypatch.setattr(tz, "pick_group", no_parse)
    said.clear()
    again = tz.surface_to_tets(path, 300, group="auto", cache=tmp_path / "cache", progress=said.append)
    named = tz.surface_to_tets(path, 300, group="body", cache=tmp_path / "cache")
    assert said[0].startswith("body.surface_group auto: group 'body'") and again.cached and named.cached
    np.testing.assert_array_equal(again.mesh.tets, first.mesh.tets)
    assert np.ptp(first.mesh.vertices, axis=0).max() < 2.5                  # the ball, not the eyes 3 away
