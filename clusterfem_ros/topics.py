"""The topics of the nodes, declared once: each name (relative to a node's namespace unless it starts with '/'),
message type and the QoS it is recorded with; and the simulation node's output streams (``OutputDeclaration``):
the topic, the scene parameter of its rate, its encoder (nodes/outputs.py: loaded by the node), its decoder (CDR
bytes -> frames, loaded by a bag's reader without ROS), what the renderer draws from it and how the Foxglove
layout shows it. The node publishes, records and serves on the live view every declared stream; the player
publishes two topics; a bag's reader and the renderer find them in a bag by ``recorded`` (rosbag2 names topics
fully qualified; a body in a namespace records them under it, which recording.bag_reader.topic_in finds).
A new output is its encoder (and decoder) and one ``declare_output`` call. Nothing here imports ROS.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .registries import Registry


@dataclass(frozen=True)
class Topic:
    name: str           # as a node creates it: relative to its namespace, or absolute ('/diagnostics')
    type: str           # 'package/msg/Type'
    qos: str            # the offered QoS recorded in a bag: 'sensor_data', 'reliable' or 'transient_local'

    @property
    def recorded(self) -> str:
        """The name in a bag of a node in the root namespace."""
        return "/" + self.name.lstrip("/")


JOINT_STATES = Topic("joint_states", "sensor_msgs/msg/JointState", "sensor_data")
SURFACE = Topic("clusterfem/surface", "visualization_msgs/msg/Marker", "reliable")
STRESS = Topic("clusterfem/stress", "sensor_msgs/msg/PointCloud2", "reliable")
DIAGNOSTICS = Topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "reliable")
ROBOT_DESCRIPTION = Topic("robot_description", "std_msgs/msg/String", "transient_local")   # latched


@dataclass(frozen=True)
class OutputDeclaration:
    """One output stream of the simulation node, everything every reader of it needs."""
    topic: Topic
    rate_param: str                 # the scene parameter of its rate [Hz] (0: no timer; still declared, recorded)
    encoder: str                    # 'package.module:name' of its nodes.outputs.Encoder (the node loads it)
    decoder: str = ""               # 'package.module:function': its CDR bytes -> one frame ('' = a bag keeps it raw)
    renders: str = ""               # what render.py draws from its frames: 'surface' (the body), 'stress' (the
                                    # colour scale of the run), '' (nothing)
    layout: dict = field(default_factory=dict)   # its topic settings in the Foxglove layout's 3D panel ({} = none)


OUTPUT_DECLARATIONS = Registry("output stream")


def declare_output(declaration: OutputDeclaration) -> OutputDeclaration:
    """Make ``declaration`` one of the node's outputs (a topic already taken is refused); returns it."""
    return OUTPUT_DECLARATIONS.register(declaration.topic.name, declaration)


def rendered(role: str) -> OutputDeclaration | None:
    """The declared stream the renderer draws as ``role`` ('surface', 'stress'), or None."""
    return next((d for d in OUTPUT_DECLARATIONS.values() if d.renders == role), None)


def layout_topics() -> dict[str, dict]:
    """{recorded topic: its 3D panel settings} of every stream the layout shows: what config/foxglove_layout.json's
    3D panel holds (tests/test_docs.py holds the file to it)."""
    return {d.topic.recorded: dict(d.layout) for d in OUTPUT_DECLARATIONS.values() if d.layout}


_OUT, _FRAMES = "clusterfem_ros.nodes.outputs", "clusterfem_ros.bag_frames"
for _d in (OutputDeclaration(SURFACE, "output.marker_rate_hz", f"{_OUT}:SURFACE", f"{_FRAMES}:decode_surface_marker",
                             "surface", {"visible": True}),
           OutputDeclaration(STRESS, "output.stress_rate_hz", f"{_OUT}:STRESS", f"{_FRAMES}:decode_stress_cloud",
                             "stress", {"visible": False, "colorField": "von_mises", "colorMode": "colormap",
                                        "colorMap": "turbo", "pointSize": 4}),
           OutputDeclaration(DIAGNOSTICS, "output.diagnostics_rate_hz", f"{_OUT}:DIAGNOSTICS")):
    declare_output(_d)
OUTPUT_DECLARATIONS.seal()
