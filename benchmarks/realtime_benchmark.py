"""The node in real time: does it keep up with everything on, how late is its output, what is left, and
what do 1, 2, 4, 8 bodies give on this machine. Prints tables; a benchmark, not a test.

    python -m benchmarks.realtime_benchmark [--duration 60] [--scaling-duration 20] [--bodies 1,2,4,8]

1. Everything on: the default scene (warped jelly man, markers 30 Hz, stress 10 Hz, diagnostics, recording
   to a temporary folder) driven by the built-in walk's player process, for ``--duration`` s of wall time
   after the first joint state (``scripts/run``'s own run, in a child process). Printed: real-time factor,
   physics headroom (simulated seconds per second the physics thread would sustain alone: simulated time over
   the thread's CPU time in inputs, skeleton, physics, checks and snapshots; beside it the headroom in the
   node: over the thread's busy wall time, waits for the GIL and for a core included), joint-state ->
   surface Marker latency (p50, p99, max), busy share per stage (wall seconds in the stage per wall second),
   the process's CPU (cores), and RSS over time (growth after the warm-up). Beside the targets of issue #21.
2. Bodies: N default bodies, each with its own player process, for ``--scaling-duration`` s, all in one
   process (one executor, a physics thread each) and one process per body: aggregate tet-steps per second
   (each body runs at real time at most: N x tets x 1000 at h = 1 ms when all keep up), the capacity
   (tets x headroom / h summed: what their measured step times would allow back to back) and the real-time
   factor of the slowest body. Outputs are computed only when consumed, so without
   ``--scaling-record`` these runs step physics and take inputs only (8 recordings would write ~16 MB/s).

Every run is ``python -m clusterfem_ros.nodes.demo`` with ``--summary-json``; its own output goes to a log
file in the temporary folder, printed when a run fails.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .timing import table

TARGETS = {"real_time_factor": 1.00, "headroom": 2.5, "latency_p99_ms": 40.0, "rss_growth_pct": 5.0,
           "two_bodies_rtf": 0.99}


def run_demo(args: list[str], tmp: Path, name: str) -> dict:
    """One demo run with ``args``; its JSON summary (SystemExit with the run's log when it fails)."""
    out, log = tmp / f"{name}.json", tmp / f"{name}.log"
    cmd = [sys.executable, "-m", "clusterfem_ros.nodes.demo", *args, "--no-png", "--no-video",
           "--bags", str(tmp / "bags"), "--summary-json", str(out)]
    t0 = time.perf_counter()
    with open(log, "w") as f:
        code = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT).returncode
    if code != 0 or not out.exists():
        raise SystemExit(f"[bench] `{' '.join(cmd)}` exited with {code}:\n{log.read_text()[-4000:]}")
    print(f"[bench] {name}: done in {time.perf_counter() - t0:.0f} s", flush=True)
    return json.loads(out.read_text())


