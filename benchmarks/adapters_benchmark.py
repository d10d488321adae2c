"""Cost of the message adapters for a 10k-triangle coloured surface (median of repeats, ms).

Run: python -m benchmarks.adapters_benchmark [--triangles N] [--repeats R]
"""
from __future__ import annotations

import argparse
import statistics
import time
from typing import Callable

import numpy as np


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--triangles", type=int, default=10_000, help="surface triangles (default 10000)")
    parser.add_argument("--repeats", type=int, default=15, help="timed repeats per row (default 15)")
    args = parser.parse_args(argv)
    from rclpy.serialization import serialize_message

    from msg_adapters.colormap import map_scalars
    from msg_adapters.joint_state import joint_state_cdr
    from msg_adapters.marker import surface_marker, surface_marker_cdr
    from msg_adapters.pointcloud import stress_cloud, stress_cloud_cdr

    rng = np.random.default_rng(0)
    t = args.triangles
    n = t // 2 + 2  # a closed surface has about half as many vertices as triangles
    v, tri = rng.normal(size=(n, 3)), rng.integers(0, n, size=(t, 3))
    vm = rng.random(n) * 1e5
    rgba = map_scalars(vm, "turbo", 0.0, 1e5)
    marker = surface_marker(v, tri, rgba, "world", 0)
    names, q, dq = [f"joint_{i}" for i in range(30)], rng.normal(size=30), rng.normal(size=30)
    rows = [
        ("colour map (map_scalars, per vertex)", lambda: map_scalars(vm, "turbo", 0.0, 1e5)),
        ("Marker, naive construction", lambda: surface_marker(v, tri, rgba, "world", 0)),
        ("Marker, rclpy serialize_message", lambda: serialize_message(marker)),
        ("Marker, CDR fast path (surface_marker_cdr)", lambda: surface_marker_cdr(v, tri, rgba, "world", 0)),
        ("PointCloud2 stress cloud, message", lambda: stress_cloud(v, vm, "world", 0)),
        ("PointCloud2 stress cloud, CDR (stress_cloud_cdr)", lambda: stress_cloud_cdr(v, vm, "world", 0)),
        ("JointState 30 joints, CDR (joint_state_cdr)", lambda: joint_state_cdr(names, q, dq, 0)),
    ]
    print(f"adapters benchmark: {t} triangles, {n} vertices, {3 * t} Marker points "
          f"({len(surface_marker_cdr(v, tri, rgba, 'world', 0)) / 1e6:.2f} MB CDR); median of {args.repeats}")
    print(f"| {'path':<50} | {'ms':>9} |")
    print(f"|{'-' * 52}|{'-' * 11}|")
    for label, fn in rows:
        print(f"| {label:<50} | {_median_ms(fn, args.repeats):9.3f} |")


if __name__ == "__main__":
    main()
