"""The main job with real motion: `scripts/run --bvh FILE`, and a scene file whose mocap_player section drives the
player (the README's commands)."""
import os
import shutil
import subprocess
import sys

import pytest
import yaml

from clusterfem_ros.config import SceneConfig, scene_file_text
from clusterfem_ros.motion import load_player_section, skeleton_source_for
from tests.shared_data import walk_clip
from tests.ros_env import child_env

pytestmark = pytest.mark.ros


def _run(args, cwd, timeout=240):
    env = child_env(140, PYTHONPATH=os.pathsep.join([str(__import__("pathlib").Path(__file__).resolve().parents[1])] +
                                          os.environ.get("PYTHONPATH", "").split(os.pathsep)))
    run = subprocess.run([sys.executable, "-m", "clusterfem_ros.nodes.demo", "--duration", "2", "--no-record", *args],
                         env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    return run.returncode, run.stdout + run.stderr


def _small_scene(path, **values):
    path.write_text(scene_file_text(SceneConfig().with_values({"body.target_tets": 700, **values})))
    return path


def _used(out: str) -> int:
    return int(out.split("inputs          ")[1].split()[0])


@pytest.fixture
def walk(tmp_path):
    return shutil.copy(walk_clip(), tmp_path / "walk.bvh")


def test_run_with_bvh_plays_the_file_on_a_body_built_on_its_skeleton(tmp_path, walk):
    code, out = _run(["--bvh", "walk.bvh", "--scene", str(_small_scene(tmp_path / "s.yaml")),
                      "--png", str(tmp_path / "f.png")], cwd=tmp_path)
    assert code == 0, out
    assert "skeleton from robot_description" in out and "binding" in out and "31 bones" in out
    assert _used(out) > 20 and "0 resets after divergence" in out, out


def test_a_scene_files_player_section_drives_the_player(tmp_path, walk):
    scene = _small_scene(tmp_path / "s.yaml", **{"skeleton.source": "robot_description"})
    doc = yaml.safe_load(scene.read_text())
    doc["mocap_player"] = {"ros__parameters": {"source": "bvh", "file": "walk.bvh", "rate_hz": 60, "loop_blend": 1}}
    scene.write_text(yaml.safe_dump(doc))
    code, out = _run(["--scene", "s.yaml", "--png", str(tmp_path / "f.png")], cwd=tmp_path)
    assert code == 0, out
    assert "file walk.bvh" in out and "rate_hz 60" in out and "source bvh" in out and _used(out) > 10, out


def test_a_player_file_named_by_the_scene_is_found_under_the_data_folders(tmp_path, monkeypatch):
    """A scene file names its capture as the character scene does (mocap/<clip>.bvh): found under
    $CLUSTERFEM_DATA from any directory; a missing one stops the run naming the file and the folders."""
    from pathlib import Path

    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.nodes.demo import _arguments, _player_plan
    data = tmp_path / "data"
    (data / "mocap").mkdir(parents=True)
    (data / "mocap" / "clip.bvh").write_text("HIERARCHY\n")            # found here, read by the player
    scene = _small_scene(tmp_path / "s.yaml", **{"skeleton.source": "robot_description"})
    doc = yaml.safe_load(scene.read_text())
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    monkeypatch.setenv("CLUSTERFEM_DATA", str(data))
    for name in ("mocap/clip.bvh", "mocap/missing.bvh"):
        doc["mocap_player"] = {"ros__parameters": {"source": "bvh", "file": name}}
        scene.write_text(yaml.safe_dump(doc))
        plan = lambda: _player_plan(_arguments(["--scene", str(scene)]), scene, load_scene_file(scene))  # noqa: E731
        if name == "mocap/clip.bvh":
            assert Path(plan()[0]["file"]) == data / "mocap" / "clip.bvh"
        else:
            with pytest.raises(SystemExit, match=f"'mocap/missing.bvh' is neither a path nor found under {data}"):
                plan()


def test_the_player_loads_a_capture_named_under_the_data_folders(tmp_path, monkeypatch, walk):
    """The player node itself (mocap_player --params-file config/character_walk.yaml) finds mocap/<clip>.bvh
    under $CLUSTERFEM_DATA from any directory, and names a missing one with the folders searched."""
    from clusterfem_ros.motion import load_motion
    data = tmp_path / "data"
    (data / "mocap").mkdir(parents=True)
    shutil.copy(walk, data / "mocap" / "w.bvh")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    monkeypatch.setenv("CLUSTERFEM_DATA", str(data))
    motion = load_motion("bvh", "mocap/w.bvh")
    assert "w.bvh" in motion.description and motion.trajectory.n_joints > 0 and not motion.builtin_skeleton
    with pytest.raises(ValueError, match=f"'mocap/none.bvh' is neither a path nor found under {data}"):
        load_motion("bvh", "mocap/none.bvh")


def test_player_sections_are_checked_and_a_bvh_on_the_built_in_skeleton_is_refused(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("clusterfem: {ros__parameters: {}}\n")
    assert load_player_section(f) is None
    f.write_text("mocap_player: {ros__parameters: {source: bvh, file: a.bvh, sped: 2}}\n")
    with pytest.raises(ValueError, match="no parameter 'sped'"):
        load_player_section(f)
    f.write_text("mocap_player: {ros__parameters: {source: fbx}}\n")
    with pytest.raises(ValueError, match="source = 'fbx'"):
        load_player_section(f)
    assert skeleton_source_for("bvh") == "robot_description" and skeleton_source_for("builtin_walk") == "builtin"
    scene = _small_scene(tmp_path / "b.yaml")
    doc = yaml.safe_load(scene.read_text())
    doc["mocap_player"] = {"ros__parameters": {"source": "bvh", "file": "walk.bvh"}}
    scene.write_text(yaml.safe_dump(doc))
    code, out = _run(["--scene", str(scene)], cwd=tmp_path, timeout=60)
    assert code != 0 and "set skeleton.source to 'robot_description'" in out, out


def test_a_bvh_on_a_character_scene_keeps_the_character_and_a_skeleton_it_refuses_stops_the_run(tmp_path, walk):
    from pathlib import Path

    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.motion import on_capture_skeleton
    trimesh = pytest.importorskip("trimesh")
    character = load_scene_file(Path(__file__).resolve().parents[1] / "config" / "character_walk.yaml")
    assert on_capture_skeleton(character)["body.kind"] == "surface"
    assert on_capture_skeleton(SceneConfig())["body.kind"] == "jelly_man"
    assert on_capture_skeleton(SceneConfig())["skeleton.source"] == "robot_description"
    # a 20 cm ball as the character: the walk's skeleton (1.7 m) sticks out of it; the run stops with the node's reason
    trimesh.creation.icosphere(subdivisions=2, radius=0.1).export(tmp_path / "ball.stl")
    scene = tmp_path / "ball.yaml"
    scene.write_text(scene_file_text(SceneConfig().with_values({
        "body.kind": "surface", "body.surface_file": str(tmp_path / "ball.stl"), "body.target_tets": 300,
        "skeleton.source": "robot_description", "skeleton.fit": "manual", "skeleton.fit_up": "Z",
        "skeleton.fit_forward": "X", "body.surface_unit": 1.0})))     # declared metres: no human's size, refused
    code, out = _run(["--bvh", "walk.bvh", "--scene", str(scene)], cwd=tmp_path, timeout=120)
    assert code != 0, out
    assert "cannot build the scene from robot_description" in out and "times the size of its skeleton" in out, out


def test_set_changes_a_scene_parameter_on_top_of_the_scene_file(tmp_path):
    """`scripts/run --scene FILE --set KEY=VALUE`: the run builds the scene with the value (here a coarser body)."""
    code, out = _run(["--scene", str(_small_scene(tmp_path / "s.yaml")), "--set", "body.target_tets=400",
                      "--no-video", "--png", str(tmp_path / "f.png")], cwd=tmp_path)
    assert code == 0, out
    tets = int(out.split("  body            ")[1].split()[0])
    assert abs(tets / 400 - 1) <= 0.2, out                # the scene file's 700 replaced


def test_a_bad_set_stops_the_run_naming_it():
    from clusterfem_ros.nodes.demo import _arguments, _child_argv, _with_sets
    config = SceneConfig()
    assert _with_sets(config, ["body.surface_unit=cm", "body.target_tets=900"])["body.target_tets"] == 900
    for pair, said in (("body.target_tets", "give KEY=VALUE"), ("body.target_tets=[1", "not YAML"),
                       ("body.no_such=1", "body.no_such"), ("body.target_tets=10", "body.target_tets")):
        with pytest.raises(SystemExit, match=said):
            _with_sets(config, [pair])
    args = _arguments(["--set", "a.b=1", "--set", "c.d=x"])         # --process-per-body passes them on
    assert _child_argv(args, __import__("pathlib").Path("s.yaml"))[-4:] == ["--set", "a.b=1", "--set", "c.d=x"]
