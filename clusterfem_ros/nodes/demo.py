"""The main job: a motion played into the simulation node, headless, recorded, summarised.

    scripts/run [--duration 8] [--scene config/default_scene.yaml] [--no-record] [--png bags/jelly_man.png]
                [--no-video]
    scripts/run --bvh FILE [--scene ...]     # any BVH, on a jelly body built on the BVH's own skeleton, or on the
                                             # scene's character (body.kind surface) fitted to that skeleton
    scripts/run --source NAME [--file FILE]  # any registered motion source (motion.MOTION_SOURCES; --help lists
                                             # them), the scene's skeleton made to fit it; --bvh F: --source bvh --file F
    scripts/run --bodies 2 [--process-per-body] [--scene a.yaml --scene b.yaml]
    scripts/run --scene config/character_walk.yaml --set body.surface_file=meshes/cesium_man.glb   # any parameter

The mocap player runs as its own process, the simulation in this one on a single-threaded executor
(rclpy's multi-threaded one is slower here; DDS discovery on this host only, nodes.spinning.default_discovery:
``ros2 topic echo`` and other ROS tools started with their defaults on this host see the topics). The player plays the built-in walk,
or what the scene file's ``mocap_player: ros__parameters:`` section says (source, file, ...: see
nodes/player_node.py; its file a path or a name under $CLUSTERFEM_DATA or ../shared/data), or ``--source`` (and
its ``--file``), or the ``--bvh`` file. The scene's skeleton.source is made to fit the source played
(``MotionSource.skeleton_source``), said in one line: a BVH brings its own skeleton, which the node takes from
robot_description; a joint sweep's URDF file is the node's skeleton.urdf_file. A scene
without skeleton (skeleton.source = none) has nothing to play: it runs at once, without a player.
Progress is printed every second; at the end: a summary, the bag folder, a PNG of the deformed
body coloured by von Mises stress, the recording rendered to run.mp4 and run.gif in the bag folder, then a table of the timed run (nodes/bodies.py): real-time factor,
physics headroom, joint-state -> marker latency, busy share per stage, RSS.

With ``--bodies N`` each body is a node in its own namespace (body1, ...) with its own player process,
scene file and recording, all on this process's executor, or each in a process of its own
(``--process-per-body``).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from .spinning import PARAMETERS_DOC, default_discovery   # before rclpy starts; the player's process inherits it

DDS_NOTE = default_discovery()


PLAYER_START_TIMEOUT_S = 60.0
LIVE_PORT = 8765            # Foxglove's default WebSocket port


def _wait_for_first_input(sim, player: subprocess.Popen, delay_s: float = 0.0) -> None:
    """Hold the timed run until the player's first joint state has arrived: its process start (imports,
    kernels) took 1-3 s on a fresh clone, which would otherwise eat into --duration with a body at rest."""
    t0 = time.perf_counter()
    while sim.diagnostics()["inputs_accepted"] == 0:
        if sim.scene is None and sim.build_error is not None:     # the player's skeleton does not fit the scene
            raise SystemExit(f"[demo] {sim.build_error}")
        if player.poll() is not None:
            raise SystemExit(f"[demo] the mocap player exited with code {player.returncode} before sending a "
                             "joint state: run `python -m clusterfem_ros.nodes.player_node` to see why")
        if getattr(sim, "building", False):     # the skeleton came; the body is being meshed (once: cached)
            t0 = time.perf_counter()
        if time.perf_counter() - t0 > PLAYER_START_TIMEOUT_S + delay_s:     # delay_s: the player's start_delay
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
                             "both processes share ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE (scripts/env.sh)")
        time.sleep(0.05)
    print(f"[demo] first joint state from the player after {time.perf_counter() - t0:.1f} s: the timed run starts",
          flush=True)


def _dds_setting() -> str:
    """The DDS variables this run goes by, as a user would repeat them in another shell."""
    shown = [f"{k}={os.environ[k]}" for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS",
                                             "FASTDDS_BUILTIN_TRANSPORTS", "FASTDDS_DEFAULT_PROFILES_FILE")
             if os.environ.get(k)]
    return "DDS " + (" ".join(shown) or "defaults")


def _say(line: str) -> None:
    print(f"[demo] {line}", flush=True)


def _played_source(args) -> tuple[str | None, str]:
    """(the motion source the options name, its file): ``--bvh F`` is ``--source bvh --file F``; (None, '') when
    neither is given (the scene file's player section plays)."""
    if args.bvh:
        if args.source not in (None, "bvh") or args.file:
            raise SystemExit(f"[demo] --bvh {args.bvh} plays source 'bvh' from that file: give it alone, or "
                             "--source NAME --file FILE instead")
        return "bvh", args.bvh
    if args.file and not args.source:
        raise SystemExit(f"[demo] --file {args.file} needs --source NAME: the motion source that reads it")
    return args.source, args.file or ""


def fit_skeleton(config, source, file: str | None, say=_say):
    """The scene ``config`` with the skeleton the motion ``source`` (a motion.MotionSource) plays on, said in one
    line: its own skeleton on robot_description (a BVH's, for a jelly body or the scene's character), the URDF file
    it reads (skeleton.urdf_file), or the built-in humanoid."""
    from ..motion import on_capture_skeleton
    fits, now = source.skeleton_source, config.skeleton.source
    if fits == "robot_description":
        # a BVH's frame 0 may be the bind pose (motion.capture_bind_pose); another source's skeleton binds at rest
        config = on_capture_skeleton(config, file if source.file_kind == ".bvh" else None, say)
    elif fits == "urdf_file":
        config = config.with_values({"skeleton.source": "urdf_file", "skeleton.urdf_file": file})
    else:
        config = config.with_values({"skeleton.source": fits})
    if config.skeleton.source != now or fits == "urdf_file":
        say(f"source {source.name!r} plays on skeleton.source {config.skeleton.source!r}"
            + (f" ({file})" if fits == "urdf_file" else "") + f"; the scene had {now!r}")
    return config


def _player_plan(args, scene_file: Path, config):
    """(player parameters, scene config) for the run: --source / --bvh, else the scene file's player section, else
    the built-in walk; the scene's skeleton is made to fit a source given on the command line (``fit_skeleton``)."""
    from ..body.fit import FitError, find_data_file
    from ..motion import MOTION_SOURCES, load_player_section, skeleton_source_for
    name, file = _played_source(args)
    if name is not None:
        kind = MOTION_SOURCES[name]
        player = {"source": name}
        if kind.file_kind is None and file:
            raise SystemExit(f"[demo] --source {name} plays no file ({kind.description}): drop --file {file}")
        if kind.file_kind is not None:
            if not file:
                raise SystemExit(f"[demo] --source {name} needs --file: a {kind.file_kind} file")
            try:
                player["file"] = file = str(find_data_file(file, what=f"--source {name}: --file").resolve())
            except FitError as exc:
                raise SystemExit(f"[demo] {exc}") from None
        config = fit_skeleton(config, kind, file or None)
    else:
        player = load_player_section(scene_file) or {"source": "builtin_walk"}
    source = player.get("source", "builtin_walk")
    fits = skeleton_source_for(source)
    if fits == "robot_description" and config.skeleton.source in ("builtin", "urdf_file"):
        raise SystemExit(f"[demo] the player plays {source!r} but the scene's skeleton.source is "
                         f"{config.skeleton.source!r}: set skeleton.source to {fits!r} (or run with --source "
                         f"{source} --file FILE)")
    if source == "bvh":                         # the scene's unit and up axis of its capture, unless the player's own
        player.setdefault("unit", config.skeleton.bvh_unit)
        player.setdefault("up", config.skeleton.bvh_up)
    if name is None and player.get("file"):     # looked up as motion.load_motion does, here so that a missing
        try:                                    # file stops the run before the player starts
            player["file"] = str(find_data_file(str(player["file"]), what="the player's file"))
        except FitError as exc:
            raise SystemExit(f"[demo] {scene_file}: {exc}") from None
    return player, config


def _source_help() -> str:
    from ..motion import MOTION_SOURCES
    return "; ".join(f"{m.name}: {m.description}" + (f" (--file {m.file_kind})" if m.file_kind else "")
                     for m in MOTION_SOURCES.values())


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=f"Scene and player parameters (what --scene files hold): {PARAMETERS_DOC}.")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds of wall time to run (default 8)")
    ap.add_argument("--scene", default=None, action="append",
                    help="scene parameter file (default: config/default_scene.yaml); once for every body, or once "
                         "per body with --bodies")
    from ..motion import MOTION_SOURCES
    ap.add_argument("--source", default=None, metavar="NAME", choices=tuple(MOTION_SOURCES),
                    help="play this motion source instead of the scene's player section, the scene's skeleton made "
                         f"to fit it: {_source_help()}")
    ap.add_argument("--file", default=None, metavar="FILE", help="the file --source plays: a path, "
                    "package://<package>/<path>, or a name under $CLUSTERFEM_DATA or ../shared/data")
    ap.add_argument("--bvh", default=None, metavar="FILE", help="--source bvh --file FILE: play this BVH file on a "
                    "jelly body built on its own skeleton, or on the scene's surface body fitted to it "
                    "(skeleton.source robot_description)")
    ap.add_argument("--set", default=[], action="append", metavar="KEY=VALUE",
                    help="a scene parameter changed on top of the --scene file (every body's), the value read as YAML "
                         "(repeat for more): e.g. --set body.surface_file=meshes/cesium_man.glb to put another "
                         "character in config/character_walk.yaml")
    ap.add_argument("--no-record", action="store_true", help="do not record an MCAP bag")
    ap.add_argument("--bags", default="bags", help="folder for the recording (default bags/)")
    ap.add_argument("--png", default=None, help="picture of the final state (default: <bag folder>/final_state.png)")
    ap.add_argument("--no-video", action="store_true", help="do not render the recording to run.mp4 / run.gif")
    ap.add_argument("--live", type=int, nargs="?", const=LIVE_PORT, default=0, metavar="PORT",
                    help=f"serve the topics to Foxglove over its WebSocket protocol on 127.0.0.1:PORT (default "
                         f"{LIVE_PORT}; body k of --bodies on PORT + k - 1): Open connection, ws://127.0.0.1:PORT, "
                         "layout config/foxglove_layout.json")
    _body_arguments(ap)
    return ap.parse_args(argv)


