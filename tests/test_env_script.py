"""scripts/env.sh is sourced into the user's shell: it must leave that shell's options as they were, whether it
succeeds or fails, and a failure must return, not close the shell."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV_SH = ROOT / "scripts" / "env.sh"

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")

# the caller's options, every way it may have set them; the script prints them before and after sourcing
PROBE = r'''
{options}
before="$(set +o; shopt -p)"
. "{env_sh}"
status=$?
after="$(set +o; shopt -p)"
[ "$before" = "$after" ] && echo "options kept" || diff <(echo "$before") <(echo "$after")
echo "status $status"
false
echo "shell alive"
'''


def _source(options: str, **env) -> subprocess.CompletedProcess:
    script = PROBE.format(options=options, env_sh=ENV_SH)
    environ = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(Path.home()), **env}
    return subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120, env=environ)


def _made_by_env_sh(venv: Path) -> bool:
    """True when env.sh would take ``venv`` as it is: it holds the stamp of this requirements.lock, setup.py and
    setup.cfg (else sourcing env.sh would remake it, which a test must not do to the environment running it)."""
    files = " ".join(f'"{ROOT / name}"' for name in ("requirements.lock", "setup.py", "setup.cfg"))
    digest = subprocess.run(f"sha1sum {files} | sha1sum | cut -c1-12",
                            shell=True, capture_output=True, text=True, check=True).stdout.strip()
    return (venv / f".lock-{digest}").is_file()


@pytest.mark.parametrize("options", ["", "set -u", "set -o pipefail; shopt -s nullglob", "set -x"])
def test_sourcing_env_sh_keeps_the_callers_options(options):
    venv = Path(sys.prefix)
    if not _made_by_env_sh(venv):
        pytest.skip(f"{venv} has no stamp of this requirements.lock (scripts/env.sh did not make it for this lock): "
                    "sourcing env.sh would remake it")
    run = _source(options, CLUSTERFEM_VENV=str(venv))
    assert "options kept" in run.stdout and "status 0" in run.stdout, run.stdout + run.stderr
    assert "shell alive" in run.stdout


def test_a_failing_env_sh_returns_1_and_keeps_the_shell_and_its_options(tmp_path):
    """A venv that cannot be made (no such interpreter) fails fast: status 1, the caller's shell goes on with
    its own options, `set -e` not left behind."""
    for options in ("", "set -u"):
        run = _source(options, CLUSTERFEM_VENV=str(tmp_path / "venv"), PYTHON=str(tmp_path / "no_python"))
        assert "options kept" in run.stdout and "status 1" in run.stdout, run.stdout + run.stderr
        assert "shell alive" in run.stdout, run.stdout + run.stderr


# a caller with `set -e` (a CI script): its flags ($-; `set +o` in a command substitution does not show -e) before
# and after sourcing; a source that may fail is written `|| status=$?`, as such a script must
ERREXIT_PROBE = r'''
set -e
before="$-"
status=0
{source}
after="$-"
[ "$before" = "$after" ] && echo "flags kept $after" || echo "flags changed: $before -> $after"
echo "status $status"
echo "shell alive"
'''


def _source_with_set_e(source: str, **env) -> subprocess.CompletedProcess:
    script = ERREXIT_PROBE.format(source=source.format(env_sh=ENV_SH))
    environ = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(Path.home()), **env}
    return subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120, env=environ)


def test_a_caller_with_set_e_keeps_it_after_sourcing_env_sh():
    venv = Path(sys.prefix)
    if not _made_by_env_sh(venv):
        pytest.skip(f"{venv} has no stamp of this requirements.lock, setup.py and setup.cfg: env.sh would remake it")
    run = _source_with_set_e('. "{env_sh}"', CLUSTERFEM_VENV=str(venv))     # unguarded: it must succeed
    flags = run.stdout.split("flags kept ")[-1].split()[0] if "flags kept" in run.stdout else ""
    assert "e" in flags and "status 0" in run.stdout and "shell alive" in run.stdout, run.stdout + run.stderr


def test_a_failing_env_sh_returns_1_to_a_caller_with_set_e_and_keeps_its_shell(tmp_path):
    """env.sh returns 1 from a failing step (never `exit`, which would close the shell even behind `||`), and
    leaves -e set."""
    run = _source_with_set_e('. "{env_sh}" || status=$?', CLUSTERFEM_VENV=str(tmp_path / "venv"),
                             PYTHON=str(tmp_path / "no_python"))
    assert "flags kept" in run.stdout and "e" in run.stdout.split("flags kept ")[1].split()[0], run.stdout
    assert "status 1" in run.stdout and "shell alive" in run.stdout, run.stdout + run.stderr


def test_env_sh_keeps_dds_discovery_on_this_host_unless_set():
    venv = Path(sys.prefix)
    if not _made_by_env_sh(venv):
        pytest.skip(f"{venv} has no stamp of this requirements.lock: sourcing env.sh would remake it")
    script = f'. "{ENV_SH}" && echo "range=$ROS_AUTOMATIC_DISCOVERY_RANGE transports=${{FASTDDS_BUILTIN_TRANSPORTS-unset}}"'
    for given, want in ((None, "LOCALHOST"), ("SUBNET", "SUBNET")):
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(Path.home()), "CLUSTERFEM_VENV": str(venv)}
        if given:
            env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = given
        run = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120, env=env)
        assert run.returncode == 0, run.stderr[-2000:]
        assert f"range={want} transports=unset" in run.stdout, run.stdout


def test_the_environment_env_sh_made_has_the_console_scripts_on_its_path():
    """setup.cfg sends colcon's scripts to lib/clusterfem_ros (ros2 run); env.sh's editable install must still put
    them in the environment's bin, on PATH once it is sourced (scripts/run, the docs' commands, tests)."""
    venv = Path(sys.prefix)
    if not _made_by_env_sh(venv):
        pytest.skip(f"{venv} has no stamp of this requirements.lock, setup.py and setup.cfg: env.sh did not make it")
    script = f'. "{ENV_SH}" && for s in clusterfem_node mocap_player clusterfem_demo; do command -v "$s"; done'
    env = {"PATH": "/usr/bin:/bin", "HOME": str(Path.home()), "CLUSTERFEM_VENV": str(venv)}
    run = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120, env=env)
    assert run.returncode == 0, run.stdout + run.stderr[-2000:]
    assert run.stdout.split() == [str(venv / "bin" / s) for s in ("clusterfem_node", "mocap_player",
                                                                   "clusterfem_demo")], run.stdout
