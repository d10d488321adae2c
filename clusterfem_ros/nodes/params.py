"""Scene parameters as ROS parameters: descriptors with descriptions and ranges from config.PARAMS."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..config import PARAMS, ConfigError, SceneConfig, check_value, from_mapping, unknown_name_error

_KNOWN = {p.name for p in PARAMS}
_LISTS = {p.name for p in PARAMS if isinstance(p.default, list)}


def _value(name: str, value):
    """An empty list in a params YAML (``anchors.points: []``) reaches rclpy as a parameter without a value
    (None): for a list parameter that is the empty list it was written as."""
    return [] if value is None and name in _LISTS else value


# Parameters a running node can take; everything else shapes the model and needs a restart. They only
# change how outputs look and how often they come; live, the rates have tighter bounds than at start-up:
# diagnostics cannot be switched off (monitoring must see the node), markers and clouds no faster than a
# display refreshes. output.frame_id is bounded for every source (config.check_value).
LIVE = {"output.marker_rate_hz", "output.stress_rate_hz", "output.diagnostics_rate_hz", "output.colormap",
        "output.stress_max", "output.frame_id"}
LIVE_BOUNDS = {"output.diagnostics_rate_hz": (0.1, 10.0), "output.marker_rate_hz": (0.0, 60.0),
               "output.stress_rate_hz": (0.0, 30.0)}
# names a params file may hold besides the scene parameters (rclpy's own)
ROS_NAMES = {"use_sim_time", "start_type_description_service"}


def _typed_by_us(p) -> bool:
    """Parameters whose type check_value makes, not rclpy: lists (rclpy types an empty default as a byte array and
    would refuse the doubles or strings a file gives), floats (a params file's ``30000`` is an integer) and text
    (YAML 1.1 reads an unquoted ``Y`` or ``on`` as a boolean)."""
    return isinstance(p.default, (list, float, str))


def descriptor(p) -> ParameterDescriptor:
    d = ParameterDescriptor(description=p.description, dynamic_typing=_typed_by_us(p))
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
            lo, hi = LIVE_BOUNDS.get(prm.name, (None, None))
            if started["done"] and lo is not None and not lo <= prm.value <= hi:
                return SetParametersResult(successful=False, reason=(
                    f"{prm.name} = {prm.value!r}: a running node takes [{lo:g}, {hi:g}] only; start the node "
                    "with the value to go beyond"))
        if started["done"]:
            on_live_change({prm.name: _value(prm.name, prm.value) for prm in params})
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(check)
    for name in getattr(node, "_parameter_overrides", {}):     # a params file's misspelt name is refused
        if name not in _KNOWN and name not in ROS_NAMES and not name.startswith("qos_overrides."):
            raise unknown_name_error(name)
    node.declare_parameters("", [(p.name, p.default, descriptor(p)) for p in PARAMS])
    values = {p.name: _value(p.name, node.get_parameter(p.name).value) for p in PARAMS}
    # what a file or -p gave as an integer for a float, a boolean or another case for a choice: stored as the value
    # the node runs with, so that `ros2 param get` shows it
    typed = {p.name: check_value(p.name, values[p.name]) for p in PARAMS if not isinstance(p.default, list)}
    retyped = [Parameter(n, value=v) for n, v in typed.items()
               if type(v) is not type(values[n]) or v != values[n]]
    if retyped:
        node.set_parameters(retyped)
    started["done"] = True
    return from_mapping(values)
