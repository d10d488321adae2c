"""A recorded bag's surfaces as numpy arrays, for drawing it without ROS: the surface Markers, the joint
states and the URDF that poses the skeleton, and every declared output stream with a decoder
(topics.OUTPUT_DECLARATIONS), decoded by it; the renderer draws the streams declared to render as 'surface' and
'stress'.

The surface Markers are decoded straight from their CDR bytes (the layout ``msg_adapters.marker`` writes:
TRIANGLE_LIST, one point and one RGBA per triangle corner) into arrays, because a message of ~9000 corners
deserialised into per-point objects costs more than drawing it. tests/test_render.py checks the decoder
against rosbags' own deserialiser.
"""
from __future__ import annotations

import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import topics
from .config import ConfigError, SceneConfig, load_scene_file
from .errors import ClusterFemError
from .registries import load_object
from .recording.bag_reader import PARAMS_FILE, JointSample, read_joint_states, topic_in

JOINT_TOPIC = topics.JOINT_STATES.recorded
URDF_TOPIC = topics.ROBOT_DESCRIPTION.recorded


class BagFramesError(ClusterFemError, ValueError):
    """A bag that cannot be drawn; the message names the folder or topic and what to do."""


@dataclass
class SurfaceFrame:
    stamp_ns: int               # header stamp: the simulated time of the state drawn
    corners: np.ndarray         # (3t, 3) float64: triangle corners, three per triangle
    rgba: np.ndarray            # (3t, 4) float32 in [0, 1]: the stress colour of each corner


@dataclass
class StressFrame:
    stamp_ns: int               # header stamp: the simulated time of the state
    points: np.ndarray          # (n, 3) float64: every vertex of the body
    von_mises: np.ndarray       # (n,) float64 [Pa]


@dataclass
class BagFrames:
    folder: Path
    surfaces: list[SurfaceFrame]
    joint_states: list[JointSample]
    urdf: str | None            # the skeleton's URDF, or None when neither the bag nor its scene gives one
    scene: SceneConfig          # scene_parameters.yaml, read as the node reads a scene file (defaults without one)
    stresses: list[StressFrame] = field(default_factory=list)   # the stress PointClouds, in recording order
    streams: dict = field(default_factory=dict)     # {topic name: its decoded frames} of every declared stream


class _Cdr:
    """Sequential little-endian CDR reads; alignment counts from the body (after the 4-byte header)."""

    def __init__(self, data: bytes):
        self.data, self.pos = data, 4

    def align(self, n: int) -> None:
        self.pos += -(self.pos - 4) % n

    def unpack(self, fmt: str, align: int) -> tuple:
        self.align(align)
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += struct.calcsize(fmt)
        return out

    def string(self) -> str:
        (n,) = self.unpack("<I", 4)
        text = self.data[self.pos:self.pos + n].rstrip(b"\x00").decode("utf-8")
        self.pos += n
        return text

    def array(self, dtype: str, width: int, align: int) -> np.ndarray:
        (n,) = self.unpack("<I", 4)
        if n == 0:
            return np.zeros((0, width), dtype=dtype)
        self.align(align)
        size = n * width * np.dtype(dtype).itemsize
        if self.pos + size > len(self.data):
            raise BagFramesError(f"a sequence of {n} elements runs past the end of a {len(self.data)}-byte message")
        out = np.frombuffer(self.data, dtype=dtype, count=n * width, offset=self.pos).reshape(n, width)
        self.pos += size
        return out


def decode_surface_marker(data: bytes) -> SurfaceFrame:
    """A TRIANGLE_LIST Marker's CDR bytes -> SurfaceFrame (stamp, corners, per-corner colours)."""
    r = _Cdr(data)
    sec, nanosec = r.unpack("<iI", 4)
    r.string()                                   # frame_id
    r.string()                                   # ns
    _, kind, _ = r.unpack("<3i", 4)              # id, type, action
    if kind != 11:
        raise BagFramesError(f"surface Marker of type {kind}: expected TRIANGLE_LIST (11)")
    r.unpack("<10d", 8)                          # pose, scale
    r.unpack("<4f", 4)                           # colour
    r.unpack("<iI", 4)                           # lifetime
    r.unpack("<?", 1)                            # frame_locked
    corners = r.array("<f8", 3, 8).astype(np.float64)
    rgba = r.array("<f4", 4, 4).astype(np.float32)
    if len(rgba) != len(corners) or len(corners) % 3:
        raise BagFramesError(f"surface Marker with {len(corners)} points and {len(rgba)} colours: expected one "
                             "colour per point and three points per triangle")
    return SurfaceFrame(sec * 1_000_000_000 + nanosec, corners, rgba)


