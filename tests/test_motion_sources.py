"""Motion sources are registered (motion.MOTION_SOURCES): loading a motion, the node's fitting skeleton and the
player's choices read the registry, so a new source is one function and one registration."""
from __future__ import annotations

import numpy as np
import pytest

from clusterfem_ros import motion
from clusterfem_ros.skeleton.humanoid import default_humanoid
from clusterfem_ros.skeleton.trajectory import JointTrajectory


@pytest.fixture
def toy_source():
    """A source of its own: the built-in humanoid standing still for a second, from no file."""
    def still(path, **_):
        spec = default_humanoid()
        times = np.array([0.0, 1.0])
        traj = JointTrajectory(times, list(spec.joint_names), np.zeros((2, len(spec.joint_names))))
        return motion.Motion(spec.urdf, traj, "standing still (1 s)", True)
    source = motion.register_source(motion.MotionSource("toy_still", "the humanoid standing still", still))
    yield source
    motion.MOTION_SOURCES.unregister(source.name)


def test_a_registered_source_loads_by_name_and_names_its_skeleton(toy_source):
    got = motion.load_motion("toy_still")
    assert got.description == "standing still (1 s)" and got.trajectory.duration == 1.0
    assert motion.skeleton_source_for("toy_still") == "builtin"
    with pytest.raises(ValueError, match="taken"):
        motion.register_source(toy_source)


def test_an_unknown_source_or_a_missing_file_is_refused_naming_the_choices():
    with pytest.raises(ValueError, match="unknown: choose one of builtin_walk, bvh, keyframes, joint_sweep"):
        motion.load_motion("bvhh")
    with pytest.raises(ValueError, match="'bvh' needs a file: set the 'file' parameter to a .bvh path"):
        motion.load_motion("bvh")


def test_the_player_offers_every_built_in_source_and_the_node_fits_each_one_skeleton():
    source = next(p for p in motion.PLAYER_TABLE if p.name == "source")
    assert tuple(source.choices) == tuple(motion.MOTION_SOURCES) == motion.SOURCES
    assert all(m.name in source.description for m in motion.MOTION_SOURCES.values())
    assert {name: motion.skeleton_source_for(name) for name in motion.SOURCES} == {
        "builtin_walk": "builtin", "bvh": "robot_description", "keyframes": "builtin", "joint_sweep": "urdf_file"}


def test_the_main_job_plays_a_registered_source_by_name_and_lists_every_source(toy_source, tmp_path, capsys):
    """`scripts/run --source NAME [--file FILE]` reads the registry: a source of one's own is offered by --help and
    played by name, the scene's skeleton made to fit it; a source needing a file is refused without one."""
    from clusterfem_ros.config import SceneConfig, load_scene_file, scene_file_text
    from clusterfem_ros.nodes.demo import _arguments, _player_plan
    with pytest.raises(SystemExit):
        _arguments(["--help"])
    shown = " ".join(capsys.readouterr().out.split())
    for m in motion.MOTION_SOURCES.values():
        assert f"{m.name}: {m.description}" in shown
    scene = tmp_path / "s.yaml"
    scene.write_text(scene_file_text(SceneConfig().with_values({"skeleton.source": "robot_description"})))
    player, config = _player_plan(_arguments(["--source", "toy_still", "--scene", str(scene)]), scene,
                                  load_scene_file(scene))
    assert player == {"source": "toy_still"} and config.skeleton.source == "builtin"
    assert "'toy_still' plays on skeleton.source 'builtin'; the scene had 'robot_description'" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="--source bvh needs --file: a .bvh file"):
        _player_plan(_arguments(["--source", "bvh", "--scene", str(scene)]), scene, load_scene_file(scene))
    with pytest.raises(SystemExit, match="--source toy_still plays no file"):
        _player_plan(_arguments(["--source", "toy_still", "--file", str(scene)]), scene, load_scene_file(scene))
    with pytest.raises(SystemExit):
        _arguments(["--source", "no_such_source"])
    assert "invalid choice: 'no_such_source'" in capsys.readouterr().err


def test_the_main_job_plays_a_joint_sweep_on_the_urdf_file_it_sweeps(tmp_path):
    from clusterfem_ros.config import SceneConfig, load_scene_file, scene_file_text
    from clusterfem_ros.nodes.demo import _arguments, _player_plan
    from tests.test_robot_cover import ARM
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM)
    scene = tmp_path / "s.yaml"
    scene.write_text(scene_file_text(SceneConfig()))
    player, config = _player_plan(_arguments(["--source", "joint_sweep", "--file", str(urdf), "--scene", str(scene)]),
                                  scene, load_scene_file(scene))
    assert player == {"source": "joint_sweep", "file": str(urdf.resolve())}
    assert (config.skeleton.source, config.skeleton.urdf_file) == ("urdf_file", str(urdf.resolve()))


def test_a_registered_capture_format_gives_the_bind_pose_of_its_files_frame_0(tmp_path):
    """A motion source of a new file kind, registered with its frame reader, is what skeleton.bind_pose
    'first_frame' reads for a file of that kind (body/fit.py asks skeleton/capture_frames.py by suffix, no format
    named there): the bind configuration is the file's frame 0; a file of no registered kind is refused naming the
    kinds that are."""
    from clusterfem_ros.body.fit import FitError, bind_configuration
    from clusterfem_ros.skeleton.capture_frames import FRAME_READERS
    from clusterfem_ros.skeleton.kinematics import Skeleton
    spec = default_humanoid()
    names = list(spec.joint_names)
    skeleton = Skeleton.from_urdf_string(spec.urdf)
    k = names.index(skeleton.joint_names[3])

    def frames(path, **_):
        q = np.zeros((2, len(names)))
        q[0, k] = float(path.read_text())           # the file holds one angle: frame 0's value of one joint
        return JointTrajectory(np.array([0.0, 1.0]), names, q)

    def play(path, **_):
        return motion.Motion(spec.urdf, frames(path), f"toy capture {path.name}", True)
    source = motion.register_source(motion.MotionSource("toy_capture", "one angle in a file", play, ".toycap",
                                                        bind_frames=frames))
    try:
        f = tmp_path / "pose.toycap"
        f.write_text("0.4")
        q = bind_configuration(skeleton, "first_frame", bvh_file=str(f))
        assert q[skeleton.joint_names.index(names[k])] == pytest.approx(0.4)
        assert np.count_nonzero(q - skeleton.neutral()) == 1
        other = tmp_path / "pose.unknown"
        other.write_text("0.4")
        with pytest.raises(FitError, match=r"no capture file a bind pose can read: .*\.bvh, \.toycap"):
            bind_configuration(skeleton, "first_frame", bvh_file=str(other))
    finally:
        motion.MOTION_SOURCES.unregister(source.name)
        FRAME_READERS.unregister(".toycap")
