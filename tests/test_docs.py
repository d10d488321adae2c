"""What a user reads: the generated parameters table is current, every command in the README is run by a
test or by CI, the Foxglove layout names topics and diagnostics the node really records, and the README and
docs/ hold no dated diary."""
from __future__ import annotations

import ast
import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.shared_data import walk_clip
from tests.ros_env import child_env

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SAMPLE = ROOT / "bags" / "sample_default_scene"

# Every command in the README's bash blocks -> the test that runs it (the same module and arguments, with
# outputs redirected out of the repository where the command would write into it).
RUN_BY = {
    "scripts/run": "tests/test_render.py::test_the_main_job_renders_its_recording",
    "scripts/run --live 8765": "tests/test_live_view.py::test_the_main_job_serves_its_topics_live",
    "python -m clusterfem_ros.render bags/sample_default_scene": "tests/test_render.py::test_the_render_command_on_the_sample_bag",
    "python -m clusterfem_ros.replay bags/sample_default_scene":
        "tests/test_recording.py::test_the_sample_recording_replays_to_round_off_and_a_changed_physics_is_reported",
    "clusterfem_node --ros-args --params-file config/default_scene.yaml -p skeleton.source:=robot_description":
        "tests/test_docs.py::test_the_readme_node_commands_run_together",
    "mocap_player --ros-args -p source:=bvh -p file:=../shared/data/mocap/cmu_06_01_walk.bvh":
        "tests/test_docs.py::test_the_readme_node_commands_run_together",
}


def ci_commands() -> set[str]:
    """The commands .ci/run executes, and what they source."""
    text = (ROOT / ".ci" / "run").read_text()
    ran = {line.split("exec ", 1)[1].strip() for line in text.splitlines() if line.strip().startswith("exec ")}
    sourced = {". scripts/env.sh"} if any("env.sh" in (ROOT / c).read_text() for c in ran if (ROOT / c).is_file()) else set()
    return ran | sourced


def readme_commands(text: str) -> list[str]:
    """Each command line of the README's fenced bash blocks (comments dropped; indented blocks included)."""
    commands = []
    for block in re.findall(r"^[ \t]*```bash\n(.*?)^[ \t]*```", text, flags=re.S | re.M):
        for line in block.splitlines():
            command = line.split("  #")[0].split(" #")[0].strip()
            if command and not command.startswith("#"):
                commands.append(command)
    return commands


def test_the_parameters_table_is_up_to_date():
    from clusterfem_ros.nodes.parameters_doc import DOC, main, render
    text = render()
    assert DOC.read_text() == text, "docs/parameters.md is out of date: run python -m clusterfem_ros.nodes.parameters_doc"
    assert main(["--check"]) == 0
    from clusterfem_ros.config import PARAMS
    for p in PARAMS:                                        # every declared parameter has its row
        assert f"| `{p.name}` |" in text, p.name
    for name in ("source", "file", "rate_hz", "speed", "start_offset", "loop"):
        assert f"| `{name}` |" in text.split("## Mocap player")[1], name


def test_a_stale_parameters_table_is_reported(tmp_path, capsys):
    from clusterfem_ros.nodes.parameters_doc import DOC, main
    stale = tmp_path / "parameters.md"
    stale.write_text(DOC.read_text().replace("| `physics.step` | `0.001` |", "| `physics.step` | `0.002` |"))
    assert main(["--check", "--out", str(stale)]) == 1
    assert "out of date" in capsys.readouterr().err


def test_every_readme_command_is_run_by_a_test_or_by_ci():
    commands = readme_commands(README.read_text())
    assert "scripts/run" in commands and "scripts/test" in commands
    ci = ci_commands()
    assert "scripts/test" in ci
    unmapped = [c for c in commands if c not in ci and c not in RUN_BY]
    assert not unmapped, f"README commands no test runs: {unmapped}; add the test to RUN_BY or drop the command"
    stale = [c for c in RUN_BY if c not in commands]
    assert not stale, f"RUN_BY names commands the README no longer has: {stale}"
    for command, where in RUN_BY.items():
        path, name = where.split("::")
        tree = ast.parse((ROOT / path).read_text())
        names = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
        assert name in names, f"{command!r} is mapped to {where}, which does not exist"


def test_the_readme_command_parser_sees_indented_blocks_and_drops_comments():
    text = "x\n```bash\nscripts/run      # the main job\n# a comment\n\n```\n- a\n  ```bash\n  a b c   # why\n  ```\n"
    assert readme_commands(text) == ["scripts/run", "a b c"]


