"""A rosbag2-compatible (Jazzy) MCAP bag writer working on CDR bytes; no rclpy needed.

Layout written: `<folder>/<name>_0.mcap` + `<folder>/metadata.yaml`, as `ros2 bag record -s mcap`:
profile `ros2`, zstd-compressed chunks, schemas `pkg/msg/Type` in `ros2msg` encoding, channels
`cdr` with `offered_qos_profiles` and `topic_type_hash`, Statistics, a `rosbag2` metadata record.

Durability: the open chunk is closed, written, flushed and fsync'ed at least every
`flush_interval_s` (by a background thread, also when no message arrives) and whenever the MCAP
writer closes a chunk on size; metadata.yaml is rewritten then too. After SIGKILL the file holds
every chunk up to the last flush but no summary/footer: `recover_bag()` makes it whole.

Signals: `close()` may be called from a signal handler. The lock is re-entrant, so a handler that
interrupts `write()` on the same thread cannot deadlock; in that case the close is deferred and done
as soon as the interrupted call returns (or unwinds), and `close()` returns False. A lock held by the
flusher thread is released within one chunk write + fsync.
"""
from __future__ import annotations

import atexit
import os
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Optional, Union

from mcap.writer import CompressionType, IndexType, Writer

from clusterfem_ros.recording.bag_metadata import (METADATA_FILE, BagInfo, TopicInfo, bag_information,
                                                   dump_yaml, write_metadata_yaml)
from clusterfem_ros.recording.msgdef import message_definition, normalize_type, type_hash
from clusterfem_ros.recording.qos import qos_profile, qos_yaml

CHUNK_SIZE = 768 * 1024  # bytes of uncompressed records per chunk (rosbag2's mcap default)
FLUSH_INTERVAL_S = 0.5
_CDR_HEADERS = (b"\x00\x01", b"\x00\x00")  # CDR little endian / big endian


def default_bag_path(prefix: str, root: Path = Path("bags")) -> Path:
    """`<root>/<prefix>_<YYYYmmdd_HHMMSS>`, with `_1`, `_2`, ... appended if that exists."""
    if not prefix or "/" in prefix or os.sep in prefix:
        raise ValueError(f"bag prefix {prefix!r} must be a non-empty name without path separators")
    base = Path(root) / f"{prefix}_{datetime.now().strftime('%Y%m%d_%H%M%S')}"
    path, n = base, 0
    while path.exists():
        n += 1
        path = base.with_name(f"{base.name}_{n}")
    return path


