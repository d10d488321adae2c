"""The simulation node's output streams, declared once: each an ``OutputStream`` registered by topic
(``register_output``). A stream names its topic (clusterfem_ros.topics: name, type, the QoS a bag records), its
ROS message class, its rate (from the scene's parameters) and ``encode(node, snapshot)``: the CDR bytes of
the state shown, or None for nothing this time. For every registered stream the node makes a publisher, and a
timer at its rate when that is above 0, publishes what ``encode`` gives, records it and serves it on the live
view; a bag's reader and the renderer find its topic by the same declaration. A new output is one encoder and
one registration (tests/test_node_outputs.py adds one of its own).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import serialize_message
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import Marker

from msg_adapters import colormap
from msg_adapters.marker import surface_marker_cdr
from msg_adapters.pointcloud import stress_cloud_cdr

from .. import topics
from ..config import SceneConfig
from ..registries import Registry
from ..topics import Topic


@dataclass(frozen=True)
class OutputStream:
    topic: Topic
    msg_class: type                             # the ROS message class its publisher is made for
    rate: Callable[[SceneConfig], float]        # [Hz]; 0: no timer (the topic is still declared and recorded)
    encode: Callable                            # (node, snapshot or None) -> CDR bytes, or None for nothing
    depth: int = 1                              # the publisher's queue
    needs_snapshot: bool = True                 # encode needs a state physics has handed over
    published: Callable | None = None           # (node, snapshot, time published) after it went out
    warm: Callable[[SceneConfig], None] | None = None     # made when the timers are (not on the first message)


OUTPUTS = Registry("output stream")


def register_output(stream: OutputStream) -> OutputStream:
    """Add an output stream under its topic's name (a name already taken is refused); returns it."""
    return OUTPUTS.register(stream.topic.name, stream)


def _surface(node, snap) -> bytes:
    scene = node.scene
    vm = node.stress_of(snap).vertex_von_mises[scene.surface_vertices]
    t0 = time.perf_counter()
    verts = scene.model.rest[scene.surface_vertices] + snap.u[scene.surface_vertices]
    out = node.config.output
    rgba = colormap.map_scalars(vm, out.colormap, 0.0, node.config.marker_stress_max)
    data = surface_marker_cdr(verts, scene.surface_triangles, rgba, out.frame_id, node.sim_stamp(snap),
                              "clusterfem", 0)
    node.physics.stages.add("markers", time.perf_counter() - t0)
    return data


def _stress(node, snap) -> bytes:
    vm = node.stress_of(snap).vertex_von_mises
    t0 = time.perf_counter()
    data = stress_cloud_cdr(node.scene.model.rest + snap.u, vm, node.config.output.frame_id, node.sim_stamp(snap))
    node.physics.stages.add("cloud", time.perf_counter() - t0)
    return data


def _diagnostics(node, snap) -> bytes:
    t0 = time.perf_counter()
    data = serialize_message(node.diagnostic_array())
    if node.physics is not None:
        node.physics.stages.add("diagnostics", time.perf_counter() - t0)
    return data


def _surface_published(node, snap, t: float) -> None:
    node.physics.latency.published(snap.inputs_used, t)     # joint state -> Marker latency


def _warm_colour_table(config: SceneConfig) -> None:
    # made now: made on the first marker, its matplotlib import held the executor 0.2 s and the joint states
    # came late, in a burst (the body re-placed at the start of every run)
    if config.output.marker_rate_hz > 0:
        colormap.colormap_lut(config.output.colormap)


register_output(OutputStream(topics.SURFACE, Marker, lambda c: c.output.marker_rate_hz, _surface,
                             published=_surface_published, warm=_warm_colour_table))
register_output(OutputStream(topics.STRESS, PointCloud2, lambda c: c.output.stress_rate_hz, _stress))
register_output(OutputStream(topics.DIAGNOSTICS, DiagnosticArray, lambda c: c.output.diagnostics_rate_hz,
                             _diagnostics, depth=10, needs_snapshot=False))
OUTPUTS.seal()