def test_the_readme_node_commands_run_together(tmp_path):
    """The README's node block as written: the node on the default scene file takes the player's skeleton
    and the CMU walk's joint states (recorded here to count them); SIGINT stops both cleanly."""
    from clusterfem_ros.recording.bag_reader import _reader
    block = [c for c in readme_commands(README.read_text()) if c.startswith(("clusterfem_node", "mocap_player"))]
    assert len(block) == 2, block
    walk_clip(beside_only=True)          # the README's example clip, read from ../shared beside the repository
    env = child_env(160, span=30)
    bindir = Path(sys.executable).parent
    procs, lines = [], {}
    try:
        for command in block:
            exe, *args = command.split()
            # recorded, so that the test can count what the node accepted
            extra = (["-p", "recording.enabled:=true", "-p", f"recording.dir:={tmp_path}",
                      "-p", "output.diagnostics_rate_hz:=5.0"] if exe == "clusterfem_node" else [])
            p = subprocess.Popen([str(bindir / exe), *args, *extra], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                 stderr=subprocess.STDOUT, text=True)
            lines[exe] = []
            threading.Thread(target=lambda p=p, out=lines[exe]: out.extend(p.stdout), daemon=True).start()
            procs.append(p)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any("scene ready" in x for x in lines["clusterfem_node"]):
            assert all(p.poll() is None for p in procs), lines
            time.sleep(0.2)
        assert any("scene ready" in x for x in lines["clusterfem_node"]), lines
        assert any("playing BVH" in x for x in lines["mocap_player"]), lines
        time.sleep(3.0)
        assert all(p.poll() is None for p in procs), lines
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
    assert [p.returncode for p in procs] == [0, 0], lines
    node_log = "".join(lines["clusterfem_node"])
    assert "waiting for the URDF on 'robot_description'" in node_log and "not in the skeleton" not in node_log
    with _reader(next(tmp_path.iterdir())) as r:
        diag = [c for c in r.connections if c.topic == "/diagnostics"]
        *_, (c, _, raw) = r.messages(connections=diag)
        last = {v.key: v.value for s in r.deserialize(raw, c.msgtype).status for v in s.values}
    assert int(last["inputs_accepted"]) > 100, last          # the player sends 120 per second


def test_the_foxglove_layout_shows_what_the_node_records():
    from rosbags.highlevel import AnyReader
    layout = json.loads((ROOT / "config" / "foxglove_layout.json").read_text())

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    panels = leaves(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"]), "every panel placed once, and only those"
    with AnyReader([SAMPLE]) as r:
        topics = {c.topic for c in r.connections}
        diag = [c for c in r.connections if c.topic == "/diagnostics"]
        _, _, raw = next(iter(r.messages(connections=diag)))
        msg = r.deserialize(raw, diag[0].msgtype)
    keys = {v.key for s in msg.status for v in s.values}
    hardware = {s.hardware_id for s in msg.status}
    three_d = [c for k, c in layout["configById"].items() if k.startswith("3D!")]
    assert three_d and set(three_d[0]["topics"]) <= topics and "/clusterfem/surface" in three_d[0]["topics"]
    from clusterfem_ros.topics import layout_topics
    assert three_d[0]["topics"] == layout_topics(), f"the 3D panel shows the declared streams as declared: {layout_topics()}"
    plotted = []
    for key, config in layout["configById"].items():
        if key.startswith("Plot!"):
            for path in config["paths"]:
                topic, hw, value = re.fullmatch(
                    r'(/\w+)\.status\[:\]\{hardware_id=="(\w+)"\}\.values\[:\]\{key=="(\w+)"\}\.value',
                    path["value"]).groups()
                assert topic in topics and hw in hardware and value in keys, path["value"]
                plotted.append(value)
    assert {"step_ms", "real_time_factor", "volume_error"} <= set(plotted)


def test_the_readme_reads_in_five_minutes():
    """What it is, the two commands, using the nodes, one results table, the layout, known limits: the rest
    lives in docs/."""
    size = len(README.read_bytes())
    assert size <= 12_000, f"README.md is {size} bytes, over 12,000: move detail to docs/"


def test_readme_and_docs_carry_no_dates_and_link_only_existing_files():
    sources = [f for top in ("clusterfem_ros", "msg_adapters", "benchmarks")
               for f in sorted((ROOT / top).rglob("*.py"))]
    for source in sources:                      # docstrings and comments say what code does and why, not when
        dates = re.findall(r"\b20\d\d-\d\d-\d\d\b", source.read_text())
        assert not dates, f"{source.relative_to(ROOT)} has dates {dates}: history lives in git"
    for page in [README, *sorted((ROOT / "docs").glob("*.md"))]:
        text = page.read_text()
        dates = re.findall(r"\b20\d\d-\d\d-\d\d\b", text)
        assert not dates, f"{page.name} has dates {dates}: history lives in git"
        for target in re.findall(r"\]\(([^)#]+)\)", text):
            if "://" not in target:
                assert (page.parent / target).exists(), f"{page.name} links {target}, which does not exist"


def test_the_pictures_scenes_are_the_shipped_scenes_on_the_input_clock():
    """The README's picture shows what a user runs: each recording scene of docs/media is its shipped scene with
    the joint-state clock and the motion played once, nothing else changed (a tuned copy would drift)."""
    import yaml
    from clusterfem_ros.config import _flatten, from_mapping, load_scene_file
    pairs = {"character_walk_recording.yaml": ROOT / "config" / "character_walk.yaml",
             "jelly_walk_recording.yaml": ROOT / "config" / "default_scene.yaml"}
    for name, shipped in pairs.items():
        rec = yaml.safe_load((ROOT / "docs" / "media" / name).read_text())
        node = _flatten(rec["clusterfem"]["ros__parameters"])
        assert node.pop("physics.clock") == "input", name
        assert from_mapping(node) == load_scene_file(shipped), f"{name} differs from {shipped.name}"
        player = dict(rec["mocap_player"]["ros__parameters"])
        assert player.pop("loop") is False, name
        player.pop("start_delay", None)
        shipped_player = (yaml.safe_load(shipped.read_text()).get("mocap_player") or {}).get("ros__parameters")
        assert player == (shipped_player or {"source": "builtin_walk"}), (name, player)
