"""Helper process for test_numba_cache.py (no tests here): runs threaded kernels with the cache in
NUMBA_CACHE_DIR and saves what they computed.

usage: python tests/test_numba_cache_child.py <out.npz> <what>...
  what: 'forces' (the threaded clustered and warped forces) and/or 'steps' (five threaded steps, linear and
  warped, of the paper's sphere from a fixed random state).
Saves each result under its name and prints one line per threaded build run: '<name> hits <h> misses <m>'
(numba's cache hits and misses for it in this process).
"""
from __future__ import annotations

import sys

import numpy as np

from benchmarks.core_benchmark import MATERIAL
from clusterfem_ros.fem.kernels.cluster_force_kernel import clustered_force, force_kernel_parallel
from clusterfem_ros.fem.materials.element_warping import element_force, element_kernel_parallel
from clusterfem_ros.fem.integrators.clustered_explicit import ClusteredExplicit, step_builds
from clusterfem_ros.fem.materials.registry import MODELS
from clusterfem_ros.fem.model import Control, State, build_model
from clusterfem_ros.fem.mesh.voxel_mesh import paper_mesh
from clusterfem_ros.fem.materials.warping import warped_force, warped_kernel_parallel


def sphere_and_state():
    """The paper's sphere and a fixed random state (u, v)."""
    model = build_model(paper_mesh("sphere"), MATERIAL)
    rng = np.random.default_rng(7)
    return model, 0.01 * rng.standard_normal((model.n_vertices, 3)), rng.standard_normal((model.n_vertices, 3))


def forces(model, u, v, threads: bool) -> dict[str, np.ndarray]:
    return {"clustered_force": clustered_force(model.clusters, u, v, model.mass, 1e-3, 1.0, threads=threads),
            "warped_force": warped_force(model, u, v, threads=threads),
            "element_force": element_force(model, u, v, threads=threads)}


def steps(model, u, v, threads: bool) -> dict[str, np.ndarray]:
    out = {}
    for warp in (False, "vertex", "element"):
        integ = ClusteredExplicit(model, warp=bool(warp), warping_model=warp or "element",
                                   allow_unbounded_warping=True, threads=threads)
        state = State.rest(model)
        state.u[:], state.v[:] = u, v
        for _ in range(5):
            integ.step(state, Control(), 1e-3)
        out[{False: "step", "vertex": "warped_step", "element": "element_step"}[warp]] = state.u.copy()
    return out


def builds(model) -> dict[str, dict]:
    """The threaded builds each kind of run uses: the force kernels, and the steps' (attachment-free) builds of
    the linear, vertex and element models (clustered_explicit.step_builds)."""
    def step(name):
        return step_builds(MODELS[name].clustered(model))[1][1]
    return {"forces": {"force_kernel_parallel": force_kernel_parallel, "warped_kernel_parallel": warped_kernel_parallel,
                       "element_kernel_parallel": element_kernel_parallel},
            "steps": {"step_parallel": step("linear"), "warped_step_parallel": step("vertex"),
                      "element_step_parallel": step("element")}}


def main(out: str, what: list[str]) -> None:
    model, u, v = sphere_and_state()
    results = {}
    for name in what:
        results.update({"forces": forces, "steps": steps}[name](model, u, v, threads=True))
        for build, d in builds(model)[name].items():
            print(f"{build} hits {sum(d.stats.cache_hits.values())} misses {sum(d.stats.cache_misses.values())}",
                  flush=True)
    np.savez(out, **results)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
