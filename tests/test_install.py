"""The package installs whole: a wheel built from setup.py, installed into a fresh environment that sees the
pinned dependencies but not this source tree, runs the main job and a key-frame scene from another folder.

The fresh environment is ``python -m venv`` plus one .pth file naming this environment's site-packages (and
repeating its .pth import lines: pinocchio's path set-up), but not the editable install's finder, so
``clusterfem_ros`` can only come from the wheel. Its numba cache is its own (under its prefix): the first
run compiles the step's kernels (~20-30 s), the key-frame scene then loads them. About a minute in all.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.wheel

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("setup.py", "setup.cfg", "package.xml", "resource", "config", "clusterfem_ros", "msg_adapters")
SCRIPTS = ("clusterfem_node", "mocap_player", "clusterfem_demo")

KEYFRAME_SCENE = r'''
import json, sys
import numpy as np
import clusterfem_ros
from clusterfem_ros.config import default_scene_path, load_scene_file
from clusterfem_ros.method_choice import SHIPPED_POINTS
from clusterfem_ros.motion import load_motion
from clusterfem_ros.scene import Scene
from clusterfem_ros.scene_build import apply_error_budget
from clusterfem_ros.skeleton.keyframes import example_path

config = load_scene_file(default_scene_path()).with_values({"physics.clock": "input"})
motion = load_motion("keyframes", example_path("wave.yaml"))
scene = Scene.build(config)
pushed = 0
for k in range(101):                                  # 1 s of the wave at 100 Hz, stamps from t = 1 s
    q, v = motion.trajectory.sample(0.01 * k)
    t = 1.0 + 0.01 * k
    scene.take_joint_state(t, motion.trajectory.names, q, v, received=t)
    pushed += 1
    if k == 0:
        x0 = scene.positions().copy()                 # on the skeleton at the first key frame
x = scene.positions()
budget = apply_error_budget(config.with_values({"budget.max_error_mm": 25.0}))
print(json.dumps({"package": clusterfem_ros.__file__, "scene_file": str(default_scene_path()),
                  "points": str(SHIPPED_POINTS), "keyframes": str(example_path("wave.yaml")),
                  "pushed": pushed, "accepted": scene.inputs.accepted, "rejected": scene.inputs.rejected,
                  "steps": scene.steps_done, "finite": bool(np.isfinite(x).all()),
                  "moved_mm": float(np.linalg.norm(x - x0, axis=1).max() * 1e3),
                  "budget": {k: budget[k] for k in ("method", "physics.step", "warping", "modal.k")}}))
'''


def _copy_sources(src: Path) -> None:
    """The files a build reads, copied to ``src`` (a build writes build/ and *.egg-info beside the sources)."""
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            src.mkdir(exist_ok=True)
            shutil.copy2(ROOT / name, src / name)


def _run(cmd, cwd: Path, env: dict, timeout: float = 300) -> subprocess.CompletedProcess:
    out = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, f"{cmd} exited with {out.returncode}:\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return out


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(wheel, the fresh environment's python, a folder outside the source tree, the environment to run in)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    _copy_sources(src)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--disable-pip-version-check",
          "-q", "-w", str(tmp / "dist"), str(src)], tmp, dict(os.environ))
    wheel, = (tmp / "dist").glob("clusterfem_ros-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp, dict(os.environ))
    python = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
          "--disable-pip-version-check", "-q", str(wheel)], tmp, dict(os.environ))
    ours = Path(sysconfig.get_paths()["purelib"])
    lines = [str(ours)]
    for pth in sorted(ours.glob("*.pth")):
        if not pth.name.startswith("__editable__"):
            lines += [line for line in pth.read_text().splitlines() if line.startswith("import ")]
    theirs = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                 capture_output=True, text=True, check=True).stdout.strip())
    (theirs / "clusterfem_test_deps.pth").write_text("\n".join(lines) + "\n")
    elsewhere = tmp / "elsewhere"
    elsewhere.mkdir()
    # this process's environment already holds the ROS wheels' library path (their bootstrap re-executed
    # the interpreter with it); numba's cache stays the new environment's own
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH", "VIRTUAL_ENV")}
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "SHM"
    return wheel, python, elsewhere, env


def test_the_wheel_holds_the_runtime_data_and_no_benchmarks(installed):
    wheel = installed[0]
    names = zipfile.ZipFile(wheel).namelist()
    assert "clusterfem_ros/data/speed_error.csv" in names
    assert "clusterfem_ros/skeleton/data/wave.yaml" in names
    assert any(n.endswith("share/clusterfem_ros/config/default_scene.yaml") for n in names)
    assert not [n for n in names if n.startswith(("benchmarks/", "tests/", "clusterfem_ros/bench/"))]
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert "clusterfem_bench" not in zipfile.ZipFile(wheel).read(entry_points).decode()


def test_the_main_job_runs_from_the_installed_wheel(installed):
    _, python, elsewhere, env = installed
    out = _run([str(python.parent / "clusterfem_demo"), "--duration", "1", "--no-record",
                "--png", str(elsewhere / "final_state.png")], elsewhere, env)
    text = out.stdout
    assert f"scene {python.parents[1]}" in text, text[-2000:]           # the installed share/ scene file
    steps = next(line for line in text.splitlines() if line.strip().startswith("physics steps"))
    assert int(steps.split()[2]) > 0, steps
    used = next(line for line in text.splitlines() if line.strip().startswith("inputs"))
    assert int(used.split()[1]) > 0 and " 0 rejected" in used, used
    assert (elsewhere / "final_state.png").read_bytes()[:4] == b"\x89PNG"


def test_a_keyframe_scene_and_the_error_budget_run_from_the_installed_wheel(installed):
    _, python, elsewhere, env = installed
    out = _run([str(python), "-c", KEYFRAME_SCENE], elsewhere, env)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    prefix = str(python.parents[1])
    for key in ("package", "scene_file", "points", "keyframes"):
        assert got[key].startswith(prefix), (key, got[key])          # from the wheel, not this source tree
    assert got["accepted"] == got["pushed"] == 101 and not got["rejected"], got
    assert got["steps"] >= 999 and got["finite"], got                # 1 s at h = 1 ms after the first stamp
    assert got["moved_mm"] > 100.0, got                      # the wave lifts the right arm (by ~0.5 m in 1 s)
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.method_choice import SHIPPED_POINTS, choose_from_file
    chosen = SceneConfig().with_values(choose_from_file(SHIPPED_POINTS, "jelly_man", 25.0).overrides)
    assert got["budget"] == {k: chosen[k] for k in got["budget"]}     # the same measured points, shipped


DATA_LOOKUP = r'''
import json
from clusterfem_ros.body.fit import find_data_file
from clusterfem_ros.data_dirs import data_roots
print(json.dumps({"roots": [str(r) for r in data_roots()], "found": str(find_data_file("mocap/probe.bvh"))}))
'''


def test_the_installed_package_finds_data_in_clusterfem_data_or_the_user_data_folder(installed, tmp_path):
    """No '../shared/data' beside site-packages (<venv>/lib/python3.X/shared/data): $CLUSTERFEM_DATA, then the
    user data folder ($XDG_DATA_HOME/clusterfem_ros here)."""
    _, python, elsewhere, env = installed
    user = tmp_path / "xdg" / "clusterfem_ros"
    (user / "mocap").mkdir(parents=True)
    (user / "mocap" / "probe.bvh").write_text("HIERARCHY\n")
    env = dict(env, XDG_DATA_HOME=str(tmp_path / "xdg"), CLUSTERFEM_DATA=str(tmp_path / "data"))
    got = json.loads(_run([str(python), "-c", DATA_LOOKUP], elsewhere, env).stdout.strip().splitlines()[-1])
    assert got["roots"] == [str(tmp_path / "data"), str(user)], got
    assert got["found"] == str(user / "mocap" / "probe.bvh"), got
    (tmp_path / "data" / "mocap").mkdir(parents=True)                    # $CLUSTERFEM_DATA comes first
    (tmp_path / "data" / "mocap" / "probe.bvh").write_text("HIERARCHY\n")
    got = json.loads(_run([str(python), "-c", DATA_LOOKUP], elsewhere, env).stdout.strip().splitlines()[-1])
    assert got["found"] == str(tmp_path / "data" / "mocap" / "probe.bvh"), got


def test_the_installed_console_scripts_answer_help(installed):
    _, python, elsewhere, env = installed
    for script in SCRIPTS:
        out = _run([str(python.parent / script), "--help"], elsewhere, env, timeout=120)
        assert out.stdout.startswith("usage:") and "docs/parameters.md" in out.stdout, out.stdout[:500]


def test_a_colcon_build_puts_the_executables_where_ros2_run_looks(tmp_path):
    """`colcon build` runs an ament_python package's setup.py install into install/<package>; `ros2 run
    clusterfem_ros clusterfem_node` then looks in install/<package>/lib/clusterfem_ros (setup.cfg's [install])."""
    src, build, prefix = tmp_path / "src", tmp_path / "build", tmp_path / "install" / "clusterfem_ros"
    _copy_sources(src)
    build.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR")}
    _run([sys.executable, "setup.py", "egg_info", "--egg-base", str(build), "build", "--build-base",
          str(build / "build"), "install", "--prefix", str(prefix), "--record", str(build / "install.log"),
          "--single-version-externally-managed", "install_data"], src, env)
    assert not (prefix / "bin").exists(), sorted(p.name for p in (prefix / "bin").iterdir())
    site = next(prefix.glob("lib/python3*/site-packages"))
    for script in SCRIPTS:
        executable = prefix / "lib" / "clusterfem_ros" / script
        assert executable.is_file() and os.access(executable, os.X_OK), sorted(prefix.rglob(script))
        out = _run([str(executable), "--help"], tmp_path, dict(env, PYTHONPATH=str(site)), timeout=120)
        assert out.stdout.startswith("usage:"), out.stdout[:500]
