"""Cost of one joint state through the node's input path, per kind of (hostile) message (mean, us).

Each row feeds the same message kind to ``ClusterFemNode._on_joint_state`` many times (no DDS, no
spinning): what a flood of that kind costs the executor. Also the joint map alone on the issue's
oversized messages (100,000 names with one duplicate; 20,000 unknown names).

Run: python -m benchmarks.input_costs [--count N]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _mean_us(fn, items) -> float:
    t0 = time.perf_counter()
    for x in items:
        fn(x)
    return (time.perf_counter() - t0) / len(items) * 1e6


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=2000, help="messages per row (default 2000)")
    args = parser.parse_args(argv)
    os.environ.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "SHM")
    from rclpy.parameter import Parameter

    from msg_adapters.joint_state import joint_state_cdr

    from clusterfem_ros.nodes.clusterfem_node import ClusterFemNode
    from clusterfem_ros.nodes.testing import RosWorld
    from clusterfem_ros.skeleton.joint_map import JointMap
    values = {"body.kind": "jelly_man", "body.target_tets": 700, "skeleton.source": "builtin", "warping": False,
              "input.max_names": 30_000}
    n = args.count
    with RosWorld() as world:
        sim = ClusterFemNode(context=world.context,
                             parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
        names, q0 = sim.scene.skeleton.joint_names, sim.scene.skeleton.neutral()
        t0 = time.time_ns()
        good = [joint_state_cdr(names, q0, stamp=t0 + k * 100_000) for k in range(n)]
        far = q0.copy()
        far[names.index("root_x")] = 1e9
        strangers = [f"stranger_{i}" for i in range(20_000)]
        rows = [("good (accepted)", good),
                ("garbage bytes", [b"garbage!"] * n),
                ("30,001 names (too_many_names)",
                 [joint_state_cdr([f"x{i}" for i in range(30_001)], np.zeros(30_001), stamp=t0)] * max(n // 10, 1)),
                ("root at 1e9 m (root_range)", [joint_state_cdr(names, far, stamp=t0 + n * 100_000)] * n),
                ("20,000 unknown names + skeleton", [joint_state_cdr(names + strangers, np.zeros(len(names) + 20_000),
                                                                     stamp=t0 + (n + k) * 100_000)
                                                     for k in range(max(n // 100, 2))])]
        print(f"{'message (node input path)':<46} {'us / message':>14}")
        for label, items in rows:
            print(f"{label:<46} {_mean_us(sim._on_joint_state, items):>14.1f}")
        sim.destroy_node()
    jm = JointMap(["a", "b"], max_names=200_000)
    for label, names in (("JointMap.update, 100,001 names, 1 duplicate", [f"n{i}" for i in range(100_000)] + ["n17"]),
                         ("JointMap.update, 20,000 unknown names", [f"u{i}" for i in range(20_000)] + ["a"])):
        print(f"{label:<46} {_mean_us(lambda x: jm.update(x, np.zeros(len(x))), [names] * 5):>14.1f}")


if __name__ == "__main__":
    main()
