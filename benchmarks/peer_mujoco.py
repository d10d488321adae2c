"""A peer side by side: the same mesh, material, load and step in MuJoCo's tetrahedral flex bodies.

    python -m benchmarks.peer_mujoco [--shapes sphere cube torus] [--step 1e-3] [--duration 0.5]

MuJoCo is pinned in requirements.lock (4.0.0) and runs in the speed-vs-error report's run; without it
this prints how to install it and exits 0. Each paper shape, bottom 20 % pinned, falls under gravity
from rest for ``duration`` s in both simulators at the same step; printed per shape: ms/step of each
(median of per-step wall times after warm-up), the peak sag, and how far MuJoCo's final shape is from
our converged reference of the linear model (scenarios.reference).

What each computes (so the comparison is honest):
- ours: linear (Cauchy-strain) FEM, lumped mass by tet volume, Rayleigh damping D = xi M + zeta K,
  the clustered explicit step (symplectic Euler, sub-stepped below the critical step), serial numba.
- MuJoCo (flexcomp type="direct", dim=3, <elasticity young poisson damping>): each vertex a body with
  three slide DOFs; tet elasticity as passive forces written on the change of squared edge lengths
  (a Green-strain, St. Venant-Kirchhoff-like model: rotation invariant, nonlinear in large strain),
  stiffness-proportional damping only (our mass damping xi has no flex counterpart here), flexcomp's
  own mass distribution of the total mass rho V, its default semi-implicit Euler (option 'euler'), or
  'implicitfast' with --integrator; collisions off.
So at small strain the two model the same elastic body; the remaining differences are mass lumping,
the missing mass damping, and the integrator.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from clusterfem_ros.fem.integrators import make_integrator
from .core_benchmark import MATERIAL
from .scenarios import reference, shape_scenario, simulate
from .timing import table


def mujoco_or_none():
    try:
        import mujoco
        return mujoco
    except ImportError:
        return None


def flex_xml(vertices: np.ndarray, tets: np.ndarray, pinned: np.ndarray, mass: float, h: float,
             integrator: str = "Euler") -> str:
    """MJCF of one 3-D flex body with the given tets (a flexcomp of type 'direct')."""
    pts = " ".join(f"{x:.9g}" for x in vertices.ravel())
    el = " ".join(str(int(i)) for i in tets.ravel())
    pin = " ".join(str(int(i)) for i in pinned)
    return (f'<mujoco><option timestep="{h!r}" gravity="0 0 -9.81" integrator="{integrator}"/><worldbody>'
            f'<flexcomp name="body" type="direct" dim="3" point="{pts}" element="{el}" mass="{mass!r}" '
            f'radius="0.001"><contact contype="0" conaffinity="0" selfcollide="none"/>'
            f'<edge equality="false"/><elasticity young="{MATERIAL.E!r}" poisson="{MATERIAL.nu!r}" '
            f'damping="{MATERIAL.zeta!r}"/><pin id="{pin}"/></flexcomp></worldbody></mujoco>')


def run_mujoco(mujoco, sc, h: float, integrator: str) -> dict:
    """Step MuJoCo over the scenario; returns ms/step, flex vertex positions at the samples, masses."""
    mesh, model = sc.model.mesh, sc.model
    xml = flex_xml(mesh.vertices, mesh.tets, np.flatnonzero(model.fixed), MATERIAL.rho * float(mesh.volumes().sum()),
                   h, integrator)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    warm = mujoco.MjData(m)
    for _ in range(3):
        mujoco.mj_step(m, warm)
    per = int(round(sc.sample_dt / h))
    u = np.empty((sc.n_samples, model.n_vertices, 3))
    times = []
    for j in range(sc.n_samples):
        for _ in range(per):
            t0 = time.perf_counter()
            mujoco.mj_step(m, d)
            times.append(time.perf_counter() - t0)
        u[j] = d.flexvert_xpos - mesh.vertices
    masses = m.body_mass[1:]
    return {"ms": float(np.median(times)) * 1e3, "u": u, "mass_range": (float(masses.min()), float(masses.max())),
            "nv": int(m.nv)}


def run_ours(sc, h: float) -> dict:
    integ = make_integrator("clustered", sc.model)
    r = simulate(sc, integ, h)
    return {"ms": r.ms_per_step, "u": r.u, "substeps": r.substeps}


HEADERS = ["shape", "ours ms/step", "MuJoCo ms/step", "MuJoCo/ours", "peak sag mm ref / ours / MuJoCo",
           "final max |u - u_ref| mm ours / MuJoCo", "vertex mass g"]
NOTE = ("u_ref: our linear model's converged reference. MuJoCo's distance from it is model difference "
        "(mass lumping, no mass damping, nonlinear strain) plus its integration error, not only error.")


def compare(shapes, h: float, duration: float, integrator: str, progress=print) -> list[list[str]] | None:
    """One row per shape (HEADERS), or None when MuJoCo is not installed."""
    mujoco = mujoco_or_none()
    if mujoco is None:
        return None
    rows = []
    for name in shapes:
        sc = shape_scenario(name, duration, 0.01)
        progress(f"  {name}: reference, ours, MuJoCo ...")
        ref = reference(sc, "linear").u
        ours = run_ours(sc, h)
        try:
            mj = run_mujoco(mujoco, sc, h, integrator)
        except Exception as e:                  # MuJoCo refuses the model or diverges: say so, keep going
            rows.append([name, f"{ours['ms']:.3f}", f"MuJoCo failed: {str(e).splitlines()[0][:80]}", "", "", "", ""])
            continue
        sag = lambda u: float(-u[..., 2].min()) * 1e3  # noqa: E731
        ok = np.isfinite(mj["u"]).all()
        diff = float(np.linalg.norm(mj["u"][-1] - ref[-1], axis=1).max()) * 1e3 if ok else float("nan")
        ours_diff = float(np.linalg.norm(ours["u"][-1] - ref[-1], axis=1).max()) * 1e3
        lm = sc.model.mass
        rows.append([f"{name} ({sc.model.n_vertices} v, {sc.model.mesh.n_tets} t)", f"{ours['ms']:.3f}",
                     f"{mj['ms']:.3f}", f"{mj['ms'] / ours['ms']:.1f}x",
                     f"{sag(ref):.2f} / {sag(ours['u']):.2f} / {sag(mj['u']) if ok else float('nan'):.2f}",
                     f"{ours_diff:.3f} / {diff:.3f}",
                     f"ours {lm.min() * 1e3:.2f}-{lm.max() * 1e3:.2f}, MuJoCo {mj['mass_range'][0] * 1e3:.2f}-"
                     f"{mj['mass_range'][1] * 1e3:.2f}"])
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=["sphere", "cube", "torus"], choices=["sphere", "cube", "torus"])
    ap.add_argument("--step", type=float, default=1e-3, help="step h [s] for both (default 1e-3)")
    ap.add_argument("--duration", type=float, default=0.5, help="simulated time [s] (default 0.5)")
    ap.add_argument("--integrator", default="Euler", choices=["Euler", "implicitfast", "implicit"],
                    help="MuJoCo integrator (default its default, Euler)")
    args = ap.parse_args(argv)
    mujoco = mujoco_or_none()
    if mujoco is None:
        print("MuJoCo is not installed: `pip install mujoco` (optional peer; tried with mujoco 4.0.0) and run again")
        return 0
    print(f"peer: MuJoCo {mujoco.__version__} flex (dim 3) vs our clustered step; h = {args.step:g} s, "
          f"{args.duration:g} s under gravity from rest; E={MATERIAL.E:g} Pa nu={MATERIAL.nu} rho={MATERIAL.rho:g} "
          f"zeta={MATERIAL.zeta:g} (ours also xi={MATERIAL.xi}); MuJoCo integrator {args.integrator}", flush=True)
    rows = compare(args.shapes, args.step, args.duration, args.integrator,
                   progress=lambda s: print(s, file=sys.stderr, flush=True))
    print(table(HEADERS, rows))
    print(NOTE)
    return 0


if __name__ == "__main__":
    sys.exit(main())
