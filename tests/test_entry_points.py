"""Every entry point answers --help (and -h) with its usage and where its parameters are documented, exit 0,
without starting anything; the player refuses a misspelt parameter as the simulation node does."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# console scripts of setup.py (as modules: the same main()) and the python -m commands of the docs
NODES = ["clusterfem_ros.nodes.clusterfem_node", "clusterfem_ros.nodes.player_node"]
COMMANDS = ["clusterfem_ros.nodes.demo", "clusterfem_ros.replay", "clusterfem_ros.render",
            "clusterfem_ros.recording.recover", "clusterfem_ros.nodes.parameters_doc"]


def _run(module: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(170 + os.getpid() % 20))
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("module", NODES + COMMANDS)
def test_help_prints_the_usage_and_exits_0(module):
    for flag in ("--help", "-h"):
        run = _run(module, flag)
        assert run.returncode == 0, run.stderr[-2000:]
        assert run.stdout.lower().startswith("usage:"), run.stdout[:500]
        assert "Traceback" not in run.stderr


@pytest.mark.parametrize("module", NODES + ["clusterfem_ros.nodes.demo"])
def test_the_nodes_help_says_where_the_parameters_are_documented(module):
    run = _run(module, "--help")
    assert "docs/parameters.md" in run.stdout, run.stdout
    assert (ROOT / "docs" / "parameters.md").is_file()


def test_the_player_refuses_a_misspelt_parameter_naming_the_nearest(tmp_path):
    run = _run(NODES[1], "--ros-args", "-p", "sorce:=bvh")
    assert run.returncode == 2, run.stdout[-1000:] + run.stderr[-1000:]
    lines = [x for x in run.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and "'sorce'" in lines[0] and "did you mean 'source'" in lines[0], run.stderr
    params = tmp_path / "player.yaml"
    params.write_text("mocap_player:\n  ros__parameters:\n    rate: 60.0\n")
    run = _run(NODES[1], "--ros-args", "--params-file", str(params))
    assert run.returncode == 2 and "'rate'" in run.stderr and "rate_hz" in run.stderr, run.stderr
