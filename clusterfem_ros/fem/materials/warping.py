"""The paper's per-vertex stiffness warping, kept for comparison (``warping_model = "vertex"``); the default is
per-element corotation (element_warping.py), the gradient of an energy, which this model is not: on an
inverting sliver or a torn vertex at the scene's damping it fed energy in (benchmarks/stability_table.py).

Stiffness warping (eq. 10) on the constant clusters: per-vertex rotations R_i, then, with w = x + zeta v,

    f_i = -sum_j 1/2 (R_i K_ij R_i^T + R_j K_ij R_j^T) (w_j - w_i - R_i (x0_j - x0_i))  -  xi m_i v_i.

Eq. 10 as printed is f_i = -R_i sum_j K_ij (R_i^T x_j - x0_j) = -sum_j R_i K_ij R_i^T (x_j - x_i - R_i (x0_j - x0_i))
(sum_j K_ij = 0): the same, with the block R_i K_ij R_i^T where we use its mean with R_j K_ij R_j^T. Why:
with the rotations held, eq. 10's force is linear in x with Jacobian blocks R_i K_ij R_i^T, and block
(j, i) = R_j K_ij^T R_j^T is not the transpose of block (i, j) once R_i != R_j. A non-symmetric stiffness
is not the gradient of any energy: it circulates energy (flutter). Where neighbouring rotations differ a
lot, as around a held vertex torn 0.5 m from its neighbours, eq. 10 gained energy: 1.3-3.1x the work put
in on the stability table's bar, growing exponentially with the rotations frozen. With the mean blocks,
block (j, i) of the held-rotation Jacobian is the transpose of block (i, j); what stays non-symmetric is
each vertex's own diagonal block, -sum_j of its row's others (K_ij is not symmetric, so the R_j halves do
not sum to a symmetric block). In the torn state that skew part was 0.24 % of the Jacobian's norm against
eq. 10's 4.1 % (largest imaginary eigenvalue part 340x smaller), and the case settles (max E / budget
0.93; benchmarks/stability_table.py, tests/test_hard_cases.py). Exact symmetry and translation invariance
together need one rotation per element (fem/materials/corotational.py). What stays exactly as in eq. 10: the same
constant clusters and per-vertex rotations; zero force for any rigid motion (all R_i equal: the two halves
coincide with eq. 10); linear FEM to second order for small deformations (the first-order part of
w_j - w_i - R_i d_ij is the linear one for every block of the row, since R_i is the row's); translation
invariance. Cost: six 3x3 matrix-vector products per block instead of two, and a rotation gather.
Stiffness damping uses the same symmetric blocks on the velocity differences (a rigid spin is not
damped); xi M v is unchanged.
Rotations are held fixed within the force: no dR/dx terms.

Rotation of vertex i: the least-squares deformation gradient of its cluster neighbourhood
    F_i = [sum_j (x_j - x_i)(x0_j - x0_i)^T] S_i^-1,   S_i = sum_j (x0_j - x0_i)(x0_j - x0_i)^T,
and R_i = polar(F_i) (rigid motion gives F_i = R exactly, at any angle up to 180 deg). The kernel evaluates
F_i = I + sum_j (u_j - u_i) g_j^T with the constant g_j = S_i^-1 (x0_j - x0_i) stored per block of the
cluster slices (warped_force_kernel.py).
R_i = polar(F_i) by the lane iteration of polar.py (scaled Newton, then Newton-Schulz, on LANES vertices at once;
Mueller's iteration, warm-started from the vertex's previous rotation, where the neighbourhood is inverted or
nearly flat).

The kernel makes two passes: all rotations (a row's force reads its neighbours'), then the forces, over the
linear kernel's slices (warped_force_kernel.py): per block y = R_i^T (w_j - w_i) - d_ij (so the bracket is
R_i y); the R_i half is R_i sum_j K_ij y, the row's rotation applied once after the loop; the R_j half is
sum_j R_j (K_ij (R_j^T (R_i y))).

``warped_force`` and ``vertex_rotations`` are the checked public entries; tests/naive_warping.py holds
the numpy twin; assembled_warp.py writes the same force with sparse matrices.

What a build injects: the kernel sources ``_rotations``, ``_warped_e`` and ``_warped_force`` call compiled
functions by global names that no import defines, bound per build (serial or threaded) by
numba_config.compiled, hence ``# noqa: F821`` at each call: ``copy_rows`` and ``gradient_sweep`` in
``_rotations``; ``rotations`` and ``sweep`` in ``_warped_e``; ``kernel_input``, ``warped_e`` and ``finish`` in
``_warped_force``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import prange

from ..kernels.cluster_force_kernel import (finish_parallel, finish_serial, input_rows, kernel_input_parallel,
                                            kernel_input_serial)
from ..kernels.cluster_slices import (ClusterSlices, aligned_zeros, host_slices, lane_vertices, position_lanes,
                                      rest_offsets)
from .kernel_args import checked_rows, output_rows, pick_build
from ..model import FemModel
from ...numba_config import SERIAL, compiled, serial_and_parallel
from .polar import LANES, chunk_start, lane_accepted, polar_lanes, scalar_rotation
from ..kernels.warped_force_kernel import (ROT_ROW, copy_rows_parallel, copy_rows_serial, gradient_sweep_parallel,
                                           gradient_sweep_serial, warped_sweep_parallel, warped_sweep_serial)

@numba.njit(**SERIAL)
def _chunk_rotations(k0, nl, owner, F, P, converged, how, tmp, rot, rot4):
    """rot[i] and rot4[i] (i = owner[k0 + l], skipped past the n vertices: padding lanes) <- lane l's polar
    factor P[:, l] if accepted, else the scalar path's, warm-started from the vertex's previous rotation."""
    n = rot.shape[0]
    for l in range(nl):
        i = owner[k0 + l]
        if i >= n:
            continue
        if lane_accepted(l, P, converged, how):
            for a in range(3):
                for b in range(3):
                    rot[i, a, b] = P[3 * a + b, l]
        else:
            scalar_rotation(l, F, tmp, rot[i])
        for a in range(3):
            for b in range(3):
                rot4[i, 4 * a + b] = rot[i, a, b]


@numba.njit(**SERIAL)
def _rotate_chunk(c, owner, F, rot, rot4, scratch, how, tmp):
    """Chunk c's vertex rotations: lanes c LANES.. of F (slice order), polar iteration on all lanes, stored."""
    k0 = c * LANES
    nl = min(LANES, F.shape[1] - k0)
    Fc = F[:, k0:k0 + nl]
    buf = scratch[c]
    chunk_start(nl, Fc, buf[0], how[c])
    P, converged = polar_lanes(nl, buf[0], buf[1])
    _chunk_rotations(k0, nl, owner, Fc, P, converged, how[c], tmp[c], rot, rot4)


