"""What the whole volume's pressure costs the default scene: steps/s of three jelly men on the built-in walk.

    python -m benchmarks.pressure_cost [--rounds 30] [--block 1.0]

The default scene (the smooth skin with ``material.volume_stiffness`` 'auto': kappa 2 on the jelly man,
fem/volume_pressure.py), the same body without the pressure, and the voxel body without it (``body.skin: voxel``),
each a ``Scene`` as the node builds it, headless, fed the built-in walk at 120 Hz and stepped up to each sample's
stamp (``Scene.advance_to``: skeleton, constraints, pressure, physics and the step's checks, one core). The three
run in interleaved blocks of ``--block`` simulated seconds; per body the median wall time of a physics step over
the blocks (the first two left out: warm-up), and its steps/s as a share of the voxel body's: the median of each
block's own ratio, so a slow spell of the host does not flip the comparison. Beside it the volume error at the
end of the walk.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from .timing import table

BODIES = {"default (smooth, kappa auto)": {},
          "smooth, no pressure": {"material.volume_stiffness": 0.0},
          "voxel, no pressure": {"body.skin": "voxel", "material.volume_stiffness": 0.0}}
BASE = "voxel, no pressure"
RATE_HZ = 120.0
WARM_UP_BLOCKS = 2


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=30, help="interleaved blocks per body (default 30)")
    ap.add_argument("--block", type=float, default=1.0, help="simulated seconds per block (default 1)")
    args = ap.parse_args(argv)
    if args.rounds <= WARM_UP_BLOCKS or not args.block > 0.0:
        ap.error(f"--rounds must exceed {WARM_UP_BLOCKS} (warm-up blocks) and --block be positive")
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.scene import Scene
    from clusterfem_ros.skeleton.procedural_walk import procedural_walk
    scenes = {}
    for name, values in BODIES.items():
        print(f"  building {name} ...", file=sys.stderr, flush=True)
        config = SceneConfig().with_values(values)
        scenes[name] = (Scene.build(config), config.material.volume_stiffness)
    per_block = int(round(args.block * RATE_HZ))
    walk = procedural_walk(args.rounds * args.block + 1.0, RATE_HZ)
    times, q = walk.times, walk.positions
    step_s = {name: [] for name in scenes}
    for r in range(args.rounds):
        lo, hi = r * per_block, (r + 1) * per_block
        for name, (scene, _) in scenes.items():
            steps0, wall0 = scene.steps_done, scene.step_wall_s
            for i in range(lo, hi):
                scene.push_joint_state(float(times[i]), walk.names, q[i])
                scene.advance_to(float(times[i]))
            if r >= WARM_UP_BLOCKS:
                step_s[name].append((scene.step_wall_s - wall0) / max(scene.steps_done - steps0, 1))
    base = np.asarray(step_s[BASE])
    rows = []
    for name, (scene, kappa) in scenes.items():
        s = np.asarray(step_s[name])
        rows.append([name, f"{kappa:g}", f"{scene.model.mesh.n_tets}", f"{np.median(s) * 1e3:.3f}",
                     f"{np.median(base / s):.3f}", f"{abs(scene.volume_error()) * 100:.2f} %"])
    print(table(["body", "kappa", "tets", "step ms (median)", f"steps/s / {BASE}", "volume error at the end"],
                rows))
    print(f"{args.rounds - WARM_UP_BLOCKS} blocks of {args.block:g} s each, interleaved, one core")
    return 0


if __name__ == "__main__":
    sys.exit(main())
