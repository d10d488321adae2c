"""Every shipped scene file loads through rclpy's own --params-file (rcl's YAML 1.1 parser, as
`clusterfem_node --ros-args --params-file FILE` reads it) to the same configuration as our scene-file loader;
what YAML 1.1 turns into booleans (y, Y, yes, on) reaches an axis or choice parameter as the choice it was spelt
as, in any case; float parameters take integers."""
from __future__ import annotations

from pathlib import Path

import pytest

from clusterfem_ros.nodes import testing  # noqa: F401  (DDS settings before rclpy starts)
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402

from clusterfem_ros.config import NODE_NAME, PARAMS, ConfigError, check_value, load_scene_file  # noqa: E402
from clusterfem_ros.motion import PLAYER_PARAMS, load_player_section  # noqa: E402
from clusterfem_ros.nodes.params import declare_scene_parameters  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "config").glob("*.yaml"))


@pytest.fixture
def context():
    ctx = Context()
    rclpy.init(context=ctx, domain_id=230)       # no node here publishes or subscribes
    yield ctx
    ctx.try_shutdown()


def _through_rclpy(context, *cli: str):
    """The scene configuration a node named like ours gets from these --ros-args, and the node (to be destroyed)."""
    node = Node(NODE_NAME, context=context, cli_args=["--ros-args", *cli])
    try:
        return declare_scene_parameters(node, lambda changes: None), node
    except Exception:
        node.destroy_node()
        raise


def test_there_are_shipped_scene_files():
    assert {"default_scene.yaml", "character_walk.yaml", "human_urdf.yaml"} <= {f.name for f in SHIPPED}


@pytest.mark.parametrize("path", SHIPPED, ids=[f.name for f in SHIPPED])
def test_every_shipped_scene_file_loads_through_the_nodes_params_file(context, path):
    config, node = _through_rclpy(context, "--params-file", str(path))
    node.destroy_node()
    assert config.values == load_scene_file(path).values
    player = load_player_section(path)                 # the player's section, if any, names only its parameters
    assert player is None or set(player) <= set(PLAYER_PARAMS)


@pytest.mark.parametrize("path", SHIPPED, ids=[f.name for f in SHIPPED])
def test_shipped_files_quote_their_choices(path):
    """An unquoted y/n/on/off is a boolean to YAML 1.1: the shipped files quote every choice, so a user copying a
    line keeps a working value whatever the choice is."""
    choices = {p.name for p in PARAMS if p.choices}
    leaves = {n.split(".")[-1] for n in choices}
    for k, line in enumerate(path.read_text().splitlines(), 1):
        key, _, rest = line.split("#")[0].partition(":")
        value = rest.strip()
        if (key.strip() in choices or key.strip() in leaves) and value:
            assert value[0] in "\"'", f"{path.name}:{k}: {line.strip()!r}: quote the choice"


def test_yaml_booleans_integers_and_any_case_reach_the_parameters_as_meant(context, tmp_path):
    params = tmp_path / "scene.yaml"
    params.write_text(f"""{NODE_NAME}:
  ros__parameters:
    body.kind: surface
    body.surface_file: some.obj
    skeleton.fit_up: Y
    skeleton.fit_forward: x
    skeleton.up_axis: Y
    skeleton.root_joint: FIXED
    material.young_modulus: 30000
    physics.gravity: -10
    output.colormap: Viridis
""")
    config, node = _through_rclpy(context, "--params-file", str(params), "-p", "physics.clock:=INPUT")
    try:
        assert config["skeleton.fit_up"] == "Y" and config["skeleton.fit_forward"] == "X"
        assert config["skeleton.up_axis"] == "y" and config["skeleton.root_joint"] == "fixed"
        assert config["output.colormap"] == "viridis" and config["physics.clock"] == "input"
        for name, want in (("material.young_modulus", 30000.0), ("physics.gravity", -10.0)):
            assert config[name] == want and isinstance(config[name], float)
            got = node.get_parameter(name).value            # what `ros2 param get` shows: the value run with
            assert got == want and isinstance(got, float)
        assert node.get_parameter("skeleton.up_axis").value == "y"
    finally:
        node.destroy_node()


def test_our_scene_file_loader_reads_the_same_spellings(tmp_path):
    """scripts/run --scene reads the file with PyYAML (which takes yes/on as booleans, y as text)."""
    params = tmp_path / "scene.yaml"
    params.write_text(f"{NODE_NAME}:\n  ros__parameters:\n    skeleton.up_axis: Y\n    skeleton.fit_up: y\n"
                      "    skeleton.root_joint: Free\n    material.young_modulus: 30000\n")
    config = load_scene_file(params)
    assert (config["skeleton.up_axis"], config["skeleton.fit_up"], config["skeleton.root_joint"]) == ("y", "Y", "free")
    assert config["material.young_modulus"] == 30000.0 and isinstance(config["material.young_modulus"], float)
    params.write_text(f"{NODE_NAME}:\n  ros__parameters:\n    recording.prefix: on\n")
    with pytest.raises(ConfigError, match="recording.prefix.*quote the value"):
        load_scene_file(params)


def test_the_command_line_form_of_the_docs_works(context):
    """docs/usage.md: `-p skeleton.up_axis:=y` (rcl reads y as true)."""
    config, node = _through_rclpy(context, "-p", "skeleton.up_axis:=y", "-p", "skeleton.fit_up:=y")
    node.destroy_node()
    assert config["skeleton.up_axis"] == "y" and config["skeleton.fit_up"] == "Y"


def test_a_boolean_for_free_text_is_refused_saying_to_quote_it(context, tmp_path):
    params = tmp_path / "scene.yaml"
    params.write_text(f"{NODE_NAME}:\n  ros__parameters:\n    recording.prefix: yes\n")
    with pytest.raises(Exception) as e:
        _through_rclpy(context, "--params-file", str(params))
    assert "recording.prefix" in str(e.value) and "quote the value" in str(e.value)
    with pytest.raises(ConfigError, match="quote the value"):
        check_value("output.frame_id", True)


def test_a_boolean_that_spells_no_choice_is_refused():
    with pytest.raises(ConfigError, match="skeleton.up_axis"):
        check_value("skeleton.up_axis", False)         # n / no / off: no axis
    with pytest.raises(ConfigError, match="choose one of"):
        check_value("method", "CLUSTERED_FAST")
