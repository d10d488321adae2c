"""The mocap player's parameters are typed and checked as the simulation node's are (nodes/params.py): from -p, a
params file or a scene file's ``mocap_player`` section, an integer is taken for a float, a choice in any case, and
an axis that YAML 1.1 read as a boolean (``up:=y``) as the axis it was spelt as; a bad value is refused naming it."""
from __future__ import annotations

import pytest

from clusterfem_ros.nodes.testing import RosWorld  # (DDS settings before rclpy starts)
from rclpy.parameter import Parameter  # noqa: E402

from clusterfem_ros.config import NODE_NAME, ConfigError  # noqa: E402
from clusterfem_ros.motion import load_player_section  # noqa: E402

pytestmark = pytest.mark.ros
FLOATS = ("rate_hz", "speed", "start_offset", "start_delay", "loop_blend")     # the player's float parameters


@pytest.fixture
def world():
    with RosWorld() as w:
        yield w


def _player(world, *cli: str):
    from clusterfem_ros.nodes.player_node import MocapPlayer
    return world.add(MocapPlayer(context=world.context, cli_args=["--ros-args", *cli]))


def _floats_are_floats(player) -> None:
    for name in FLOATS:
        assert isinstance(player.params[name], float), (name, player.params[name])
        assert isinstance(player.get_parameter(name).value, float), name     # what `ros2 param get` shows


def test_integers_for_floats_any_case_and_a_yaml_boolean_axis_reach_the_player_as_meant(world):
    player = _player(world, "-p", "rate_hz:=60", "-p", "speed:=2", "-p", "start_offset:=1", "-p", "start_delay:=0",
                     "-p", "loop_blend:=1", "-p", "source:=Builtin_Walk", "-p", "up:=y", "-p", "unit:=0.01")
    assert player.params == {"source": "builtin_walk", "file": "", "rate_hz": 60.0, "speed": 2.0,
                             "start_offset": 1.0, "start_delay": 0.0, "loop": True, "loop_blend": 1.0,
                             "unit": "0.01", "up": "Y"}
    _floats_are_floats(player)
    assert player.get_parameter("up").value == "Y" and player.get_parameter("source").value == "builtin_walk"


def test_a_scene_files_player_section_with_integers_loads_for_the_demo_and_the_player(world, tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(f"{NODE_NAME}:\n  ros__parameters:\n    body.kind: 'jelly_man'\n"
                     "mocap_player:\n  ros__parameters:\n    source: BUILTIN_WALK\n    rate_hz: 60\n    speed: 2\n"
                     "    start_delay: 1\n    loop_blend: 0\n    up: Y\n")
    section = load_player_section(scene)                   # what the demo hands the player (nodes/demo.py)
    assert section == {"source": "builtin_walk", "rate_hz": 60.0, "speed": 2.0, "start_delay": 1.0,
                       "loop_blend": 0.0, "up": "Y"}
    assert all(isinstance(section[n], float) for n in ("rate_hz", "speed", "start_delay", "loop_blend"))
    player = _player(world, "--params-file", str(scene))   # `mocap_player --ros-args --params-file scene.yaml`
    assert (player.params["rate_hz"], player.params["start_delay"], player.params["up"]) == (60.0, 1.0, "Y")
    _floats_are_floats(player)


def test_a_bad_value_is_refused_naming_the_parameter_and_the_way_out(world, tmp_path):
    with pytest.raises(Exception) as e:
        _player(world, "-p", "rate_hz:=0.5")                # rclpy's own range check, from the descriptor
    assert all(part in str(e.value) for part in ("rate_hz", "0.5", "2000")), e.value
    with pytest.raises(Exception, match=r"rate_hz = 0.0 is outside \[1, 2000\]"):
        _player(world, "-p", "rate_hz:=0")                  # an integer: ours (rclpy checks doubles only)
    with pytest.raises(Exception, match="up = False.*quote the value"):
        _player(world, "-p", "up:=n")                      # n: no axis
    with pytest.raises(Exception, match="source = 'fbx': choose one of builtin_walk"):
        _player(world, "-p", "source:=fbx")
    scene = tmp_path / "scene.yaml"
    scene.write_text("mocap_player:\n  ros__parameters:\n    speed: fast\n")
    with pytest.raises(ConfigError, match=r"scene\.yaml'.*mocap_player\.speed = 'fast': expected float"):
        load_player_section(scene)


def test_a_playing_player_refuses_a_change_it_would_not_use_saying_to_restart(world):
    player = _player(world)
    result = player.set_parameters([Parameter("speed", value=2.0)])[0]
    assert not result.successful and "restart the player" in result.reason, result.reason
    assert player.get_parameter("speed").value == 1.0


def test_start_player_hands_the_player_the_sections_values_as_doubles(world, monkeypatch):
    from clusterfem_ros.nodes import bodies
    started = []
    monkeypatch.setattr(bodies.subprocess, "Popen", lambda cmd: started.append(cmd))
    bodies.start_player("", {"source": "builtin_walk", "rate_hz": 60, "speed": 2, "start_offset": 1,
                             "start_delay": 3, "loop_blend": 0, "loop": False, "up": "Y"})
    cmd = started[0]
    given = dict(cmd[k + 1].split(":=") for k, arg in enumerate(cmd) if arg == "-p")
    # written as doubles, the type the player declares (a `ros2 param` tool or an older player take no integer)
    assert {n: given[n] for n in FLOATS} == {"rate_hz": "60.0", "speed": "2.0", "start_offset": "1.0",
                                             "start_delay": "3.0", "loop_blend": "0.0"}
    ros_args = cmd[cmd.index("--ros-args") + 1:cmd.index("--log-level")]
    player = _player(world, *ros_args)
    assert (player.params["start_delay"], player.params["loop"], player.params["up"]) == (3.0, False, "Y")
