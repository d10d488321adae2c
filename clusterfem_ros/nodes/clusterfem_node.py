"""The clusterfem node: joint states in; surface Marker, stress PointCloud2, diagnostics (and an MCAP) out.

Physics runs on a thread of its own (clusterfem_ros.sim_loop), decoupled from message arrival; the output
timers publish the latest finished state it handed over (a snapshot), so building markers, stress and
recording never stall a step. Every output is computed only when somebody consumes it (a subscriber or the
recording). Bad input is counted, warned about (throttled) and never stops the node; a diverging body is
reset, never published; a failing step is reported on the log and the diagnostics (ERROR).

A joint state is size-checked and decoded in the callback, judged on the physics thread
(Scene.take_joint_state), and recorded only if the joint stream took it in: a refused sample is counted per kind
in the diagnostics and never reaches the bag (a replay needs only the samples taken in). The recording never
raises into a callback: a full
queue drops and counts (recording.max_queue_mb), a write failure stops the recording with an ERROR log and an
ERROR diagnostic while the simulation goes on.

Several bodies share a ROS graph by namespace: every topic but /diagnostics is relative, and the
diagnostics status is named after the node's fully qualified name.
"""
from __future__ import annotations

import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from msg_adapters.diagnostics import diagnostic_array
from msg_adapters.joint_state import joint_state_cdr_extent, joint_state_fields, joint_state_name_count

from .. import topics
from .outputs import output_streams
from ..scene import Scene
from ..skeleton.urdf_check import UrdfLimits, UrdfRefused, check_urdf
from ..sim_loop import SimLoop, Snapshot
from .params import declare_scene_parameters
from .spinning import run_node

