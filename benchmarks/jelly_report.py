"""The paper's jelly man (Figure 1): a walking humanoid driving a soft body, with and without warping.

    python -m benchmarks.jelly_report [--duration 3] [--step 1e-3] [--tets 4800]

The default scene: ``smooth_jelly_man_mesh`` (``jelly_man_mesh``'s ~4800 tets, skin on the blended capsules,
masses scaled to the voxel body's critical step: fem/mass_scaling.py) around the built-in ~48-DOF humanoid, bound
with the
scene defaults (``config.PARAMS``: binding.level_radii / kp / kd, the material), driven by
``procedural_walk`` through ``SkeletonDriver`` and stepped by the clustered method at a 1 ms physics
step, with the whole volume's pressure the scene runs (``material.volume_stiffness`` 'auto': kappa 2 on the
jelly man, fem/volume_pressure.py; ``--kappa`` another). Printed per run: simulation steps per second
(skeleton, constraints, pressure and physics, JIT excluded), the real-time factor at that step, the explicit sub-steps per step, the maximum relative change of the
total tet volume over the run, and the innermost level's worst tracking error; beside the paper's
"1000 steps in 2 s" (500 steps/s on a 1.6 GHz Pentium).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from clusterfem_ros.body import LevelGains, SkeletonDriver, bind_to_skeleton
from clusterfem_ros.config import PARAMS, SceneConfig
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.linear.material import Material
from clusterfem_ros.fem.model import State, build_model
from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes
from clusterfem_ros.fem.volume_pressure import volume_pressure
from .timing import table

PAPER_STEPS_PER_S = 1000 / 2.0


def scene_default(name: str):
    """The default of scene parameter ``name`` (one table for the node and the benchmarks)."""
    for p in PARAMS:
        if p.name == name:
            return p.default
    raise KeyError(f"no scene parameter {name!r} in config.PARAMS")


def rest_configuration(skeleton) -> np.ndarray:
    """The configuration the jelly body was built around (the skeleton's neutral pose)."""
    for attr in ("neutral", "neutral_configuration", "q_neutral", "q0"):
        val = getattr(skeleton, attr, None)
        if val is not None:
            return np.asarray(val() if callable(val) else val, dtype=np.float64)
    model = getattr(skeleton, "model", None)
    if model is not None:
        import pinocchio as pin
        return pin.neutral(model)
    raise AttributeError("the skeleton exposes no neutral configuration (neutral(), q0 or a pinocchio model)")


def build_scene(target_tets: int, duration: float, step: float, skin: str | None = None, mesh=None,
                mass_reference=None):
    """(skeleton, trajectory, model, binding, gains) of the default jelly man scene; ``skin`` 'smooth' or 'voxel'
    (default: the scene's body.skin), or the body ``mesh`` given (its masses scaled to ``mass_reference``'s
    stiffest vertex when given, as the scene scales the smooth body's: fem/mass_scaling.py)."""
    from clusterfem_ros.skeleton.humanoid import default_humanoid
    from clusterfem_ros.skeleton.jelly_body import jelly_man_mesh
    from clusterfem_ros.skeleton.kinematics import Skeleton
    from clusterfem_ros.skeleton.procedural_walk import procedural_walk
    from clusterfem_ros.fem.mass_scaling import scale_to_reference
    from clusterfem_ros.skeleton.smooth_body import smooth_jelly_man_meshes
    spec = default_humanoid()
    skeleton = Skeleton.from_urdf_string(spec.urdf)
    traj = procedural_walk(duration + step, 1.0 / step)
    if mesh is None and (skin or scene_default("body.skin")) == "smooth":
        mesh, mass_reference = smooth_jelly_man_meshes(spec, target_tets=target_tets)
    elif mesh is None:
        mesh = jelly_man_mesh(spec, target_tets=target_tets)
    material = Material(E=scene_default("material.young_modulus"), nu=scene_default("material.poisson_ratio"),
                        rho=scene_default("material.density"), xi=scene_default("material.mass_damping"),
                        zeta=scene_default("material.stiffness_damping"))
    model = build_model(mesh, material, gravity=(0.0, 0.0, scene_default("physics.gravity")))
    if mass_reference is not None:
        model, _ = scale_to_reference(model, mass_reference)
    q0 = rest_configuration(skeleton)
    starts, ends = skeleton.bone_segments(q0)
    rest = skeleton.forward(q0, np.zeros(getattr(skeleton, "nv", None) or traj.sample(0.0)[1].size))
    binding = bind_to_skeleton(model.rest, starts, ends, scene_default("binding.level_radii"),
                               rest_rotation=rest.rotation, rest_translation=rest.translation,
                               bone_names=skeleton.bone_names, warn=False)
    gains = LevelGains(tuple(scene_default("binding.kp")), tuple(scene_default("binding.kd")))
    return skeleton, traj, model, binding, gains


def scene_kappa() -> float:
    """The default scene's whole-volume pressure kappa (material.volume_stiffness resolved for the jelly man)."""
    return SceneConfig().material.volume_stiffness


def run(skeleton, traj, model, binding, gains, warp: bool | str, duration: float, step: float,
        kappa: float | None = None) -> dict:
    """Walk for ``duration`` s; time it after a 20-step warm-up (JIT compile) that is then discarded. ``warp``:
    False (linear), True (the default warping model) or a warping model's name ('element', 'vertex', 'neohookean');
    ``kappa``: the whole volume's pressure (default: the scene's, ``scene_kappa``; 0 = none), evaluated once a step
    from the state it starts from and held over its sub-steps, as the scene does."""
    pressure = volume_pressure(model, scene_kappa() if kappa is None else kappa, step)
    opts = {"warp": bool(warp)}
    if isinstance(warp, str):
        opts["warping_model"] = warp
        opts["allow_unbounded_warping"] = warp == "vertex"     # the paper's model, for comparison
    integ = make_integrator("clustered", model, threads=False, **opts)    # one core, as printed
    tets = model.mesh.tets
    v0 = float(signed_volumes(model.rest, tets).sum())

    def simulate(steps: int, timed: bool):
        driver = SkeletonDriver(binding, model.rest, gains, bone_names=skeleton.bone_names)
        state = driver.rigid_state(skeleton.forward(*traj.sample(0.0)))
        vol_err, track, subs = 0.0, 0.0, []
        t0 = time.perf_counter()
        for k in range(steps):
            control = driver.control(skeleton.forward(*traj.sample(k * step)), step, state=state,
                                     f_ext=None if pressure is None else pressure.force(state.u))
            if timed:
                track = max(track, float(driver.tracking_error(state)[0]))
            info = integ.step(state, control, step)
            subs.append(info.substeps)
            if timed and k % 10 == 0:
                vol = float(signed_volumes(model.rest + state.u, tets).sum())
                vol_err = max(vol_err, abs(vol / v0 - 1.0))
        return time.perf_counter() - t0, vol_err, track, subs, state.u.copy()

    simulate(20, False)
    steps = int(round(duration / step))
    # the volume/tracking probes cost time: time a clean run, measure on a second one
    wall, _, _, subs, _ = simulate(steps, False)
    _, vol_err, track, _, u_end = simulate(steps, True)
    return {"steps/s": steps / wall, "rtf": steps * step / wall, "substeps": (min(subs), max(subs)),
            "substeps_mean": float(np.mean(subs)),
            "volume": vol_err, "track": track, "u_end": u_end}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=3.0, help="walking time simulated per run [s] (default 3)")
    ap.add_argument("--step", type=float, default=1e-3, help="physics step h [s] (default 1e-3)")
    ap.add_argument("--tets", type=int, default=int(scene_default("body.target_tets")),
                    help="approximate tet count of the jelly man (default: the scene's)")
    ap.add_argument("--kappa", type=float, default=None,
                    help="the whole volume's pressure, material.volume_stiffness (default: the scene's; 0 = none)")
    args = ap.parse_args(argv)
    try:
        skeleton, traj, model, binding, gains = build_scene(args.tets, args.duration, args.step)
    except ImportError as e:
        print(f"jelly report cannot run yet: {e}; it needs clusterfem_ros.skeleton (kinematics, humanoid, "
              "procedural_walk, jelly_body)", file=sys.stderr)
        return 2
    nq = traj.sample(0.0)[0].size
    print(f"jelly man: {model.mesh.n_vertices} vertices, {model.mesh.n_tets} tets; skeleton {len(skeleton.bone_names)} "
          f"bones, nq = {nq}; {binding.summary()}; gains kp {gains.kp} kd {gains.kd}; h = {args.step:g} s, "
          f"{args.duration:g} s of walking per run; volume pressure kappa "
          f"{scene_kappa() if args.kappa is None else args.kappa:g}", flush=True)
    for w in binding.warnings:
        print(f"  binding: {w}")
    rows = []
    for warp in (False, "element", "vertex", "neohookean"):
        print(f"  running warp={warp} ...", file=sys.stderr, flush=True)
        try:
            r = run(skeleton, traj, model, binding, gains, warp, args.duration, args.step, args.kappa)
        except TypeError as e:
            rows.append([f"clustered, warp={warp}", "n/a", "n/a", "n/a", "n/a", "n/a", f"{e}"])
            continue
        s0, s1 = r["substeps"]
        rows.append([f"clustered, warp={warp}", f"{r['steps/s']:.0f}", f"{r['rtf']:.2f}",
                     f"{s0}" if s0 == s1 else f"{s0}-{s1}", f"{r['volume'] * 100:.2f} %",
                     f"{r['track'] * 1e3:.2f}", f"{r['steps/s'] / PAPER_STEPS_PER_S:.2f}x paper"])
    print(table(["run", "steps/s", "real-time factor", "sub-steps", "max volume error", "level-0 tracking mm",
                 f"vs paper {PAPER_STEPS_PER_S:.0f} steps/s"], rows))
    print("steps/s: skeleton forward kinematics + constraint targets + physics, wall clock, serial; "
          "volume error: max over the run of |sum of tet volumes / rest - 1|.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