def everything_on(duration: float, tmp: Path) -> dict:
    s = run_demo(["--duration", f"{duration:g}"], tmp, "everything_on")
    r, rss = s["bodies"][0], s["rss"]
    print(f"\n## Everything on: default scene, markers 30 Hz, stress 10 Hz, diagnostics, recording; {duration:g} s\n")
    rows = [["real-time factor", f"{r['real_time_factor']:.3f}", f">= {TARGETS['real_time_factor']:.2f}"],
            ["physics headroom (per thread CPU s)", f"{r['headroom']:.2f}", f">= {TARGETS['headroom']:g}"],
            ["physics headroom in the node (per busy wall s)", f"{r['headroom_in_node']:.2f}", ""],
            ["steps on the threaded build (their workers' CPU is not in the headroom) %",
             f"{100 * r['threaded_steps']:.1f}", ""],
            ["mean step (skeleton + physics) ms", f"{r['mean_step_ms']:.3f}", ""],
            ["latency p50 ms", f"{r['latency_p50_ms']:.1f}", ""],
            ["latency p99 ms", f"{r['latency_p99_ms']:.1f}", f"<= {TARGETS['latency_p99_ms']:g}"],
            ["latency max ms", f"{r['latency_max_ms']:.1f}", ""],
            ["of it to the snapshot p50 / p99 ms", f"{r['latency_state_p50_ms']:.1f} / {r['latency_state_p99_ms']:.1f}",
             ""],
            ["latencies measured", r["latencies"], ""],
            ["process CPU (cores)", f"{r['process_cpu']:.2f}", ""],
            ["RSS after warm-up / end / peak MB",
             f"{rss['rss_warm_mb']:.0f} / {rss['rss_end_mb']:.0f} / {rss['rss_peak_mb']:.0f}", ""],
            ["RSS growth after warm-up %", f"{rss['rss_growth_pct']:+.1f}", f"<= {TARGETS['rss_growth_pct']:g}"],
            ["resets / physics failures / dropped s", f"{r['resets']} / {r['physics_failures']} / {r['dropped_s']:.3f}",
             ""],
            ["late joint states that re-placed the body", r["late_jumps"], ""],
            ["joint states waiting for physics: most seen / dropped (queue full)",
             f"{r['inputs_waiting_max']} / {r['inputs_dropped_queue_full']}", ""]]
    rows += [[f"busy share: {k}", f"{v:.3f}", ""] for k, v in r["shares"].items()]
    print(table(["measure", "value", "target"], rows))
    every = max(1, len(rss["rss_samples"]) // 12)
    print("\nRSS over time: " + ", ".join(f"{t:.0f} s {mb:.0f} MB" for t, mb in rss["rss_samples"][::every]))
    return s


def scaling(bodies: list[int], duration: float, record: bool, tmp: Path) -> list[dict]:
    rows, runs = [], []
    for n in bodies:
        for mode in (["one process"] if n == 1 else ["one process", "process per body"]):
            args = ["--duration", f"{duration:g}", "--bodies", str(n)] + ([] if record else ["--no-record"])
            if mode == "process per body":
                args.append("--process-per-body")
            s = run_demo(args, tmp, f"bodies_{n}_{mode.replace(' ', '_')}")
            rtf = [b["real_time_factor"] for b in s["bodies"]]
            total = sum(b["tet_steps_per_s"] for b in s["bodies"])
            runs.append({"bodies": n, "mode": mode, "summary": s})
            capacity = sum(b["tets"] * b["headroom"] / b["h"] for b in s["bodies"])   # if steps ran back to back
            rows.append([n, mode, f"{total / 1e6:.2f}", f"{capacity / 1e6:.2f}", f"{min(rtf):.3f}",
                         f"{sum(rtf) / len(rtf):.3f}", f"{min(b['headroom'] for b in s['bodies']):.2f}"])
    print(f"\n## Bodies: default scene each, {duration:g} s, outputs {'recorded' if record else 'off (no consumer)'}\n")
    print(table(["bodies", "mode", "M tet-steps/s", "capacity M tet-steps/s", "slowest RTF", "mean RTF",
                 "lowest headroom"], rows))
    print("\n(capacity: tets x headroom / h summed over the bodies, the tet-steps/s their steps' measured time "
          "would allow back to back; the bodies themselves run at real time at most)")
    return runs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of the everything-on run (default 60)")
    ap.add_argument("--scaling-duration", type=float, default=20.0, help="seconds of each bodies run (default 20)")
    ap.add_argument("--bodies", default="1,2,4,8", help="body counts to run, comma separated ('' = none)")
    ap.add_argument("--scaling-record", action="store_true", help="record (and so compute every output) in the "
                                                                  "bodies runs too")
    ap.add_argument("--skip-everything-on", action="store_true", help="only the bodies runs")
    ap.add_argument("--json", default=None, help="also write every run's summary to this file")
    args = ap.parse_args(argv)
    bodies = [int(b) for b in args.bodies.split(",") if b.strip()]
    out = {}
    with tempfile.TemporaryDirectory(prefix="clusterfem_realtime_") as tmp:
        if not args.skip_everything_on:
            out["everything_on"] = everything_on(args.duration, Path(tmp))
        if bodies:
            out["bodies"] = scaling(bodies, args.scaling_duration, args.scaling_record, Path(tmp))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
