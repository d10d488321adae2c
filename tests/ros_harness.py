"""Launch-free rclpy test harness: each test gets its own Context, ROS_DOMAIN_ID and executor thread.

DDS stays in shared memory (FASTDDS_BUILTIN_TRANSPORTS=SHM, set before rclpy loads). Teardown order
matters (../shared/notes): shut the executor down, join its thread, destroy nodes, shut the context.
"""
from __future__ import annotations

import itertools
import os
import threading
import time
from typing import Callable

os.environ.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "SHM")

import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

_domains = itertools.count((os.getpid() % 50) * 4 + 20)


class RosWorld:
    """Nodes spinning in a background thread, in a private context and domain."""

    def __init__(self):
        self.domain_id = next(_domains) % 200 + 1
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain_id)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._started = False
        self.error: BaseException | None = None

    def _spin(self):
        try:
            self.executor.spin()
        except Exception as exc:  # a callback raised: the test fails with it, not with a time-out
            if self.context.ok():
                self.error = exc

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        if not self._started:
            self._thread.start()
            self._started = True
        return node

    def node(self, name: str):
        return self.add(rclpy.create_node(name, context=self.context))

    def wait_for(self, predicate: Callable[[], bool], timeout: float = 10.0, what: str = "condition") -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.error is not None:
                raise AssertionError(f"a node callback raised while waiting for {what}") from self.error
            if predicate():
                return
            time.sleep(0.01)
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")

    def close(self):
        self.executor.shutdown(timeout_sec=5.0)
        if self._started:
            self._thread.join(timeout=10.0)
        for n in self.nodes:
            if hasattr(n, "close"):
                n.close()
            n.destroy_node()
        self.context.try_shutdown()
