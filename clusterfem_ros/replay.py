"""Replay a recorded bag's joint states through a Scene, and compare with the recorded surfaces. No ROS.

A node running with ``physics.clock: input`` steps on the joint-state stamps only, so its states are a
function of the inputs and the parameters; the bag folder keeps both (``scene_parameters.yaml`` beside
the .mcap). Replaying the joint states through a fresh Scene in the same order reproduces every
recorded surface Marker (stamped with its simulated time) to round-off:

    python -m clusterfem_ros.replay bags/clusterfem_20261122_120000

It exits with 1 when a bag recorded that way differs by more than ``--tolerance`` (the physics or the
parameters' meaning changed since the recording), 2 when the bag cannot be replayed.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .recording.bag_reader import PARAMS_FILE, JointSample, read_joint_states, read_surfaces


def replay(scene, samples: list[JointSample], at_ns: list[int]) -> dict[int, np.ndarray]:
    """Drive ``scene`` (fresh, physics.clock = input) as the node does: each sample through
    Scene.take_joint_state with its receive time, which steps up to the newest stamp. Returns the
    triangle-list surface points at each simulated time in ``at_ns`` that the replay passes through."""
    wanted = sorted(set(at_ns))
    got: dict[int, np.ndarray] = {}
    k = 0

    def collect():
        nonlocal k
        now = int(round(scene.sim_time * 1e9))
        while k < len(wanted) and wanted[k] < now:
            k += 1                                            # a time the replay stepped over
        if k < len(wanted) and wanted[k] == now:
            verts, tris = scene.surface()
            got[now] = verts[tris].reshape(-1, 3)
            k += 1

    from .fem.stability import DivergenceError, StabilityError
    if scene.config.physics.clock != "input":
        raise ValueError("replay needs a scene with physics.clock = input (its states follow the stamps only)")
    for s in samples:
        try:
            scene.take_joint_state(s.stamp, s.names, s.q, s.v, received=s.log_ns * 1e-9, on_step=collect)
        except (DivergenceError, StabilityError):         # as the node's physics thread: reset, go on
            scene.reset()
    return got


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", help="bag folder written by the clusterfem node")
    ap.add_argument("--tolerance", type=float, default=1e-6,
                    help="largest vertex difference [m] a physics.clock = input bag may show (default 1e-6)")
    args = ap.parse_args(argv)
    from .config import load_scene_file
    folder = Path(args.bag)
    params = folder / PARAMS_FILE
    if not params.exists():
        print(f"error: {params} is missing: only bags recorded by the clusterfem node can be replayed", file=sys.stderr)
        return 2
    try:
        return _compare(folder, load_scene_file(params), args.tolerance)
    except Exception as exc:        # a damaged bag or parameter file: one line, not a traceback
        print(f"error: cannot replay {folder}: {exc}", file=sys.stderr)
        return 2


def _compare(folder: Path, config, tolerance: float) -> int:
    from .scene import Scene
    exact = config.physics.clock == "input"
    if not exact:
        print("note: the bag was recorded with physics.clock = wall; its surfaces depend on timing and are "
              "compared only where the replay passes through their stamps", file=sys.stderr)
    samples = read_joint_states(folder)
    surfaces = read_surfaces(folder)
    print(f"replaying {len(samples)} joint states; {len(surfaces)} recorded surfaces")
    scene = Scene.build(config.with_values({"physics.clock": "input"}))     # a replay follows the stamps
    got = replay(scene, samples, [t for t, _ in surfaces])
    diffs = [float(np.abs(got[t] - p).max()) for t, p in surfaces if t in got and got[t].shape == p.shape]
    worst = max(diffs) if diffs else float("nan")
    print(f"compared {len(diffs)} surfaces; max vertex difference {worst:.3g} m")
    if exact and not (len(diffs) == len(surfaces) and worst <= tolerance):
        print(f"error: the replay differs from the recording ({len(diffs)} of {len(surfaces)} surfaces compared, "
              f"max difference {worst:.3g} m > --tolerance {tolerance:g} m): the physics changed since it was "
              "recorded; record it again with the same scene file to update it", file=sys.stderr)
        return 1
    return 0

if __name__ == "__main__":
    sys.exit(main())
