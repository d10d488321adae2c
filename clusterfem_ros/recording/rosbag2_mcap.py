"""A rosbag2-compatible (Jazzy) MCAP bag writer working on CDR bytes; no rclpy needed.

Layout written: `<folder>/<name>_0.mcap` + `<folder>/metadata.yaml`, as `ros2 bag record -s mcap`:
profile `ros2`, zstd-compressed chunks, schemas `pkg/msg/Type` in `ros2msg` encoding, channels
`cdr` with `offered_qos_profiles` and `topic_type_hash`, Statistics, a `rosbag2` metadata record.

Threads: `write()` validates and appends to a lock-free deque; one I/O thread owns the MCAP writer
and the file (compression, writes and fsync never run on the caller's thread). Python runs signal
handlers only on the main thread, so a handler that raises (SystemExit, KeyboardInterrupt) can
interrupt `write()` but never the MCAP internals: the bag stays consistent.

Durability: the I/O thread closes the open chunk, writes, flushes and fsyncs it at least every
`flush_interval_s` (and whenever a chunk fills up), then rewrites metadata.yaml. After SIGKILL the
file holds every chunk up to the last flush, without summary/footer: `recover_bag()` completes it.

Memory: with `max_queue_bytes` set, the queue waiting for the I/O thread holds at most that many bytes
of messages: `write()` drops (and counts in `dropped`, `dropped_bytes`) what does not fit instead of
waiting, so a flood or a slow disk never blocks the caller and never grows memory. Without it, `write()`
waits while more than MAX_PENDING messages are queued (what an offline copy such as recovery wants).

Failures: an I/O error (disk full, folder removed or read-only) ends the I/O thread; `error` holds it at
once (for the caller to log and stop recording), `write()` then raises RuntimeError and `close()` raises
it once. The file keeps every chunk flushed before the error, for `recover_bag()`.

Signals: `close()` takes no lock the caller could already hold; it asks the I/O thread to finish
(summary, footer, metadata.yaml) and joins it, so it is safe in a SIGTERM/SIGINT handler (also
when the handler interrupted `write()` or another `close()`).
"""
from __future__ import annotations

import atexit
import collections
import os
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Optional, Union

from mcap.writer import CompressionType, IndexType, Writer

from clusterfem_ros.recording.bag_metadata import BagInfo, TopicInfo, bag_information, dump_yaml, write_metadata_yaml
from clusterfem_ros.recording.msgdef import message_definition, normalize_type, type_hash
from clusterfem_ros.recording.qos import qos_profile, qos_yaml

