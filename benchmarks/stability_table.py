"""Hard cases x methods: does each method stay bounded, or refuse at set-up with a clear message?

    python -m benchmarks.stability_table [--scale 2] [--steps 300] [--max-substeps 1000]

Scene: a 0.4 x 0.1 x 0.1 m bar clamped at x = 0 under gravity, h = 10 ms, E = 1 MPa, nu = 0.3 (tip sag about 4 cm), unless the
case changes it. Per run we track the energy E = kinetic + elastic (linear 1/2 u.K u; the corotated
element energy for warped methods) against the budget: initial energy + work of gravity and external
forces (f . du per step) + the energy a prescribed vertex injects when it is set (E after - E before).
Bounded = no NaN / divergence and max E / budget <= ENERGY_SLACK (symplectic Euler's energy oscillates
a little above the true value near its step limit). Refused = StabilityError when the method is set up
(implicit with warping on nu > 0.49) or at the first step, before the state is touched (the explicit step
would need more than --max-substeps sub-steps). Implicit with warping sub-steps where vertex rotations
turn fast (fem/integrators/standard_implicit.py); its sub-step count is in the table.
Volume error = max over the run of |sum of signed tet volumes / rest - 1|.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from clusterfem_ros.fem.corotational import ElementCorotation
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.material import Material
from clusterfem_ros.fem.model import Control, FemModel, State, build_model
from clusterfem_ros.fem.stability import DivergenceError, StabilityError
from clusterfem_ros.fem.tet_mesh import TetMesh, signed_volumes
from clusterfem_ros.fem.voxel_mesh import box_mesh
from .timing import table

ENERGY_SLACK = 1.05
LENGTH, WIDTH = 0.4, 0.1

METHODS: dict[str, tuple[str, dict]] = {
    "clustered": ("clustered", {}),
    "clustered+warp": ("clustered", {"warp": True}),
    "standard explicit": ("standard_explicit", {}),
    "implicit direct": ("implicit_direct", {}),
    "implicit cg": ("implicit_cg", {}),
    "implicit direct+warp": ("implicit_direct", {"warp": True}),
    "implicit cg+warp": ("implicit_cg", {"warp": True}),
    "modal 30": ("modal", {"k": 30}),
}
EXPLICIT = ("clustered", "clustered+warp", "standard explicit")


def bar_mesh(scale: float = 1.0) -> TetMesh:
    n = max(1, int(round(2 * scale)))
    return box_mesh((LENGTH, WIDTH, WIDTH), (4 * n, n, n), (0.0, -WIDTH / 2, -WIDTH / 2))


def sliver_mesh(scale: float = 1.0) -> TetMesh:
    """The bar with one voxel layer (the 2nd along x) squashed to 1 % of its thickness: valid slivers."""
    mesh = bar_mesh(scale)
    grid = np.unique(mesh.vertices[:, 0])
    new = grid.copy()
    a = grid[1] - grid[0]
    new[2:] -= 0.99 * a                                   # layer 1 -> [a, 1.01 a]; the rest keeps its size
    new *= LENGTH / new[-1]
    x = mesh.vertices.copy()
    x[:, 0] = np.interp(x[:, 0], grid, new)
    return TetMesh(x, mesh.tets).validate()


def twist_state(model: FemModel, angle: float = np.pi) -> State:
    """The bar's cross-sections rotated about x by angle * x / L (the free end by ``angle``)."""
    s = State.rest(model)
    x = model.rest
    th = angle * x[:, 0] / LENGTH
    c, sn = np.cos(th), np.sin(th)
    s.u[:, 1] = c * x[:, 1] - sn * x[:, 2] - x[:, 1]
    s.u[:, 2] = sn * x[:, 1] + c * x[:, 2] - x[:, 2]
    return s


@dataclass
class Case:
    name: str
    material: Material = field(default_factory=lambda: Material(E=1e6))
    mesh: Callable[[float], TetMesh] = bar_mesh
    clamped: bool = True
    h: float = 0.01
    initial: Callable[[FemModel], State] | None = None
    teleport: float = 0.0                    # metres a prescribed end vertex jumps at step 1

    def model(self, scale: float) -> FemModel:
        mesh = self.mesh(scale)
        fixed = np.isclose(mesh.vertices[:, 0], 0.0) if self.clamped else None
        return build_model(mesh, self.material, fixed=fixed)


