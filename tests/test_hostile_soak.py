"""Soak (issue 19): joint_states flooded at >= 5 kHz for 60 s (good, oversized and garbage messages) while the
node records onto a 3 MB disk that fills up. The node stays alive, its memory flat, the bag readable after
recover_bag, and its counters account for every message it received.

    scripts/test tests/test_hostile_soak.py -m soak -s

Needs root for the 3 MB tmpfs (skipped otherwise). Prints the achieved flood rate and the DDS loss.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rclpy.parameter import Parameter

from clusterfem_ros.nodes.testing import RosWorld
from tests.test_recording_signals import rosbags_count

pytestmark = [pytest.mark.ros, pytest.mark.soak]
ROOT = Path(__file__).resolve().parents[1]
SECONDS, RATE_HZ = 60.0, 6000.0


@pytest.fixture
def small_disk(tmp_path):
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a 3 MB tmpfs (needs root)")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def fatal_kinds() -> set[str]:
    from clusterfem_ros.skeleton.joint_map import FATAL as MAP_FATAL
    from clusterfem_ros.skeleton.joint_stream import FATAL as STREAM_FATAL
    return set(MAP_FATAL) | set(STREAM_FATAL) | {"malformed", "no_skeleton"}


def test_a_joint_state_flood_onto_a_full_disk(small_disk, tmp_path):
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    from clusterfem_ros.recording.recover import RecoveryError, recover_bag
    values = {"body.kind": "jelly_man", "body.target_tets": 700, "skeleton.source": "builtin", "warping": False,
              "output.marker_rate_hz": 10.0, "output.stress_rate_hz": 2.0, "output.diagnostics_rate_hz": 2.0,
              "recording.enabled": True, "recording.dir": str(small_disk), "recording.max_queue_mb": 8.0}
    with RosWorld() as world:
        sim = world.add(ClusterFemNode(context=world.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in values.items()]))
        env = dict(os.environ, PYTHONPATH=str(ROOT), FASTDDS_BUILTIN_TRANSPORTS="SHM")
        child = subprocess.Popen([sys.executable, str(Path(__file__).with_name("test_hostile_flood_child.py")),
                                  str(world.domain_id), str(SECONDS), str(RATE_HZ),
                                  ",".join(sim.scene.skeleton.joint_names)],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
        assert child.stdout.readline().strip() == "ready", child.stderr.read()
        time.sleep(10.0)                                              # warm-up: caches, the disk fills
        rss0 = rss_mb()
        samples = []
        while child.poll() is None:
            samples.append(rss_mb())
            time.sleep(1.0)
            assert world.error is None
        sent = json.loads(child.stdout.read().strip().splitlines()[-1])
        time.sleep(1.0)                                               # the last messages in flight
        rss1 = rss_mb()
        world.executor.shutdown(timeout_sec=5.0)
        assert sim.physics.stop()                                     # nothing is pushed while we count
        waiting, dropped = sim.physics.waiting, sim.physics.queue_full
        inputs = sim.scene.inputs
        fatal = sum(n for k, n in inputs.rejected.items() if k in fatal_kinds())
        total_sent = sent["good"] + sent["too_many_names"] + sent["malformed"]
        rate = total_sent / sent["seconds"]
        print(f"\nflood: {total_sent} messages in {sent['seconds']:.1f} s ({rate:.0f} Hz); node received "
              f"{sim.received} ({100 * (1 - sim.received / total_sent):.1f} % lost in DDS); accepted "
              f"{inputs.accepted}; rejected {inputs.rejected}; RSS {rss0:.0f} -> {rss1:.0f} MB (max "
              f"{max(samples):.0f}); physics queue: {dropped} dropped full, {waiting} waiting at the end; "
              f"recording: {sim.recording_error or 'on'}")
        assert rate >= 5000.0
        # every message accounted for once: used, refused, before the scene, or dropped or left in the physics queue
        assert sim.received == inputs.accepted + fatal + sim.before_scene + dropped + waiting
        assert sim.received <= total_sent and sim.scene.inputs.rejected.get("too_many_names", 0) <= \
            sent["too_many_names"] and sim.scene.inputs.rejected.get("malformed", 0) <= sent["malformed"]
        assert inputs.rejected.get("too_many_names", 0) > 0 and inputs.rejected.get("malformed", 0) > 0
        assert "No space left on device" in sim.recording_error                # the disk filled, the node went on
        assert max(samples) <= 1.10 * rss0 and rss1 <= 1.10 * rss0
        bag = sim.recording_path
        sim.close()
    (tmp_path / "work").mkdir()
    killed = sorted(bag.glob("*.mcap"))[0]
    killed_size = killed.stat().st_size
    try:
        report = recover_bag(bag, work_dir=tmp_path / "work")
    except RecoveryError as exc:
        # the disk is full to the last block: the copy, which adds a summary, may not fit back in the bag's place;
        # then the bag is left as it was and the complete copy is a bag folder in the work dir
        assert "does not fit in place of" in str(exc) and "the bag is unchanged" in str(exc)
        assert killed.stat().st_size == killed_size
        counts = rosbags_count(tmp_path / "work" / (bag.name + ".recovering"))
        assert counts.get("/joint_states", 0) > 0
    else:
        counts = rosbags_count(bag)
        assert counts.get("/joint_states", 0) > 0 and sum(counts.values()) == report.messages
