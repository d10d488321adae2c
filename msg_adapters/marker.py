"""Triangle meshes -> visualization_msgs/Marker TRIANGLE_LIST (naive message and direct CDR).

Both paths give the same message: per-vertex colours expanded per triangle corner, pose identity,
scale 1, colour white with alpha 1 (RViz uses the per-corner colours), lifetime 0, action ADD.
`surface_marker_cdr` writes the CDR bytes straight from numpy; it is byte-identical to
`rclpy.serialization.serialize_message(surface_marker(...))` except in padding bytes, which
rclpy (Fast DDS) leaves uninitialised and we set to zero (tests/test_msg_adapters_cdr.py).
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

from msg_adapters._cdr import CdrWriter
from msg_adapters.time import StampLike, as_ns, ns_to_stamp, split_ns


def check_surface(vertices: np.ndarray, triangles: np.ndarray, vertex_rgba: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate and convert: vertices (n,3) finite float64, triangles (t,3) int in [0,n),
    vertex_rgba (n,4) finite in [0,1]. Raises ValueError naming the bad entry."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (n, 3), got {v.shape}")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"vertex {i} is {v[i].tolist()} ({int(bad.sum())} non-finite vertices): "
                         "refusing to publish NaN/inf; the simulation state is invalid")
    tri = np.asarray(triangles)
    if tri.ndim != 2 or tri.shape[1] != 3 or not np.issubdtype(tri.dtype, np.integer):
        raise ValueError(f"triangles must be an integer array of shape (t, 3), got {tri.dtype} {tri.shape}")
    if tri.size and (tri.min() < 0 or tri.max() >= len(v)):
        raise ValueError(f"triangle indices span [{tri.min()}, {tri.max()}] but there are {len(v)} vertices")
    c = np.asarray(vertex_rgba, dtype=np.float32)
    if c.shape != (len(v), 4):
        raise ValueError(f"vertex_rgba must have shape ({len(v)}, 4) (one RGBA per vertex), got {c.shape}")
    if not np.isfinite(c).all() or c.min(initial=0.0) < 0.0 or c.max(initial=0.0) > 1.0:
        raise ValueError("vertex_rgba must be finite and in [0, 1]: map scalars with msg_adapters.colormap.map_scalars")
    return v, tri, c


def surface_marker(vertices: np.ndarray, triangles: np.ndarray, vertex_rgba: np.ndarray,
                   frame_id: str, stamp: StampLike, ns: str = "surface", id: int = 0) -> Marker:
    """The Marker built field by field (the reference for `surface_marker_cdr`)."""
    v, tri, c = check_surface(vertices, triangles, vertex_rgba)
    corners = tri.reshape(-1)
    msg = Marker(header=Header(stamp=ns_to_stamp(as_ns(stamp)), frame_id=frame_id), ns=ns, id=id,
                 type=Marker.TRIANGLE_LIST, action=Marker.ADD)
    msg.pose.orientation.w = 1.0
    msg.scale.x = msg.scale.y = msg.scale.z = 1.0
    msg.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
    msg.points = [Point(x=x, y=y, z=z) for x, y, z in v[corners].tolist()]
    msg.colors = [ColorRGBA(r=r, g=g, b=b, a=a) for r, g, b, a in c[corners].tolist()]
    return msg


def surface_marker_cdr(vertices: np.ndarray, triangles: np.ndarray, vertex_rgba: np.ndarray,
                       frame_id: str, stamp: StampLike, ns: str = "surface", id: int = 0) -> bytes:
    """CDR bytes of `surface_marker(...)`, built from numpy (publish with `publisher.publish(b)`)."""
    v, tri, c = check_surface(vertices, triangles, vertex_rgba)
    corners = tri.reshape(-1)
    w = CdrWriter()
    w.header(*split_ns(as_ns(stamp)), frame_id)
    w.string(ns)
    w.packed("<3i", 4, id, Marker.TRIANGLE_LIST, Marker.ADD)
    w.packed("<10d", 8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0)  # pose (p, q), scale
    w.packed("<4f", 4, 1.0, 1.0, 1.0, 1.0)  # color
    w.time(0, 0)  # lifetime
    w.boolean(False)  # frame_locked
    w.array_seq(v[corners], "<f8", 8)  # points
    w.array_seq(c[corners], "<f4", 4)  # colors
    w.string("")  # texture_resource
    w.header(0, 0, "")  # texture.header
    w.string("")  # texture.format
    w.bytes_seq(b"")  # texture.data
    w.u32(0)  # uv_coordinates
    w.string("")  # text
    w.string("")  # mesh_resource
    w.string("")  # mesh_file.filename
    w.bytes_seq(b"")  # mesh_file.data
    w.boolean(False)  # mesh_use_embedded_materials
    return w.getvalue()
