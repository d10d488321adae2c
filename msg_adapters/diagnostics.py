"""A flat dict of named values <-> diagnostic_msgs/DiagnosticArray with one DiagnosticStatus."""
from __future__ import annotations

from typing import Mapping, Union

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from msg_adapters.time import StampLike, as_ns, ns_to_stamp

DiagValue = Union[float, int, str]
LEVELS: dict[str, int] = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}


def _level_byte(level: Union[int, str]) -> bytes:
    if isinstance(level, str):
        if level.upper() not in LEVELS:
            raise ValueError(f"diagnostic level {level!r} is not one of {list(LEVELS)}")
        level = LEVELS[level.upper()]
    if level not in LEVELS.values():
        raise ValueError(f"diagnostic level {level!r} is not one of {LEVELS}")
    return bytes([level])


def _format(value: DiagValue) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)  # shortest text that parses back to the same float
    if isinstance(value, (int, str)):
        return str(value)
    raise TypeError(f"diagnostic value {value!r} is a {type(value).__name__}: pass float, int, bool or str")


def diagnostic_array(stamp: StampLike, name: str, hardware_id: str, values: Mapping[str, DiagValue],
                     level: Union[int, str] = "OK", message: str = "") -> DiagnosticArray:
    """DiagnosticArray with a single status `name`; values become KeyValue strings, in order."""
    status = DiagnosticStatus(level=_level_byte(level), name=name, message=message, hardware_id=hardware_id,
                              values=[KeyValue(key=str(k), value=_format(v)) for k, v in values.items()])
    return DiagnosticArray(header=Header(stamp=ns_to_stamp(as_ns(stamp))), status=[status])


def _parse(text: str) -> DiagValue:
    if text in ("true", "false"):
        return text == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def diagnostic_values(msg: DiagnosticArray, name: str | None = None) -> dict[str, DiagValue]:
    """The inverse of `diagnostic_array`: values of the status `name` (or the only status) parsed
    back to int, float, bool or str."""
    statuses = [s for s in msg.status if name is None or s.name == name]
    if len(statuses) != 1:
        raise ValueError(f"expected one status named {name!r}, found {[s.name for s in msg.status]}")
    return {kv.key: _parse(kv.value) for kv in statuses[0].values}
