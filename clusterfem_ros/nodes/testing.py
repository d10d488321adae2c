"""Launch-free rclpy integration tests: nodes spinning in a background thread of the test's own process.

    from clusterfem_ros.nodes.testing import RosWorld

    with RosWorld() as world:
        sim = world.add(ClusterFemNode(context=world.context, parameter_overrides=[...]))
        markers = world.collect(Marker, "clusterfem/surface")
        world.wait_for(lambda: len(markers) >= 3, 30, "three surface markers")

Each RosWorld has its own rclpy Context, ROS_DOMAIN_ID and single-threaded executor, so tests do not hear
each other. DDS stays on this machine: while a RosWorld lives it sets FASTDDS_BUILTIN_TRANSPORTS=SHM unless it
is set (before its context starts; the variable comes back as it was when the last world closes); where
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST is set too (scripts/env.sh), rmw_fastrtps takes that instead: shared
memory and UDP to 127.0.0.1 only (docs/usage.md, Network). Teardown order
matters (../shared/notes): shut the executor down, join its thread, close and destroy the nodes (a node's
``close()`` finalises its recording), shut the context down. Used by this package's own node tests.
"""
from __future__ import annotations

import itertools
import os
import threading
import time
from typing import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

_domains = itertools.count((os.getpid() % 50) * 4 + 20)
WORLD_ENVIRONMENT = {"FASTDDS_BUILTIN_TRANSPORTS": "SHM"}     # set while a world lives, unless already set


class _Environment:
    """The worlds' environment variables: set (where unset) when the first world opens, given back as they were
    when the last one closes."""

    def __init__(self):
        self._lock = threading.Lock()
        self._open = 0
        self._before: dict[str, str | None] = {}

    def enter(self) -> None:
        with self._lock:
            if self._open == 0:
                self._before = {k: os.environ.get(k) for k in WORLD_ENVIRONMENT}
                for k, v in WORLD_ENVIRONMENT.items():
                    os.environ.setdefault(k, v)
            self._open += 1

    def leave(self) -> None:
        with self._lock:
            self._open -= 1
            if self._open == 0:
                for k, v in self._before.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v


_ENVIRONMENT = _Environment()


class RosWorld:
    """Nodes spinning in a background thread, in a private context and domain (1-200, by process id)."""

    def __init__(self):
        self.domain_id = next(_domains) % 200 + 1
        self.context = Context()
        _ENVIRONMENT.enter()
        self._entered = True
        try:
            rclpy.init(context=self.context, domain_id=self.domain_id)
        except BaseException:
            self._leave()
            raise
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._started = False
        self._probes = itertools.count()
        self.error: BaseException | None = None

    def __enter__(self) -> "RosWorld":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception as exc:  # a callback raised: the test fails with it, not with a time-out
            if self.context.ok():
                self.error = exc

    def add(self, node):
        """Spin ``node`` (made with ``context=world.context``) from now on; returns it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        if not self._started:
            self._thread.start()
            self._started = True
        return node

    def node(self, name: str):
        """A plain node of this world, spinning (for probes and test publishers)."""
        return self.add(rclpy.create_node(name, context=self.context))

    def collect(self, msg_type, topic: str, qos: int = 10, raw: bool = True) -> list:
        """A list that every message on ``topic`` is appended to, serialized (``raw``: decoding every big Marker
        in Python would starve the executor; rclpy.serialization.deserialize_message the ones you check)."""
        got: list = []
        self.node(f"probe_{next(self._probes)}").create_subscription(msg_type, topic, got.append, qos, raw=raw)
        return got

    def wait_for(self, predicate: Callable[[], bool], timeout: float = 10.0, what: str = "condition") -> None:
        """Return once ``predicate()`` holds; AssertionError naming ``what`` after ``timeout`` s, or at once
        (chained) when a node's callback raised."""
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
        try:
            for n in self.nodes:
                if hasattr(n, "close"):
                    n.close()
                n.destroy_node()
            self.context.try_shutdown()
        finally:
            self._leave()

    def _leave(self) -> None:
        if self._entered:                       # once, however often close is called
            self._entered = False
            _ENVIRONMENT.leave()
