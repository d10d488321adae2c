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