def decode_stress_cloud(data: bytes) -> StressFrame:
    """A stress PointCloud2's CDR bytes (float32 fields x, y, z, von_mises, as ``msg_adapters.pointcloud``
    writes them) -> StressFrame."""
    r = _Cdr(data)
    sec, nanosec = r.unpack("<iI", 4)
    r.string()                                   # frame_id
    height, width = r.unpack("<II", 4)
    (n_fields,) = r.unpack("<I", 4)
    offsets = {}
    for _ in range(n_fields):
        name = r.string()
        (offset,) = r.unpack("<I", 4)
        (datatype,) = r.unpack("<B", 1)
        r.unpack("<I", 4)                        # count
        if datatype == 7:                        # FLOAT32
            offsets[name] = offset
    (big,) = r.unpack("<?", 1)
    step, _ = r.unpack("<II", 4)
    (size,) = r.unpack("<I", 4)
    missing = [f for f in ("x", "y", "z", "von_mises") if f not in offsets]
    n = height * width
    if missing or big or size < n * step or r.pos + size > len(data):
        raise BagFramesError(f"stress PointCloud2 without float32 little-endian fields {missing or ''} or with "
                             f"{size} data bytes for {n} points of {step} bytes: not a clusterfem stress cloud")
    raw = np.frombuffer(data, dtype=np.uint8, count=n * step, offset=r.pos).reshape(n, step)
    col = {f: raw[:, offsets[f]:offsets[f] + 4].copy().view("<f4")[:, 0].astype(np.float64) for f in offsets}
    return StressFrame(sec * 1_000_000_000 + nanosec, np.column_stack([col["x"], col["y"], col["z"]]),
                       col["von_mises"])


def scene_of(folder: Path) -> SceneConfig:
    """The bag folder's scene_parameters.yaml, read and checked as the node reads a scene file; the default scene
    when the folder has none, or when its file no longer loads (a bag of an older version: said in a warning)."""
    path = folder / PARAMS_FILE
    if not path.exists():
        return SceneConfig()
    try:
        return load_scene_file(path)
    except ConfigError as exc:
        warnings.warn(f"{exc}; the bag is drawn with the default scene's parameters", stacklevel=2)
        return SceneConfig()


def _mcap_file(folder: Path) -> Path:
    if folder.is_file() and folder.suffix == ".mcap":
        return folder
    files = sorted(folder.glob("*.mcap")) if folder.is_dir() else []
    if not files:
        raise BagFramesError(f"{str(folder)!r} is not a bag folder with an .mcap file: pass the folder scripts/run "
                             "printed after 'recording'")
    return files[0]


def _skeleton_urdf(scene: SceneConfig, bag_urdf: str | None, folder: Path) -> str | None:
    """The scene's skeleton.urdf_file when it names one that is found (the node ignores robot_description then,
    which a player may still have latched into the bag), else the bag's own robot_description, else the built-in
    humanoid for a builtin scene; mounted and with leaf tips as the node made its skeleton
    (skeleton.link_shapes.prepare_urdf), so the drawn bones match the body."""
    from .skeleton.urdf_check import CEILING, check_urdf, read_urdf_file
    source = scene.skeleton.source
    urdf, where = None, None
    if source == "urdf_file":
        from .body.fit import FitError, find_data_file
        name = scene.skeleton.urdf_file
        if name and (folder / name).is_file():
            where = folder / name
        elif name:
            try:
                where = find_data_file(name)
            except FitError:
                pass
        urdf = read_urdf_file(where, CEILING) if where is not None else None
    urdf = urdf or bag_urdf
    if not urdf and source == "builtin":
        from .skeleton.humanoid import humanoid_urdf
        urdf = humanoid_urdf()
    if not urdf:
        return None
    from .body_kinds import BODY_DECLARATIONS
    from .skeleton.link_shapes import prepare_urdf
    check_urdf(urdf, CEILING)               # a bag's description is the world's: a bounded tree first (urdf_check.py)
    return prepare_urdf(urdf, scene.skeleton.up_axis, scene.skeleton.root_joint,
                        leaf_shapes=BODY_DECLARATIONS[scene.body.kind].leaf_shapes, urdf_file=where).urdf


def read_bag_frames(folder: str | Path) -> BagFrames:
    """Every surface Marker and stress cloud (in recording order), the joint states and the skeleton's URDF of
    one bag."""
    from mcap.reader import make_reader

    folder = Path(folder)
    mcap_path = _mcap_file(folder)
    folder = mcap_path.parent
    decoded = {name: d for name, d in topics.OUTPUT_DECLARATIONS.items() if d.decoder}
    decoders = {name: load_object(d.decoder) for name, d in decoded.items()}
    streams: dict[str, list] = {name: [] for name in decoded}
    bag_urdf, recorded = None, set()
    with open(mcap_path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        if summary is not None:
            recorded = {c.topic for c in summary.channels.values()}
        # a node in a namespace records its topics under it ('/body1/clusterfem/surface')
        names = {topic_in(recorded, d.topic.recorded) or d.topic.recorded: name for name, d in decoded.items()}
        urdf_topic = topic_in(recorded, URDF_TOPIC) or URDF_TOPIC
        for _, channel, message in reader.iter_messages(topics=[*names, urdf_topic]):
            if channel.topic in names:
                name = names[channel.topic]
                streams[name].append(decoders[name](message.data))
            elif bag_urdf is None:
                bag_urdf = _Cdr(message.data).string()
    surface, stress = topics.rendered("surface"), topics.rendered("stress")
    surfaces = streams.get(surface.topic.name, []) if surface is not None else []
    stresses = streams.get(stress.topic.name, []) if stress is not None else []
    if not surfaces:
        shown = surface.topic.recorded if surface is not None else "surface"
        rate = f"{surface.rate_param} > 0" if surface is not None else "a stream declared to render as 'surface'"
        raise BagFramesError(f"bag {str(folder)!r} has no {shown} messages (topics: {sorted(recorded)}): "
                             f"record with {rate}")
    joints = read_joint_states(folder) if topic_in(recorded, JOINT_TOPIC) else []
    scene = scene_of(folder)
    return BagFrames(folder, surfaces, joints, _skeleton_urdf(scene, bag_urdf, folder), scene, stresses, streams)
