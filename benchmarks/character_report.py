"""The character walk, headless: surface -> ready scene time, and the walk beside the voxel jelly man.

    python -m benchmarks.character_report [--tets 2000 5000 20000] [--duration 3] [--png FILE]
        [--scene config/character_walk.yaml] [--bvh ../shared/data/mocap/cmu_06_01_walk.bvh] [--skip-walk] [--late S]

Part 1, per tet count: the time from the surface file to a ready Scene (tetrahedralize, fit, check,
bind, assemble, load kernels), cold (an empty cache folder; wall and this process's CPU time, the one a loaded
host does not inflate) and cached (the same folder again), with the
tet count, its error from the request, the minimum dihedral angle and radius ratio.
Part 2, at the scene's body.target_tets: the scene driven by the BVH's trajectory (the skeleton the
player latches on robot_description, bvh_urdf) for --duration seconds of simulated time, and the voxel
jelly man on the same skeleton at the same tet count, the two fed each input in turn (interleaved, so a host's
changing load falls on both): steps/s (wall, JIT excluded) and their ratio, the worst relative
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
    return drive_all([scene], traj, duration, rate_hz, late, seed)[0]


def drive_all(scenes: list[Scene], traj, duration: float, rate_hz: float = 120.0, late: float = 0.0,
              seed: int = 0) -> list[dict]:
    """``drive`` for several scenes interleaved: each input goes to every scene in turn, so a host's changing load
    falls on all of them alike (their steps/s compare; each scene's ``late`` draws are its own, same seed)."""
    from clusterfem_ros.fem.stability import DivergenceError
    names = traj.names
    rngs = [np.random.default_rng(seed) for _ in scenes]
    acc = [{"volume_error": 0.0, "tracking_m": 0.0, "bone_distance_m": 0.0, "resets": 0, "withheld": 0,
            "wall0": scene.step_wall_s, "steps0": scene.steps_done} for scene in scenes]
    for k in range(int(duration * rate_hz) + 1):
        t = k / rate_hz
        q, v = traj.sample(t, loop=True)
        for scene, a, rng in zip(scenes, acc, rngs):
            scene.push_joint_state(t, names, q, v)
            try:
                if late <= 0 or scene.sim_time is None:
                    scene.follow_inputs()
                else:
                    scene.advance_to(scene.wall_target(t + late * rng.random()), max_steps=250)
            except DivergenceError:
                a["resets"] += 1
                scene.reset()
            if scene.sim_time is not None and k % 12 == 0:
                if scene.output_problem() is not None:      # what the node would withhold from its topics and bag
                    a["withheld"] += 1
                    continue
                a["volume_error"] = max(a["volume_error"], abs(scene.volume_error()))
                a["tracking_m"] = max(a["tracking_m"], innermost_tracking_error(scene))
                a["bone_distance_m"] = max(a["bone_distance_m"], float(scene.bone_distance()[0].max()))
    out = []
    for scene, a in zip(scenes, acc):
        steps = scene.steps_done - a.pop("steps0")
        a["steps_per_s"] = steps / max(scene.step_wall_s - a.pop("wall0"), 1e-12)
        out.append({"steps": steps, **a, "finite": bool(np.isfinite(scene.positions()).all())})
    return out


def ready_times(config, urdf: str, counts: list[int]) -> list[list]:
    rows = []
    for n in counts:
        with tempfile.TemporaryDirectory() as cache:
            import os
            old = os.environ.get("CLUSTERFEM_CACHE")
            os.environ["CLUSTERFEM_CACHE"] = cache
            try:
                c = config.with_values({"body.target_tets": n})
                t0, c0 = time.perf_counter(), time.process_time()
                scene = Scene.build(c, urdf_xml=urdf)
                cold, cold_cpu = time.perf_counter() - t0, time.process_time() - c0
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
                     f"{tets.min_dihedral_deg:.1f}", f"{tets.min_radius_ratio:.3f}", f"{cold:.1f}", f"{cold_cpu:.1f}",
                     f"{warm:.1f}"])
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
                     "cold CPU [s]", "cached [s]"], ready_times(config, urdf, a.tets)))
    if a.skip_walk:
        return
    n = config.body.target_tets
    bodies = (("character (surface)", config),
              ("voxel jelly man", config.with_values({"body.kind": "jelly_man", "binding.relative_levels": False,
                                                      "binding.level_radii": [0.035, 0.06]})))
    scenes = [Scene.build(c, urdf_xml=urdf) for _, c in bodies]
    results = drive_all(scenes, traj, a.duration, late=a.late)
    rows = []
    for (name, _), scene, r in zip(bodies, scenes, results):
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
    ratio = results[0]["steps_per_s"] / results[1]["steps_per_s"]
    print(f"the walk ({a.bvh.name}, {a.duration:g} s simulated, method {config['method']}, warping "
          f"{config['warping']}, step {config['physics.step']:g} s"
          + (f", inputs up to {a.late:g} s late" if a.late > 0 else "") + "):")
    print(table(["body", "tets", "steps/s", "worst |V/V0-1|", "worst level-0 tracking [mm]",
                 "worst skin to bone [m]", "resets", "withheld", "finite"], rows))
    print(f"the character runs {ratio:.2f} of the jelly man's steps/s (the two driven interleaved, input by input)")


if __name__ == "__main__":
    main()
