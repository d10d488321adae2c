"""A minimal little-endian CDR (XCDR1, as used by ROS 2 over Fast DDS) writer.

Alignment is counted from the start of the body (after the 4-byte encapsulation header), every
primitive is aligned to its own size, padding bytes are zero. An empty sequence is its count alone:
no padding follows it (this is what goes on the wire; see `joint_state.py` for rclpy's garbage tail).
"""
from __future__ import annotations

import struct

import numpy as np

ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"
_ZEROS = bytes(8)


class CdrWriter:
    """Append-only CDR writer; big arrays are appended as one `bytes` part and joined once."""

    __slots__ = ("_parts", "_pos")

    def __init__(self) -> None:
        self._parts: list[bytes] = [ENCAPSULATION_CDR_LE]
        self._pos = 0  # body offset, the origin of alignment

    def align(self, size: int) -> None:
        pad = -self._pos % size
        if pad:
            self._parts.append(_ZEROS[:pad])
            self._pos += pad

    def raw(self, data: bytes) -> None:
        self._parts.append(data)
        self._pos += len(data)

    def packed(self, fmt: str, align: int, *values: object) -> None:
        """Several primitives of one alignment at once, e.g. `packed('<3d', 8, x, y, z)`."""
        self.align(align)
        self.raw(struct.pack(fmt, *values))

    def u8(self, value: int) -> None:
        self.raw(struct.pack("<B", value))

    def boolean(self, value: bool) -> None:
        self.raw(b"\x01" if value else b"\x00")

    def u32(self, value: int) -> None:
        self.packed("<I", 4, value)

    def i32(self, value: int) -> None:
        self.packed("<i", 4, value)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\x00"
        self.u32(len(data))
        self.raw(data)

    def string_seq(self, texts: list[str]) -> None:
        self.u32(len(texts))
        for text in texts:
            self.string(text)

    def time(self, sec: int, nanosec: int) -> None:
        """builtin_interfaces/Time or Duration: int32 sec, uint32 nanosec."""
        self.packed("<iI", 4, sec, nanosec)

    def header(self, sec: int, nanosec: int, frame_id: str) -> None:
        self.time(sec, nanosec)
        self.string(frame_id)

    def array_seq(self, values: np.ndarray, dtype: str, align: int) -> None:
        """A sequence of `len(values)` elements (structs of one primitive type flattened in
        `values`' trailing axes): count, then alignment only if non-empty, then the raw data."""
        arr = np.ascontiguousarray(values, dtype=dtype)
        self.u32(arr.shape[0] if arr.ndim else 0)
        if arr.size:
            self.align(align)
            self.raw(arr.tobytes())

    def bytes_seq(self, data: bytes) -> None:
        self.u32(len(data))
        self.raw(data)

    def getvalue(self) -> bytes:
        return b"".join(self._parts)
