"""Make a killed recording (no summary, no footer) whole again.

A SIGKILLed `Rosbag2McapWriter` leaves complete chunks on disk (fsync'ed at each flush) and maybe a
torn chunk at the end. `recover_bag` reads the readable prefix record by record (CRC-checked), and
rewrites the bag folder with a fresh writer: same topics, QoS, hashes, schemas, log/publish times.
The file is rewritten rather than patched in place: simpler and safe (the old file is replaced
only once the new one is complete), at the cost of one copy of the bag.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Union

import yaml
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from clusterfem_ros.recording.rosbag2_mcap import Rosbag2McapWriter

_MAGIC = b"\x89MCAP0\r\n"


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


def recover_bag(folder: Union[str, Path]) -> RecoveryReport:
    """Rewrite summary, footer and metadata.yaml of a killed recording in `folder`, keeping every
    message of every complete chunk. A bag that is already complete is left untouched."""
    folder = Path(folder)
    path = _mcap_file(folder)
    if is_complete(path):
        return RecoveryReport(path, -1, {}, True, None)
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
    tmp = folder.with_name(folder.name + ".recovering")
    if tmp.exists():
        shutil.rmtree(tmp)
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
    os.replace(writer.path, path)
    os.replace(tmp / "metadata.yaml", folder / "metadata.yaml")
    shutil.rmtree(tmp)
    return RecoveryReport(path, len(messages), counts, False, stopped_by)
