"""sensor_msgs/JointState <-> arrays, and exact CDR bytes for it.

Use `joint_state_cdr` for recording and pre-serialized publishing: rclpy's `serialize_message`
(Fast DDS) appends 4 uninitialised bytes per empty float64[] that is followed by nothing but other
empty sequences (e.g. 44 B instead of 36 B for an empty JointState; 60 B instead of 52 B with no
velocity or effort) and `rosbags` rejects such records ("CDR message size mismatch").
"""
from __future__ import annotations

import struct
from typing import Optional, Sequence

import numpy as np
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from msg_adapters._cdr import CdrWriter
from msg_adapters.time import StampLike, as_ns, ns_to_stamp, split_ns, stamp_to_seconds


def _check(names: Sequence[str], positions: np.ndarray, velocities: Optional[np.ndarray]
           ) -> tuple[list[str], np.ndarray, np.ndarray]:
    names = [str(n) for n in names]
    if len(set(names)) != len(names):
        raise ValueError(f"joint names must be unique, got {names}")
    q = np.asarray(positions, dtype=np.float64)
    if q.shape != (len(names),):
        raise ValueError(f"positions must have shape ({len(names)},) (one per joint name), got {q.shape}")
    v = np.zeros(0) if velocities is None else np.asarray(velocities, dtype=np.float64)
    if velocities is not None and v.shape != (len(names),):
        raise ValueError(f"velocities must be None or have shape ({len(names)},), got {v.shape}")
    if not (np.isfinite(q).all() and np.isfinite(v).all()):
        raise ValueError(f"joint positions/velocities must be finite, got {q.tolist()} / {v.tolist()}")
    return names, q, v


def arrays_to_joint_state(names: Sequence[str], positions: np.ndarray,
                          velocities: Optional[np.ndarray] = None, stamp: StampLike = 0,
                          frame_id: str = "") -> JointState:
    """JointState with name/position (and velocity if given); effort left empty."""
    names, q, v = _check(names, positions, velocities)
    return JointState(header=Header(stamp=ns_to_stamp(as_ns(stamp)), frame_id=frame_id),
                      name=names, position=q.tolist(), velocity=v.tolist(), effort=[])


def joint_state_fields(msg: JointState) -> tuple[float, list[str], np.ndarray, Optional[np.ndarray]]:
    """(stamp [s], names, positions, velocities or None) as sent, lengths unchecked: for a consumer that
    classifies bad messages itself (the skeleton's JointMap counts length mismatches)."""
    v = np.asarray(msg.velocity, dtype=np.float64)
    return (stamp_to_seconds(msg.header.stamp), list(msg.name), np.asarray(msg.position, dtype=np.float64),
            (v if len(v) else None))


def joint_state_to_arrays(msg: JointState) -> tuple[float, list[str], np.ndarray, Optional[np.ndarray]]:
    """(stamp in seconds, names, positions (n,), velocities (n,) or None if the message has none)."""
    stamp, names, q, v = joint_state_fields(msg)
    n = len(names)
    if q.shape != (n,):
        raise ValueError(f"JointState has {n} names but {len(q)} positions")
    if v is not None and len(v) != n:
        raise ValueError(f"JointState has {n} names but {len(v)} velocities (expected 0 or {n})")
    return stamp, names, q, v


def joint_state_cdr(names: Sequence[str], positions: np.ndarray, velocities: Optional[np.ndarray] = None,
                    stamp: StampLike = 0, frame_id: str = "") -> bytes:
    """Exact CDR bytes of `arrays_to_joint_state(...)` (what goes on the wire, no garbage tail)."""
    names, q, v = _check(names, positions, velocities)
    w = CdrWriter()
    w.header(*split_ns(as_ns(stamp)), frame_id)
    w.string_seq(names)
    w.array_seq(q, "<f8", 8)
    w.array_seq(v, "<f8", 8)
    w.u32(0)  # effort
    return w.getvalue()


def _cdr_order(data: bytes) -> str:
    if len(data) < 20 or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError(f"not CDR bytes (first bytes {bytes(data[:4])!r}, length {len(data)})")
    return "<" if data[1] == 1 else ">"


def _string_end(data: bytes, at: int, order: str, what: str) -> int:
    """Offset after the CDR string at body-aligned offset ``at``."""
    at += -(at - 4) % 4
    if at + 4 > len(data):
        raise ValueError(f"{what} runs past the end of a {len(data)}-byte message")
    return at + 4 + struct.unpack_from(order + "I", data, at)[0]


def joint_state_name_count(data: bytes) -> int:
    """The number of names a serialized JointState declares, read from its first bytes without decoding
    it, so a receiver can refuse an oversized message before any per-name work. ValueError if the bytes
    are not a CDR JointState prefix."""
    return struct.unpack_from(_cdr_order(data) + "I", data, _name_count_at(data))[0]


def _name_count_at(data: bytes) -> int:
    at = _string_end(data, 12, _cdr_order(data), "header.frame_id")
    at += -(at - 4) % 4
    if at + 4 > len(data):
        raise ValueError(f"the name count runs past the end of a {len(data)}-byte message")
    return at


def joint_state_cdr_extent(data: bytes) -> int:
    """The length of the JointState that ``data`` serializes, without what a sender appended after it
    (strict readers such as rosbags refuse such a tail). ``data[:extent]`` is what to record."""
    order = _cdr_order(data)
    at = _name_count_at(data)
    (n,) = struct.unpack_from(order + "I", data, at)
    at += 4
    for k in range(n):
        at = _string_end(data, at, order, f"name {k}")
    for field in ("position", "velocity", "effort"):
        at += -(at - 4) % 4
        if at + 4 > len(data):
            raise ValueError(f"{field} runs past the end of a {len(data)}-byte message")
        (count,) = struct.unpack_from(order + "I", data, at)
        at += 4
        if count:
            at += -(at - 4) % 8 + 8 * count
    if at > len(data):
        raise ValueError(f"the effort sequence runs past the end of a {len(data)}-byte message")
    return at
