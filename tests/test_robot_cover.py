"""Soft covers on robots: the joint sweep, the cover around the links' own shapes, its binding, and each shipped
robot scene (config/robot_*.yaml) played headless with 0 resets."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks.cover_extent import diagonal_bar, far_apart
from clusterfem_ros.body.link_binding import bind_to_links
from clusterfem_ros.skeleton.joint_sweep import joint_sweep
from clusterfem_ros.skeleton.kinematics import Skeleton
from clusterfem_ros.skeleton.robot_cover import robot_cover
from clusterfem_ros.skeleton.robot_data import package_file, robot_data_folder
from clusterfem_ros.skeleton.urdf_check import DEFAULT_MAX_LINKS

ROOT = Path(__file__).resolve().parents[1]
ROBOT_SCENES = sorted((ROOT / "config").glob("robot_*.yaml"))


def _link(name: str, shape: str = "", mass: float = 1.0, xyz: str = "0 0 0") -> str:
    geometry = f"<collision><origin xyz='{xyz}'/><geometry>{shape}</geometry></collision>" if shape else ""
    return (f"<link name='{name}'><inertial><mass value='{mass}'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' "
            f"iyz='0'/></inertial>{geometry}</link>")


def _joint(name: str, kind: str, parent: str, child: str, xyz: str = "0 0 0", axis: str = "0 1 0",
           limit: str = "", extra: str = "") -> str:
    return (f"<joint name='{name}' type='{kind}'><parent link='{parent}'/><child link='{child}'/>"
            f"<origin xyz='{xyz}'/><axis xyz='{axis}'/>{limit}{extra}</joint>")


# an arm: a base, two 0.3 m links on revolute joints, a wrist fixed to the second, two fingers (prismatic, one a
# mimic of the other) and a spinning tool (continuous)
ARM = ("<robot name='arm'>"
       + _link("base", "<box size='0.2 0.2 0.1'/>")
       + _link("upper", "<box size='0.08 0.08 0.3'/>", xyz="0 0 0.15")
       + _link("fore", "<cylinder radius='0.04' length='0.3'/>", xyz="0 0 0.15")
       + _link("wrist", "<sphere radius='0.05'/>")
       + _link("finger_a", "<box size='0.02 0.02 0.06'/>", xyz="0 0 0.03")
       + _link("finger_b", "<box size='0.02 0.02 0.06'/>", xyz="0 0 0.03")
       + _link("tool", "<box size='0.03 0.03 0.08'/>", xyz="0 0 0.04")
       + _joint("shoulder", "revolute", "base", "upper", "0 0 0.05", limit="<limit lower='-1' upper='2' effort='1' velocity='1'/>")
       + _joint("elbow", "revolute", "upper", "fore", "0 0 0.3", limit="<limit lower='-2.5' upper='-0.5' effort='1' velocity='1'/>")
       + _joint("wrist_fix", "fixed", "fore", "wrist", "0 0 0.3")
       + _joint("grip_a", "prismatic", "wrist", "finger_a", "0.05 0 0.04", axis="1 0 0",
                limit="<limit lower='0' upper='0.04' effort='1' velocity='1'/>")
       + _joint("grip_b", "prismatic", "wrist", "finger_b", "-0.05 0 0.04", axis="-1 0 0",
                limit="<limit lower='0' upper='0.04' effort='1' velocity='1'/>", extra="<mimic joint='grip_a' multiplier='1' offset='0'/>")
       + _joint("spin", "continuous", "wrist", "tool", "0 0.08 0", axis="0 1 0")
       + "</robot>")


def test_sweep_stays_in_range_loops_and_moves_mimics_with_their_master():
    sweep = joint_sweep(ARM, fraction=0.6, period=4.0)
    tr = sweep.trajectory
    assert tr.names == ["shoulder", "elbow", "grip_a", "grip_b", "spin"]     # fixed joints are not played
    q = tr.positions
    limits = {"shoulder": (-1, 2), "elbow": (-2.5, -0.5), "grip_a": (0, 0.04), "grip_b": (0, 0.04)}
    for name, (lo, hi) in limits.items():
        col = q[:, tr.names.index(name)]
        assert lo - 1e-12 <= col.min() and col.max() <= hi + 1e-12, name
        assert np.ptp(col) == pytest.approx(0.6 * (hi - lo), rel=0.02), f"{name} sweeps 60 % of its range"
    # the sweep is around the rest pose where the range allows: the shoulder's range holds 0 +- 0.9
    assert q[:, 0].mean() == pytest.approx(0.0, abs=0.02)
    # the elbow's range excludes 0: its sweep is as near 0 as the range allows
    assert q[:, 1].max() == pytest.approx(-0.5, abs=1e-3)
    np.testing.assert_allclose(q[:, 3], q[:, 2], atol=1e-15)             # the mimic follows its master
    spin = q[:, 4]
    assert spin.min() == pytest.approx(0.0, abs=1e-9) and spin.max() == pytest.approx(2 * np.pi, rel=1e-3)
    np.testing.assert_allclose(q[-1], q[0], atol=1e-9)                  # one period: it loops without a seam
    v = np.abs(np.diff(q, axis=0)) / np.diff(tr.times)[:, None]
    assert v.max() < 2 * np.pi * np.pi / 4.0 * 1.01, "no joint is faster than the turn of the continuous one"


def test_sweep_holds_a_joint_without_range_and_names_it():
    urdf = ("<robot name='r'>" + _link("a") + _link("b") + _link("c")
            + _joint("j1", "revolute", "a", "b", limit="<limit lower='0' upper='0' effort='1' velocity='1'/>")
            + _joint("j2", "revolute", "b", "c", limit="<limit lower='-1' upper='1' effort='1' velocity='1'/>")
            + "</robot>")
    sweep = joint_sweep(urdf)
    assert not sweep.trajectory.positions[:, 0].any()
    assert any("j1" in note for note in sweep.notes)
    with pytest.raises(ValueError, match="fraction"):
        joint_sweep(urdf, fraction=1.5)
    with pytest.raises(ValueError, match="nothing to sweep"):
        joint_sweep("<robot name='r'>" + _link("a") + "</robot>")


def _arm_cover(**kw):
    sk = Skeleton.from_urdf_string(ARM)
    return sk, robot_cover(ARM, sk, **kw)


def test_cover_keeps_rigid_bodies_apart_and_holds_every_link():
    sk, cover = _arm_cover(thickness=0.01, target_tets=3000)
    mesh = cover.mesh
    assert 0.8 * 3000 <= mesh.n_tets <= 1.2 * 3000
    names = sk.bone_names
    body = {"base": 0, "upper": 1, "fore": 2, "wrist": 2, "finger_a": 3, "finger_b": 4, "tool": 5}
    vertex_body = np.array([body[names[b]] for b in cover.bone])
    # no tet joins two rigid bodies (wrist is fixed to fore: one body), so each part moves with its own link
    assert (vertex_body[mesh.tets] == vertex_body[mesh.tets[:, :1]]).all()
    # each rigid body of these sizes keeps a part
    assert set(vertex_body.tolist()) == set(body.values())
    # the cover holds each link's shape: the centres of the upper arm's box and the forearm's cylinder lie in the
    # cover (inside a tet of their own link)
    for link, centre in (("upper", [0, 0, 0.2]), ("fore", [0, 0, 0.5])):
        tets = mesh.tets[cover.bone[mesh.tets[:, 0]] == names.index(link)]
        x = mesh.vertices[tets]
        lo, hi = x.min(axis=(0, 1)), x.max(axis=(0, 1))
        assert (lo <= centre).all() and (np.array(centre) <= hi).all(), link
        assert cover.depth[np.unique(tets)].min() < 0, f"{link}: vertices inside the closed shape have depth < 0"


def test_link_binding_binds_every_vertex_to_its_own_link_in_levels_by_depth():
    sk, cover = _arm_cover(thickness=0.02, target_tets=2000)
    poses = sk.forward(sk.neutral())
    starts, ends = sk.bone_segments(sk.neutral())
    b = bind_to_links(cover.mesh.vertices, cover.bone, cover.depth, 2, core=0.5 * cover.spacing,
                      skin=cover.thickness, starts=starts, ends=ends, rest_rotation=poses.rotation,
                      rest_translation=poses.translation)
    np.testing.assert_array_equal(b.bone, cover.bone)
    assert (b.level >= 0).all(), "every vertex of a robot cover is bound"
    assert (b.level[cover.depth <= 0.5 * cover.spacing] == 0).all()
    for bone in np.unique(cover.bone):
        assert (b.level[cover.bone == bone] == 0).any(), f"bone {sk.bone_names[bone]} holds its part firmly"
    # the local coordinates carry the rest positions: x = R local + p at rest
    x = np.einsum("nij,nj->ni", poses.rotation[b.bone], b.local) + poses.translation[b.bone]
    np.testing.assert_allclose(x, cover.mesh.vertices, atol=1e-12)


def test_cover_puts_capsules_on_bare_bones_and_refuses_a_urdf_with_nothing_to_cover():
    urdf = ("<robot name='r'>" + _link("a") + _link("b") + _link("c")
            + _joint("j", "revolute", "a", "b", "0 0 0.3", limit="<limit lower='-1' upper='1' effort='1' velocity='1'/>")
            + _joint("k", "revolute", "b", "c", "0 0 0.3", limit="<limit lower='-1' upper='1' effort='1' velocity='1'/>")
            + "</robot>")
    sk = Skeleton.from_urdf_string(urdf)
    cover = robot_cover(urdf, sk, thickness=0.01, target_tets=1500, bare_radius=0.04)
    assert any("capsule of 0.04 m" in note for note in cover.notes)
    # a and b have segments of 0.3 m (c has none): their capsules of radius 0.04 (plus the skin) hold the cover
    assert set(np.unique(cover.bone).tolist()) == {sk.bone_names.index("a"), sk.bone_names.index("b")}
    x = cover.mesh.vertices
    assert np.hypot(x[:, 0], x[:, 1]).max() < 0.04 + cover.thickness + cover.spacing
    assert x[:, 2].min() < -0.03 and x[:, 2].max() > 0.63
    lone = "<robot name='r'>" + _link("a") + "</robot>"
    with pytest.raises(ValueError, match="no link of this URDF has a usable collision or visual shape"):
        robot_cover(lone, Skeleton.from_urdf_string(lone))


def _no_pinocchio_data(monkeypatch):
    """Make any use of the skeleton's pinocchio Data fail (its size grows with the cube of the joints)."""
    def refuse(*_args, **_kw):
        raise AssertionError("the cover made pinocchio's Data")
    monkeypatch.setattr(Skeleton, "data", property(refuse))
    monkeypatch.setattr(Skeleton, "pinocchio_data", refuse, raising=False)


