"""What mass scaling (physics.mass_scaling, fem/mass_scaling.py) changes on the character's walk, against the unscaled run.

    python -m benchmarks.mass_scaling_error [--scene config/character_walk.yaml] [--bvh CLIP] [--duration 3]
        [--shares 0 0.01] [--plan-stretch both|on|off]

The same scene is built once per share (0: unscaled) and driven on the input clock by the same capture, so the runs
differ only by the added mass (and the sub-steps it saves). Every 12th input (10 Hz) the surface vertices are
compared with the first run's of the same stretch plan at the same time (the unscaled one, unless it was refused
for needing more than physics.max_substeps): the largest and the mean distance [mm], over the run and at its
end, beside the sub-steps a step (the mean of each input's largest), steps/s (wall, one process, the runs one after the other: re-measure on a quiet
host), the worst volume error and the worst surface vertex's distance to its bone.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clusterfem_ros.config import load_scene_file
from clusterfem_ros.fem.stability import StabilityError
from clusterfem_ros.scene import Scene
from .character_report import DEFAULT_BVH, DEFAULT_SCENE, bvh_skeleton
from .timing import table


def walk(scene: Scene, traj, duration: float, rate_hz: float = 120.0) -> dict:
    """Surface positions every 12th input, sub-steps, steps/s, volume and bone checks of ``scene`` driven by ``traj``."""
    surf, vol, bone, sub = [], 0.0, 0.0, []
    wall0, steps0 = scene.step_wall_s, scene.steps_done
    for k in range(int(duration * rate_hz) + 1):
        t = k / rate_hz
        q, v = traj.sample(t, loop=True)
        scene.push_joint_state(t, traj.names, q, v)
        before = scene.steps_done
        scene.follow_inputs()
        if scene.steps_done > before:
            sub.append(scene.last.substeps)
        if scene.sim_time is not None and k % 12 == 0:
            surf.append(scene.positions()[scene.surface_vertices].copy())
            vol = max(vol, abs(scene.volume_error()))
            bone = max(bone, float(scene.bone_distance()[0].max()))
    steps = scene.steps_done - steps0
    return {"surface": np.array(surf), "steps_per_s": steps / max(scene.step_wall_s - wall0, 1e-12),
            "volume": vol, "bone": bone, "steps": steps, "substeps": float(np.mean(sub)) if sub else 0.0}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", type=Path, default=DEFAULT_SCENE)
    ap.add_argument("--bvh", type=Path, default=DEFAULT_BVH)
    ap.add_argument("--duration", type=float, default=3.0)
    ap.add_argument("--shares", type=float, nargs="+", default=[0.0, 0.01])
    ap.add_argument("--plan-stretch", choices=("both", "on", "off"), default="on")
    a = ap.parse_args(argv)
    config = load_scene_file(a.scene)
    urdf, traj = bvh_skeleton(a.bvh)
    stretch = {"both": (True, False), "on": (True,), "off": (False,)}[a.plan_stretch]
    rows = []
    for plan in stretch:
        ref = None
        for share in sorted(set([0.0] + a.shares)):
            c = config.with_values({"physics.mass_scaling": share, "physics.plan_stretch": plan})
            log = []
            scene = Scene.build(c, urdf_xml=urdf, progress=log.append)
            line = next((s for s in log if s.startswith("mass scaling")), "mass scaling: off")
            try:
                r = walk(scene, traj, a.duration)
            except StabilityError as exc:           # more sub-steps than physics.max_substeps: a row, not the end
                rows.append([f"{share:g}", "on" if plan else "off", f"refused: {exc}"[:60]] + ["-"] * 8)
                continue
            ref = r if ref is None else ref
            n = min(len(ref["surface"]), len(r["surface"]))
            d = np.linalg.norm(r["surface"][:n] - ref["surface"][:n], axis=2) * 1000.0
            rows.append([f"{share:g}", "on" if plan else "off", line.split(": ", 1)[1][:60],
                         f"{scene.integrator.critical_step() * 1e3:.3g}", f"{r['substeps']:.2f}", f"{r['steps_per_s']:.0f}",
                         f"{d.max():.2f}", f"{d.mean():.3f}", f"{d[-1].max():.2f}", f"{r['volume']:.2%}",
                         f"{r['bone']:.3f}"])
    print(f"mass scaling on {a.scene.name} walking {a.bvh.name} for {a.duration:g} s (distances to the unscaled run "
          "of the same stretch plan, surface vertices, every 0.1 s):")
    print(table(["max share", "plan_stretch", "scaling", "h_crit [ms]", "sub-steps", "steps/s", "max [mm]", "mean [mm]",
                 "max at end [mm]", "worst |V/V0-1|", "worst skin to bone [m]"], rows))


if __name__ == "__main__":
    main()
