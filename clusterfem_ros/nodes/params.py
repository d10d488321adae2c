"""A node's parameters as ROS parameters from a table of config.Param (the scene's config.PARAMS, the player's
motion.PLAYER_TABLE): descriptors with descriptions and ranges, every value checked and typed by config.check_param."""
from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..config import PARAMS, ConfigError, SceneConfig, check_value, from_mapping, unknown_name_error

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
    if p.lo is not None and not p.or_auto:          # 'auto' or a number: its range is check_param's
        if isinstance(p.default, int) and not isinstance(p.default, bool):
            d.integer_range = [IntegerRange(from_value=int(p.lo), to_value=int(p.hi), step=0)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(p.lo), to_value=float(p.hi), step=0.0)]
    return d


def declare_checked(node: Node, table, check, unknown, once_running) -> dict[str, Any]:
    """Declare the parameters of ``table`` (config.Param) on ``node``, every value checked by ``check(name, value)``
    (which raises ConfigError naming the value and the way out): from a params file, -p or ``ros2 param set``.

    A params file's name that is not in the table is refused by ``unknown(name)``. What a file or -p gave as an
    integer for a float, as a boolean or in another case for a choice is stored as the value the node runs with,
    so that ``ros2 param get`` shows it. Once declared, a change passes ``once_running({name: value})`` too: it
    returns the reason to refuse it, or None to take it. Returns {name: value} as the node runs with it."""
    lists = {p.name for p in table if isinstance(p.default, list)}
    started = {"done": False}

    def value(name: str, v):
        """An empty list in a params YAML (``anchors.points: []``) reaches rclpy as a parameter without a value
        (None): for a list parameter that is the empty list it was written as."""
        return [] if v is None and name in lists else v

    def on_set(params) -> SetParametersResult:
        for prm in params:
            try:
                check(prm.name, value(prm.name, prm.value))
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        reason = once_running({prm.name: value(prm.name, prm.value) for prm in params}) if started["done"] else None
        return SetParametersResult(successful=reason is None, reason=reason or "")

    node.add_on_set_parameters_callback(on_set)     # first, so that values from a file are checked too
    names = {p.name for p in table}
    for name in getattr(node, "_parameter_overrides", {}):
        if name not in names and name not in ROS_NAMES and not name.startswith("qos_overrides."):
            raise unknown(name)
    node.declare_parameters("", [(p.name, p.default, descriptor(p)) for p in table])
    values = {p.name: value(p.name, node.get_parameter(p.name).value) for p in table}
    typed = {p.name: check(p.name, values[p.name]) for p in table}
    retyped = [Parameter(n, value=v) for n, v in typed.items()
               if n not in lists and (type(v) is not type(values[n]) or v != values[n])]
    if retyped:
        node.set_parameters(retyped)
    started["done"] = True
    return typed


def declare_scene_parameters(node: Node, on_live_change) -> SceneConfig:
    """The scene parameters declared on ``node`` (declare_checked); a running node takes the LIVE ones only,
    within LIVE_BOUNDS, and hands them to ``on_live_change({name: value})``."""
    def once_running(changes: dict) -> str | None:
        for name, v in changes.items():
            if name not in LIVE:
                return (f"{name} shapes the model and cannot change while running: restart the node with "
                        f"the new value (live parameters: {', '.join(sorted(LIVE))})")
            lo, hi = LIVE_BOUNDS.get(name, (None, None))
            if lo is not None and not lo <= v <= hi:
                return (f"{name} = {v!r}: a running node takes [{lo:g}, {hi:g}] only; start the node "
                        "with the value to go beyond")
        on_live_change(changes)
        return None

    return from_mapping(declare_checked(node, PARAMS, check_value, unknown_name_error, once_running))
