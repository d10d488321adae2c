"""The frames of a capture file as recorded, by the file's kind: what a bind pose in a capture's frame 0 reads
(skeleton.bind_pose 'first_frame' with skeleton.bind_bvh, body/fit.py).

``FRAME_READERS`` maps a file suffix ('.bvh') to a reader ``(path, unit, up) -> JointTrajectory`` whose frame 0
is the file's first frame (no T-pose skipped, nothing despiked). A motion source that plays a file kind gives
its reader with its registration (motion.MotionSource.bind_frames), so a new capture format binds as it plays;
``read_frames`` picks the reader by the file's name.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from ..registries import Registry
from .trajectory import JointTrajectory

FRAME_READERS = Registry("capture file kind")


def register_frames(suffix: str, reader: Callable[..., JointTrajectory]) -> Callable[..., JointTrajectory]:
    """Make ``reader`` read files whose name ends with ``suffix`` (a suffix already taken is refused)."""
    return FRAME_READERS.register(suffix.lower(), reader)


def read_frames(path: str | Path, unit="auto", up: str = "auto") -> JointTrajectory:
    """The file's frames as recorded, read by the reader registered for its suffix; ValueError naming the kinds
    that have one otherwise."""
    name = Path(path).name.lower()
    for suffix, reader in FRAME_READERS.items():
        if name.endswith(suffix):
            return reader(Path(path), unit=unit, up=up)
    raise ValueError(f"{str(path)!r} is no capture file a bind pose can read: its frame 0 is read from "
                     f"{', '.join(FRAME_READERS) or 'no'} files (a motion source registers its kind)")


def bvh_frames(path: Path, unit="auto", up: str = "auto") -> JointTrajectory:
    """A BVH file's frames on its own skeleton, frame 0 first (the CMU files' T-pose kept)."""
    from .bvh import load_bvh
    from .bvh_to_urdf import bvh_trajectory
    return bvh_trajectory(load_bvh(path, unit, up), skip_tpose=False, despike=False)


register_frames(".bvh", bvh_frames)
FRAME_READERS.seal()
