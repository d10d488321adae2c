"""Stamps: builtin_interfaces/Time <-> int nanoseconds <-> float seconds.

Adapters take a `StampLike`: a builtin_interfaces/Time, an `rclpy.time.Time` (anything with an
int `nanoseconds`), or an int of nanoseconds since the epoch. Floats are refused on purpose
(is 5 seconds or nanoseconds?): convert with `seconds_to_ns` first.
"""
from __future__ import annotations

from typing import Protocol, Union

from builtin_interfaces.msg import Time

NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


class _HasNanoseconds(Protocol):
    nanoseconds: int


StampLike = Union[Time, _HasNanoseconds, int]


def split_ns(ns: int) -> tuple[int, int]:
    """int nanoseconds -> (sec int32, nanosec in [0, 1e9)), as in builtin_interfaces/Time."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise ValueError(f"stamp {ns} ns is {sec} s, outside builtin_interfaces/Time's int32 seconds")
    return sec, nanosec


def as_ns(stamp: StampLike) -> int:
    """Any `StampLike` -> int nanoseconds since the epoch."""
    if isinstance(stamp, Time):
        return stamp.sec * NS_PER_S + stamp.nanosec
    if isinstance(stamp, bool) or isinstance(stamp, float):
        raise TypeError(
            f"stamp {stamp!r} is a {type(stamp).__name__}: pass int nanoseconds "
            f"(msg_adapters.time.seconds_to_ns({stamp!r})), a builtin_interfaces/Time or an rclpy Time")
    if isinstance(stamp, int) or hasattr(stamp, "__index__"):
        return int(stamp)
    nanoseconds = getattr(stamp, "nanoseconds", None)
    if isinstance(nanoseconds, int):
        return nanoseconds
    raise TypeError(f"stamp {stamp!r} is not a builtin_interfaces/Time, rclpy Time or int nanoseconds")


def ns_to_stamp(ns: int) -> Time:
    sec, nanosec = split_ns(ns)
    return Time(sec=sec, nanosec=nanosec)


def stamp_to_ns(stamp: Time) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def seconds_to_ns(seconds: float) -> int:
    """Float seconds -> int nanoseconds, rounded to the nearest nanosecond."""
    if seconds != seconds or seconds in (float("inf"), float("-inf")):
        raise ValueError(f"time {seconds!r} s is not finite")
    return round(seconds * NS_PER_S)


def seconds_to_stamp(seconds: float) -> Time:
    return ns_to_stamp(seconds_to_ns(seconds))


def stamp_to_seconds(stamp: Time) -> float:
    return stamp.sec + stamp.nanosec * 1e-9
