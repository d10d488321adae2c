"""The clusterfem node: joint states in; surface Marker, stress PointCloud2, diagnostics (and an MCAP) out.

Physics runs on a thread of its own (clusterfem_ros.sim_loop), decoupled from message arrival; the output
timers publish the latest finished state it handed over (a snapshot), so building markers, stress and
recording never stall a step. Every output is computed only when somebody consumes it (a subscriber or the
recording). Bad input is counted, warned about (throttled) and never stops the node; a diverging body is
reset, never published; a failing step is reported on the log and the diagnostics (ERROR).

Several bodies share a ROS graph by namespace: every topic but /diagnostics is relative, and the
diagnostics status is named after the node's fully qualified name.
"""
from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String
from visualization_msgs.msg import Marker

from msg_adapters.colormap import map_scalars
from msg_adapters.diagnostics import diagnostic_array
from msg_adapters.joint_state import joint_state_fields
from msg_adapters.marker import surface_marker_cdr
from msg_adapters.pointcloud import stress_cloud_cdr

from ..fem.tet_mesh import signed_volumes
from ..scene import Scene
from ..sim_loop import SimLoop, Snapshot
from .params import declare_scene_parameters
from .spinning import run_node

SURFACE_TOPIC, STRESS_TOPIC, DIAG_TOPIC, JOINTS_TOPIC = "clusterfem/surface", "clusterfem/stress", "/diagnostics", "joint_states"
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
        self.counts: dict[str, int] = {}      # messages per topic published (outputs) or received (inputs)
        self._stats = {"t_wall": time.perf_counter(), "steps": 0}
        self._rtf = 0.0
        self._window: dict[str, float] = {}   # headroom and stage shares over the real-time factor's window
        self._marker_pub = self.create_publisher(Marker, SURFACE_TOPIC, 1)
        self._stress_pub = self.create_publisher(PointCloud2, STRESS_TOPIC, 1)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAG_TOPIC, 10)
        if c["recording.enabled"]:
            self._open_recording()
        self.create_subscription(JointState, JOINTS_TOPIC, self._on_joint_state, qos_profile_sensor_data, raw=True)
        if c["skeleton.source"] == "robot_description":
            self.get_logger().info("waiting for the URDF on 'robot_description' (transient local)")
            self.create_subscription(String, "robot_description", self._on_robot_description, LATCHED)
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
                 f"method {self.config['method']}, warping {self.config['warping']}, h = {self.scene.h:g} s")
        c = self.config
        self.physics = SimLoop(self.scene, c["physics.clock"], self._now, c["physics.timer_hz"],
                               c["physics.max_catchup_steps"], self._log, name=f"physics {self.get_fully_qualified_name()}")
        self.physics.start()

    def _log(self, level: str, text: str) -> None:
        """The physics thread's log lines (throttled like the callbacks' own)."""
        getattr(self.get_logger(), level)(text, throttle_duration_sec=2.0)

    def _on_robot_description(self, msg: String) -> None:
        if self.scene is None:
            try:
                self._build(msg.data)
            except Exception as exc:  # a bad URDF must not kill the node: say what and wait for another
                self.get_logger().error(f"cannot build the scene from robot_description: {exc}")

    def _open_recording(self) -> None:
        from ..recording.rosbag2_mcap import Rosbag2McapWriter, default_bag_path
        c = self.config
        path = default_bag_path(c["recording.prefix"], root=c["recording.dir"])
        self.recorder = Rosbag2McapWriter(path)
        # bags name topics fully qualified, as rosbag2 does (namespace and remapping applied)
        self._bag_topics = {t: self.resolve_topic_name(t) for t in (JOINTS_TOPIC, SURFACE_TOPIC, STRESS_TOPIC, DIAG_TOPIC)}
        for topic, msg_type, qos in ((JOINTS_TOPIC, "sensor_msgs/msg/JointState", "sensor_data"),
                                     (SURFACE_TOPIC, "visualization_msgs/msg/Marker", "reliable"),
                                     (STRESS_TOPIC, "sensor_msgs/msg/PointCloud2", "reliable"),
                                     (DIAG_TOPIC, "diagnostic_msgs/msg/DiagnosticArray", "reliable")):
            self.recorder.add_topic(self._bag_topics[topic], msg_type, qos=qos)
        self.recording_path = path
        from ..config import scene_file_text
        from ..recording.bag_reader import PARAMS_FILE
        (path / PARAMS_FILE).write_text(scene_file_text(self.config))   # what a replay needs besides the inputs
        self.get_logger().info(f"recording to {path}")

    def _make_output_timers(self) -> None:
        for t in self._output_timers.values():
            self.destroy_timer(t)
        self._output_timers = {}
        for key, fn in (("output.marker_rate_hz", self._publish_surface), ("output.stress_rate_hz", self._publish_stress),
                        ("output.diagnostics_rate_hz", self._publish_diagnostics)):
            if self.config[key] > 0:
                self._output_timers[key] = self.create_timer(1.0 / self.config[key], fn)

    def _on_live_change(self, changes: dict) -> None:
        self.config = self.config.with_values(changes)
        if any(k.endswith("rate_hz") for k in changes):
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
    def divergences(self) -> int:
        return self.physics.divergences if self.physics is not None else 0

    def close(self) -> None:
        """Stop physics, then finalise the recording (idempotent); called on every way out."""
        self.stop_physics()
        if self.recorder is not None:
            self.recorder.close()
            self.get_logger().info(f"recording finalised: {self.recording_path}")
            self.recorder = None

    # -- inputs ----------------------------------------------------------------------------------
    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _record(self, topic: str, data: bytes, log_ns: int | None = None) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if self.recorder is not None:
            self.recorder.write(self._bag_topics[topic], self.get_clock().now().nanoseconds if log_ns is None
                                else log_ns, data)

    def _on_joint_state(self, data: bytes) -> None:
        now_ns = self.get_clock().now().nanoseconds
        self._record(JOINTS_TOPIC, data, now_ns)        # the receive time is what a replay passes as 'now'
        scene = self.scene
        if scene is None:
            return
        try:
            stamp, names, q, v = joint_state_fields(deserialize_message(data, JointState))
        except Exception as exc:
            scene.inputs.count("malformed")
            self.get_logger().warning(f"joint state rejected: {exc}; fix the publisher", throttle_duration_sec=2.0)
            return
        if stamp == 0.0:
            stamp = now_ns * 1e-9
        # queued for the physics thread, which pushes it (and, on the input clock, steps up to its stamp)
        self.physics.take_input(lambda: self._push_sample(scene, stamp, names, q, v, now_ns))

    def _push_sample(self, scene: Scene, stamp: float, names, q, v, now_ns: int) -> None:
        for kind, message in scene.push_joint_state(stamp, names, q, v, now=now_ns * 1e-9):
            if kind == "unknown_joint":
                self.get_logger().warning(message)          # reported once per name by the joint map
            else:
                self.get_logger().warning(f"{message} [{kind}: {scene.inputs.rejected.get(kind, 0)} so far]",
                                          throttle_duration_sec=2.0)

    # -- outputs ---------------------------------------------------------------------------------
    def _snapshot_for(self, pub) -> Snapshot | None:
        """The state to publish on ``pub``, if anybody consumes it and physics has handed one over."""
        snap = self.physics.snapshot if self.physics is not None else None
        if snap is None or not (pub.get_subscription_count() > 0 or self.recorder is not None):
            return None
        return snap

    def _stamp(self):
        return self.get_clock().now().nanoseconds

    @staticmethod
    def _sim_stamp(snap: Snapshot) -> int:
        """Outputs carry the simulated time of the state they show (behind the clock in slow motion)."""
        return int(round(snap.sim_time * 1e9))

    def _stress_max(self) -> float:
        return self.config["output.stress_max"] or self.config["material.young_modulus"] / 20.0

    def _stress(self, snap: Snapshot):
        return snap.stress(self.scene.model, bool(self.config["warping"]), self.physics.stages)

    def _publish_surface(self) -> None:
        snap = self._snapshot_for(self._marker_pub)
        if snap is None:
            return
        scene, stages = self.scene, self.physics.stages
        try:                               # non-finite state or stress: never published
            vm = self._stress(snap).vertex_von_mises[scene.surface_vertices]
            t0 = time.perf_counter()
            verts = scene.model.rest[scene.surface_vertices] + snap.u[scene.surface_vertices]
            rgba = map_scalars(vm, self.config["output.colormap"], 0.0, self._stress_max())
            data = surface_marker_cdr(verts, scene.surface_triangles, rgba, self.config["output.frame_id"],
                                      self._sim_stamp(snap), "clusterfem", 0)
        except ValueError as exc:
            self.get_logger().error(f"surface not published: {exc}", throttle_duration_sec=2.0)
            return
        self._marker_pub.publish(data)
        t1 = time.perf_counter()
        self.physics.latency.published(snap.inputs_used, t1)
        self._record(SURFACE_TOPIC, data)
        stages.add("markers", t1 - t0)
        stages.add("recording", time.perf_counter() - t1)

    def _publish_stress(self) -> None:
        snap = self._snapshot_for(self._stress_pub)
        if snap is None:
            return
        try:
            vm = self._stress(snap).vertex_von_mises
            t0 = time.perf_counter()
            data = stress_cloud_cdr(self.scene.model.rest + snap.u, vm, self.config["output.frame_id"],
                                    self._sim_stamp(snap))
        except ValueError as exc:
            self.get_logger().error(f"stress not published: {exc}", throttle_duration_sec=2.0)
            return
        self._stress_pub.publish(data)
        t1 = time.perf_counter()
        self._record(STRESS_TOPIC, data)
        self.physics.stages.add("cloud", t1 - t0)
        self.physics.stages.add("recording", time.perf_counter() - t1)

    def diagnostics(self) -> dict:
        """The values /diagnostics carries (also read by the demo's progress lines and summary). The state's
        values (energy, volume) are those of the latest snapshot; the stage shares and the headroom cover
        the time since the previous call."""
        s, loop = self.scene, self.physics
        snap = loop.snapshot if loop is not None else None
        now = time.perf_counter()
        if s is not None and now - self._stats["t_wall"] >= 0.5:   # simulated (not dropped) time per wall time
            self._rtf = (s.steps_done - self._stats["steps"]) * s.h / (now - self._stats["t_wall"])
            self._stats = {"t_wall": now, "steps": s.steps_done}
            if loop is not None:                                    # the same window for headroom and shares
                self._window = {"physics_headroom": loop.headroom(),
                                **{f"share_{k}": v for k, v in loop.stages.shares().items()}}
        last = s.last if s else None
        values = {"steps": s.steps_done if s else 0,
                  "step_ms": (last.wall_s / max(last.steps, 1) * 1e3) if s else 0.0,
                  "real_time_factor": self._rtf,
                  "substeps": last.substeps if s else 0,
                  "stability_margin": last.margin if s else 0.0,
                  "energy_J": self._energy(snap),
                  "volume_error": self._volume_error(snap),
                  "inputs_accepted": s.inputs.accepted if s else 0,
                  "inputs_rejected": s.inputs.total_rejected if s else 0,
                  "resets_after_divergence": self.divergences,
                  "dropped_time_s": s.dropped_s if s else 0.0}
        if s:
            rejected = dict(s.inputs.rejected)            # one copy: the physics thread adds kinds as it pushes
            values.update({f"rejected_{k}": n for k, n in sorted(rejected.items())})
        if loop is not None:
            values.update(loop.latency.percentiles())
            values.update(self._window)
            values.update({"physics_failures": loop.crashes, "physics_stopped": loop.stopped,
                           "physics_error": loop.error or "", "unpublishable_states": loop.unpublishable,
                           "inputs_dropped_queue_full": loop.queue_full})
        return values

    def _energy(self, snap: Snapshot | None) -> float:
        if snap is None:
            return 0.0
        m = self.scene.model
        return m.kinetic_energy(snap.v) + m.elastic_energy(snap.u)

    def _volume_error(self, snap: Snapshot | None) -> float:
        if snap is None:
            return 0.0
        s = self.scene
        return float(signed_volumes(s.model.rest + snap.u, s.model.mesh.tets).sum()) / s.rest_volume - 1.0

    def _publish_diagnostics(self) -> None:
        if not (self._diag_pub.get_subscription_count() > 0 or self.recorder is not None):
            return
        t0 = time.perf_counter()
        values = self.diagnostics()
        finite = all(np.isfinite(v) for v in values.values() if isinstance(v, float))
        loop = self.physics
        # ERROR while physics is stopped or for ERROR_HOLD_S after a failed step (then WARN: the count stays)
        failed = loop is not None and (loop.stopped or time.perf_counter() - loop.error_at < ERROR_HOLD_S)
        level = "ERROR" if failed else ("OK" if finite and not values["inputs_rejected"] and not self.divergences
                                        and not values.get("physics_failures") else "WARN")
        message = ("physics stopped: " if loop.stopped else "physics failed: ") + loop.error if failed else ""
        values = {k: (v if not isinstance(v, float) or np.isfinite(v) else -1.0) for k, v in values.items()}
        me = self.get_fully_qualified_name().lstrip("/")     # "clusterfem", or "<namespace>/clusterfem"
        msg = diagnostic_array(self._stamp(), f"{me}: simulation", me, values, level, message)
        self._diag_pub.publish(msg)
        data = serialize_message(msg)
        t1 = time.perf_counter()
        self._record(DIAG_TOPIC, data)
        if self.physics is not None:
            self.physics.stages.add("diagnostics", t1 - t0)
            self.physics.stages.add("recording", time.perf_counter() - t1)


def main(args=None) -> None:
    run_node(ClusterFemNode, args)


if __name__ == "__main__":
    main()