def _body_arguments(ap: argparse.ArgumentParser) -> None:
    """Several bodies (nodes/bodies.py) and the run's measurements."""
    ap.add_argument("--bodies", type=int, default=1, help="bodies to run, each in its own namespace (body1, ...) "
                    "with its own player, joint_states, outputs and recording (default 1)")
    ap.add_argument("--process-per-body", action="store_true",
                    help="run each body as a process of its own (default: all as nodes of this process, one executor)")
    ap.add_argument("--namespace", default="", help="namespace of the body (of the bodies' namespaces with --bodies)")
    ap.add_argument("--walk-offset", type=float, default=0.0, help="start this far into the built-in walk [s]")
    ap.add_argument("--no-png", action="store_true", help="no picture of the final state")
    ap.add_argument("--summary-json", default=None, help="also write the summary to this JSON file")


def _child_argv(args: argparse.Namespace, scene: Path) -> list[str]:
    """The demo arguments of a body's own process (--process-per-body)."""
    out = ["--duration", f"{args.duration:g}", "--bags", args.bags, "--no-png", "--scene", str(scene)]
    out += ["--bvh", args.bvh] if args.bvh else []
    out += ["--source", args.source] if args.source else []
    out += ["--file", args.file] if args.file else []
    out += [a for pair in args.set for a in ("--set", pair)]
    return out + (["--no-record"] if args.no_record else []) + (["--no-video"] if args.no_video else [])


