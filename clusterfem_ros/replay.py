"""Replay a recorded bag's joint states through a Scene, and compare with the recorded surfaces. No ROS.

A node running with ``physics.clock: input`` steps on the joint-state stamps only, so its states are a
function of the inputs and the parameters; the bag folder keeps both (``scene_parameters.yaml`` beside
the .mcap). The node records the joint states its joint stream took in (never a refused one), and the replay
gives them to a fresh Scene in the same order, each as taken in (Scene.take_joint_state, ``taken=True``): the
same operations in the same order, so on the same build and CPU every recorded surface Marker (stamped with its
simulated time) comes back bit for bit:

    python -m clusterfem_ros.replay bags/clusterfem_20261122_120000

It compares every recorded surface with the replay's at the same simulated time, exactly by default
(``--tolerance 0``). The compiled kernels are built for the host's vector instructions (numba), so another CPU
(AVX2 against AVX-512) rounds differently: a bag recorded on another machine replays to round-off (about 1e-14 m
on the sample bag), to compare with ``--tolerance 1e-9``. Exit 1 when the replay differs (the physics or the
parameters' meaning changed since the recording; a NaN or inf vertex differs at any tolerance); 2 when the bag
cannot be replayed: recorded on the wall clock (its states depend on when each step ran), no recorded surface or
joint state, no parameter file, or a damaged bag. It never exits 0 having compared nothing.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from .recording.bag_reader import PARAMS_FILE, JointSample, bag_topics, read_joint_states, read_surfaces, topic_in


def replay(scene, samples: list[JointSample], at_ns: list[int]) -> dict[int, np.ndarray]:
    """Drive ``scene`` (fresh, physics.clock = input) as the node did: each recorded sample through
    Scene.take_joint_state with its receive time, as taken in (``taken=True``), which steps up to the newest
    stamp. Returns the triangle-list surface points, as the node's Marker holds them, at each simulated time in
    ``at_ns`` that the replay passes through."""
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
            scene.take_joint_state(s.stamp, s.names, s.q, s.v, received=s.log_ns * 1e-9, on_step=collect, taken=True)
        except (DivergenceError, StabilityError):         # as the node's physics thread: reset, go on
            scene.reset()
    return got


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", help="bag folder written by the clusterfem node with physics.clock: input")
    ap.add_argument("--tolerance", type=float, default=0.0,
                    help="largest vertex difference [m] accepted (default 0: bit for bit; 1e-9 for a bag recorded "
                         "on another CPU)")
    args = ap.parse_args(argv)
    if not args.tolerance >= 0.0:
        print(f"error: --tolerance {args.tolerance} must be a distance >= 0 [m]", file=sys.stderr)
        return 2
    from .config import RECORDED_BEFORE, load_scene_file
    folder = Path(args.bag)
    params = folder / PARAMS_FILE
    if not params.exists():
        print(f"error: {params} is missing: only bags recorded by the clusterfem node can be replayed", file=sys.stderr)
        return 2
    try:
        return _compare(folder, load_scene_file(params, absent=RECORDED_BEFORE), args.tolerance)
    except Exception as exc:        # a damaged bag or parameter file: one line, not a traceback
        print(f"error: cannot replay {folder}: {exc}", file=sys.stderr)
        return 2


RECORD_ON_INPUT = ("record it with physics.clock: input (in the scene file, or -p physics.clock:=input) to get a "
                   "bag that replays")


def _compare(folder: Path, config, tolerance: float) -> int:
    from .scene import Scene
    if config.physics.clock != "input":
        print(f"error: {folder} was recorded with physics.clock = {config.physics.clock}: its states depend on when "
              f"each step ran, so no replay reproduces them and nothing was compared; {RECORD_ON_INPUT}",
              file=sys.stderr)
        return 2
    samples = read_joint_states(folder) if topic_in(bag_topics(folder), "/joint_states") else []
    surfaces = read_surfaces(folder)
    print(f"replaying {len(samples)} joint states; {len(surfaces)} recorded surfaces")
    if not surfaces or not samples:
        what = "surface Marker" if not surfaces else "joint state"
        print(f"error: {folder} holds no {what}, so nothing was compared; record with a subscriber or "
              f"recording.enabled on, output.marker_rate_hz above 0 and joint states coming in ({RECORD_ON_INPUT})",
              file=sys.stderr)
        return 2
    scene = Scene.build(config)
    got = replay(scene, samples, [t for t, _ in surfaces])
    missing = [t for t, p in surfaces if t not in got or got[t].shape != p.shape]
    compared = [(t, p) for t, p in surfaces if t not in missing]
    diffs = [float(np.abs(got[t] - p).max()) for t, p in compared]
    identical = sum(np.array_equal(got[t], p) for t, p in compared)
    # a NaN difference is not > any tolerance (and max() may pass over it): a non-finite one differs without bound
    nonfinite = [t for (t, _), d in zip(compared, diffs) if not math.isfinite(d)]
    worst = math.inf if nonfinite else max(diffs, default=0.0)
    print(f"compared {len(diffs)} of {len(surfaces)} surfaces: {identical} identical bit for bit; max vertex "
          f"difference {worst:.3g} m")
    if missing:
        print(f"error: the replay never reached {len(missing)} of the {len(surfaces)} recorded surfaces (the first at "
              f"{missing[0] * 1e-9:.9f} s) or gave them another size: the physics or the scene changed since it was "
              "recorded; record it again with the same scene file to update it", file=sys.stderr)
        return 1
    if nonfinite:
        print(f"error: the replay differs from the recording: {len(nonfinite)} of the {len(compared)} compared "
              f"surfaces have a non-finite vertex (NaN or inf) in the replay or the recording (the first at "
              f"{nonfinite[0] * 1e-9:.9f} s), which no --tolerance accepts: the physics diverged since it was "
              "recorded or the bag is damaged; record it again with the same scene file to update it", file=sys.stderr)
        return 1
    if worst > tolerance:
        why = ("differences of round-off size: a bag recorded on another CPU replays so (numba compiles for the "
               "host's vector instructions); there, compare with --tolerance 1e-9" if worst <= 1e-9 else
               "the physics changed since it was recorded; record it again with the same scene file to update it")
        print(f"error: the replay differs from the recording (max difference {worst:.3g} m > --tolerance "
              f"{tolerance:g} m): {why}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
