"""rosbag2 `metadata.yaml` (version 9, as Jazzy writes it) and its atomic rewrite."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import yaml

METADATA_FILE = "metadata.yaml"
METADATA_VERSION = 9
ROS_DISTRO = "jazzy"


@dataclass
class TopicInfo:
    """One topic as rosbag2 lists it; `count` is the number of messages written so far."""

    name: str
    msg_type: str  # 'pkg/msg/Type'
    qos_profiles: list[dict]
    type_hash: str
    count: int = 0


@dataclass
class BagInfo:
    """What metadata.yaml says about a bag of one MCAP file."""

    storage_file: str  # relative file name, e.g. 'run_0.mcap'
    topics: list[TopicInfo] = field(default_factory=list)
    start_ns: int = 0  # smallest log time (0 while empty)
    end_ns: int = 0  # largest log time

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns) if self.message_count else 0


def bag_information(info: BagInfo) -> dict:
    """The mapping under `rosbag2_bagfile_information` (also the MCAP `serialized_metadata`)."""
    start = {"nanoseconds_since_epoch": info.start_ns}
    duration = {"nanoseconds": info.duration_ns}
    return {
        "version": METADATA_VERSION,
        "storage_identifier": "mcap",
        "duration": duration,
        "starting_time": start,
        "message_count": info.message_count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.msg_type, "serialization_format": "cdr",
                                "offered_qos_profiles": t.qos_profiles, "type_description_hash": t.type_hash},
             "message_count": t.count}
            for t in info.topics],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [info.storage_file],
        "files": [{"path": info.storage_file, "starting_time": dict(start), "duration": dict(duration),
                   "message_count": info.message_count}],
        "custom_data": None,
        "ros_distro": ROS_DISTRO,
    }


def dump_yaml(data: dict) -> str:
    return yaml.safe_dump(data, default_flow_style=False, sort_keys=False)


def write_metadata_yaml(folder: Path, info: BagInfo) -> None:
    """Replace `<folder>/metadata.yaml` atomically (temporary file, fsync, rename)."""
    path = Path(folder) / METADATA_FILE
    tmp = path.with_name(METADATA_FILE + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(dump_yaml({"rosbag2_bagfile_information": bag_information(info)}))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
