"""ROS tools started with their defaults see the nodes: the main job (its own DDS default, discovery on this host)
and a subscriber in a plain environment (no transport or discovery variable, the same ROS_DOMAIN_ID) exchange
markers, stress clouds and diagnostics. Run in a network namespace holding only loopback (unshare), so that
nothing this test sends can leave the machine whatever DDS does; skipped where namespaces are not permitted."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
CHILD = Path(__file__).with_name("test_dds_default_tools_child.py")
DDS_VARIABLES = ("FASTDDS_BUILTIN_TRANSPORTS", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS",
                 "ROS_DISCOVERY_SERVER", "FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
LOOPBACK_ONLY = "ip link set lo up && exec \"$0\" \"$@\""


def _loopback_namespace() -> list[str]:
    """The command prefix that runs a program in a new network namespace with only loopback, up; skips the test
    (naming why) where that cannot be made."""
    if not sys.platform.startswith("linux"):
        pytest.skip("network namespaces are Linux's")
    missing = [t for t in ("unshare", "ip") if shutil.which(t) is None]
    if missing:
        pytest.skip(f"needs {' and '.join(missing)} (util-linux, iproute2) to isolate the network")
    prefix = ["unshare", "--net", "sh", "-c", LOOPBACK_ONLY]
    probe = subprocess.run(prefix + ["ip", "-o", "link"], capture_output=True, text=True, timeout=30)
    if probe.returncode:
        pytest.skip(f"cannot make a network namespace here (unshare --net needs root or user namespaces): "
                    f"{probe.stderr.strip()[:200]}")
    links = [line.split(":")[1].strip() for line in probe.stdout.splitlines()]
    assert links == ["lo"], f"the namespace should hold loopback only: {links}"
    return prefix


def test_a_subscriber_with_ros_defaults_receives_the_main_jobs_outputs():
    prefix = _loopback_namespace()
    env = {k: v for k, v in os.environ.items() if k not in DDS_VARIABLES}
    env.update(PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(60 + os.getpid() % 30))
    run = subprocess.run(prefix + [sys.executable, str(CHILD), "8"], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["job_exit"] == 0, got["job_tail"]
    assert got["job_dds"] and "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in got["job_dds"][0], got["job_dds"]
    for topic, n in got["received"].items():
        assert n >= 3, f"{topic}: {n} messages reached a subscriber with ROS defaults; {got['received']}\n" \
                       f"{got['job_tail']}"