def _cover_robots():
    """(name, prepared URDF, urdf_file): the arm, and example-robot-data's Panda (meshes on fixed-joint links,
    links beyond them) prepared as the robot scene does, when installed."""
    out = [("arm", ARM, None)]
    panda = package_file("package://example-robot-data/robots/panda_description/urdf/panda.urdf")
    if panda is not None:
        from clusterfem_ros.skeleton.link_shapes import prepare_urdf
        out.append(("panda", prepare_urdf(panda.read_text(), root_joint="fixed", urdf_file=panda).urdf, panda))
    return out


@pytest.mark.parametrize("name, urdf, path", _cover_robots(), ids=[n for n, _, _ in _cover_robots()])
def test_cover_parts_place_the_shapes_where_pinocchio_puts_their_links_without_its_data(monkeypatch, name, urdf,
                                                                                      path):
    """cover_parts places each link's shapes by the skeleton's own kinematics: equal, to round-off, to the shapes
    moved by pinocchio's oMf of the link's BODY frame, and pinocchio's Data is never made."""
    import pinocchio as pin

    from clusterfem_ros.skeleton.robot_cover import cover_parts, link_geometry, search_folders
    sk = Skeleton.from_urdf_string(urdf)
    data = sk.model.createData()                    # the reference, made before Data is forbidden
    pin.forwardKinematics(sk.model, data, pin.neutral(sk.model))
    pin.updateFramePlacements(sk.model, data)
    geometry, _ = link_geometry(urdf, "collision", search_folders(path))
    _no_pinocchio_data(monkeypatch)
    parts, _ = cover_parts(urdf, sk, geometry, spacing=0.01)
    assert len(parts) >= 7, [p.link for p in parts]
    for part in parts:
        M = data.oMf[sk.model.getFrameId(part.link, pin.BODY)]
        for mesh, world in zip(geometry[part.link], part.meshes):
            want = np.asarray(mesh.vertices) @ M.rotation.T + M.translation
            np.testing.assert_allclose(np.asarray(world.vertices), want, atol=1e-12, err_msg=f"{name} {part.link}")


