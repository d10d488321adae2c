"""The Neo-Hookean step plan against the true tangent's largest eigenvalue on the character's walk.

    python -m benchmarks.stretch_plan_check [--scene config/character_walk.yaml] [--bvh CLIP] [--duration 0.3]
        [--first 30] [--every 25]

The scene (plan_stretch on) walks the capture on the input clock; at each of the ``--first`` steps after placement
and every ``--every``-th step after, the state the step starts from is taken and the true largest eigenvalue of
M^-1 K_t is computed (K_t the Neo-Hookean tangent at u, from central differences of the stress P(F) per element,
assembled; the scaled masses; eigsh), beside what the plan made of the same state: the element-by-element need
max_e r_e s_e (fem/materials/stretch.py, the stiffening alone: the character is damped), the factor the step took
(rounded, held) and the body-wide need max_e s_e, all in units of the linear K's lambda_max. A plan stays stable
while the true eigenvalue is below 1 / safety^2 of the factor (1.56 at the default 0.8).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from clusterfem_ros.config import load_scene_file
from clusterfem_ros.fem.linear.assembly import shape_gradients
from clusterfem_ros.fem.materials.corotational import deformation_gradients
from clusterfem_ros.fem.materials.neohookean import parameters
from clusterfem_ros.fem.materials.stretch import element_need
from clusterfem_ros.scene import Scene
from .character_report import DEFAULT_BVH, DEFAULT_SCENE, bvh_skeleton
from .timing import table


class TrueTangent:
    """The largest eigenvalue of M^-1 K_t of a Neo-Hookean model at displacement u (module docstring)."""

    def __init__(self, model):
        self.model = model
        self.lam_s, self.alpha = parameters(*model.material.lame)
        self.mu = model.material.lame[1]
        tets = np.asarray(model.mesh.tets)
        self.g, self.vol = shape_gradients(model.rest, tets)
        self.B = np.zeros((len(tets), 9, 12))           # corner displacements (c, a) -> F entries (a, j)
        for c in range(4):
            for a in range(3):
                self.B[:, 3 * a:3 * a + 3, 3 * c + a] = self.g[:, c, :]
        dof = (3 * tets[:, :, None] + np.arange(3)).reshape(len(tets), 12)
        self.rows, self.cols = np.repeat(dof, 12, axis=1).ravel(), np.tile(dof, (1, 12)).ravel()
        self.s = 1.0 / np.sqrt(np.repeat(model.mass, 3))
        self.tets = tets

    def _stress(self, F):
        c = np.stack([np.cross(F[:, 1], F[:, 2]), np.cross(F[:, 2], F[:, 0]), np.cross(F[:, 0], F[:, 1])], axis=1)
        return self.mu * F + (self.lam_s * (np.linalg.det(F) - self.alpha))[:, None, None] * c

    def largest(self, u: np.ndarray) -> float:
        F = deformation_gradients(self.g, self.tets, u)
        T = np.empty((F.shape[0], 9, 9))
        eps = 1e-6
        for k in range(9):
            d = np.zeros(9)
            d[k] = eps
            d = d.reshape(3, 3)
            T[:, :, k] = ((self._stress(F + d) - self._stress(F - d)) / (2 * eps)).reshape(-1, 9)
        Ke = self.vol[:, None, None] * np.einsum("eia,eij,ejb->eab", self.B, 0.5 * (T + np.swapaxes(T, 1, 2)), self.B)
        n3 = 3 * self.model.n_vertices
        K = sp.csr_matrix((Ke.ravel(), (self.rows, self.cols)), shape=(n3, n3))
        free = self.model.free_dofs
        A = (sp.diags(self.s) @ K @ sp.diags(self.s))[free][:, free]
        return float(spla.eigsh(A, k=1, which="LA", tol=1e-6, return_eigenvectors=False)[0])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", type=Path, default=DEFAULT_SCENE)
    ap.add_argument("--bvh", type=Path, default=DEFAULT_BVH)
    ap.add_argument("--duration", type=float, default=0.3)
    ap.add_argument("--first", type=int, default=30)
    ap.add_argument("--every", type=int, default=25)
    a = ap.parse_args(argv)
    config = load_scene_file(a.scene).with_values({"physics.plan_stretch": True})
    urdf, traj = bvh_skeleton(a.bvh)
    scene = Scene.build(config, urdf_xml=urdf)
    integ = scene.integrator
    plan = integ.stretch
    if plan is None or plan.energy != "neohookean":
        raise SystemExit(f"{a.scene}: the scene does not run the Neo-Hookean plan (warping_model {integ.name!r})")
    ones, lanes = np.ones_like(plan.weights), np.empty(plan.weights.shape[1])
    taken = []
    stiffer = integ._stiffer

    def spy(state, h, parallel):
        out = stiffer(state, h, parallel)
        k = len(taken)
        if k < a.first or k % a.every == 0:
            kept = integ._parts.bound()
            weighed = element_need(kept, plan.weights, plan.rest_modulus, 4.0, 1.0, 0.0, lanes)
            unweighed = element_need(kept, ones, plan.rest_modulus, 4.0, 1.0, 0.0, lanes)
            taken.append((k, scene.sim_time, out[0], weighed, unweighed, state.u.copy()))
        else:
            taken.append(None)
        return out

    integ._stiffer = spy
    for k in range(int(a.duration * 120.0) + 1):
        t = k / 120.0
        q, v = traj.sample(t, loop=True)
        scene.push_joint_state(t, traj.names, q, v)
        scene.follow_inputs()
    true = TrueTangent(scene.model)
    lam = integ.lam_max
    rows, ratios = [], []
    for rec in taken:
        if rec is None:
            continue
        k, t, factor, need, whole, u = rec
        x = true.largest(u) / lam
        ratios.append((x, factor, need))
        rows.append([k, f"{t:.3f}", f"{x:.3f}", f"{need:.3g}", f"{factor:.3g}", f"{whole:.3g}", f"{x / factor:.3f}"])
    print(f"{a.scene.name} walking {a.bvh.name}: the plan against the true tangent (units of lambda_max "
          f"{lam:.4g} 1/s^2; stable while true / factor < {1 / integ.safety ** 2:.3g})")
    print(table(["step", "t [s]", "true", "need, element by element", "factor taken", "need, body-wide",
                 "true / factor"], rows))
    x, f, n = (np.array(c) for c in zip(*ratios))
    print(f"need / true: {np.min(n / x):.2f} .. {np.max(n / x):.2f}; largest true / factor {np.max(x / f):.3f}")


if __name__ == "__main__":
    main()
