"""The jelly man's two skins side by side: the voxel body and the smooth one (skeleton/smooth_body.py).

    python -m benchmarks.skin_compare [--duration 2] [--tets 4800] [--repeats 2] [--min-altitude 0.6 ...]

Both bodies are the default scene's (benchmarks/jelly_report.build_scene: the built-in humanoid, the scene's
binding and material, the procedural walk, the clustered method with the default Neo-Hookean warping, one core),
at the same tet count (the smooth body keeps the voxel body's tets and moves its vertices). Printed per skin:
tets; the surface vertices' distance to the blended capsule surface (median / 95th percentile / max, in voxel
edges h); the smallest tet altitude as a share of its voxel altitude; the critical step of the free body
(fem/stability.py) and the sub-steps it plans per 1 ms step, the largest stretch factor (fem/materials/stretch.py)
at which the bound body still plans one sub-step, and the sub-steps the walk took (the bound body's
own plan; with the same tets, their mean is the cost ratio that load does not blur); steps/s (runs interleaved,
the best of ``--repeats``, and its ratio to the voxel body's); the largest volume error and level-0 tracking
error of the walk. ``--min-altitude`` adds smooth bodies with other floors on the tets' altitude
(smooth_body.MIN_ALTITUDE).

Each smooth body runs twice: with its own lumped masses, and with the masses the scene gives it (raised at the
vertices stiffer for their mass than the voxel body's stiffest: fem/mass_scaling.py). For the scaled one the
table adds the mass added (share of the body's, vertices raised) and its error: the largest distance between
its vertices and the unscaled body's at the end of the same walk [mm], beside the largest displacement there.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from .jelly_report import build_scene, run, scene_default
from .timing import table


def surface_depth(mesh, shape) -> np.ndarray:
    """|depth| [m] of the mesh's surface vertices to the blended capsules of their bones' neighbourhoods."""
    from clusterfem_ros.fem.mesh.tet_mesh import boundary_triangles
    from clusterfem_ros.skeleton.smooth_body import vertex_bones
    surface = np.unique(boundary_triangles(mesh))
    return np.abs(shape.depth(mesh.vertices[surface], vertex_bones(mesh, shape)[surface]))


def one_substep_stretch(lam: float, material, gains, step: float, safety: float = 0.8) -> float:
    """The largest stretch factor (fem/materials/stretch.py: quarter octaves) whose plan, with the binding's
    stiffest gains, still takes one sub-step per ``step``."""
    from clusterfem_ros.fem.stability import critical_step, plan_substeps
    k, factor = 0, 1.0
    while plan_substeps(step, critical_step(lam * 2 ** ((k + 1) / 4), material.xi, material.zeta, max(gains.kp),
                                            max(gains.kd)), safety).substeps == 1 and k < 64:
        k += 1
        factor = 2 ** (k / 4)
    return factor


def main(argv: list[str] | None = None) -> int:
    from clusterfem_ros.fem.stability import critical_step, max_eigenvalue, plan_substeps
    from clusterfem_ros.skeleton.humanoid import default_humanoid
    from clusterfem_ros.skeleton.jelly_body import jelly_man_mesh
    from clusterfem_ros.skeleton.smooth_body import edge_length, min_altitudes, smooth_capsules_of, snap_to_shape
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=2.0, help="walking time simulated per run [s] (default 2)")
    ap.add_argument("--tets", type=int, default=int(scene_default("body.target_tets")))
    ap.add_argument("--repeats", type=int, default=2, help="interleaved timed runs per skin (default 2)")
    ap.add_argument("--min-altitude", type=float, nargs="*", default=[], help="more smooth bodies, these floors")
    args = ap.parse_args(argv)
    step = 1e-3
    spec = default_humanoid()
    shape = smooth_capsules_of(spec)
    voxels = jelly_man_mesh(spec, target_tets=args.tets)
    h = edge_length(voxels)
    alt0 = min_altitudes(voxels.vertices, voxels.tets)
    from clusterfem_ros.skeleton.smooth_body import MIN_ALTITUDE
    floors = [None, MIN_ALTITUDE] + [a for a in args.min_altitude if a != MIN_ALTITUDE]
    from clusterfem_ros.fem.mass_scaling import scale_to_reference
    scenes, scaled = [], {}
    for floor in floors:
        mesh = voxels if floor is None else snap_to_shape(voxels, shape, floor)[0]
        name = "voxel" if floor is None else f"smooth (altitude >= {floor:g})"
        skeleton, traj, model, binding, gains = build_scene(args.tets, args.duration, step, mesh=mesh)
        scenes.append((name, model, binding, mesh))
        if floor is not None:
            own = model
            skeleton, traj, model, binding, gains = build_scene(args.tets, args.duration, step, mesh=mesh,
                                                                mass_reference=voxels)
            scenes.append((name + ", mass scaled", model, binding, mesh))
            scaled[name + ", mass scaled"] = (name, scale_to_reference(own, voxels)[1])
    rows, best = [], {}
    for _ in range(args.repeats):
        for name, model, binding, mesh in scenes:
            r = run(skeleton, traj, model, binding, gains, "neohookean", args.duration, step)
            if name not in best or r["steps/s"] > best[name]["steps/s"]:
                best[name] = r

    def scaling_error(name: str, r: dict) -> str:
        if name not in scaled:
            return ""
        own, scaling = scaled[name]
        diff = np.linalg.norm(r["u_end"] - best[own]["u_end"], axis=1).max()
        return (f"+{100 * scaling.added_share:.2f} % at {scaling.raised.size} v; {diff * 1e3:.2f} mm of "
                f"{np.linalg.norm(r['u_end'], axis=1).max() * 1e3:.0f}")

    for name, model, binding, mesh in scenes:
        depth = surface_depth(mesh, shape)
        share = float(np.min(min_altitudes(mesh.vertices, mesh.tets) / alt0))
        lam = max_eigenvalue(model)
        m = model.material
        free = critical_step(lam, m.xi, m.zeta)
        one = one_substep_stretch(lam, m, gains, step)
        r = best[name]
        s0, s1 = r["substeps"]
        rows.append([name, f"{mesh.n_tets}", f"{np.median(depth) / h:.3f} / {np.percentile(depth, 95) / h:.3f} / "
                     f"{depth.max() / h:.3f}", f"{share:.2f}", f"{free * 1e3:.3f}",
                     f"{plan_substeps(step, free).substeps}", f"{one:.2f}",
                     f"{s0}" if s0 == s1 else f"{s0}-{s1}, mean {r['substeps_mean']:.3f}",
                     f"{r['steps/s']:.0f}", f"{r['steps/s'] / best['voxel']['steps/s']:.2f}",
                     f"{r['volume'] * 100:.2f} %", f"{r['track'] * 1e3:.2f}", scaling_error(name, r)])
    print(f"jelly man skins, {args.tets} target tets, voxel edge h = {h * 1e3:.1f} mm, {args.duration:g} s of walking "
          f"per run, best of {args.repeats} interleaved runs")
    print(table(["skin", "tets", "surface |depth| / h (p50 / p95 / max)", "min altitude share",
                 "h_crit free [ms]", "planned sub-steps", "stretch at 1 sub-step", "sub-steps in the walk",
                 "steps/s", "vs voxel", "max volume error", "level-0 tracking mm",
                 "mass added; end vs unscaled / max displacement"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
