"""The clusterfem node: joint states in; surface Marker, stress PointCloud2, diagnostics (and an MCAP) out.

Physics runs on its own timer, decoupled from message arrival; every output is computed only when
somebody consumes it (a subscriber or the recording). Bad input is counted, warned about (throttled)
and never stops the node; a diverging body is reset, never published.
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

from ..fem.stability import DivergenceError, StabilityError
from ..scene import Scene
from .params import declare_scene_parameters
from .spinning import run_node

SURFACE_TOPIC, STRESS_TOPIC, DIAG_TOPIC, JOINTS_TOPIC = "clusterfem/surface", "clusterfem/stress", "/diagnostics", "joint_states"
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class ClusterFemNode(Node):
    def __init__(self, **node_kwargs):
        super().__init__("clusterfem", **node_kwargs)
        self.config = declare_scene_parameters(self, self._on_live_change)
        c = self.config
        self.scene: Scene | None = None
        self.recorder = None
        self.counts: dict[str, int] = {}      # messages per topic published (outputs) or received (inputs)
        self.divergences = 0
        self.withheld = 0                     # outputs not published: body not yet placed, or a failed check
        self._stats = {"t_wall": time.perf_counter(), "steps": 0}
        self._rtf = 0.0
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
        self._physics_timer = self.create_timer(1.0 / c["physics.timer_hz"], self._on_physics)
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
        from ..recording.replay import PARAMS_FILE
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

    def close(self) -> None:
        """Finalise the recording (idempotent); called on every way out."""
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
        for kind, message in scene.push_joint_state(stamp, names, q, v, now=now_ns * 1e-9):
            if kind == "unknown_joint":
                self.get_logger().warning(message)          # reported once per name by the joint map
            else:
                self.get_logger().warning(f"{message} [{kind}: {scene.inputs.rejected.get(kind, 0)} so far]",
                                          throttle_duration_sec=2.0)
        if self.config["physics.clock"] == "input":
            self._advance(None)

    # -- physics ---------------------------------------------------------------------------------
    def _on_physics(self) -> None:
        """Wall clock: advance to now, 70 % of a timer period at most (slow motion beyond). Input clock:
        nothing here; each joint-state sample steps the scene up to its stamp (Scene.follow_inputs)."""
        if self.scene is None or self.config["physics.clock"] == "input":
            return
        self._advance(self._now(), deadline=time.perf_counter() + 0.7 / self.config["physics.timer_hz"])

    def _advance(self, target: float | None, deadline: float | None = None) -> None:
        """Step to target (None: follow the inputs); a divergence resets the body and is logged."""
        scene = self.scene
        max_steps = self.config["physics.max_catchup_steps"]
        try:
            if target is None:
                scene.follow_inputs(max_steps)
            else:
                scene.advance_to(target, max_steps=max_steps, deadline=deadline)
        except (DivergenceError, StabilityError) as exc:
            self.divergences += 1
            self.get_logger().error(f"{exc}; the body is reset ({self.divergences} resets so far)",
                                    throttle_duration_sec=2.0)
            scene.reset()

    # -- outputs ---------------------------------------------------------------------------------
    def _wanted(self, pub) -> bool:
        """Someone consumes this output and the state may be shown (Scene.output_problem): nothing before the
        body is placed on its skeleton, never a state that fails the checks (counted, and the body reset)."""
        if self.scene is None or self.scene.sim_time is None or not (
                pub.get_subscription_count() > 0 or self.recorder is not None):
            return False
        problem = self.scene.output_problem()
        if problem is None:
            return True
        self.withheld += 1
        if self.scene.placed:           # a state that fails the checks between two ticks' own checks
            self.divergences += 1
            self.get_logger().error(f"output withheld: {problem}; the body is reset ({self.divergences} resets so "
                                    "far)", throttle_duration_sec=2.0)
            self.scene.reset()
        return False

    def _stamp(self):
        return self.get_clock().now().nanoseconds

    def _sim_stamp(self) -> int:
        """Outputs carry the simulated time of the state they show (behind the clock in slow motion)."""
        return int(round(self.scene.sim_time * 1e9))

    def _stress_max(self) -> float:
        return self.config["output.stress_max"] or self.config["material.young_modulus"] / 20.0

    def _publish_surface(self) -> None:
        if not self._wanted(self._marker_pub):
            return
        try:                               # non-finite state or stress: never published
            verts, tris = self.scene.surface()
            vm = self.scene.vertex_von_mises()[self.scene.surface_vertices]
            rgba = map_scalars(vm, self.config["output.colormap"], 0.0, self._stress_max())
            data = surface_marker_cdr(verts, tris, rgba, self.config["output.frame_id"], self._sim_stamp(), "clusterfem", 0)
        except ValueError as exc:
            self.get_logger().error(f"surface not published: {exc}", throttle_duration_sec=2.0)
            return
        self._marker_pub.publish(data)
        self._record(SURFACE_TOPIC, data)

    def _publish_stress(self) -> None:
        if not self._wanted(self._stress_pub):
            return
        try:
            data = stress_cloud_cdr(self.scene.positions(), self.scene.vertex_von_mises(),
                                    self.config["output.frame_id"], self._sim_stamp())
        except ValueError as exc:
            self.get_logger().error(f"stress not published: {exc}", throttle_duration_sec=2.0)
            return
        self._stress_pub.publish(data)
        self._record(STRESS_TOPIC, data)

    def diagnostics(self) -> dict:
        s = self.scene
        now = time.perf_counter()
        if s is not None and now - self._stats["t_wall"] >= 0.5:   # simulated (not dropped) time per wall time
            self._rtf = (s.steps_done - self._stats["steps"]) * s.h / (now - self._stats["t_wall"])
            self._stats = {"t_wall": now, "steps": s.steps_done}
        values = {"steps": s.steps_done if s else 0,
                  "step_ms": (s.last.wall_s / max(s.last.steps, 1) * 1e3) if s else 0.0,
                  "real_time_factor": self._rtf,
                  "substeps": s.last.substeps if s else 0,
                  "stability_margin": s.last.margin if s else 0.0,
                  "energy_J": s.energy() if s else 0.0,
                  "volume_error": s.volume_error() if s else 0.0,
                  "inputs_accepted": s.inputs.accepted if s else 0,
                  "inputs_rejected": s.inputs.total_rejected if s else 0,
                  "resets_after_divergence": self.divergences,
                  "outputs_withheld": self.withheld,
                  "dropped_time_s": s.dropped_s if s else 0.0}
        if s:
            values.update({f"rejected_{k}": n for k, n in sorted(s.inputs.rejected.items())})
        return values

    def _publish_diagnostics(self) -> None:
        if not (self._diag_pub.get_subscription_count() > 0 or self.recorder is not None):
            return
        values = self.diagnostics()
        finite = all(np.isfinite(v) for v in values.values() if isinstance(v, float))
        level = "OK" if finite and not values["inputs_rejected"] and not self.divergences else "WARN"
        values = {k: (v if not isinstance(v, float) or np.isfinite(v) else -1.0) for k, v in values.items()}
        msg = diagnostic_array(self._stamp(), "clusterfem: simulation", "clusterfem", values, level)
        self._diag_pub.publish(msg)
        self._record(DIAG_TOPIC, serialize_message(msg))


def main(args=None) -> None:
    run_node(ClusterFemNode, args)


if __name__ == "__main__":
    main()
