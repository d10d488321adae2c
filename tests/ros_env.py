"""The environment of a test's child process that starts ROS nodes (the main job, a node, a player).

DDS on shared memory only (``FASTDDS_BUILTIN_TRANSPORTS=SHM``: no UDP socket is opened, nothing is sent to any
address) in a domain of the test's own, ``base + pid % span``, so parallel runs and a user's ROS graph on the same
host do not meet. A ``RosWorld`` (clusterfem_ros/nodes/testing.py) sets the same for its own lifetime; a child
started outside one needs it passed.
"""
from __future__ import annotations

import os


def child_env(base: int, span: int = 20, **extra: str) -> dict[str, str]:
    """os.environ with DDS kept on shared memory and ROS_DOMAIN_ID = base + pid % span, plus ``extra``."""
    return dict(os.environ, FASTDDS_BUILTIN_TRANSPORTS="SHM", ROS_DOMAIN_ID=str(base + os.getpid() % span), **extra)
