"""Make a killed recording (no summary, no footer) whole again.

A SIGKILLed `Rosbag2McapWriter` leaves complete chunks on disk (fsync'ed at each flush) and maybe a
torn chunk at the end. `recover_bag` reads the readable prefix record by record (CRC-checked), and
rewrites the bag folder with a fresh writer: same topics, QoS, hashes, schemas, log/publish times.
The file is rewritten rather than patched in place: simpler and safe (the old file is replaced
only once the new one is complete), at the cost of one copy of the bag.

On a full disk that copy does not fit: the free space is checked first, and the error names the
folder and the space needed; ``work_dir`` (``--work-dir``) writes the copy on another disk, then the
original is replaced by it, if the copy fits in its place: the summary the copy adds can make it larger
than a bag that filled its disk, and then the original stays as it was and the complete copy stays in
``work_dir`` (as it does if that last copy fails). A recovery that fails before the copy is complete
leaves no ``*.recovering`` folder behind.

    python -m clusterfem_ros.recording.recover bags/clusterfem_20261122_120000 [--work-dir /tmp]
"""
from __future__ import annotations

import argparse
import errno
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Union

import yaml
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from ..errors import ClusterFemError
from .rosbag2_mcap import Rosbag2McapWriter

_MAGIC = b"\x89MCAP0\r\n"
_SPARE_BYTES = 1 << 20          # summary, footer, metadata.yaml and file-system slack on top of the copy
_COPY_SLACK_BYTES = 64 << 10    # file-system blocks and metadata.yaml when the copy goes back onto a full disk


class RecoveryError(ClusterFemError, RuntimeError):
    """recover_bag cannot finish; the message says where it needs space or what to do. The bag is unchanged."""


@dataclass
class RecoveryReport:
    """What `recover_bag` found: messages kept, whether the file was already complete, and why
    reading stopped (None if it reached the end cleanly)."""

    mcap_path: Path
    messages: int
    topics: dict[str, int]
    was_complete: bool
    stopped_by: str | None


def is_complete(mcap_path: Path) -> bool:
    """True if the file ends with an MCAP footer + magic (i.e. it was closed)."""
    size = mcap_path.stat().st_size
    if size < 8 + 37:
        return False
    with open(mcap_path, "rb") as f:
        f.seek(-8, os.SEEK_END)
        return f.read(8) == _MAGIC


def _mcap_file(folder: Path) -> Path:
    files = sorted(folder.glob("*.mcap"))
    if len(files) != 1:
        raise FileNotFoundError(f"expected exactly one .mcap file in {folder}, found {[f.name for f in files]}")
    return files[0]


def recover_bag(folder: Union[str, Path], work_dir: Union[str, Path, None] = None) -> RecoveryReport:
    """Rewrite summary, footer and metadata.yaml of a killed recording in `folder`, keeping every
    message of every complete chunk. A bag that is already complete is left untouched. The new file is
    written next to the bag, or in ``work_dir`` (another disk, when the bag's disk is full)."""
    folder = Path(folder)
    path = _mcap_file(folder)
    if is_complete(path):
        return RecoveryReport(path, -1, {}, True, None)
    where = Path(work_dir) if work_dir is not None else folder.parent
    need, free = path.stat().st_size + _SPARE_BYTES, shutil.disk_usage(where).free
    if free < need:
        raise RecoveryError(f"recovering {path} needs about {need / 1e6:.1f} MB free in {where} (it has "
                            f"{free / 1e6:.1f} MB): free space there, or pass work_dir (--work-dir) on another disk")
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    stopped_by = None
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False, validate_crcs=True).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    messages.append(record)
        except Exception as exc:  # torn last record: everything before it is kept
            stopped_by = f"{type(exc).__name__}: {exc}"
    tmp = where / (folder.name + ".recovering")
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        counts, new_path = _rewrite(tmp, path, schemas, channels, messages)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        cause = exc.__cause__ if exc.__cause__ is not None else exc     # the writer wraps its I/O error
        if isinstance(cause, OSError) and cause.errno == errno.ENOSPC:
            raise RecoveryError(f"recovering {path}: {where} ran out of space while writing the copy (needs about "
                                f"{need / 1e6:.1f} MB): free space there, or pass work_dir (--work-dir) on another "
                                "disk; the bag is unchanged") from exc
        raise
    try:
        os.replace(new_path, path)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
        # another disk: the copy replaces the original only if it fits in the original's place (the summary it
        # adds can make it larger than a bag that filled its disk); else both stay as they are
        size, room = new_path.stat().st_size, path.stat().st_size + shutil.disk_usage(path.parent).free
        if size + _COPY_SLACK_BYTES > room:
            raise RecoveryError(f"the recovered bag {new_path} ({size / 1e6:.2f} MB) does not fit in place of {path} "
                                f"(room for {room / 1e6:.2f} MB with it removed): free "
                                f"{(size + _COPY_SLACK_BYTES - room) / 1e6:.2f} MB on that disk and copy it over {path} "
                                f"with {tmp / 'metadata.yaml'}, or use the complete bag folder {tmp} as it is; the bag "
                                "is unchanged")
        path.unlink()                     # make room, then copy (the copy in tmp stays until done)
        try:
            shutil.copyfile(new_path, path)
        except OSError as copy_exc:
            raise RecoveryError(f"recovered bag written to {new_path} but copying it over {path} failed "
                                f"({copy_exc}): copy it there yourself, with {tmp / 'metadata.yaml'}") from copy_exc
    try:
        os.replace(tmp / "metadata.yaml", folder / "metadata.yaml")
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
        shutil.copyfile(tmp / "metadata.yaml", folder / "metadata.yaml")   # in place: no second file on a full disk
    shutil.rmtree(tmp)
    return RecoveryReport(path, len(messages), counts, False, stopped_by)


def _rewrite(tmp: Path, path: Path, schemas: dict, channels: dict, messages: list) -> tuple[dict[str, int], Path]:
    """The messages in a fresh, complete bag folder ``tmp``; returns the count per topic and the new file."""
    counts: dict[str, int] = {}
    writer = Rosbag2McapWriter(tmp, storage_name=path.name.removesuffix("_0.mcap").removesuffix(".mcap"))
    try:
        ids: dict[int, str] = {}
        for cid, ch in channels.items():
            schema = schemas[ch.schema_id]
            qos = yaml.safe_load(ch.metadata.get("offered_qos_profiles", "")) or []
            writer._add_channel(ch.topic, schema.name, schema.data.decode("utf-8"), qos,
                                ch.metadata.get("topic_type_hash", ""))
            ids[cid] = ch.topic
        for m in messages:
            writer.write(ids[m.channel_id], m.log_time, m.data, m.publish_time)
            counts[ids[m.channel_id]] = counts.get(ids[m.channel_id], 0) + 1
    finally:
        writer.close()
    return counts, writer.path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Complete a bag whose recording was killed or hit a full disk.")
    ap.add_argument("bag", help="bag folder (holding one .mcap file)")
    ap.add_argument("--work-dir", help="write the recovered copy here first (a folder on a disk with free space)")
    args = ap.parse_args(argv)
    try:
        r = recover_bag(args.bag, args.work_dir)
    except (RecoveryError, FileNotFoundError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{r.mcap_path}: " + ("already complete" if r.was_complete else
                               f"{r.messages} messages kept ({r.stopped_by or 'clean end'})"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