# The warped kernels, one source each, serial and threaded builds (the module docstring names the globals
# each build binds).
# Argument groups (VertexFrames): ``gradients`` and ``slices``, the two sweeps' slice arrays; ``work``, the
# workspace (rot, rot4, u_rows, F, scratch, how, tmp, e).

def _rotations(gradients, u, work):
    """rot, rot4 <- the vertex rotations of u: the gradient sweep, then the polar iteration by chunks."""
    rot, rot4, u_rows, F, scratch, how, tmp, _ = work
    sh_ptr, shared, boundary, lane_vertex, owner = gradients
    copy_rows(u, u_rows)  # noqa: F821 (bound)
    gradient_sweep(sh_ptr, shared, boundary, (u_rows, lane_vertex, F))  # noqa: F821
    for c in prange(scratch.shape[0]):
        _rotate_chunk(c, owner, F, rot, rot4, scratch, how, tmp)


def _warped_e(gradients, slices, u, w, work):
    """e <- the elastic-damping part of the warped force of w = x0 + u + zeta v (warped_force_kernel.py), in
    rows by vertex (the padding lanes' rows after the n vertices'); rot <- the vertex rotations of u. Every
    rotation first (a row reads its neighbours'), then the sweep."""
    rotations(gradients, u, work)  # noqa: F821 (bound)
    sh_ptr, shared, boundary, lane_vertex, owner = slices
    sweep(sh_ptr, shared, boundary, (w, work[1], lane_vertex, owner, work[7]))  # noqa: F821


