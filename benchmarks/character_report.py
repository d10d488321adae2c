"""The character walk, headless: surface -> ready scene time, and the walk beside the voxel jelly man.

    python -m benchmarks.character_report [--tets 2000 5000 20000] [--duration 3] [--png FILE]
        [--scene config/character_walk.yaml] [--bvh ../shared/data/mocap/cmu_06_01_walk.bvh] [--skip-walk] [--late S]

Part 1, per tet count: the time from the surface file to a ready Scene (tetrahedralize, fit, check,
bind, assemble, load kernels), cold (an empty cache folder) and cached (the same folder again), with the
tet count, its error from the request, the minimum dihedral angle and radius ratio.
Part 2, at the scene's body.target_tets: the scene driven by the BVH's trajectory (the skeleton the
player latches on robot_description, bvh_urdf) for --duration seconds of simulated time, and the voxel
jelly man on the same skeleton at the same tet count: steps/s (wall, JIT excluded), the worst relative
volume error, the innermost level's worst tracking error, the worst distance of a surface vertex to its bone,
the divergence resets and the sampled states the node's output checks would withhold.
Timings depend on the machine and its load: re-measure on a quiet one.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from clusterfem_ros.config import load_scene_file
from clusterfem_ros.scene import Scene
from .timing import table

DEFAULT_SCENE = Path(__file__).resolve().parents[1] / "config" / "character_walk.yaml"
DEFAULT_BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap" / "cmu_06_01_walk.bvh"


def bvh_skeleton(bvh: Path):
    """(URDF text, trajectory) of a capture: what the mocap player latches and publishes."""
    from clusterfem_ros.skeleton.bvh import load_bvh
    from clusterfem_ros.skeleton.bvh_to_urdf import bvh_trajectory, bvh_urdf
    motion = load_bvh(bvh)
    return bvh_urdf(motion), bvh_trajectory(motion)


def innermost_tracking_error(scene: Scene) -> float:
    """Worst distance [m] of a level-0 vertex from the point its bone carries (its target)."""
    b = scene.binding
    idx = np.flatnonzero(b.level == 0)
    poses = scene._poses(scene.sim_time)
    target = np.einsum("nij,nj->ni", poses.rotation[b.bone[idx]], b.local[idx]) + poses.translation[b.bone[idx]]
    return float(np.linalg.norm(scene.positions()[idx] - target, axis=1).max())


def drive(scene: Scene, traj, duration: float, rate_hz: float = 120.0, late: float = 0.0, seed: int = 0) -> dict:
    """Play ``traj`` into the scene at ``rate_hz`` for ``duration`` s of input time; measure as it goes.

    ``late`` = 0: physics on the input clock (as physics.clock input). ``late`` > 0: physics on a wall clock that
    runs ahead of each sample by a random 0..``late`` s (seeded), as in a node whose executor is starved of CPU,
    stepping up to Scene.wall_target as the node does (the scene's physics.input_wait: how long it waits for late
    samples)."""
    from clusterfem_ros.fem.stability import DivergenceError
    names = traj.names
    rng = np.random.default_rng(seed)
    worst_volume, worst_track, worst_bone, resets, withheld = 0.0, 0.0, 0.0, 0, 0
    wall0, steps0 = scene.step_wall_s, scene.steps_done
    for k in range(int(duration * rate_hz) + 1):
        t = k / rate_hz
        q, v = traj.sample(t, loop=True)
        scene.push_joint_state(t, names, q, v)
        try:
            if late <= 0 or scene.sim_time is None:
                scene.follow_inputs()
            else:
                scene.advance_to(scene.wall_target(t + late * rng.random()), max_steps=250)
        except DivergenceError:
            resets += 1
            scene.reset()
        if scene.sim_time is not None and k % 12 == 0:
            if scene.output_problem() is not None:      # what the node would withhold from its topics and bag
                withheld += 1
                continue
            worst_volume = max(worst_volume, abs(scene.volume_error()))
            worst_track = max(worst_track, innermost_tracking_error(scene))
            worst_bone = max(worst_bone, float(scene.bone_distance()[0].max()))
    steps = scene.steps_done - steps0
    return {"steps": steps, "steps_per_s": steps / max(scene.step_wall_s - wall0, 1e-12),
            "volume_error": worst_volume, "tracking_m": worst_track, "bone_distance_m": worst_bone, "resets": resets,
            "withheld": withheld,
            "finite": bool(np.isfinite(scene.positions()).all())}


def ready_times(config, urdf: str, counts: list[int]) -> list[list]:
    rows = []
    for n in counts:
        with tempfile.TemporaryDirectory() as cache:
            import os
            old = os.environ.get("CLUSTERFEM_CACHE")
            os.environ["CLUSTERFEM_CACHE"] = cache
            try:
                c = config.with_values({"body.target_tets": n})
                t0 = time.perf_counter()
                scene = Scene.build(c, urdf_xml=urdf)
                cold = time.perf_counter() - t0
                t0 = time.perf_counter()
                Scene.build(c, urdf_xml=urdf)
                warm = time.perf_counter() - t0
            finally:
                if old is None:
                    del os.environ["CLUSTERFEM_CACHE"]
                else:
                    os.environ["CLUSTERFEM_CACHE"] = old
        tets = scene.surface_body.tets
        rows.append([n, scene.model.mesh.n_tets, f"{scene.model.mesh.n_tets / n - 1:+.1%}", tets.attempts,
                     f"{tets.min_dihedral_deg:.1f}", f"{tets.min_radius_ratio:.3f}", f"{cold:.1f}", f"{warm:.1f}"])
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", type=Path, default=DEFAULT_SCENE)
    ap.add_argument("--bvh", type=Path, default=DEFAULT_BVH)
    ap.add_argument("--tets", type=int, nargs="*", default=[2000, 5000, 20000])
    ap.add_argument("--duration", type=float, default=3.0, help="simulated seconds of the walk (default 3)")
    ap.add_argument("--png", type=Path, default=None, help="picture of the character at the end of the walk")
    ap.add_argument("--skip-walk", action="store_true")
    ap.add_argument("--late", type=float, default=0.0, help="inputs reach the physics up to this late [s] (a node "
                    "starved of CPU), physics on a wall clock; default 0: on the input clock")
    a = ap.parse_args(argv)
    config = load_scene_file(a.scene)
    urdf, traj = bvh_skeleton(a.bvh)
    if a.tets:
        print("surface -> ready scene (tetrahedralize, fit, bind, assemble, kernels), cold and cached cache:")
        print(table(["target", "tets", "off", "mesher runs", "min dihedral [deg]", "min radius ratio", "cold [s]",
                     "cached [s]"], ready_times(config, urdf, a.tets)))
    if a.skip_walk:
        return
    n = config.body.target_tets
    rows = []
    for name, c in (("character (surface)", config),
                    ("voxel jelly man", config.with_values({"body.kind": "jelly_man", "binding.relative_levels": False,
                                                            "binding.level_radii": [0.035, 0.06]}))):
        scene = Scene.build(c, urdf_xml=urdf)
        r = drive(scene, traj, a.duration, late=a.late)
        rows.append([name, scene.model.mesh.n_tets, f"{r['steps_per_s']:.0f}", f"{r['volume_error']:.2%}",
                     f"{r['tracking_m'] * 1000:.1f}", f"{r['bone_distance_m']:.3f}", r["resets"], r["withheld"],
                     r["finite"]])
        if a.png is not None and name.startswith("character"):
            from clusterfem_ros.render import render_surface_png
            verts, tris = scene.surface()
            render_surface_png(a.png, verts, tris, scene.vertex_von_mises()[scene.surface_vertices],
                               title=f"MakeHuman body on the CMU walk after {a.duration:g} s "
                                     f"({scene.model.mesh.n_tets} tets)")
            print(f"picture: {a.png}")
    print(f"the walk ({a.bvh.name}, {a.duration:g} s simulated, method {config['method']}, warping "
          f"{config['warping']}, step {config['physics.step']:g} s"
          + (f", inputs up to {a.late:g} s late" if a.late > 0 else "") + "):")
    print(table(["body", "tets", "steps/s", "worst |V/V0-1|", "worst level-0 tracking [mm]",
                 "worst skin to bone [m]", "resets", "withheld", "finite"], rows))


if __name__ == "__main__":
    main()
