"""Running a node until the process is asked to stop, the same way for every node's main()."""
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


def run_node(make_node, args=None) -> None:
    """A node's main(): rclpy.init, ``make_node()``, spin until shutdown; on every way out (including an
    exception while building the node) the node's ``close()`` if it has one (a recording is finalised),
    then destroy_node and shutdown."""
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        spin_until_shutdown(node)
    finally:
        if node is not None:
            if hasattr(node, "close"):
                node.close()
            node.destroy_node()
        rclpy.try_shutdown()
