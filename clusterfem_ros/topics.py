"""The topics of the nodes, declared once: each name (relative to a node's namespace unless it starts with '/'),
message type and the QoS it is recorded with. The simulation node's output streams (nodes/outputs.py) are made
from them, and it records and serves on the live view what it takes in and publishes; the player publishes two; a bag's reader and the renderer find them in a bag by
``recorded`` (rosbag2 names topics fully qualified; a body in a namespace records them under it, which
recording.bag_reader.topic_in finds). Nothing here imports ROS."""
from __future__ import annotations

from dataclasses import dataclass


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
