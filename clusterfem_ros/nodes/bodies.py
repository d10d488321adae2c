"""Running several bodies and measuring a timed run: what the demo's ``--bodies N`` and the real-time
benchmark share. No physics here: namespaces, player processes, run windows, summaries, child processes.

Each body is a ClusterFemNode in its own namespace (``body1``, ``body2``, ...) with its own ``joint_states``,
outputs, scene file and recording, driven by its own mocap player process (the built-in walk, each body at
another phase of it). ``--process-per-body`` runs each body as a child demo process instead of a node of
this one; the children write their summaries as JSON and this process prints the total.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

WALK_PHASE_S = 0.7          # body k starts k * this far into the built-in walk: the bodies do not move alike


def body_namespaces(n: int, namespace: str = "") -> list[str]:
    """'' (no namespace) for one body unless one is given; body1..bodyN (under ``namespace``) for several."""
    if n < 1:
        raise ValueError(f"--bodies {n}: run at least one body")
    if n == 1:
        return [namespace.strip("/")]
    base = namespace.strip("/")
    return [f"{base}/body{k + 1}" if base else f"body{k + 1}" for k in range(n)]


def start_player(namespace: str, params: dict) -> subprocess.Popen:
    """The mocap player, with ``params`` (source, file, start_offset, ...: nodes/player_node.py), playing on
    ``<namespace>/joint_states`` in a process of its own."""
    from ..motion import check_player_value
    cmd = [sys.executable, "-m", "clusterfem_ros.nodes.player_node", "--ros-args"]
    for key, value in params.items():
        value = check_player_value(key, value)          # typed as the player's table says: a float stays a float
        text = str(value).lower() if isinstance(value, bool) else repr(value) if isinstance(value, float) else value
        cmd += ["-p", f"{key}:={text}"]
    if namespace:
        cmd += ["-r", f"__ns:=/{namespace}"]
    return subprocess.Popen(cmd + ["--log-level", "warn"])


def rss_mb() -> float:
    """Resident memory of this process [MB] (Linux /proc)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


class RunWindow:
    """What one body did between ``start()`` and ``result()``: steps, real-time factor, headroom, latency,
    busy share per stage (seconds per wall second) and the process's CPU share."""

    def __init__(self, sim):
        self.sim = sim
        self.waiting_max = 0             # joint states queued for the physics thread, the most seen by sample()

    def sample(self) -> None:
        """Look at what may grow during the run (called every second): the physics thread's input queue."""
        self.waiting_max = max(self.waiting_max, self.sim.physics.waiting)

    def start(self) -> None:
        s, loop = self.sim.scene, self.sim.physics
        self.t0, self.cpu0 = time.perf_counter(), time.process_time()
        self.steps0, self.wall0, self.busy0, self.thread_cpu0 = s.steps_done, s.step_wall_s, loop.busy_s(), loop.cpu_s()
        self.stages0 = dict(loop.stages.totals)
        self.inputs0 = s.inputs.accepted
        self.threaded0 = getattr(s.integrator, "threaded_steps", 0)
        loop.latency.restart()

    def result(self) -> dict:
        s, loop = self.sim.scene, self.sim.physics
        elapsed = time.perf_counter() - self.t0
        steps = s.steps_done - self.steps0
        wall = s.step_wall_s - self.wall0
        busy = loop.busy_s() - self.busy0
        cpu = loop.cpu_s() - self.thread_cpu0
        m = s.model
        return {"namespace": self.sim.get_namespace(), "tets": int(m.mesh.n_tets), "vertices": int(m.n_vertices),
                "h": s.h, "seconds": elapsed, "steps": steps, "real_time_factor": steps * s.h / elapsed,
                "mean_step_ms": wall / max(steps, 1) * 1e3,
                "headroom": steps * s.h / cpu if cpu > 0 else 0.0,
                "headroom_in_node": steps * s.h / busy if busy > 0 else 0.0,
                # the headroom counts the physics thread's CPU: a threaded step's workers are not in it
                "threaded_steps": (getattr(s.integrator, "threaded_steps", 0) - self.threaded0) / max(steps, 1),
                "tet_steps_per_s": m.mesh.n_tets * steps / elapsed,
                **loop.latency.percentiles(), "latencies": loop.latency.count,
                "shares": {k: (v - self.stages0[k]) / elapsed for k, v in loop.stages.totals.items()},
                "process_cpu": (time.process_time() - self.cpu0) / elapsed,
                "inputs_used": s.inputs.accepted - self.inputs0, "inputs_rejected": s.inputs.total_rejected,
                "resets": self.sim.divergences, "physics_failures": loop.crashes,
                "dropped_s": s.dropped_s, "late_jumps": s.late_jumps,
                "inputs_waiting_max": self.waiting_max, "inputs_dropped_queue_full": loop.queue_full}


