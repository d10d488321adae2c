"""Read what the clusterfem node recorded in a bag folder: its joint states, its surface Markers, and the name of
the scene parameter file it writes beside them. No ROS (rosbags decodes the CDR).

The replay that drives a Scene with these lives above the recording layer, in clusterfem_ros/replay.py.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import topics
from ..errors import ClusterFemError

PARAMS_FILE = "scene_parameters.yaml"


@dataclass
class JointSample:
    log_ns: int                 # receive time (the node's clock)
    stamp: float                # header stamp [s]
    names: list
    q: np.ndarray
    v: np.ndarray | None


class BagReadError(ClusterFemError, ValueError):
    """A bag record that cannot be read back; the message names the bag and the record."""


def topic_in(topics, name: str) -> str | None:
    """The bag's topic for ``name`` ('/joint_states'): the name itself, or the one topic that is the name under a
    namespace ('/body1/joint_states', as a node in a namespace records it); None when there is none. Two
    namespaced matches are ambiguous: ValueError names them."""
    topics = set(topics)
    if name in topics:
        return name
    found = sorted(t for t in topics if t.endswith("/" + name.lstrip("/")))
    if len(found) > 1:
        raise ValueError(f"the bag has {len(found)} topics named {name!r} under namespaces ({', '.join(found)}): "
                         "pass the one to read")
    return found[0] if found else None


def _reader(folder: Path):
    from rosbags.highlevel import AnyReader
    return AnyReader([Path(folder)])


def bag_topics(folder: str | Path) -> set[str]:
    """The topics recorded in the bag folder."""
    with _reader(Path(folder)) as r:
        return {c.topic for c in r.connections}


def read_joint_states(folder: str | Path, topic: str = topics.JOINT_STATES.recorded) -> list[JointSample]:
    """Every joint state in the bag, in recording order. BagReadError names the first record that does not
    decode (the node records only what it decoded, so such a record was written by something else)."""
    out = []
    with _reader(Path(folder)) as r:
        found = topic_in((c.topic for c in r.connections), topic)
        conns = [c for c in r.connections if c.topic == found]
        if not conns:
            raise ValueError(f"bag {str(folder)!r} has no {topic!r} topic (topics: "
                             f"{sorted({c.topic for c in r.connections})})")
        for k, (c, log_ns, raw) in enumerate(r.messages(connections=conns)):
            try:
                m = r.deserialize(raw, c.msgtype)
            except Exception as exc:
                raise BagReadError(f"bag {str(folder)!r}: {found} record {k} (log time {log_ns} ns, {len(raw)} bytes) "
                                   f"does not decode as {c.msgtype}: {exc}") from None
            stamp = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
            q = np.asarray(m.position, dtype=np.float64)
            v = np.asarray(m.velocity, dtype=np.float64) if len(m.velocity) else None
            out.append(JointSample(log_ns, stamp, list(m.name), q, v))
    return out


def read_surfaces(folder: str | Path, topic: str | None = None) -> list[tuple[int, np.ndarray]]:
    """(stamp in ns, triangle-list points (3t, 3)) of every recorded surface Marker (none without the topic);
    ``topic``: the output stream declared to render as the surface (topics.rendered) unless given."""
    topic = topic or topics.rendered("surface").topic.recorded
    out = []
    with _reader(Path(folder)) as r:
        found = topic_in((c.topic for c in r.connections), topic)
        conns = [c for c in r.connections if c.topic == found]
        if not conns:                          # rosbags reads every topic when given no connection
            return out
        for c, _, raw in r.messages(connections=conns):
            m = r.deserialize(raw, c.msgtype)
            pts = np.array([[p.x, p.y, p.z] for p in m.points], dtype=np.float64).reshape(-1, 3)
            out.append((m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, pts))
    return out
