"""The main job: a motion played into the simulation node, headless, recorded, summarised.

    scripts/run [--duration 8] [--scene config/default_scene.yaml] [--no-record] [--png bags/jelly_man.png]
    scripts/run --bvh FILE [--scene ...]     # any BVH, on a jelly body built on the BVH's own skeleton

The mocap player runs as its own process, the simulation in this one on a single-threaded executor
(rclpy's multi-threaded one is slower here; shared-memory DDS only). The player plays the built-in walk,
or what the scene file's ``mocap_player: ros__parameters:`` section says (source, file, ...: see
nodes/player_node.py; relative paths are relative to the current directory), or the ``--bvh`` file. A
BVH brings its own skeleton: the node takes it from robot_description (``--bvh`` sets that). A scene
without skeleton (skeleton.source = none) has nothing to play: it runs at once, without a player.
Progress is printed every second; at the end: a summary, the bag folder, and a PNG of the deformed
body coloured by von Mises stress.
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

os.environ.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "SHM")


PLAYER_START_TIMEOUT_S = 60.0


def _player_plan(args, scene_file: Path, config):
    """(player parameters, scene config) for the run: --bvh, else the scene file's player section, else the
    built-in walk; a BVH's skeleton comes on robot_description, so the scene is made to take it from there."""
    from ..motion import load_player_section, skeleton_source_for
    if args.bvh:
        bvh = Path(args.bvh)
        if not bvh.is_file():
            raise SystemExit(f"[demo] --bvh {args.bvh}: no such file")
        player = {"source": "bvh", "file": str(bvh.resolve())}
        config = config.with_values({"skeleton.source": "robot_description", "body.kind": "jelly_man"})
    else:
        player = load_player_section(scene_file) or {"source": "builtin_walk"}
    source = player.get("source", "builtin_walk")
    fits = skeleton_source_for(source)
    if fits == "robot_description" and config["skeleton.source"] in ("builtin", "urdf_file"):
        raise SystemExit(f"[demo] the player plays {source!r} but the scene's skeleton.source is "
                         f"{config['skeleton.source']!r}: set skeleton.source to {fits!r} (or run with --bvh FILE)")
    return player, config


def _player_command(player: dict) -> list[str]:
    cmd = [sys.executable, "-m", "clusterfem_ros.nodes.player_node", "--ros-args"]
    for key, value in player.items():
        if key in ("rate_hz", "speed", "start_offset", "loop_blend"):      # rclpy refuses an int for a double
            text = repr(float(value))
        else:
            text = str(value).lower() if isinstance(value, bool) else str(value)
        cmd += ["-p", f"{key}:={text}"]
    return cmd + ["--log-level", "warn"]