def _with_sets(config, pairs: list[str]):
    """``config`` with the --set KEY=VALUE pairs applied (values read as YAML); SystemExit naming a bad one."""
    import yaml
    values = {}
    for pair in pairs:
        key, eq, text = pair.partition("=")
        if not eq or not key.strip():
            raise SystemExit(f"[demo] --set {pair!r}: give KEY=VALUE, e.g. --set body.target_tets=3000")
        try:
            values[key.strip()] = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise SystemExit(f"[demo] --set {pair!r}: the value is not YAML ({exc.__class__.__name__})") from None
    try:
        return config.with_values(values) if values else config
    except (ValueError, TypeError) as exc:                 # ConfigError: the name, the value and the range
        raise SystemExit(f"[demo] --set: {exc}") from None


def _scene_files(args: argparse.Namespace, n: int) -> list[Path]:
    from ..config import default_scene_path
    files = [Path(f) for f in args.scene] if args.scene else [default_scene_path()]
    if len(files) not in (1, n):
        raise SystemExit(f"[demo] {len(files)} --scene files for {n} bodies: give one for all or one per body")
    return files * n if len(files) == 1 else files


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    if args.bodies > 1 and args.process_per_body:
        from .bodies import run_process_per_body
        scenes = _scene_files(args, args.bodies)
        return run_process_per_body(args, lambda k: _child_argv(args, scenes[k]) + (
            ["--live", str(args.live + k)] if args.live else []))

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from ..config import load_scene_file
    from .bodies import WALK_PHASE_S, RunWindow, body_namespaces, print_summary, rss_growth, rss_mb, start_player
    from .clusterfem_node import ClusterFemNode

    names = body_namespaces(args.bodies, args.namespace)
    scenes = _scene_files(args, len(names))
    plans = [_player_plan(args, f, _with_sets(load_scene_file(f), args.set))   # validated here, before ROS starts
             for f in scenes]
    configs = [config for _, config in plans]
    for ns, f, (player_params, config) in zip(names, scenes, plans):
        print(f"[demo] {ns or 'scene'} {f}: body {config.body.kind}, method {config.method}, "
              f"warping {config.warping}, h = {config.physics.step:g} s; ROS_DOMAIN_ID="
              f"{os.environ.get('ROS_DOMAIN_ID', '0')}, {_dds_setting()}",
              flush=True)
        if config.skeleton.source != "none":
            print(f"[demo] player: {', '.join(f'{k} {v}' for k, v in player_params.items())}; skeleton from "
                  f"{config.skeleton.source}", flush=True)
        if player_params.get("source") == "bvh":             # what the player (logging warnings only) decides
            from ..skeleton.bvh import load_bvh
            try:
                capture = load_bvh(player_params["file"], player_params.get("unit", "auto"),
                                   player_params.get("up", "auto"))
            except ValueError as exc:
                raise SystemExit(f"[demo] {exc}") from None
            print(f"[demo] {capture.placement}", flush=True)
    rclpy.init()
    sims, players, delays, spin = [], [], [], None
    executor = SingleThreadedExecutor()
    try:
        t_build = time.perf_counter()
        for k, (ns, config) in enumerate(zip(names, configs)):
            overrides = [Parameter(key, value=v) for key, v in config.values.items()]
            overrides += [Parameter("recording.enabled", value=not args.no_record),
                          Parameter("recording.dir", value=args.bags)]
            if ns:
                overrides.append(Parameter("recording.prefix", value="clusterfem_" + ns.replace("/", "_")))
            if args.live:
                overrides.append(Parameter("output.live_port", value=args.live + k))
            sims.append(ClusterFemNode(parameter_overrides=overrides, **({"namespace": ns} if ns else {})))
            if config.skeleton.source != "none":
                player_params = dict(plans[k][0])
                offset = args.walk_offset + (k * WALK_PHASE_S if len(names) > 1 else 0.0)
                if offset:
                    player_params["start_offset"] = float(player_params.get("start_offset", 0.0)) + offset
                players.append((sims[-1], start_player(ns, player_params)))
                delays.append(float(player_params.get("start_delay", 0.0)))
        print(f"[demo] simulation ready in {time.perf_counter() - t_build:.1f} s", flush=True)
        for sim in sims:
            executor.add_node(sim)
        spin = threading.Thread(target=executor.spin, daemon=True)
        spin.start()
        for (sim, player), delay in zip(players, delays):
            _wait_for_first_input(sim, player, delay)
        if not players:
            print("[demo] the scene has no skeleton (skeleton.source = none): no mocap player; the body moves under "
                  "gravity and its anchors", flush=True)
        windows = [RunWindow(sim) for sim in sims]
        for w in windows:
            w.start()
        t0 = time.perf_counter()
        rss = [(0.0, rss_mb())]
        last = [(0, 0.0)] * len(sims)
        while time.perf_counter() - t0 < args.duration:
            time.sleep(1.0)
            rss.append((time.perf_counter() - t0, rss_mb()))
            for w in windows:
                w.sample()
            for k, sim in enumerate(sims):
                last[k] = _progress(sim, names[k], time.perf_counter() - t0, *last[k], rss[-1][1])
        executor.shutdown(timeout_sec=5.0)
        spin.join(timeout=10.0)
        spin = None
        results = [w.result() for w in windows]
        for sim in sims:
            sim.stop_physics()                 # the scenes are still from here on
        memory = rss_growth(rss, warm_up_s=min(5.0, args.duration / 4))
        for sim, ns, result in zip(sims, names, results):
            _final(sim, ns, args, result)
        print_summary(results, memory, "timed run, all bodies in this process")
        if args.summary_json:
            Path(args.summary_json).write_text(json.dumps({"mode": "one_process", "bodies": results, "rss": memory},
                                                          indent=1))
        return 0
    finally:
        if spin is not None:                    # an early exit: stop spinning before the node goes, or the
            executor.shutdown(timeout_sec=5.0)  # executor thread dies with the process ("terminate called")
            spin.join(timeout=10.0)
        for _, player in players:
            if player.poll() is None:
                player.send_signal(signal.SIGINT)
        for _, player in players:
            try:
                player.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                player.kill()
        for sim in sims:
            sim.close()
            sim.destroy_node()
        rclpy.try_shutdown()