def boxed_star(n: int) -> str:
    """A root and n - 1 leaves on revolute joints, each link with a 2 cm box, the leaves 5 cm apart on a grid of 32
    columns at height 0.1 m (leaf k at (0.05 (k % 32), 0.05 (k // 32), 0.1))."""
    box = "<box size='0.02 0.02 0.02'/>"
    return ("<robot name='boxed_star'>" + "".join(_link(f"l{k}", box) for k in range(n))
            + "".join(_joint(f"j{k}", "revolute", "l0", f"l{k}", f"{0.05 * (k % 32):g} {0.05 * (k // 32):g} 0.1",
                             limit="<limit lower='-1' upper='1' effort='1' velocity='1'/>") for k in range(1, n))
            + "</robot>")


_LARGE_COVER = """
import os, resource, sys
import numpy as np
resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))  # a regression fails with MemoryError, not the host's OOM
from benchmarks.hostile_urdf import memory_kb
from clusterfem_ros.config import SceneConfig
from clusterfem_ros.scene import Scene
from clusterfem_ros.skeleton.kinematics import UrdfError
from clusterfem_ros.skeleton.urdf_check import DEFAULT_MAX_LINKS
from tests.test_robot_cover import boxed_star
config = SceneConfig().with_values({"skeleton.source": "robot_description", "body.kind": "robot_cover",
                                    "body.target_tets": 3000})
Scene.build(config, urdf_xml=boxed_star(3))               # imports and compiled kernels, before the measurement
before = memory_kb(os.getpid())[1]
notes = []
scene = Scene.build(config, urdf_xml=boxed_star(DEFAULT_MAX_LINKS), progress=notes.append)
grew = (memory_kb(os.getpid())[1] - before) / 1024
sk, b, x = scene.skeleton, scene.binding, scene.model.rest
k = np.array([int(sk.bone_names[i][1:]) for i in b.bone])
centre = np.stack([0.05 * (k % 32), 0.05 * (k // 32), np.where(k > 0, 0.1, 0.0)], axis=1)
print("joints", sk.nq, "bones", sk.n_bones, "covered", len(np.unique(b.bone)))
print("farthest", np.linalg.norm(x - centre, axis=1).max())
print("notes", " | ".join(n for n in notes if "robot cover:" in n or "surface samples" in n))
try:
    sk.data
    print("data made")
except UrdfError as e:
    print("data refused", e)
print("grew_mb", grew)
"""