def _wait_for_first_input(sim, player: subprocess.Popen) -> None:
    """Hold the timed run until the player's first joint state has arrived: its process start (imports,
    kernels) took 1-3 s on a fresh clone, which would otherwise eat into --duration with a body at rest."""
    t0 = time.perf_counter()
    while sim.diagnostics()["inputs_accepted"] == 0:
        if player.poll() is not None:
            raise SystemExit(f"[demo] the mocap player exited with code {player.returncode} before sending a "
                             "joint state: run `python -m clusterfem_ros.nodes.player_node` to see why")
        if time.perf_counter() - t0 > PLAYER_START_TIMEOUT_S:
            received = sim.counts.get("joint_states", 0)
            if received:
                rejected = dict(sim.scene.inputs.rejected) if sim.scene is not None else {}
                raise SystemExit(f"[demo] {received} joint states arrived in {PLAYER_START_TIMEOUT_S:g} s but none was "
                                 f"used (rejected: {rejected}): the player's joints do not fit this scene's skeleton "
                                 "(a BVH needs skeleton.source robot_description); the node's warnings above name them")
            if sim.scene is None:
                raise SystemExit(f"[demo] no skeleton on robot_description within {PLAYER_START_TIMEOUT_S:g} s: the "
                                 "player latches it at its start; run `python -m clusterfem_ros.nodes.player_node` "
                                 "to see why it did not")
            raise SystemExit(f"[demo] no joint state from the player within {PLAYER_START_TIMEOUT_S:g} s: check that "
                             "both processes share ROS_DOMAIN_ID and FASTDDS_BUILTIN_TRANSPORTS (scripts/env.sh)")
        time.sleep(0.05)
    print(f"[demo] first joint state from the player after {time.perf_counter() - t0:.1f} s: the timed run starts",
          flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=8.0, help="seconds of wall time to run (default 8)")
    ap.add_argument("--scene", default=None, help="scene parameter file (default: config/default_scene.yaml)")
    ap.add_argument("--bvh", default=None, metavar="FILE", help="play this BVH file on a jelly body built on its "
                    "own skeleton (skeleton.source robot_description)")
    ap.add_argument("--no-record", action="store_true", help="do not record an MCAP bag")
    ap.add_argument("--bags", default="bags", help="folder for the recording (default bags/)")
    ap.add_argument("--png", default=None, help="picture of the final state (default: <bag folder>/final_state.png)")
    args = ap.parse_args(argv)

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from ..config import default_scene_path, load_scene_file
    from .clusterfem_node import ClusterFemNode
    from ..render import render_surface_png

    scene_file = Path(args.scene) if args.scene else default_scene_path()
    config = load_scene_file(scene_file)           # validated here, with a clear error, before ROS starts
    try:
        player_params, config = _player_plan(args, scene_file, config)
    except ValueError as exc:
        raise SystemExit(f"[demo] {exc}") from None
    overrides = [Parameter(k, value=v) for k, v in config.values.items()]
    overrides += [Parameter("recording.enabled", value=not args.no_record), Parameter("recording.dir", value=args.bags)]
    print(f"[demo] scene {scene_file}: body {config['body.kind']}, method {config['method']}, "
          f"warping {config['warping']}, h = {config['physics.step']:g} s; ROS_DOMAIN_ID="
          f"{os.environ.get('ROS_DOMAIN_ID', '0')}, DDS transport {os.environ['FASTDDS_BUILTIN_TRANSPORTS']}", flush=True)
    if config["skeleton.source"] != "none":
        print(f"[demo] player: {', '.join(f'{k} {v}' for k, v in player_params.items())}; skeleton from "
              f"{config['skeleton.source']}", flush=True)
    rclpy.init()
    sim = player = spin = None
    executor = SingleThreadedExecutor()
    driven = config["skeleton.source"] != "none"
    try:
        t_build = time.perf_counter()
        sim = ClusterFemNode(parameter_overrides=overrides)
        print(f"[demo] simulation ready in {time.perf_counter() - t_build:.1f} s", flush=True)
        if driven:
            player = subprocess.Popen(_player_command(player_params))
        executor.add_node(sim)
        spin = threading.Thread(target=executor.spin, daemon=True)
        spin.start()
        if driven:
            _wait_for_first_input(sim, player)
        else:
            print("[demo] the scene has no skeleton (skeleton.source = none): no mocap player; the body moves under "
                  "gravity and its anchors", flush=True)
        t0 = time.perf_counter()
        last_steps, last_wall = 0, 0.0
        while time.perf_counter() - t0 < args.duration:
            time.sleep(1.0)
            d = sim.diagnostics()
            wall = sim.scene.step_wall_s                # the second's own mean step, not the last tick's
            step_ms = (wall - last_wall) / max(d["steps"] - last_steps, 1) * 1e3
            print(f"[demo] t = {time.perf_counter() - t0:4.1f} s  steps {d['steps']:6d} (+{d['steps'] - last_steps})  "
                  f"step {step_ms:.3f} ms  RTF {d['real_time_factor']:.2f}  sub-steps {d['substeps']}  "
                  f"volume error {d['volume_error'] * 100:+.2f} %  inputs {d['inputs_accepted']} ok / "
                  f"{d['inputs_rejected']} rejected", flush=True)
            last_steps, last_wall = d["steps"], wall
        executor.shutdown(timeout_sec=5.0)
        spin.join(timeout=10.0)
        spin = None
        d = sim.diagnostics()
        scene = sim.scene
        verts, tris = scene.surface()
        vm = scene.vertex_von_mises()
        bag = getattr(sim, "recording_path", None)
        sim.close()
        png = Path(args.png) if args.png else (Path(bag) / "final_state.png" if bag else Path(args.bags) / "final_state.png")
        render_surface_png(png, verts, tris, vm[scene.surface_vertices],
                           title=f"{config['body.kind']} after {scene.sim_time - scene.start_time:.2f} s "
                                 f"({config['method']}, warping {config['warping']})")
        print("\n[demo] summary")
        print(f"  body            {scene.model.mesh.n_tets} tets, {scene.model.n_vertices} vertices")
        mean_ms = scene.step_wall_s / max(scene.steps_done, 1) * 1e3
        print(f"  physics steps   {d['steps']} of {scene.h * 1e3:g} ms; mean step {mean_ms:.3f} ms over the run; "
              f"real-time factor {d['real_time_factor']:.2f}")
        print(f"  stability       sub-steps {d['substeps']}, margin {d['stability_margin']:.2f}")
        print(f"  volume error    {d['volume_error'] * 100:+.3f} %;  energy {d['energy_J']:.4g} J")
        print(f"  inputs          {d['inputs_accepted']} joint states used, {d['inputs_rejected']} rejected, "
              f"{d['resets_after_divergence']} resets after divergence")
        print(f"  recording       {bag or 'off'}")
        print(f"  picture         {png}")
        return 0
    finally:
        if spin is not None:                    # an early exit: stop spinning before the node goes, or the
            executor.shutdown(timeout_sec=5.0)  # executor thread dies with the process ("terminate called")
            spin.join(timeout=10.0)
        if player is not None and player.poll() is None:
            player.send_signal(signal.SIGINT)
            try:
                player.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                player.kill()
        if sim is not None:
            sim.close()
            sim.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
