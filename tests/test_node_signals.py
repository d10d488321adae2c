"""SIGINT and SIGTERM stop the node process cleanly with its recording finalised (complete MCAP)."""
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_finalises_the_recording(tmp_path, sig):
    from rosbags.highlevel import AnyReader
    from clusterfem_ros.recording.recover import is_complete
    env = dict(os.environ, FASTDDS_BUILTIN_TRANSPORTS="SHM", ROS_DOMAIN_ID=str(150 + os.getpid() % 50 + sig))
    proc = subprocess.Popen(
        [sys.executable, "-m", "clusterfem_ros.nodes.clusterfem_node", "--ros-args",
         "-p", "body.kind:=sphere", "-p", "skeleton.source:=none", "-p", "warping:=false",
         "-p", "recording.enabled:=true", "-p", f"recording.dir:={tmp_path}",
         "-p", "output.marker_rate_hz:=20.0", "-p", "output.diagnostics_rate_hz:=10.0"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any("scene ready" in x for x in lines) and proc.poll() is None:
            time.sleep(0.1)
        time.sleep(2.0)                                  # publish and record a while
        assert proc.poll() is None, "".join(lines)
        proc.send_signal(sig)
        proc.wait(timeout=30)
        reader.join(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    out = "".join(lines)
    assert proc.returncode == 0, out
    assert "recording finalised" in out
    bag = next(tmp_path.iterdir())
    mcap = next(bag.glob("*.mcap"))
    assert is_complete(mcap)
    assert (bag / "metadata.yaml").exists()
    with AnyReader([Path(bag)]) as r:
        topics = {c.topic for c in r.connections}
        n = sum(1 for _ in r.messages())
    assert {"/clusterfem/surface", "/diagnostics"} <= topics and n >= 10