JOINTS_TOPIC = topics.JOINT_STATES.name
URDF_TOPIC = topics.ROBOT_DESCRIPTION.name      # latched by the player when skeleton.source is robot_description
ERROR_HOLD_S = 10.0         # /diagnostics stays at ERROR this long after a failed physics step
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class ClusterFemNode(Node):
    def __init__(self, **node_kwargs):
        super().__init__("clusterfem", **node_kwargs)
        self.config = declare_scene_parameters(self, self._on_live_change)
        c = self.config
        self.scene: Scene | None = None
        self.recorder = None
        self.physics: SimLoop | None = None   # the physics thread, once the scene is built
        self.recording_error = ""             # why recording stopped early ('' while it runs or is off)
        self._dropped_at_stop = 0             # messages the recorder's byte budget dropped, once it is closed
        self._record_lock = threading.Lock()  # _record runs on the executor and on the physics thread
        self.counts: dict[str, int] = {}      # messages per topic published (outputs) or taken in (inputs)
        self.received = 0                     # joint states received; taken in + refused + before the scene
        self.before_scene = 0                 # joint states received before the scene was built (ignored)
        self.build_error: str | None = None   # why the last robot_description was refused (the demo reports it)
        self.descriptions_refused: dict[str, int] = {}    # robot_description refusals by kind
        self.building = False                 # a scene is being built from robot_description (meshing may take minutes)
        self._warned: dict[str, float] = {}   # input problem kind -> when it was last logged
        self._stats = {"t_wall": time.perf_counter(), "steps": 0}
        self._rtf = 0.0
        self._window: dict[str, float] = {}   # headroom and stage shares over the real-time factor's window
        self._pubs = {name: self.create_publisher(s.msg_class, name, s.depth) for name, s in output_streams().items()}
        self.live = None                      # the Foxglove live view (nodes/live_view.py), if output.live_port
        if c.recording.enabled:
            self._open_recording()
        if c.output.live_port:
            self._open_live_view()
        self.create_subscription(JointState, JOINTS_TOPIC, self._on_joint_state, qos_profile_sensor_data, raw=True)
        if c.skeleton.source == "robot_description":
            self.get_logger().info("waiting for the URDF on 'robot_description' (transient local)")
            self.create_subscription(String, URDF_TOPIC, self._on_robot_description, LATCHED, raw=True)
        else:
            self._build(None)
        self._output_timers = {}
        self._make_output_timers()

    # -- set-up ----------------------------------------------------------------------------------
    def _build(self, urdf_xml: str | None) -> None:
        log = self.get_logger()
        t0 = time.perf_counter()
        self.scene = Scene.build(self.config, urdf_xml=urdf_xml, progress=lambda s: log.info(s))
        m = self.scene.model
        log.info(f"scene ready in {time.perf_counter() - t0:.1f} s: {m.mesh.n_tets} tets, {m.n_vertices} vertices, "
                 f"method {self.config.method}, warping {self.config.warping}, h = {self.scene.h:g} s")
        c = self.config
        self.physics = SimLoop(self.scene, self._now, c.physics.timer_hz,
                               c.physics.max_catchup_steps, self._log, name=f"physics {self.get_fully_qualified_name()}")
        self.physics.start()

    def _log(self, level: str, text: str) -> None:
        """The physics thread's log lines (throttled like the callbacks' own). One call site per level: rclpy
        keys a throttled line by where it is logged from and refuses another severity there ("Logger severity
        cannot be changed between calls"), which would end the physics thread at a reset logged after a warning."""
        log = self.get_logger()
        if level == "error":
            log.error(text, throttle_duration_sec=2.0)
        elif level == "warning":
            log.warning(text, throttle_duration_sec=2.0)
        elif level == "info":
            log.info(text, throttle_duration_sec=2.0)
        else:
            raise ValueError(f"log level {level!r}: give 'info', 'warning' or 'error'")

    def _refuse_description(self, kind: str, text: str) -> None:
        """One line and one count (diagnostics: robot_description_refused_<kind>) per refused description."""
        self.descriptions_refused[kind] = self.descriptions_refused.get(kind, 0) + 1
        self.build_error = text
        self.get_logger().error(f"{text} [{kind}: {self.descriptions_refused[kind]} so far]")

    def _on_robot_description(self, data: bytes) -> None:
        """Every description is checked as a tree under the skeleton.max_* limits (skeleton/urdf_check.py) before
        anything else reads it; the first one that passes builds the scene. A refused one leaves the node as it
        was (waiting, or running its body) with one line and a count; a later good one is ignored with one line."""
        limits = UrdfLimits.of(self.config.skeleton)
        if len(data) > limits.max_bytes + 64:         # the CDR header and length: refused before decoding
            self._refuse_description("too_large", f"robot_description refused: {len(data)} bytes (skeleton."
                                     f"max_urdf_bytes {limits.max_bytes}); raise it if this robot is real")
            return
        try:
            text = deserialize_message(data, String).data
            check_urdf(text, limits)
        except UrdfRefused as exc:
            self._refuse_description(exc.kind, f"robot_description refused: {exc}")
            return
        except Exception as exc:
            self._refuse_description("malformed", f"robot_description refused: {exc}")
            return
        if self.scene is not None:
            self.get_logger().warning("a new robot_description was received while the body runs on the first one: "
                                      "ignored; restart the node to take it", throttle_duration_sec=2.0)
            return
        self.building = True
        try:
            self._build(text)
        except Exception as exc:  # a bad URDF must not kill the node: say what and wait for another
            self._refuse_description(getattr(exc, "kind", "build_failed"),
                                     f"cannot build the scene from robot_description: {exc}")
            return
        finally:
            self.building = False
        self.build_error = None
        self._record(URDF_TOPIC, data)    # the bag carries its skeleton (the renderer poses it)

    def _served_topics(self) -> tuple:
        """What the bag records and the live view serves: the joint states taken in, every output stream
        (nodes/outputs.py) and the skeleton the scene was built on when it came on robot_description."""
        served = (topics.JOINT_STATES, *(s.topic for s in output_streams().values()))
        if self.config.skeleton.source == "robot_description":
            return (*served, topics.ROBOT_DESCRIPTION)
        return served

    def _open_recording(self) -> None:
        from ..recording.rosbag2_mcap import Rosbag2McapWriter, default_bag_path
        c = self.config
        path = default_bag_path(c.recording.prefix, root=c.recording.dir)
        self.recorder = Rosbag2McapWriter(path, max_queue_bytes=int(c.recording.max_queue_mb * 1e6))
        # bags name topics fully qualified, as rosbag2 does (namespace and remapping applied)
        served = self._served_topics()
        self._bag_topics = {t.name: self.resolve_topic_name(t.name) for t in served}
        for t in served:
            self.recorder.add_topic(self._bag_topics[t.name], t.type, qos=t.qos)
        self.recording_path = path
        from ..config import scene_file_text
        from ..recording.bag_reader import PARAMS_FILE
        (path / PARAMS_FILE).write_text(scene_file_text(self.config.resolved()))   # a replay's other input
        self.get_logger().info(f"recording to {path}")

    def _open_live_view(self) -> None:
        from .live_view import LiveView
        out = self.config.output
        self.live = LiveView(out.live_host, out.live_port, name=self.get_fully_qualified_name())
        served = self._served_topics()
        self._live_topics = {t.name: self.resolve_topic_name(t.name) for t in served}
        for t in served:
            self.live.add_topic(self._live_topics[t.name], t.type)
        self.get_logger().info(f"live view on {self.live.url} (Foxglove: Open connection, Foxglove WebSocket; "
                               "layout config/foxglove_layout.json)")

    def _consumed(self, pub) -> bool:
        """Somebody takes this output: a subscriber, the recording or the live view."""
        return pub.get_subscription_count() > 0 or self.recorder is not None or self.live is not None

    def _make_output_timers(self) -> None:
        for t in self._output_timers.values():
            self.destroy_timer(t)
        self._output_timers = {}
        for name, stream in output_streams().items():
            if stream.warm is not None:
                stream.warm(self.config)
            rate = stream.rate(self.config)
            if rate > 0:
                self._output_timers[name] = self.create_timer(1.0 / rate, lambda s=stream: self._publish(s))

    def _on_live_change(self, changes: dict) -> None:
        self.config = self.config.with_values(changes)
        rates = {s.declaration.rate_param for s in output_streams().values()}
        if any(k in rates or k == "output.colormap" for k in changes):
            self._make_output_timers()

    def stop_physics(self) -> None:
        """Stop and join the physics thread (idempotent): the scene is then still and may be read."""
        physics = getattr(self, "physics", None)       # None too when the constructor failed before it
        if physics is not None and not physics.stop():
            self.get_logger().error("the physics thread did not end within 10 s; the process exit ends it")

    def destroy_node(self) -> None:
        self.stop_physics()
        super().destroy_node()

    @property
    def withheld(self) -> int:
        """States the outputs did not show (SimLoop.unpublishable: not yet placed on the skeleton, or a failed
        output check)."""
        return self.physics.unpublishable if self.physics is not None else 0

    @property
    def divergences(self) -> int:
        return self.physics.divergences if self.physics is not None else 0

    def close(self) -> None:
        """Stop physics, then finalise the recording (idempotent); called on every way out."""
        self.stop_physics()
        with self._record_lock:
            live, self.live = self.live, None
        if live is not None:
            live.close()
        if self.recorder is not None:
            rec, self.recorder = self.recorder, None
            try:
                rec.close()
            except Exception as exc:
                self._recording_failed(exc, rec)
                return
            self._dropped_at_stop = rec.dropped
            self.get_logger().info(f"recording finalised: {self.recording_path}")

    def _recording_failed(self, exc: BaseException, rec) -> None:
        """Stop recording after a write failure (disk full, folder gone): log it, say it in the diagnostics
        (ERROR) and let the simulation go on. The bag keeps every chunk flushed before the failure."""
        self.recorder = None
        self._dropped_at_stop = rec.dropped
        self.recording_error = f"{type(exc).__name__}: {exc}"
        try:
            rec.close(timeout_s=1.0)
        except Exception:                   # the same failure, raised once more by close()
            pass
        self.get_logger().error(
            f"recording stopped: {self.recording_error}; the simulation goes on without it. {self.recording_path} "
            "keeps what was flushed before: once its disk has space, complete it with 'python -m "
            f"clusterfem_ros.recording.recover {self.recording_path}' (--work-dir DIR to use another disk)")

    # -- inputs ----------------------------------------------------------------------------------
    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _record(self, topic: str, data: bytes, log_ns: int | None = None) -> None:
        """Count a message taken in or published and queue it for the bag; never raises (a write failure
        stops recording, see _recording_failed; a full queue drops the message and counts it). Called on the
        executor thread (outputs) and on the physics thread (joint states): one at a time."""
        with self._record_lock:
            self.counts[topic] = self.counts.get(topic, 0) + 1
            live = self.live
            if live is not None and topic in self._live_topics:     # the same bytes, served live
                try:
                    live.log(self._live_topics[topic], data, self.get_clock().now().nanoseconds if log_ns is None
                             else log_ns)
                except Exception as exc:        # the live view stops, the node goes on
                    self.live = None
                    self.get_logger().error(f"live view stopped: {type(exc).__name__}: {exc}")
            rec = self.recorder
            if rec is None:
                return
            try:
                rec.write(self._bag_topics[topic], self.get_clock().now().nanoseconds if log_ns is None else log_ns,
                          data)
            except Exception as exc:
                self._recording_failed(rec.error or exc, rec)
                return
            if rec.error is not None:
                self._recording_failed(rec.error, rec)

    def _warn_input(self, kind: str, message: str, count: int) -> None:
        """One warning per kind of input problem every 2 s at most, with the count so far."""
        t = time.monotonic()
        if t - self._warned.get(kind, -1e9) >= 2.0:
            self._warned[kind] = t
            self.get_logger().warning(f"{message} [{kind}: {count} so far]")

    def _on_joint_state(self, data: bytes) -> None:
        """Check the size and decode here; the physics thread judges it (Scene.take_joint_state) and records what
        the joint stream took in: the samples a replay needs to take the same decisions. Refused messages are
        counted, not recorded."""
        now_ns = self.get_clock().now().nanoseconds
        self.received += 1
        scene = self.scene
        if scene is None:
            self.before_scene += 1
            return
        try:
            n_names = joint_state_name_count(data)     # refuse a huge message before decoding it
            if n_names > self.config.input.max_names:
                scene.inputs.count("too_many_names")
                self._warn_input("too_many_names", f"joint state with {n_names} names dropped (input.max_names "
                                 f"{self.config.input.max_names})", scene.inputs.rejected["too_many_names"])
                return
            stamp, names, q, v = joint_state_fields(deserialize_message(data, JointState))
            exact = data[:joint_state_cdr_extent(data)]     # without a tail strict bag readers refuse
        except Exception as exc:
            scene.inputs.count("malformed")
            self._warn_input("malformed", f"joint state rejected: {exc}; fix the publisher",
                             scene.inputs.rejected["malformed"])
            return
        # queued for the physics thread, which gives it to the scene (Scene.take_joint_state: an unstamped sample
        # takes its receive time), records it if the joint stream took it in, and (on the input clock) steps up
        # to its stamp
        self.physics.take_input(lambda: self._take_sample(scene, stamp, names, q, v, now_ns, exact))

    def _take_sample(self, scene: Scene, stamp: float, names, q, v, now_ns: int, exact: bytes) -> None:
        def judged(problems: list) -> None:
            if scene.inputs.taken_in:                 # the receive time is what a replay passes as 'received'
                self._record(JOINTS_TOPIC, exact, now_ns)
            for kind, message in problems:
                self._warn_input(kind, message, scene.inputs.rejected.get(kind, 0))
        scene.take_joint_state(stamp, names, q, v, received=now_ns * 1e-9, on_judged=judged)

    # -- outputs ---------------------------------------------------------------------------------
    def _stamp(self):
        return self.get_clock().now().nanoseconds

    @staticmethod
    def sim_stamp(snap: Snapshot) -> int:
        """Outputs carry the simulated time of the state they show (behind the clock in slow motion)."""
        return int(round(snap.sim_time * 1e9))

    def stress_of(self, snap: Snapshot):
        """The stress of a snapshot (made once per snapshot, timed as the 'stress' stage)."""
        return snap.stress(self.scene.model, self.scene.integrator.material_model, self.physics.stages)

    def _publish(self, stream) -> None:
        """One output stream's message of the state shown (nodes/outputs.py), if anybody consumes it: published,
        recorded and served live; a state or stress that is not finite is never published (logged)."""
        pub = self._pubs[stream.topic.name]
        if not self._consumed(pub):
            return
        snap = None
        if stream.needs_snapshot:
            snap = self.physics.shown() if self.physics is not None else None
            if snap is None:
                return
        try:
            data = stream.encode(self, snap)
        except ValueError as exc:
            self.get_logger().error(f"{stream.topic.name} not published: {exc}", throttle_duration_sec=2.0)
            return
        if data is None:
            return
        pub.publish(data)
        t1 = time.perf_counter()
        if stream.published is not None:
            stream.published(self, snap, t1)
        self._record(stream.topic.name, data)
        if self.physics is not None:
            self.physics.stages.add("recording", time.perf_counter() - t1)

    def diagnostics(self) -> dict:
        """The values /diagnostics carries (also read by the demo's progress lines and summary). The state's
        values (energy, volume) are those of the snapshot shown (SimLoop.shown); the stage shares and the headroom cover
        the time since the previous call."""
        s, loop = self.scene, self.physics
        snap = loop.shown() if loop is not None else None
        now = time.perf_counter()
        if s is not None and now - self._stats["t_wall"] >= 0.5:   # simulated (not dropped) time per wall time
            self._rtf = (s.steps_done - self._stats["steps"]) * s.h / (now - self._stats["t_wall"])
            self._stats = {"t_wall": now, "steps": s.steps_done}
            if loop is not None:                                    # the same window for headroom and shares
                room = loop.headroom()
                self._window = {"physics_headroom": room["alone"], "physics_headroom_in_node": room["in_node"],
                                **{f"share_{k}": v for k, v in loop.stages.shares().items()}}
        last = s.last if s else None
        values = {"steps": s.steps_done if s else 0,
                  "step_ms": (last.wall_s / max(last.steps, 1) * 1e3) if s else 0.0,
                  "real_time_factor": self._rtf,
                  "substeps": last.substeps if s else 0,
                  "substeps_mean": s.substeps_done / s.steps_done if s and s.steps_done else 0.0,
                  "stability_margin": last.margin if s else 0.0,
                  "energy_J": self._energy(snap),
                  "volume_error": self._volume_error(snap),
                  "inputs_accepted": s.inputs.accepted if s else 0,
                  "inputs_rejected": s.inputs.total_rejected if s else 0,
                  "late_jumps": s.late_jumps if s else 0,
                  "resets_after_divergence": self.divergences,
                  "outputs_withheld": self.withheld,
                  "dropped_time_s": s.dropped_s if s else 0.0}
        if s:
            rejected = dict(s.inputs.rejected)            # one copy: the physics thread adds kinds as it pushes
            values.update({f"rejected_{k}": n for k, n in sorted(rejected.items())})
        if loop is not None:
            values.update(loop.latency.percentiles())
            values.update(self._window)
            values.update({"physics_failures": loop.crashes, "physics_stopped": loop.stopped,
                           "physics_error": loop.error or "",
                           "inputs_waiting": loop.waiting, "inputs_dropped_queue_full": loop.queue_full})
        if s:
            values.update({"tet_quality_worst": s.model.quality.worst, "tet_slivers": s.model.quality.slivers})
        if self.config.skeleton.source == "robot_description":
            refused = dict(self.descriptions_refused)
            values["robot_description_refused"] = sum(refused.values())
            values.update({f"robot_description_refused_{k}": n for k, n in sorted(refused.items())})
        values["joint_states_received"] = self.received
        values["joint_states_before_scene"] = self.before_scene
        rec = self.recorder
        if rec is not None and rec.error is not None:
            self._recording_failed(rec.error, rec)
            rec = None
        if self.config.recording.enabled:
            values.update({"recording": "stopped" if self.recording_error else "on" if rec is not None else "closed",
                           "recording_dropped": rec.dropped if rec is not None else self._dropped_at_stop,
                           "recording_queue_bytes": rec.queued_bytes if rec is not None else 0,
                           "recording_error": self.recording_error})
        return values

    def _energy(self, snap: Snapshot | None) -> float:
        if snap is None:
            return 0.0
        return self.scene.energy_of(snap.u, snap.v)

    def _volume_error(self, snap: Snapshot | None) -> float:
        if snap is None:
            return 0.0
        s = self.scene
        return s.volume_error_of(s.model.rest + snap.u)

    def diagnostic_array(self) -> DiagnosticArray:
        """The node's /diagnostics message now: its values (``diagnostics``), and its level and message: ERROR
        while physics is stopped, for ERROR_HOLD_S after a failed step and once the recording stopped, WARN
        while anything is refused or has diverged, else OK. A value that is not finite is sent as -1."""
        values = self.diagnostics()
        finite = all(np.isfinite(v) for v in values.values() if isinstance(v, float))
        loop = self.physics
        failed = loop is not None and (loop.stopped or time.perf_counter() - loop.error_at < ERROR_HOLD_S)
        level = "ERROR" if failed else ("OK" if finite and not values["inputs_rejected"] and not self.divergences
                                        and not values.get("physics_failures")
                                        and not values.get("robot_description_refused") else "WARN")
        message = ("physics stopped: " if loop.stopped else "physics failed: ") + loop.error if failed else ""
        if not message and self.build_error:
            message = self.build_error if self.scene is None else f"last {self.build_error}"
        if self.recording_error:
            level = "ERROR"
            message = (message + "; " if message else "") + f"recording stopped: {self.recording_error}"
        values = {k: (v if not isinstance(v, float) or np.isfinite(v) else -1.0) for k, v in values.items()}
        me = self.get_fully_qualified_name().lstrip("/")     # "clusterfem", or "<namespace>/clusterfem"
        return diagnostic_array(self._stamp(), f"{me}: simulation", me, values, level, message)


def main(args=None) -> None:
    run_node(ClusterFemNode, args, help_text=__doc__)


if __name__ == "__main__":
    main()