def _progress(sim, ns: str, t: float, last_steps: int, last_wall: float, rss: float) -> tuple[int, float]:
    """One progress line of a body; returns its (steps, step wall time) for the next."""
    d = sim.diagnostics()
    wall = sim.scene.step_wall_s                # the second's own mean step, not the last tick's
    step_ms = (wall - last_wall) / max(d["steps"] - last_steps, 1) * 1e3
    print(f"[demo{' ' + ns if ns else ''}] t = {t:4.1f} s  steps {d['steps']:6d} (+{d['steps'] - last_steps})  "
          f"step {step_ms:.3f} ms  RTF {d['real_time_factor']:.2f}  headroom {d.get('physics_headroom', 0.0):.2f}  "
          f"latency p99 {d.get('latency_p99_ms', 0.0):.1f} ms  sub-steps {d['substeps']}  "
          f"volume error {d['volume_error'] * 100:+.2f} %  inputs {d['inputs_accepted']} ok / "
          f"{d['inputs_rejected']} rejected  RSS {rss:.0f} MB", flush=True)
    return d["steps"], wall


def _png_scale(bag) -> tuple[float | None, str]:
    """(top of the picture's stress scale [Pa], colour bar label): the run's scale, as its video has it
    (run_stress), when the run was recorded; else None (the picture's own 99th percentile)."""
    from ..bag_frames import read_bag_frames
    from ..run_stress import LABEL, run_stress_of
    stress = run_stress_of(read_bag_frames(bag)) if bag else None
    if stress is None:
        return None, f"{LABEL}, 0 to the 99th percentile of this state"
    return stress.vmax, f"{LABEL}, 0 to the {stress.percentile:g}th percentile of the run"


