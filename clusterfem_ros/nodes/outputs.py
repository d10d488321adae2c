"""The simulation node's output streams: each declared once (clusterfem_ros.topics.OutputDeclaration: topic, rate
parameter, encoder, decoder, what renders it, its layout), its encoder here an ``Encoder``: the ROS message class
its publisher is made for and ``encode(node, snapshot)``, the CDR bytes of the state shown, or None for nothing
this time. For every declared stream (``output_streams``) the node makes a publisher, and a timer at its rate
when that is above 0, publishes what ``encode`` gives, records it and serves it on the live view; a bag's reader,
the renderer and the layout read the same declaration. A new output is one encoder and one ``declare_output``
(tests/test_node_outputs.py adds one of its own).
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

from ..config import SceneConfig
from ..registries import Registry, load_object
from ..topics import OUTPUT_DECLARATIONS, OutputDeclaration, Topic


@dataclass(frozen=True)
class Encoder:
    """How the node makes a stream's messages."""
    msg_class: type                             # the ROS message class its publisher is made for
    encode: Callable                            # (node, snapshot or None) -> CDR bytes, or None for nothing
    depth: int = 1                              # the publisher's queue
    needs_snapshot: bool = True                 # encode needs a state physics has handed over
    published: Callable | None = None           # (node, snapshot, time published) after it went out
    warm: Callable[[SceneConfig], None] | None = None     # made when the timers are (not on the first message)


@dataclass(frozen=True)
class OutputStream:
    """A declared stream with its encoder loaded."""
    declaration: OutputDeclaration
    encoder: Encoder

    @property
    def topic(self) -> Topic:
        return self.declaration.topic

    def rate(self, config: SceneConfig) -> float:
        """[Hz]: its rate parameter's value; 0: no timer (the topic is still declared and recorded)."""
        return float(config[self.declaration.rate_param])

    def __getattr__(self, name):                # msg_class, encode, depth, ...: the encoder's
        return getattr(self.encoder, name)


OUTPUTS = Registry("output stream")             # the declared streams loaded so far, by topic name


def output_streams() -> dict[str, OutputStream]:
    """{topic name: stream} of every declared output (topics.OUTPUT_DECLARATIONS), each encoder loaded once."""
    for name, declaration in OUTPUT_DECLARATIONS.items():
        if name not in OUTPUTS or OUTPUTS[name].declaration is not declaration:
            OUTPUTS.pop(name, None)
            encoder = load_object(declaration.encoder)
            if not isinstance(encoder, Encoder):
                raise ValueError(f"output {name!r}: encoder {declaration.encoder!r} is a {type(encoder).__name__}, "
                                 "not a nodes.outputs.Encoder")
            OUTPUTS.register(name, OutputStream(declaration, encoder))
    for name in [n for n in OUTPUTS if n not in OUTPUT_DECLARATIONS]:
        del OUTPUTS[name]                       # a declaration taken back (a test's own)
    return dict(OUTPUTS)


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


SURFACE = Encoder(Marker, _surface, published=_surface_published, warm=_warm_colour_table)
STRESS = Encoder(PointCloud2, _stress)
DIAGNOSTICS = Encoder(DiagnosticArray, _diagnostics, depth=10, needs_snapshot=False)