def rss_growth(samples: list[tuple[float, float]], warm_up_s: float) -> dict:
    """RSS at the end of the warm-up, at the end, its peak after the warm-up and the growth from warm-up [%]."""
    after = [mb for t, mb in samples if t >= warm_up_s] or [samples[-1][1]]
    base = after[0]
    return {"rss_warm_mb": base, "rss_end_mb": after[-1], "rss_peak_mb": max(after),
            "rss_growth_pct": (max(after) / base - 1.0) * 100.0, "rss_samples": samples}


def print_summary(results: list[dict], rss: dict | None, label: str) -> None:
    """One line per body and the total: what the benchmark and the demo print."""
    print(f"\n[demo] {label}: {len(results)} bod{'y' if len(results) == 1 else 'ies'}")
    print("  body          tets  steps   RTF  headroom  latency p50/p99/max ms   physics skeleton stress markers "
          "recording  process CPU")
    for r in results:
        sh = r["shares"]
        print(f"  {r['namespace']:<12} {r['tets']:5d} {r['steps']:6d} {r['real_time_factor']:5.2f} {r['headroom']:9.2f}"
              f"  {r['latency_p50_ms']:6.1f} / {r['latency_p99_ms']:5.1f} / {r['latency_max_ms']:5.1f}   "
              f"{sh['physics']:7.3f} {sh['skeleton']:8.3f} {sh['stress']:6.3f} {sh['markers']:7.3f} "
              f"{sh['recording']:9.3f}  {r['process_cpu']:6.2f}")
    total = sum(r["tet_steps_per_s"] for r in results)
    print(f"  aggregate     {total / 1e6:.2f} M tet-steps/s; lowest real-time factor "
          f"{min(r['real_time_factor'] for r in results):.2f}")
    if rss:
        print(f"  memory        RSS {rss['rss_warm_mb']:.0f} MB after warm-up, {rss['rss_end_mb']:.0f} MB at the end, "
              f"peak {rss['rss_peak_mb']:.0f} MB ({rss['rss_growth_pct']:+.1f} %)")


def run_process_per_body(args, child_argv: Callable[[int], list[str]]) -> int:
    """``args.bodies`` child demo processes, one body each (own namespace, player and walk phase); their JSON
    summaries are gathered and the total printed (and written to ``args.summary_json``)."""
    import tempfile
    names = body_namespaces(args.bodies, args.namespace)
    with tempfile.TemporaryDirectory(prefix="clusterfem_bodies_") as tmp:
        children = []
        for k, ns in enumerate(names):
            out = Path(tmp) / f"body{k + 1}.json"
            cmd = [sys.executable, "-m", "clusterfem_ros.nodes.demo", *child_argv(k), "--bodies", "1",
                   "--namespace", ns, "--walk-offset", f"{k * WALK_PHASE_S:g}", "--summary-json", str(out)]
            children.append((subprocess.Popen(cmd), out))
        codes = [p.wait() for p, _ in children]
        if any(codes):
            print(f"[demo] body processes exited with {codes}", flush=True)
            return 1
        summaries = [json.loads(out.read_text()) for _, out in children]
    results = [r for s in summaries for r in s["bodies"]]
    print_summary(results, None, "one process per body")
    for s in summaries:
        print(f"  {s['bodies'][0]['namespace']:<12} RSS {s['rss']['rss_warm_mb']:.0f} -> {s['rss']['rss_end_mb']:.0f} MB")
    if args.summary_json:
        Path(args.summary_json).write_text(json.dumps({"mode": "process_per_body", "bodies": results,
                                                        "rss": [s["rss"] for s in summaries]}, indent=1))
    return 0
