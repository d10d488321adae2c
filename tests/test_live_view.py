"""The node's live view: a Foxglove WebSocket client on 127.0.0.1 sees the node's channels advertised (those the
shipped layout shows among them), subscribes, and decodes the surface Marker with the advertised ROS schema;
the bytes are those the node publishes on DDS (and records)."""
from __future__ import annotations

import json
import socket
import struct
import time
from pathlib import Path

import pytest
from rclpy.parameter import Parameter

from clusterfem_ros.nodes.testing import RosWorld
from tests.ros_env import child_env

pytestmark = pytest.mark.ros
pytest.importorskip("foxglove")
client = pytest.importorskip("websockets.sync.client")

ROOT = Path(__file__).resolve().parents[1]
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01                    # server binary opcode: subscription id (u32), receive time (u64), payload


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _layout_topics() -> set[str]:
    layout = json.loads((ROOT / "config" / "foxglove_layout.json").read_text())
    topics = set()
    for key, panel in layout["configById"].items():
        topics |= set(panel.get("topics", {})) if key.startswith("3D!") else set()
        topics |= {p["value"].split(".")[0] for p in panel.get("paths", [])}
    return topics


def _decoder(channel: dict):
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    schema = Schema(id=1, name=channel["schemaName"], encoding=channel["schemaEncoding"],
                    data=channel["schema"].encode())
    return DecoderFactory().decoder_for(channel["encoding"], schema)


def test_a_websocket_client_sees_subscribes_and_decodes_the_surface():
    from visualization_msgs.msg import Marker

    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    port = _free_port()
    values = {"body.kind": "sphere", "skeleton.source": "none", "warping": False, "output.marker_rate_hz": 20.0,
              "output.live_port": port}
    with RosWorld() as world:
        node = world.add(ClusterFemNode(context=world.context,
                                        parameter_overrides=[Parameter(k, value=v) for k, v in values.items()]))
        assert node.live is not None and node.live.url == f"ws://127.0.0.1:{port}"
        on_dds = world.collect(Marker, "clusterfem/surface")
        with client.connect(node.live.url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
            channels = {}
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and not _layout_topics() <= set(channels):
                msg = ws.recv(timeout=10)
                if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
                    channels.update({c["topic"]: c for c in json.loads(msg)["channels"]})
            assert _layout_topics() <= set(channels), (sorted(channels), _layout_topics())
            surface = channels["/clusterfem/surface"]
            assert (surface["encoding"], surface["schemaEncoding"]) == ("cdr", "ros2msg")
            assert surface["schemaName"] == "visualization_msgs/msg/Marker"
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": surface["id"]}]}))
            payloads = []
            while len(payloads) < 3:
                msg = ws.recv(timeout=20)
                if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:
                    sub_id, _stamp = struct.unpack_from("<IQ", msg, 1)
                    assert sub_id == 7
                    payloads.append(msg[13:])
        world.wait_for(lambda: len(on_dds) >= 1, 20, "a marker on DDS")
    marker = _decoder(surface)(payloads[-1])
    assert marker.type == Marker.TRIANGLE_LIST and marker.header.frame_id == "world" and marker.ns == "clusterfem"
    assert len(marker.points) == 3 * len(node.scene.surface_triangles) == len(marker.colors)
    # the same CDR bytes as published on DDS: one of the live payloads is one of the DDS messages
    assert set(payloads) & set(on_dds), "live payloads are not the published bytes"


def test_the_live_view_is_off_by_default_and_a_taken_port_is_one_clear_error():
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    values = {"body.kind": "sphere", "skeleton.source": "none", "warping": False}
    with RosWorld() as world:
        node = world.add(ClusterFemNode(context=world.context,
                                        parameter_overrides=[Parameter(k, value=v) for k, v in values.items()]))
        assert node.live is None
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with RosWorld() as world, pytest.raises(RuntimeError, match=f"{port}.*output.live_port"):
            ClusterFemNode(context=world.context, parameter_overrides=[
                Parameter(k, value=v) for k, v in {**values, "output.live_port": port}.items()])


def test_the_main_job_serves_its_topics_live():
    """`scripts/run --live PORT` (the README's command): the main job's node serves its topics on 127.0.0.1:PORT."""
    import subprocess
    import sys
    port = _free_port()
    env = child_env(100, PYTHONPATH=str(ROOT))
    job = subprocess.Popen([sys.executable, "-m", "clusterfem_ros.nodes.demo", "--duration", "30", "--no-record",
                            "--no-png", "--no-video", "--live", str(port)], cwd=ROOT, env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        for line in job.stdout:                         # the node says where it serves once it does
            if f"live view on ws://127.0.0.1:{port}" in line or "timed run starts" in line:
                break
        with client.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=30) as ws:
            topics = set()
            while not _layout_topics() <= topics:
                msg = ws.recv(timeout=30)
                if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
                    topics |= {c["topic"] for c in json.loads(msg)["channels"]}
    finally:
        job.terminate()
        job.wait(timeout=60)
    assert {"/clusterfem/surface", "/clusterfem/stress", "/diagnostics", "/joint_states"} <= topics
