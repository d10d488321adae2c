"""Per-point stress fields <-> sensor_msgs/PointCloud2 (float32 fields, one row, dense).

Like sensor_msgs_py.point_cloud2 (`create_cloud`, `read_points`), without depending on it.
"""
from __future__ import annotations

from typing import Mapping, Optional

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from msg_adapters._cdr import CdrWriter
from msg_adapters.time import StampLike, as_ns, ns_to_stamp, split_ns

BASE_FIELDS: tuple[str, ...] = ("x", "y", "z", "von_mises")
_DTYPES: dict[int, str] = {PointField.INT8: "i1", PointField.UINT8: "u1", PointField.INT16: "i2",
                           PointField.UINT16: "u2", PointField.INT32: "i4", PointField.UINT32: "u4",
                           PointField.FLOAT32: "f4", PointField.FLOAT64: "f8"}


def _stress_columns(points: np.ndarray, von_mises: np.ndarray,
                    extra_fields: Optional[Mapping[str, np.ndarray]]) -> tuple[list[str], np.ndarray]:
    """Validated field names and the (n, k) float32 table whose rows are the points."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {p.shape}")
    columns = [p[:, 0], p[:, 1], p[:, 2]]
    names = list(BASE_FIELDS)
    for name, values in [("von_mises", von_mises), *(extra_fields or {}).items()]:
        if name in names[:len(columns)] or not name or not name.isidentifier():
            raise ValueError(f"field name {name!r} is empty, not an identifier or already used ({names[:len(columns)]})")
        if name != "von_mises":
            names.append(name)
        col = np.asarray(values, dtype=np.float64)
        if col.shape != (len(p),):
            raise ValueError(f"field {name!r} must have shape ({len(p)},) (one value per point), got {col.shape}")
        columns.append(col)
    table = np.column_stack(columns).astype(np.float32) if len(p) else np.zeros((0, len(names)), np.float32)
    bad = ~np.isfinite(table).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"point {i} has non-finite values {dict(zip(names, table[i].tolist()))} "
                         f"({int(bad.sum())} such points): refusing to publish NaN/inf")
    return names, table


def _fields(names: list[str]) -> list[PointField]:
    return [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate(names)]


def stress_cloud(points: np.ndarray, von_mises: np.ndarray, frame_id: str, stamp: StampLike,
                 extra_fields: Optional[Mapping[str, np.ndarray]] = None) -> PointCloud2:
    """PointCloud2 with float32 fields x, y, z, von_mises, then `extra_fields` in their order."""
    names, table = _stress_columns(points, von_mises, extra_fields)
    step = 4 * len(names)
    return PointCloud2(header=Header(stamp=ns_to_stamp(as_ns(stamp)), frame_id=frame_id),
                       height=1, width=len(table), fields=_fields(names), is_bigendian=False,
                       point_step=step, row_step=step * len(table), data=table.tobytes(), is_dense=True)


def stress_cloud_cdr(points: np.ndarray, von_mises: np.ndarray, frame_id: str, stamp: StampLike,
                     extra_fields: Optional[Mapping[str, np.ndarray]] = None) -> bytes:
    """CDR bytes of `stress_cloud(...)`, built from numpy."""
    names, table = _stress_columns(points, von_mises, extra_fields)
    step = 4 * len(names)
    w = CdrWriter()
    w.header(*split_ns(as_ns(stamp)), frame_id)
    w.packed("<2I", 4, 1, len(table))
    w.u32(len(names))
    for i, name in enumerate(names):
        w.string(name)
        w.u32(4 * i)
        w.u8(PointField.FLOAT32)
        w.u32(1)
    w.boolean(False)
    w.packed("<2I", 4, step, step * len(table))
    w.bytes_seq(table.tobytes())
    w.boolean(True)
    return w.getvalue()


def cloud_dtype(cloud: PointCloud2) -> np.dtype:
    """The structured numpy dtype of one point of `cloud` (offsets and point_step respected)."""
    endian = ">" if cloud.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in cloud.fields:
        if f.datatype not in _DTYPES:
            raise ValueError(f"field {f.name!r} has unknown PointField datatype {f.datatype}")
        names.append(f.name)
        formats.append((endian + _DTYPES[f.datatype], (f.count,)) if f.count != 1 else endian + _DTYPES[f.datatype])
        offsets.append(f.offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": cloud.point_step})


def read_points(cloud: PointCloud2) -> np.ndarray:
    """All points of `cloud` as a structured array of shape (height * width,) (a copy)."""
    dtype = cloud_dtype(cloud)
    n = cloud.width * cloud.height
    if cloud.row_step != cloud.point_step * cloud.width:
        raise ValueError(f"row_step {cloud.row_step} != point_step {cloud.point_step} * width "
                         f"{cloud.width}: padded rows are not supported")
    buf = memoryview(cloud.data).cast("B") if not isinstance(cloud.data, (bytes, bytearray)) else cloud.data
    if len(buf) < n * cloud.point_step:
        raise ValueError(f"cloud data holds {len(buf)} bytes, {n} points of {cloud.point_step} need {n * cloud.point_step}")
    return np.frombuffer(buf, dtype=dtype, count=n).copy()
