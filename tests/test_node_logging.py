"""The node's physics-thread log lines: every level the physics loop uses can follow any other."""
import pytest

pytestmark = pytest.mark.ros


class _Logged:
    """Stands in for the node: ClusterFemNode._log reads only get_logger()."""

    def __init__(self, name: str):
        from rclpy.logging import get_logger
        self._logger = get_logger(name)

    def get_logger(self):
        return self._logger


def test_a_reset_logged_after_a_dropped_sample_warning_does_not_raise():
    """sim_loop logs 'warning' (samples dropped) and then 'error' (a reset) through the node's one _log: rclpy
    refused the second severity at the same throttled call site with a ValueError, which ended the physics
    thread on the first reset after a warning (seen in the clip soak through the node under load)."""
    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    node = _Logged("test_node_logging")
    for level in ("warning", "error", "info", "error", "warning"):
        ClusterFemNode._log(node, level, f"a {level} line")
    with pytest.raises(ValueError, match="log level 'fatal'"):
        ClusterFemNode._log(node, "fatal", "no such level here")