CASES = [
    Case("stiff E=1e7", Material(E=1e7)),
    Case("nu=0.49", Material(E=1e6, nu=0.49)),
    Case("nu=0.499", Material(E=1e6, nu=0.499)),
    Case("slivers 1%", mesh=sliver_mesh),
    Case("twist 180", initial=twist_state),
    Case("h=1/30", h=1.0 / 30.0),
    Case("teleport 0.5 m", teleport=0.5),
    Case("free fall", clamped=False),
]


@dataclass
class Result:
    method: str
    case: str
    outcome: str                 # "bounded", "refused", "diverged", "energy grew"
    energy_ratio: float = float("nan")
    volume_error: float = float("nan")
    substeps: int = 0
    message: str = ""


def run(method: str, case: Case, scale: float = 1.0, steps: int = 100, max_substeps: int = 1000) -> Result:
    model = case.model(scale)
    kind, options = METHODS[method]
    options = dict(options)
    if method in EXPLICIT:
        options["max_substeps"] = max_substeps
    try:
        integ = make_integrator(kind, model, **options)
    except StabilityError as exc:
        return Result(method, case.name, "refused", message=str(exc))
    warped = bool(options.get("warp"))
    corot = ElementCorotation(model) if warped else None

    def energy(s: State) -> float:
        el = corot.energy(s.u) if warped else model.elastic_energy(s.u)
        return model.kinetic_energy(s.v) + el

    state = case.initial(model) if case.initial else State.rest(model)
    tets = model.mesh.tets
    v0 = float(signed_volumes(model.rest, tets).sum())
    budget = energy(state)
    ratio, vol_err, sub = 0.0, 0.0, 0
    gravity = model.gravity_force()
    end = np.flatnonzero(np.isclose(model.rest[:, 0], LENGTH))[:1]
    for k in range(steps):
        control = Control()
        if case.teleport:
            pu = np.array([[0.0, 0.0, case.teleport if k >= 1 else 0.0]])
            control = Control(prescribed_index=end, prescribed_u=pu, prescribed_v=np.zeros((1, 3)))
            before = energy(state)
            state.u[end], state.v[end] = pu, 0.0
            budget += energy(state) - before              # work done by moving the constraint
        u_before = state.u.copy()
        try:
            info = integ.step(state, control, case.h)
        except StabilityError as exc:
            return Result(method, case.name, "refused", message=str(exc))
        except DivergenceError as exc:
            return Result(method, case.name, "diverged", ratio, vol_err, sub, str(exc))
        sub = max(sub, info.substeps)
        budget += float((gravity * (state.u - u_before)).sum())
        e = energy(state)
        if not np.isfinite(e):
            return Result(method, case.name, "diverged", ratio, vol_err, sub, f"energy {e} at step {k}")
        if budget > 0:
            ratio = max(ratio, e / budget)
        vol_err = max(vol_err, abs(float(signed_volumes(model.rest + state.u, tets).sum()) / v0 - 1.0))
    outcome = "bounded" if ratio <= ENERGY_SLACK else "energy grew"
    return Result(method, case.name, outcome, ratio, vol_err, sub)


def row(r: Result) -> list[str]:
    if r.outcome == "refused":
        return [r.case, r.method, "refused", "-", "-", ">limit"]
    return [r.case, r.method, r.outcome, f"{r.energy_ratio:.3f}", f"{r.volume_error * 100:.2f} %", str(r.substeps)]


HEADERS = ["case", "method", "outcome", "max E / budget", "max volume error", "sub-steps"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=2.0, help="mesh refinement (2: 16x4x4 voxels, 1280 tets)")
    ap.add_argument("--steps", type=int, default=300, help="steps per run")
    ap.add_argument("--max-substeps", type=int, default=1000, help="explicit sub-step limit per step")
    args = ap.parse_args(argv)
    rows, notes = [], []
    for case in CASES:
        for method in METHODS:
            print(f"  {case.name} / {method} ...", file=sys.stderr, flush=True)
            r = run(method, case, args.scale, args.steps, args.max_substeps)
            rows.append(row(r))
            if r.message:
                notes.append(f"{case.name} / {method}: {r.message}")
    mesh = bar_mesh(args.scale)
    print(f"Hard cases: {mesh.n_tets} tets / {mesh.n_vertices} vertices (slivers: same grid), {args.steps} steps, "
          f"explicit limit {args.max_substeps} sub-steps, bounded = max E / budget <= {ENERGY_SLACK}\n")
    print(table(HEADERS, rows))
    for n in notes:
        print(f"\n- {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