def _warped_force(gradients, slices, rest, u, v, w, mass3, zeta, xi, work, out):
    """out <- the warped force of (u, v), f = -e - xi M v (mass3: the lumped mass per coordinate)."""
    kernel_input(u.shape[0], zeta, rest, u, v, w, True)  # noqa: F821 (bound)
    warped_e(gradients, slices, u, w, work)  # noqa: F821
    finish(work[7], v, mass3, xi, out)  # noqa: F821


rotation_kernel_serial, rotation_kernel_parallel = serial_and_parallel(
    _rotations, serial={"gradient_sweep": gradient_sweep_serial, "copy_rows": copy_rows_serial},
    parallel={"gradient_sweep": gradient_sweep_parallel, "copy_rows": copy_rows_parallel})
# no loop of their own: their callees carry the threads
warped_e_serial = compiled(_warped_e, rotations=rotation_kernel_serial, sweep=warped_sweep_serial)
warped_e_parallel = compiled(_warped_e, "_parallel", rotations=rotation_kernel_parallel, sweep=warped_sweep_parallel)
warped_kernel_serial = compiled(_warped_force, kernel_input=kernel_input_serial, warped_e=warped_e_serial,
                                finish=finish_serial)
warped_kernel_parallel = compiled(_warped_force, "_parallel", kernel_input=kernel_input_parallel,
                                  warped_e=warped_e_parallel, finish=finish_parallel)


def rest_gram_inverse(model: FemModel) -> np.ndarray:
    """S_i^-1, (n, 3, 3): inverse of sum_j (x0_j - x0_i)(x0_j - x0_i)^T over each vertex's cluster."""
    ptr, cols = model.clusters.neighbours()
    rows = np.repeat(np.arange(model.n_vertices), np.diff(ptr))
    d = model.rest[cols] - model.rest[rows]
    S = np.zeros((model.n_vertices, 3, 3))
    np.add.at(S, rows, d[:, :, None] * d[:, None, :])
    det = np.linalg.det(S)
    scale = np.einsum("nii->n", S) ** 3
    bad = np.flatnonzero(~(det > 1e-12 * scale))
    if bad.size:
        raise ValueError(f"vertex {bad[0]}'s cluster neighbours are coplanar (det S = {det[bad[0]]:.3g}): "
                         "its rotation is undefined; fix the mesh (every vertex needs a non-flat tet)")
    return np.linalg.inv(S)


