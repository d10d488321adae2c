"""Spinning a node until the process is asked to stop, the same way for every node's main()."""
from __future__ import annotations

import rclpy
from rclpy.executors import ExternalShutdownException


def spin_until_shutdown(node) -> None:
    """rclpy.spin(node) until Ctrl-C, SIGTERM or an external shutdown.

    SIGINT and SIGTERM shut the context down from rclpy's signal handler; a timer callback already under way
    then fails to publish ("publisher's context is invalid"). That is the shutdown, not an error: only an
    exception raised while the context is still valid propagates.
    """
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok(context=node.context):
            raise
