"""Scene parameters as ROS parameters: descriptors with descriptions and ranges from config.PARAMS."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node

from ..config import PARAMS, ConfigError, SceneConfig, check_value, from_mapping

_LISTS = {p.name for p in PARAMS if isinstance(p.default, list)}


def _value(name: str, value):
    """An empty list in a params YAML (``anchors.points: []``) reaches rclpy as a parameter without a value
    (None): for a list parameter that is the empty list it was written as."""
    return [] if value is None and name in _LISTS else value

# Parameters a running node can take; everything else shapes the model and needs a restart.
LIVE = {"output.marker_rate_hz", "output.stress_rate_hz", "output.diagnostics_rate_hz", "output.colormap",
        "output.stress_max", "output.frame_id"}


def descriptor(p) -> ParameterDescriptor:
    # lists: rclpy types an empty default as a byte array and would refuse the doubles or strings a file gives;
    # the type is checked by check_value instead
    d = ParameterDescriptor(description=p.description, dynamic_typing=isinstance(p.default, list))
    if p.choices:
        d.additional_constraints = "one of: " + ", ".join(p.choices)
    if p.lo is not None:
        if isinstance(p.default, int) and not isinstance(p.default, bool):
            d.integer_range = [IntegerRange(from_value=int(p.lo), to_value=int(p.hi), step=0)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(p.lo), to_value=float(p.hi), step=0.0)]
    return d


def declare_scene_parameters(node: Node, on_live_change) -> SceneConfig:
    """Register the checking callback first (so values from a file are checked too), then declare."""
    started = {"done": False}

    def check(params) -> SetParametersResult:
        for prm in params:
            try:
                check_value(prm.name, _value(prm.name, prm.value))
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
            if started["done"] and prm.name not in LIVE:
                return SetParametersResult(successful=False, reason=(
                    f"{prm.name} shapes the model and cannot change while running: restart the node with "
                    f"the new value (live parameters: {', '.join(sorted(LIVE))})"))
        if started["done"]:
            on_live_change({prm.name: _value(prm.name, prm.value) for prm in params})
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(check)
    node.declare_parameters("", [(p.name, p.default, descriptor(p)) for p in PARAMS])
    values = {p.name: _value(p.name, node.get_parameter(p.name).value) for p in PARAMS}
    started["done"] = True
    return from_mapping(values)
