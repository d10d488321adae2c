"""The physics thread's work without the node: what it costs back to back and paced, with the other core idle
and busy. Prints a table; a benchmark, not a test.

    python -m benchmarks.physics_alone [--duration 5] [--rate 120]

The node's headroom (``realtime_benchmark``: simulated seconds per CPU second of its physics thread) is
measured where the thread runs: paced by the wall clock (one step, then a wait for the next, as sim_loop's
wall clock runs it) while the executor, the DDS threads and the player process use the other core. This
command makes the same calls in one thread of its own, without ROS: the default scene, the built-in walk's
joint states at ``--rate`` Hz through ``Scene.take_joint_state``, one step per ``advance_to`` (deadline 0),
and on every new sample what the thread does to hand a state over (the placement check and the copies of a
snapshot; the outputs check it on their side). Four runs of ``--duration`` simulated seconds each:

- back to back: steps as fast as the thread can, the simulated time running ahead of the wall;
- paced: each step waits until its wall time is due (real time), as in the node;

each with the other core idle, and with a busy loop (a second Python process, ``while True: pass``, which
touches no memory) on it. Printed per run: CPU ms per step (the thread's CPU time, ``time.thread_time``),
the headroom it gives (simulated seconds per CPU second), the wall real-time factor and the share of steps the
integrator ran on its threaded build (ThreadChoice picks it where it measures faster, which back to back on
an idle machine it can be: their worker threads' CPU is then not in the thread's time). The differences
between the rows are the host's, not the code's: on a VM whose two vCPUs share a physical core's
resources, or whose clock drops when both are busy, the thread's CPU per step rises with the other core's
load, and a thread that sleeps between steps restarts with colder caches.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np

from .timing import table


def _scene_and_walk():
    from clusterfem_ros.config import default_scene_path, load_scene_file
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.scene import Scene
    scene = Scene.build(load_scene_file(default_scene_path()))
    return scene, load_motion("builtin_walk").trajectory


def run(scene, walk, duration: float, rate: float, paced: bool) -> dict:
    """``duration`` simulated seconds of the physics thread's calls on ``scene`` (module docstring)."""
    from clusterfem_ros.sim_loop import Snapshot
    names, h, period = list(walk.names), scene.h, 1.0 / rate
    t_sim = 0.0 if scene.sim_time is None else scene.sim_time - 1.0      # stamps start at 1 s
    steps = int(round(duration / h))
    next_input = t_sim
    threaded0 = getattr(scene.integrator, "threaded_steps", 0)
    steps0, cpu0, wall0 = scene.steps_done, time.thread_time(), time.perf_counter()
    for k in range(steps):
        if paced:
            wait = wall0 + k * h - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
        fresh = t_sim >= next_input - 1e-9
        if fresh:
            q, v = walk.sample(next_input, loop=True)
            scene.take_joint_state(1.0 + next_input, names, q, v, received=1.0 + next_input)
            next_input += period
        t_sim += h
        scene.advance_to(1.0 + t_sim + 1e-3 * h, 10, deadline=0.0)
        if fresh:
            Snapshot.of_scene(scene, 0, 0.0)
    cpu, wall = time.thread_time() - cpu0, time.perf_counter() - wall0
    n = scene.steps_done - steps0
    threaded = (getattr(scene.integrator, "threaded_steps", 0) - threaded0) / n
    return {"steps": n, "cpu_ms": cpu / n * 1e3, "headroom": n * h / cpu, "rtf": n * h / wall, "threaded": threaded}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=5.0, help="simulated seconds per run (default 5)")
    ap.add_argument("--rate", type=float, default=120.0, help="joint states per second (default 120, the player's)")
    args = ap.parse_args(argv)
    if args.duration <= 0 or args.rate <= 0:
        ap.error(f"--duration {args.duration:g} and --rate {args.rate:g} must be positive")
    print("[bench] building the default scene (compiles the kernels on a fresh machine) ...", flush=True)
    scene, walk = _scene_and_walk()
    run(scene, walk, 0.5, args.rate, paced=False)                     # warm-up
    rows = []
    for other in ("idle", "busy loop"):
        hog = None
        if other != "idle":
            hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
            time.sleep(0.5)
        try:
            for paced in (False, True):
                print(f"[bench] {'paced' if paced else 'back to back'}, other core {other} ...", flush=True)
                r = run(scene, walk, args.duration, args.rate, paced)
                if not np.isfinite(scene.state.u).all():
                    raise SystemExit("[bench] the state is not finite: the run is not a measurement")
                rows.append(["paced (real time)" if paced else "back to back", other, f"{r['cpu_ms']:.3f}",
                             f"{r['headroom']:.2f}", f"{r['rtf']:.2f}", f"{100 * r['threaded']:.0f}"])
        finally:
            if hog is not None:
                hog.kill()
                hog.wait()
    print(f"\n## The physics thread alone: default scene, {args.rate:g} joint states/s, {args.duration:g} s per run\n")
    print(table(["run", "other core", "CPU ms per step", "headroom (sim s per CPU s)", "real-time factor",
                 "threaded steps %"], rows))
    print("\nheadroom: simulated seconds per CPU second of this thread (inputs, skeleton, physics, checks, "
          "snapshot copies), as the node's physics_headroom counts it; a step on the threaded build (chosen by "
          "measured time, ClusteredExplicit's ThreadChoice) leaves its worker threads' CPU out of it")
    return 0


if __name__ == "__main__":
    sys.exit(main())