def test_a_cover_on_the_largest_star_the_limits_accept_builds_small_and_on_its_links():
    """A robot_description of max_links links (a star, each link a 2 cm box on a 5 cm grid) becomes a robot-cover
    scene in a process of its own whose peak resident memory (its own VmHWM) grows by less than 300 MB: the links are
    placed without pinocchio's Data (~60 GB for these 1,005 joints, refused), and the cover's surface samples stay
    within robot_cover.MAX_SAMPLES (at extent / 300 these small shapes took 400,000 samples per link, 17 GB). Each
    vertex lies at its own link's box. The child's address space is capped (6 GB), so a regression fails here
    instead of exhausting the host."""
    out = subprocess.run([sys.executable, "-c", _LARGE_COVER], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    got = {line.split()[0]: line.split(maxsplit=1)[1] for line in out.stdout.splitlines() if line.strip()}
    joints, bones, covered = (int(v) for v in got["joints"].split()[::2])
    assert bones == DEFAULT_MAX_LINKS and joints >= DEFAULT_MAX_LINKS - 1 and covered >= 100, got
    # a link's box, its skin and a voxel (33 mm): 67 mm; a part placed on another link or at the root is farther
    assert float(got["farthest"]) < 0.1, f"a vertex {float(got['farthest']):.3f} m from its own link's box"
    assert "surface samples" in got["notes"], got["notes"]
    assert got["data"].startswith(f"refused pinocchio's Data for {joints} joints"), got["data"]
    grew = float(got["grew_mb"])
    assert grew < 300, f"building the cover on {DEFAULT_MAX_LINKS} links added {grew:.0f} MB"


def test_shapes_past_the_triangle_budget_are_refused_with_one_line_before_any_meshing():
    """body.cover_max_triangles bounds the shapes a cover reads (a mesh named 2,000 times, or 20,000 spheres, in
    a URDF within the size limits held gigabytes): past it the scene refuses, naming the count and the parameter."""
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.scene_build import scene_parts
    from clusterfem_ros.skeleton.urdf_check import UrdfRefused
    spheres = "".join(f"<collision><origin xyz='{0.05 * k} 0 0'/><geometry><sphere radius='0.02'/></geometry>"
                      "</collision>" for k in range(4))                 # 4 x 320 triangles
    urdf = ARM.replace("<link name='base'>", f"<link name='base'>{spheres}")
    config = SceneConfig().with_values({"skeleton.source": "robot_description", "body.kind": "robot_cover",
                                        "body.cover_max_triangles": 1000})
    with pytest.raises(UrdfRefused, match=r"more than 1,000 triangles \(body.cover_max_triangles; 1,\d{3} read up to "
                                          r"link 'base', <collision>\).*raise body.cover_max_triangles") as refused:
        scene_parts(config, urdf)
    assert refused.value.kind == "too_many_triangles" and "\n" not in str(refused.value)
    sk = Skeleton.from_urdf_string(urdf)
    assert robot_cover(urdf, sk, target_tets=300, max_triangles=2000).mesh.n_tets > 0     # 1,280 + the arm's


_FAR_COVER = """
import os, resource
import numpy as np
resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))  # a regression fails with MemoryError, not the host's OOM
from benchmarks.hostile_urdf import memory_kb
from clusterfem_ros.config import SceneConfig
from clusterfem_ros.scene import Scene
from benchmarks.cover_extent import far_apart
config = SceneConfig().with_values({"skeleton.source": "robot_description", "body.kind": "robot_cover"})
Scene.build(config, urdf_xml=far_apart(0.3))                # imports and compiled kernels, before the measurement
before = memory_kb(os.getpid())[1]
for d, plane in ((9.0, True), (9.0, False), (100.0, True), (100.0, False)):
    notes = []
    scene = Scene.build(config, urdf_xml=far_apart(d, plane), progress=notes.append)
    sk, b, x = scene.skeleton, scene.binding, scene.model.rest
    centre = {n: sk.link_placements(sk.neutral(), [n])[1][0] for n in ("root", "a", "b")}
    at = np.array([centre[sk.bone_names[i]] for i in b.bone])
    cover = [n for n in notes if n.startswith("robot cover:")][0]
    print(f"case {d:g} {'plane' if plane else 'diagonal'} tets {scene.model.mesh.n_tets} "
          f"farthest {np.linalg.norm(x - at, axis=1).max():.4f} covered {cover.split(' on ')[1].split(' shaped')[0]!r}")
print("grew_mb", (memory_kb(os.getpid())[1] - before) / 1024)
"""


def test_links_far_apart_get_a_cover_whose_cost_follows_their_shapes():
    """A robot_description of three 5 cm boxes, the leaves 9 m and 100 m apart (across the space diagonal, and at a
    right angle in a plane), becomes a robot-cover scene of the tets asked for on all three links, in a process of its
    own whose peak resident memory (its own VmHWM) grows by less than 300 MB for the four: the voxels are looked at
    in each link's box only (over the whole bounding box, 9 m in a plane took ~1 GB and 16 s, and across the diagonal
    the grid was refused past 5e7 voxels, 'choose a larger spacing'). The child's address space is capped (6 GB)."""
    out = subprocess.run([sys.executable, "-c", _FAR_COVER], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    cases = [line.split() for line in out.stdout.splitlines() if line.startswith("case ")]
    assert len(cases) == 4, out.stdout
    for case in cases:
        tets, farthest, covered = int(case[4]), float(case[6]), " ".join(case[8:])
        assert abs(tets - 4800) <= 0.2 * 4800, case
        # a link's box (half-diagonal 43 mm), its skin (20 mm) and a voxel's diagonal (~23 mm)
        assert farthest < 0.1, f"a vertex {farthest:.3f} m from its own link: {case}"
        assert covered == "'3 of 3'", case
    grew = float(out.stdout.split("grew_mb")[1])
    assert grew < 300, f"the four far-apart covers added {grew:.0f} MB"


def test_a_cover_past_the_voxel_limit_is_refused_with_one_line():
    """A 30 m bar on the space diagonal has a box of 17 m a side: at the spacing of the tets asked for its box alone
    holds more voxels than robot_cover.MAX_VOXELS, so the scene refuses in one line naming the robot's extent, the
    count, the link, the limit and what to change; links 1 km apart pass MAX_AXIS_VOXELS along an axis, refused
    alike."""
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.scene_build import scene_parts
    from clusterfem_ros.skeleton.urdf_check import UrdfRefused
    config = SceneConfig().with_values({"skeleton.source": "robot_description", "body.kind": "robot_cover"})
    with pytest.raises(UrdfRefused, match=r"^a robot cover over links spanning 17.\d x 17.\d x 17.\d m would look at "
                                          r"[\d,]+ voxels of [\d.]+ mm around its 2 shaped links \([\d,]+ around link "
                                          r"'bar', 17.\d x 17.\d x 17.\d m\), past the limit of 4,000,000 \(robot_cover"
                                          r".MAX_VOXELS\); refused; lower body.target_tets \(now 4,800\) for larger "
                                          r"voxels, or check the URDF's link shapes and joint origins$") as refused:
        scene_parts(config, diagonal_bar(30.0))
    assert refused.value.kind == "cover_too_large" and "\n" not in str(refused.value)
    with pytest.raises(UrdfRefused, match=r"^a robot cover over links spanning 57\d x 57\d x 57\d m would need "
                                          r"[\d.e+]+ voxels of [\d.]+ mm along an axis, past the limit of 16,384 "
                                          r"\(robot_cover.MAX_AXIS_VOXELS\); refused; lower body.target_tets"
                       ) as refused:
        scene_parts(config, far_apart(1000.0))
    assert refused.value.kind == "cover_too_large" and "\n" not in str(refused.value)


def test_the_voxel_limit_is_checked_before_any_voxel_is_looked_at(monkeypatch):
    """Every spacing tried looks at the voxels of the links' boxes only when their count is within MAX_VOXELS: with
    the limit below the arm's boxes the cover is refused and no box was looked at past it."""
    from clusterfem_ros.skeleton import robot_cover as rc
    from clusterfem_ros.skeleton.urdf_check import UrdfRefused
    looked = []
    voxels = rc._voxels

    def counting(parts, trees, lo, n, i0, i1, h, thickness):
        looked.append(int(np.prod(np.maximum(i1 - i0, 0), axis=1).sum()))
        return voxels(parts, trees, lo, n, i0, i1, h, thickness)

    monkeypatch.setattr(rc, "_voxels", counting)
    cover = robot_cover(ARM, Skeleton.from_urdf_string(ARM), target_tets=2000)
    assert cover.mesh.n_tets > 0 and looked
    limit = max(looked) - 1
    monkeypatch.setattr(rc, "MAX_VOXELS", limit)
    looked.clear()
    with pytest.raises(UrdfRefused, match=rf"past the limit of {limit:,} \(robot_cover.MAX_VOXELS\)"):
        robot_cover(ARM, Skeleton.from_urdf_string(ARM), target_tets=2000)
    assert all(c <= limit for c in looked), looked


def test_separating_rigid_bodies_on_lattice_keys_equals_the_dense_twin():
    """_separate on the solid voxels' lattice keys drops the voxels the dense, one-neighbour-at-a-time twin
    (tests/naive.py) drops, on random lattices of random parts and bodies."""
    from clusterfem_ros.skeleton.robot_cover import _key, _separate

    from . import naive
    rng = np.random.default_rng(11)
    body_of = np.array([0, 0, 1, 2, 2, 3])
    for trial in range(12):
        n = rng.integers(2, 8, 3)
        mask = rng.random(tuple(n)) < rng.uniform(0.2, 0.9)
        part = rng.integers(0, len(body_of), tuple(n))
        ijk = np.argwhere(mask)
        kept = _separate(n, _key(n, *ijk.T), part[mask], body_of)
        assert np.array_equal(kept, naive.separate(mask, body_of[part])[mask]), f"trial {trial}"


def test_package_names_resolve_only_in_installed_packages():
    from clusterfem_ros.body.fit import FitError, find_data_file
    assert package_file("package://no-such-package/robots/x.urdf") is None
    assert package_file("robots/x.urdf") is None
    with pytest.raises(FitError, match="in no installed package"):
        find_data_file("package://no-such-package/robots/x.urdf")


def test_the_player_section_takes_the_joint_sweep(tmp_path):
    from clusterfem_ros.motion import load_motion, load_player_section, skeleton_source_for
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM)
    scene = tmp_path / "scene.yaml"
    scene.write_text(f"mocap_player:\n  ros__parameters: {{source: joint_sweep, file: {urdf}}}\n")
    assert load_player_section(scene)["source"] == "joint_sweep"
    motion = load_motion("joint_sweep", urdf)
    assert motion.urdf == ARM and motion.trajectory.names[-1] == "spin"
    assert skeleton_source_for("joint_sweep") == "urdf_file"


def _need_robot_data():
    if robot_data_folder() is None:
        pytest.skip("example-robot-data is not installed (requirements.lock pins it): the robot scenes use its URDFs")


@pytest.mark.parametrize("scene_file", ROBOT_SCENES, ids=[p.stem for p in ROBOT_SCENES])
def test_robot_scene_plays_its_sweep_with_no_reset(scene_file):
    """Each shipped robot scene, its player's joint sweep played 3 s headless on the input clock: 0 resets, the
    cover on its links (no vertex farther from where its link carries it than its skin is thick)."""
    _need_robot_data()
    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.fem.stability import DivergenceError
    from clusterfem_ros.motion import load_motion, load_player_section
    from clusterfem_ros.scene import Scene
    player = load_player_section(scene_file)
    assert player["source"] == "joint_sweep"
    tr = load_motion("joint_sweep", player["file"]).trajectory
    scene = Scene.build(load_scene_file(scene_file))
    assert scene.model.mesh.n_tets >= 1000
    column = {n: k for k, n in enumerate(tr.names)}
    assert set(column) <= set(scene.skeleton.joint_names), "the sweep plays the robot's own joint names"
    b = scene.binding
    worst = 0.0
    for k in range(3 * 120 + 1):
        t = 1000.0 + k / 120
        q, v = tr.sample(k / 120)
        scene.push_joint_state(t, tr.names, q, v)
        try:
            scene.advance_to(t)
        except DivergenceError as exc:
            pytest.fail(f"{scene_file.name}: reset at {k / 120:.2f} s: {exc}")
        if k % 30 == 0 and scene.sim_time is not None:
            assert scene.output_problem() is None
            qs = np.array([q[column[n]] if n in column else 0.0 for n in scene.skeleton.joint_names])
            poses = scene.skeleton.forward(qs)
            carried = np.einsum("nij,nj->ni", poses.rotation[b.bone], b.local) + poses.translation[b.bone]
            worst = max(worst, float(np.linalg.norm(scene.model.rest + scene.state.u - carried, axis=1).max()))
    thickness = scene.config.body.cover_thickness
    assert worst < thickness, f"a vertex lags {worst * 1e3:.1f} mm behind its link, more than the skin's thickness"


def test_a_mimic_joint_left_out_follows_its_master():
    from dataclasses import replace

    from clusterfem_ros.skeleton.joint_limits import JointLimits
    from clusterfem_ros.skeleton.joint_map import JointMap
    limits = replace(JointLimits.none(3), mimic=((1, 0, -2.0, 0.1),))        # b = -2 a + 0.1
    jm = JointMap(["a", "b", "c"], limits=limits)
    r = jm.update(["a", "c"], [0.5, 0.2], [1.0, 3.0])
    np.testing.assert_allclose(r.q, [0.5, -0.9, 0.2])
    np.testing.assert_allclose(r.v, [1.0, -2.0, 3.0])
    assert r.updated.all()
    r = jm.update(["a", "b"], [0.5, 0.3])                # a message that sets the mimic joint itself wins
    np.testing.assert_allclose(r.q, [0.5, 0.3, 0.2])
    r = jm.update(["c"], [0.0])                          # the master not set: the mimic keeps its value
    np.testing.assert_allclose(r.q, [0.5, 0.3, 0.0])


def test_binding_keeps_each_vertex_on_the_bones_it_may_take():
    from clusterfem_ros.body.binding import bind_to_skeleton
    starts = np.array([[0.0, 0, 0], [0.1, 0, 0]])
    ends = np.array([[0.0, 0, 1], [0.1, 0, 1]])
    x = np.array([[0.04, 0, 0.5], [0.06, 0, 0.5], [0.2, 0, 0.5]])
    free = bind_to_skeleton(x, starts, ends, [0.1], warn=False)
    np.testing.assert_array_equal(free.bone, [0, 1, 1])
    allowed = np.array([[False, True], [True, False], [False, False]])      # the last row: every bone
    kept = bind_to_skeleton(x, starts, ends, [0.1], warn=False, allowed=allowed)
    np.testing.assert_array_equal(kept.bone, [1, 0, 1])
    np.testing.assert_allclose(kept.distance, [0.06, 0.06, 0.1])


def test_the_panda_on_the_jelly_body_plays_its_sweep_with_no_reset():
    """The issue's case: example-robot-data's Panda as the skeleton of the default jelly body, its joints swept. At
    q = 0 its hand hangs 5 cm beside its forearm; bound by the nearest segment alone, vertices of the forearm's
    voxels went to the fingers and the sweep tore those tets (116 resets in 4 s). Bound to the bones of their own
    voxels, the body holds."""
    _need_robot_data()
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.fem.stability import DivergenceError
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.scene import Scene
    urdf = "package://example-robot-data/robots/panda_description/urdf/panda.urdf"
    tr = load_motion("joint_sweep", urdf).trajectory
    # the voxel skin: the smooth one, snapped onto the hand's boxes, leaves tets there that need 86 sub-steps at
    # the placement (physics.max_substeps 64; README, known limits)
    scene = Scene.build(SceneConfig().with_values({"skeleton.source": "urdf_file", "skeleton.urdf_file": urdf,
                                                   "body.skin": "voxel"}))
    names = scene.skeleton.bone_names
    bones = scene.binding.bone[scene.model.mesh.tets]
    forearm, finger = names.index("panda_link4"), names.index("panda_rightfinger")
    assert not ((bones == forearm).any(axis=1) & (bones == finger).any(axis=1)).any(), \
        "a tet holds vertices bound to the forearm and to a finger"
    for k in range(3 * 120 + 1):
        t = 1000.0 + k / 120
        q, v = tr.sample(k / 120 + 2.0)            # from 2 s on: the stretch of the sweep that tore the body
        scene.push_joint_state(t, tr.names, q, v)
        try:
            scene.advance_to(t)
        except DivergenceError as exc:
            pytest.fail(f"reset at {k / 120:.2f} s: {exc}")
