"""Helper process for test_recording_signals.py (no tests here): records until signalled.

usage: python tests/test_recording_child.py <bag folder> <term|kill>
  term: installs SIGTERM/SIGINT handlers that close the writer, prints 'closed <n>' and exits 0.
  kill: after 200 messages idles 1.2 s (the background flush makes them durable), prints
        'durable 200', then keeps writing until SIGKILLed.
Prints 'ready' once recording.
"""
from __future__ import annotations

import signal
import sys
import time

import numpy as np

from clusterfem_ros.recording import Rosbag2McapWriter
from msg_adapters.joint_state import joint_state_cdr
from msg_adapters.marker import surface_marker_cdr


def main(folder: str, mode: str) -> None:
    writer = Rosbag2McapWriter(folder, flush_interval_s=0.5)
    writer.add_topic("/joint_states", "sensor_msgs/msg/JointState", "sensor_data")
    writer.add_topic("/surface", "visualization_msgs/msg/Marker")
    count = 0

    def on_signal(signum: int, frame: object) -> None:
        writer.close()  # safe here: deferred if the signal interrupted writer.write()
        print(f"closed {count}", flush=True)
        raise SystemExit(0)

    if mode == "term":
        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
    rng = np.random.default_rng(0)
    v, tri = rng.normal(size=(200, 3)), rng.integers(0, 200, size=(300, 3))
    rgba = np.ones((200, 4), np.float32)
    print("ready", flush=True)
    while True:
        t = time.time_ns()
        # count only after the write returned: 'closed <n>' must equal what the bag holds
        writer.write("/joint_states", t, joint_state_cdr(["a", "b"], np.array([count, 1.0]), None, t))
        count += 1
        writer.write("/surface", t, surface_marker_cdr(v, tri, rgba, "world", t))
        count += 1
        if mode == "kill" and count == 200:
            time.sleep(1.2)
            print("durable 200", flush=True)
        time.sleep(0.001)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