CHUNK_SIZE = 768 * 1024  # bytes of uncompressed records per chunk (rosbag2's mcap default)
FLUSH_INTERVAL_S = 0.5
MAX_PENDING = 10_000  # queued messages before write() waits for the I/O thread
# The I/O thread drains the queue this often, and at once on a flush, a new topic, close, back-pressure or half
# the byte budget queued. Polling every 2 ms would take the GIL from the physics thread 500 times a second,
# nearly always to find nothing to do.
DRAIN_INTERVAL_S = 0.05
_BACK_PRESSURE_SLEEP_S = 0.002     # write() waits this long at a time while MAX_PENDING messages are queued
_CDR_HEADERS = (b"\x00\x01", b"\x00\x00")  # CDR little endian / big endian
_COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


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
                 compression: str = "zstd", max_queue_bytes: Optional[int] = None) -> None:
        self.folder = Path(folder)
        if self.folder.exists() and any(self.folder.iterdir()):
            raise FileExistsError(f"bag folder {self.folder} exists and is not empty: choose a new folder "
                                  f"(e.g. default_bag_path(prefix))")
        if flush_interval_s <= 0:
            raise ValueError(f"flush_interval_s {flush_interval_s} must be > 0")
        if compression not in _COMPRESSIONS:
            raise ValueError(f"compression {compression!r}: choose one of {list(_COMPRESSIONS)}")
        if max_queue_bytes is not None and max_queue_bytes < 1:
            raise ValueError(f"max_queue_bytes {max_queue_bytes} must be >= 1 (None: no byte budget)")
        self.folder.mkdir(parents=True, exist_ok=True)
        self.path = self.folder / f"{storage_name or self.folder.name}_0.mcap"
        self._flush_interval = flush_interval_s
        # caller side (any thread): topic table, the queue, flags
        self._topics: dict[str, tuple[int, str]] = {}  # name -> (channel id, msg type)
        self._schemas: dict[str, int] = {}
        self._ops: collections.deque[tuple] = collections.deque()
        self._topic_lock = threading.Lock()  # add_topic only; never taken by write()/close()
        self._close_requested = False
        self._wake = threading.Event()          # set for what must not wait for the next drain
        self._error: Optional[BaseException] = None
        self._max_queue_bytes = max_queue_bytes
        self._bytes_in = 0    # queued by callers; bytes_out by the I/O thread: each counter has one writer
        self._bytes_out = 0
        self.dropped = 0      # messages refused by the byte budget, and their bytes
        self.dropped_bytes = 0
        # I/O thread side
        self._info = BagInfo(storage_file=self.path.name)
        self._file = open(self.path, "xb")
        self._mcap = Writer(self._file, chunk_size=chunk_size, compression=_COMPRESSIONS[compression],
                            index_types=IndexType.ALL, use_chunking=True, use_statistics=True,
                            use_summary_offsets=True, enable_crcs=True)
        self._mcap.start(profile="ros2", library="clusterfem_ros.recording")
        self._sync()
        write_metadata_yaml(self.folder, self._info)
        self._thread = threading.Thread(target=self._run, name=f"bag-io:{self.folder.name}", daemon=True)
        self._thread.start()
        atexit.register(self.close)  # a forgotten close() still ends in a complete bag at normal exit

    # -- public API (caller threads) ----------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._close_requested and not self._thread.is_alive()

    @property
    def error(self) -> Optional[BaseException]:
        """The I/O thread's failure (None while it works): recording has stopped, the file waits for recover_bag."""
        return None if isinstance(self._error, _Reported) else self._error

    @property
    def queued_bytes(self) -> int:
        """Bytes of messages queued and not yet handed to the MCAP writer."""
        return self._bytes_in - self._bytes_out

    def add_topic(self, name: str, msg_type: str, qos: str = "reliable") -> int:
        """Register a topic (once; again with the same type returns the same channel id)."""
        full = normalize_type(msg_type)
        return self._add_channel(name, full, message_definition(full), [qos_profile(qos)], type_hash(full))

    def write(self, topic: str, log_time_ns: int, cdr_bytes: bytes, publish_time_ns: Optional[int] = None) -> bool:
        """Queue one CDR-serialized message (log time = receive time, ns since the epoch). Returns False
        when the byte budget dropped it (counted in ``dropped``)."""
        self._check_open()
        entry = self._topics.get(topic)
        if entry is None:
            raise ValueError(f"topic {topic!r} was not added: call add_topic({topic!r}, msg_type) first "
                             f"(known: {sorted(self._topics)})")
        if not isinstance(cdr_bytes, (bytes, bytearray, memoryview)) or bytes(cdr_bytes[:2]) not in _CDR_HEADERS:
            raise ValueError(f"message for {topic!r} is not CDR bytes (first bytes {bytes(cdr_bytes[:4])!r}, "
                             "expected b'\\x00\\x01\\x00\\x00'): pass serialize_message(msg) or a *_cdr() result")
        log_time_ns = int(log_time_ns)
        if log_time_ns < 0:
            raise ValueError(f"log time {log_time_ns} ns is negative")
        publish = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        data = bytes(cdr_bytes)
        if self._max_queue_bytes is not None:
            if self.queued_bytes + len(data) > self._max_queue_bytes or len(self._ops) > MAX_PENDING:
                self.dropped += 1
                self.dropped_bytes += len(data)
                return False
        elif len(self._ops) > MAX_PENDING:
            self._wake.set()
            while len(self._ops) > MAX_PENDING and self._thread.is_alive():  # back-pressure, no lock
                time.sleep(_BACK_PRESSURE_SLEEP_S)
        self._bytes_in += len(data)
        self._ops.append(("msg", entry[0], topic, log_time_ns, publish, data))
        if self._max_queue_bytes is not None and 2 * self.queued_bytes > self._max_queue_bytes:
            self._wake.set()                    # half the budget queued: drain now, before it drops messages
        return True

    def flush(self, timeout_s: float = 10.0) -> None:
        """Block until everything queued so far is written, in a closed chunk, and fsync'ed."""
        self._check_open()
        done = threading.Event()
        self._ops.append(("flush", done))
        self._wake.set()
        if not done.wait(timeout_s):
            self._check_open()
            raise TimeoutError(f"bag {self.folder}: flush not done after {timeout_s} s")

    def close(self, timeout_s: float = 30.0) -> bool:
        """Write everything queued, the summary, the footer and the final metadata.yaml. Idempotent.
        Returns True when the bag is closed (False only if the I/O thread did not finish in time)."""
        self._close_requested = True
        self._wake.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        atexit.unregister(self.close)
        if self._error is not None and not isinstance(self._error, _Reported):
            err, self._error = self._error, _Reported()
            raise RuntimeError(f"bag {self.folder}: the I/O thread failed: {err!r}") from err
        return not self._thread.is_alive()

    def __enter__(self) -> "Rosbag2McapWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ----------------------------------------------------------------------------
    def _add_channel(self, name: str, msg_type: str, schema_text: str, qos_profiles: list[dict],
                     topic_hash: str) -> int:
        self._check_open()
        if not name.startswith("/"):
            raise ValueError(f"topic name {name!r} must be absolute (start with '/'), as rosbag2 records it")
        with self._topic_lock:
            if name in self._topics:
                channel, known = self._topics[name]
                if known != msg_type:
                    raise ValueError(f"topic {name!r} already added with type {known}, not {msg_type}")
                return channel
            if msg_type not in self._schemas:  # ids as the mcap Writer assigns them: 1, 2, ...
                self._schemas[msg_type] = len(self._schemas) + 1
                self._ops.append(("schema", self._schemas[msg_type], msg_type, schema_text))
            channel = len(self._topics) + 1
            self._ops.append(("channel", channel, name, self._schemas[msg_type],
                              TopicInfo(name, msg_type, qos_profiles, topic_hash)))
            self._topics[name] = (channel, msg_type)
            self._wake.set()
            return channel

    def _check_open(self) -> None:
        if self._close_requested or not self._thread.is_alive():
            why = f" (I/O error: {self._error!r})" if self._error and not isinstance(self._error, _Reported) else ""
            raise RuntimeError(f"bag {self.folder} is closed{why} (perhaps by a shutdown handler): stop writing to it")

    # -- I/O thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        infos: dict[str, TopicInfo] = {}
        dirty, flushed_at = False, time.monotonic()
        try:
            while True:
                self._wake.clear()               # before draining: what is queued after it sets it again
                closing = self._close_requested  # read before draining: nothing queued before close is lost
                while self._ops:
                    op = self._ops.popleft()
                    if op[0] == "msg":
                        _, channel, topic, log_ns, pub_ns, data = op
                        self._bytes_out += len(data)
                        info = infos[topic]
                        self._mcap.add_message(channel_id=channel, log_time=log_ns, data=data,
                                               publish_time=pub_ns, sequence=info.count)
                        info.count += 1
                        i = self._info
                        i.start_ns = log_ns if i.message_count == 1 else min(i.start_ns, log_ns)
                        i.end_ns = max(i.end_ns, log_ns)
                        dirty = True
                    elif op[0] == "schema":
                        got = self._mcap.register_schema(name=op[2], encoding="ros2msg", data=op[3].encode("utf-8"))
                        assert got == op[1], f"schema id {got} != {op[1]}"
                    elif op[0] == "channel":
                        _, channel, topic, schema_id, info = op
                        got = self._mcap.register_channel(
                            topic=topic, message_encoding="cdr", schema_id=schema_id,
                            metadata={"offered_qos_profiles": qos_yaml(info.qos_profiles),
                                      "topic_type_hash": info.type_hash})
                        assert got == channel, f"channel id {got} != {channel}"
                        infos[topic] = info
                        self._info.topics.append(info)
                        write_metadata_yaml(self.folder, self._info)
                    elif op[0] == "flush":
                        self._flush_chunk()
                        dirty, flushed_at = False, time.monotonic()
                        op[1].set()
                if closing:
                    break
                if dirty and time.monotonic() - flushed_at >= self._flush_interval:
                    self._flush_chunk()
                    dirty, flushed_at = False, time.monotonic()
                self._wake.wait(DRAIN_INTERVAL_S)
            self._finish()
        except BaseException as exc:  # keep the error for the caller; the file is left for recover_bag
            self._error = exc
            self._close_requested = True
            self._ops.clear()         # what cannot be written any more is not kept in memory
            try:
                self._file.close()    # flushes what it can; the chunks already synced stay readable
            except OSError:
                pass

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def _flush_chunk(self) -> None:
        self._mcap.flush()  # closes the open chunk and writes it
        self._sync()
        write_metadata_yaml(self.folder, self._info)

    def _finish(self) -> None:
        self._mcap.flush()  # last chunk, then the metadata record, then the summary
        self._mcap.add_metadata("rosbag2", {"serialized_metadata": dump_yaml(bag_information(self._info)).strip()})
        self._mcap.finish()
        self._sync()
        self._file.close()
        write_metadata_yaml(self.folder, self._info)


class _Reported(Exception):
    """Marks an I/O error already raised once from close()."""