class Rosbag2McapWriter:
    """Write CDR messages to a new rosbag2 MCAP bag folder. Use as a context manager."""

    def __init__(self, folder: Union[str, Path], storage_name: Optional[str] = None,
                 chunk_size: int = CHUNK_SIZE, flush_interval_s: float = FLUSH_INTERVAL_S,
                 compression: str = "zstd") -> None:
        self.folder = Path(folder)
        if self.folder.exists() and any(self.folder.iterdir()):
            raise FileExistsError(f"bag folder {self.folder} exists and is not empty: choose a new folder "
                                  f"(e.g. default_bag_path(prefix))")
        if flush_interval_s <= 0:
            raise ValueError(f"flush_interval_s {flush_interval_s} must be > 0")
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in kinds:
            raise ValueError(f"compression {compression!r}: choose one of {list(kinds)}")
        self.folder.mkdir(parents=True, exist_ok=True)
        name = storage_name or self.folder.name
        self.path = self.folder / f"{name}_0.mcap"
        self._info = BagInfo(storage_file=self.path.name)
        self._topics: dict[str, tuple[int, TopicInfo]] = {}
        self._schemas: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._lock = threading.RLock()
        self._depth = 0  # nesting of public calls on the thread holding the lock
        self._close_pending = False
        self._closing = False
        self._closed = False
        self._dirty = False  # messages since the last flush
        self._file = open(self.path, "xb")
        self._mcap = Writer(self._file, chunk_size=chunk_size, compression=kinds[compression],
                            index_types=IndexType.ALL, use_chunking=True, use_statistics=True,
                            use_summary_offsets=True, enable_crcs=True)
        self._mcap.start(profile="ros2", library="clusterfem_ros.recording")
        self._sync()
        write_metadata_yaml(self.folder, self._info)
        self._flushed_at = time.monotonic()
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, args=(flush_interval_s,),
                                         name=f"bag-flush:{self.folder.name}", daemon=True)
        self._flush_interval = flush_interval_s
        self._flusher.start()
        atexit.register(self.close)  # a forgotten close() still ends in a complete bag at normal exit

    # -- public API ---------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def add_topic(self, name: str, msg_type: str, qos: str = "reliable") -> int:
        """Register a topic (once; again with the same type returns the same channel id)."""
        full = normalize_type(msg_type)
        return self._add_channel(name, full, message_definition(full), [qos_profile(qos)], type_hash(full))

    def write(self, topic: str, log_time_ns: int, cdr_bytes: bytes, publish_time_ns: Optional[int] = None) -> None:
        """Append one CDR-serialized message (log time = receive time, ns since the epoch)."""
        with self._lock:
            self._depth += 1
            try:
                self._check_open()
                if topic not in self._topics:
                    raise ValueError(f"topic {topic!r} was not added: call add_topic({topic!r}, msg_type) first "
                                     f"(known: {sorted(self._topics)})")
                if not isinstance(cdr_bytes, (bytes, bytearray, memoryview)) or bytes(cdr_bytes[:2]) not in _CDR_HEADERS:
                    raise ValueError(f"message for {topic!r} is not CDR bytes (first bytes {bytes(cdr_bytes[:4])!r}, "
                                     "expected b'\\x00\\x01\\x00\\x00'): pass serialize_message(msg) or a *_cdr() result")
                log_time_ns = int(log_time_ns)
                if log_time_ns < 0:
                    raise ValueError(f"log time {log_time_ns} ns is negative")
                channel, info = self._topics[topic]
                seq = self._sequence[channel]
                self._sequence[channel] = seq + 1
                before = self._file.tell()
                self._mcap.add_message(channel_id=channel, log_time=log_time_ns, data=bytes(cdr_bytes),
                                       publish_time=log_time_ns if publish_time_ns is None else int(publish_time_ns),
                                       sequence=seq)
                info.count += 1
                i = self._info
                i.start_ns = log_time_ns if i.message_count == 1 else min(i.start_ns, log_time_ns)
                i.end_ns = max(i.end_ns, log_time_ns)
                self._dirty = True
                if self._file.tell() != before:  # the mcap writer closed a chunk on size
                    self._flush_locked(finalize=False)
            finally:
                self._exit()

    def flush(self) -> None:
        """Close the open chunk and make everything written so far durable (fsync)."""
        with self._lock:
            self._depth += 1
            try:
                self._check_open()
                self._flush_locked(finalize=True)
            finally:
                self._exit()

    def close(self) -> bool:
        """Finish the file (summary, footer) and write the final metadata.yaml. Idempotent.

        Returns True once the bag is closed; False if the close was deferred because the call
        interrupted a `write()` of this thread (signal handler): it completes when that call returns."""
        with self._lock:
            if self._closed or self._closing:
                return self._closed
            if self._depth > 0:
                self._close_pending = True
                return False
            self._close_locked()
        self._stop_flusher()
        return True

    def __enter__(self) -> "Rosbag2McapWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ----------------------------------------------------------------------------
    def _add_channel(self, name: str, msg_type: str, schema_text: str, qos_profiles: list[dict],
                     topic_hash: str) -> int:
        with self._lock:
            self._depth += 1
            try:
                self._check_open()
                if not name.startswith("/"):
                    raise ValueError(f"topic name {name!r} must be absolute (start with '/'), as rosbag2 records it")
                if name in self._topics:
                    channel, info = self._topics[name]
                    if info.msg_type != msg_type:
                        raise ValueError(f"topic {name!r} already added with type {info.msg_type}, not {msg_type}")
                    return channel
                if msg_type not in self._schemas:
                    self._schemas[msg_type] = self._mcap.register_schema(
                        name=msg_type, encoding="ros2msg", data=schema_text.encode("utf-8"))
                channel = self._mcap.register_channel(
                    topic=name, message_encoding="cdr", schema_id=self._schemas[msg_type],
                    metadata={"offered_qos_profiles": qos_yaml(qos_profiles), "topic_type_hash": topic_hash})
                info = TopicInfo(name, msg_type, qos_profiles, topic_hash)
                self._topics[name] = (channel, info)
                self._sequence[channel] = 0
                self._info.topics.append(info)
                write_metadata_yaml(self.folder, self._info)
                return channel
            finally:
                self._exit()

    def _exit(self) -> None:
        self._depth -= 1
        if self._depth == 0 and self._close_pending and not self._closed:
            self._close_pending = False
            self._close_locked()

    def _check_open(self) -> None:
        if self._closed or self._closing:
            raise RuntimeError(f"bag {self.folder} is closed (perhaps by a shutdown handler): stop writing to it")

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def _flush_locked(self, finalize: bool) -> None:
        if finalize and self._dirty:
            self._mcap.flush()  # closes the open chunk and writes it
        self._sync()
        self._dirty = False if finalize else self._dirty
        self._flushed_at = time.monotonic()
        write_metadata_yaml(self.folder, self._info)

    def _flush_loop(self, interval: float) -> None:
        while not self._stop.wait(interval / 2):
            with self._lock:
                if self._closed or self._closing:
                    return
                if self._dirty and time.monotonic() - self._flushed_at >= interval:
                    self._flush_locked(finalize=True)

    def _close_locked(self) -> None:
        self._closing = True
        try:
            self._mcap.flush()  # last chunk first, then the metadata record, then the summary
            self._mcap.add_metadata("rosbag2", {"serialized_metadata": dump_yaml(bag_information(self._info)).strip()})
            self._mcap.finish()
            self._sync()
            self._file.close()
            write_metadata_yaml(self.folder, self._info)
        finally:
            self._closed = True
            self._closing = False
            self._stop.set()

    def _stop_flusher(self) -> None:
        self._stop.set()
        atexit.unregister(self.close)
        if self._flusher is not threading.current_thread() and self._flusher.is_alive():
            self._flusher.join(timeout=5.0)