@dataclass
class VertexFrames:
    """What warping keeps per model: rest positions, S_i^-1, each vertex's last rotation (the fallback's
    warm start), the kernels' argument groups over the cluster slices (cluster_slices.py) and workspace."""
    rest: np.ndarray        # (n, 3)
    s0inv: np.ndarray       # (n, 3, 3)
    rot: np.ndarray         # (n, 3, 3), updated by every force / rotation call
    gradients: tuple        # the gradient sweep's: (sh_ptr, (sh_w_at, sh_grads), (bd_w_at, bd_grads), lane_vertex,
                            #   owner); g = S_i^-1 (x0_j - x0_i) per block, (P, 3, C)
    slices: tuple           # the force sweep's: (sh_ptr, (sh_w_at, sh_blocks, sh_offsets), (bd_w_at, bd_blocks,
                            #   bd_offsets), lane_vertex, owner); offsets d = x0_j - x0_i per block, (P, 3, C)
    w: np.ndarray           # (lanes + 1, 3) workspace: x + zeta v in the first n rows (input_rows)
    rot4: np.ndarray        # (n, 12) workspace: the rotations' rows padded to 4
    u_rows: np.ndarray      # (lanes + 1, 3) workspace: u in the first n rows (input_rows)
    F: np.ndarray           # (9, n_slices * C) workspace: deformation gradient per lane, slice order
    scratch: np.ndarray     # (chunks, 2, 9, LANES) workspace: polar iterates
    how: np.ndarray         # (chunks, LANES) workspace: 0 polar, 1 inverted/flat
    tmp: np.ndarray         # (chunks, 2, 3, 3) workspace of the scalar fallback
    e: np.ndarray           # (n_slices * C, 3) workspace: the force sweep's rows (vertex i's in row i)

    @classmethod
    def from_model(cls, model: FemModel, slices: ClusterSlices | None = None) -> "VertexFrames":
        """``slices``: the cluster slices to walk (default the model's, as wide as this host's vectors)."""
        n = model.n_vertices
        sl = host_slices(model.clusters) if slices is None else slices
        lanes = len(sl.owner)
        chunks = -(-lanes // LANES)
        rest = np.ascontiguousarray(model.rest, dtype=np.float64)
        s0inv = rest_gram_inverse(model)
        lane_vertex = lane_vertices(sl)
        offsets = rest_offsets(sl, rest)
        grads = []
        for d, own in zip(offsets, position_lanes(sl)):       # g = S_i^-1 d per entry; zero where d is
            g = aligned_zeros(d.shape)
            g[...] = np.einsum("pcab,pbc->pac", s0inv[own], d)
            grads.append(g)
        gradients = (sl.shared_ptr, (sl.shared_w_at, grads[0]), (sl.boundary_w_at, grads[1]), lane_vertex, sl.owner)
        slices = (sl.shared_ptr, (sl.shared_w_at, sl.shared_blocks, offsets[0]),
                  (sl.boundary_w_at, sl.boundary_blocks, offsets[1]), lane_vertex, sl.owner)
        return cls(rest, s0inv, np.repeat(np.eye(3)[None], n, axis=0), gradients, slices,
                   input_rows(sl), aligned_zeros((n, ROT_ROW)), input_rows(sl), aligned_zeros((9, lanes)),
                   np.zeros((chunks, 2, 9, LANES)), np.zeros((chunks, LANES), dtype=np.int8),
                   np.zeros((chunks, 2, 3, 3)), np.zeros((lanes, 3)))

    @property
    def work(self) -> tuple:
        """The kernels' workspace group: (rot, rot4, u_rows, F, scratch, how, tmp, e)."""
        return self.rot, self.rot4, self.u_rows, self.F, self.scratch, self.how, self.tmp, self.e


def vertex_rotations(model: FemModel, u: np.ndarray, frames: VertexFrames | None = None,
                     threads: bool | None = None) -> np.ndarray:
    """R_i for every vertex, (n, 3, 3), of the displacement u (n, 3)."""
    (u,) = checked_rows(model, u=u)
    frames = VertexFrames.from_model(model) if frames is None else frames
    kern = pick_build(model.n_vertices, threads, rotation_kernel_serial, rotation_kernel_parallel)
    kern(frames.gradients, u, frames.work)
    return frames.rot.copy()


def warped_force(model: FemModel, u: np.ndarray, v: np.ndarray | None = None, frames: VertexFrames | None = None,
                 out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """Warped elastic + damping force, (n, 3): eq. 10 with symmetric blocks (module docstring)."""
    u, = checked_rows(model, u=u)
    v, = checked_rows(model, v=np.zeros_like(u) if v is None else v)
    frames = VertexFrames.from_model(model) if frames is None else frames
    n = model.n_vertices
    out = output_rows(n, out)
    kern = pick_build(n, threads, warped_kernel_serial, warped_kernel_parallel)
    m = model.material
    kern(frames.gradients, frames.slices, frames.rest, u, v, frames.w, np.repeat(model.mass, 3), float(m.zeta),
         float(m.xi), frames.work, out)
    return out
