"""Live view: the node's topics served over the Foxglove WebSocket protocol (foxglove-sdk), for Foxglove (the
app or the web page: *Open connection* -> ws://127.0.0.1:8765) without a ROS bridge or DDS on the viewer's side.

Each topic is a channel with message encoding ``cdr`` and a ``ros2msg`` schema (the .msg text with its
dependencies, as the recorder writes it in the MCAP bag), and carries the same CDR bytes that are published and
recorded, so config/foxglove_layout.json shows a live node as it shows a bag. The server binds
``output.live_host`` (127.0.0.1 by default: this host only) on ``output.live_port``; nothing is computed for it
beyond what the node publishes while somebody consumes (a live view counts as a consumer).
"""
from __future__ import annotations

from ..recording.msgdef import message_definition, normalize_type

ENCODING, SCHEMA_ENCODING = "cdr", "ros2msg"


class LiveView:
    """A Foxglove WebSocket server with one channel per topic; ``log`` sends a message to subscribed clients."""

    def __init__(self, host: str, port: int, name: str = "clusterfem"):
        import foxglove
        self._foxglove = foxglove
        self.context = foxglove.Context()           # our own: the channels go to this server only
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        except Exception as exc:
            raise RuntimeError(f"live view: cannot serve on {host}:{port} ({exc}): choose another output.live_port, "
                               "or 0 for none") from None
        self.host, self.port = host, self.server.port
        self.channels: dict[str, object] = {}

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def add_topic(self, topic: str, msg_type: str) -> None:
        """Advertise ``topic`` (fully qualified, as in the bag) with the ROS schema of ``msg_type``."""
        full = normalize_type(msg_type)
        schema = self._foxglove.Schema(name=full, encoding=SCHEMA_ENCODING,
                                       data=message_definition(full).encode())
        self.channels[topic] = self._foxglove.Channel(topic, schema=schema, message_encoding=ENCODING,
                                                      context=self.context)

    def log(self, topic: str, cdr: bytes, log_time_ns: int) -> None:
        self.channels[topic].log(cdr, log_time=int(log_time_ns))

    def close(self) -> None:
        for ch in self.channels.values():
            ch.close()
        self.server.stop()