def _final(sim, ns: str, args: argparse.Namespace, result: dict) -> None:
    """A body's closing lines and its picture (the physics thread is stopped: the scene is still); ``result`` is
    its timed run (bodies.RunWindow.result), which the summary reports."""
    from ..render import render_surface_png
    d = sim.diagnostics()
    scene, config = sim.scene, sim.config
    bag = getattr(sim, "recording_path", None)
    sim.close()
    png = None
    timed_s = result["steps"] * scene.h              # simulated time of the timed run
    if not args.no_png:
        verts, tris = scene.surface()
        vm = scene.vertex_von_mises()
        default = Path(args.bags) / (f"final_state_{ns.replace('/', '_')}.png" if ns else "final_state.png")
        png = Path(args.png) if args.png and not ns else (Path(bag) / "final_state.png" if bag else default)
        vmax, label = _png_scale(bag)
        render_surface_png(png, verts, tris, vm[scene.surface_vertices], vmax=vmax, label=label,
                           title=f"{config.body.kind} at the end of a {result['seconds']:.1f} s run: {timed_s:.2f} s "
                                 f"simulated ({config.method}, warping {config.warping})")
    print(f"\n[demo] summary{' of ' + ns if ns else ''}")
    print(f"  body            {scene.model.mesh.n_tets} tets, {scene.model.n_vertices} vertices")
    print(f"  physics steps   {result['steps']} of {scene.h * 1e3:g} ms in the {result['seconds']:.1f} s timed run; "
          f"mean step {result['mean_step_ms']:.3f} ms; real-time factor {result['real_time_factor']:.2f}")
    if d.get("dropped_time_s", 0.0) > 0:
        print(f"  behind          {d['dropped_time_s']:.1f} s of simulated time dropped: physics fell more than "
              f"physics.max_catchup_steps behind its inputs and the body was put back on the skeleton")
    print(f"  stability       sub-steps {d['substeps']} (a step: {d.get('substeps_mean', 0.0):.3f} since the start), "
          f"margin {d['stability_margin']:.2f}")
    print(f"  volume error    {d['volume_error'] * 100:+.3f} %;  energy {d['energy_J']:.4g} J")
    print(f"  inputs          {d['inputs_accepted']} joint states used, {d['inputs_rejected']} rejected, "
          f"{d['resets_after_divergence']} resets after divergence, {d.get('physics_failures', 0)} physics failures")
    print(f"  recording       {bag or 'off'}")
    print(f"  picture         {png or 'off'}")
    if bag and not args.no_video:
        from ..render import render_bag
        mp4, gif = render_bag(bag)
        print(f"  video           {mp4} and {gif}")


if __name__ == "__main__":
    sys.exit(main())
