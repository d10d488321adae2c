"""The warped force's passes over the clusters (eq. 10, symmetric blocks; fem/materials/warping.py), C rows at a time:
the vertices' deformation gradients (for their rotations), then the force.

With w = x0 + u + zeta v and the vertex rotations R held, the elastic-damping part of the warped force is

    e_i = 1/2 sum_j (R_i K_ij R_i^T + R_j K_ij R_j^T) (w_j - w_i - R_i d_ij),   d_ij = x0_j - x0_i,

and f_i = -e_i - xi m_i v_i, the linear kernel's convention with K w replaced by e (cluster_force_kernel.py).
Per block, with z = w_j - w_i: y = R_i^T z - d_ij, t = z - R_i d_ij (= R_i y); the R_i half is R_i sum_j K_ij y,
rotated once per row after the loop, the R_j half is sum_j R_j K_ij R_j^T t.

The pass walks the same slices as the linear kernel (cluster_slices.py: C rows per slice, lane l for row l),
with d_ij stored per block beside K_ij (``rest_offsets``) and the rotations as rows of 4 (x, y, z, padding)
per matrix row, so that R_j is gathered like w_j: C row loads and one transpose per matrix row (R_j's rows
start at ROT_ROW j = 4 w_at). The row kernel it replaced did the 54 products of a block one lane at a time:
12-18 ns per block on the jelly man on an AMD EPYC VM (Zen 4), where this sweep takes ~4 ns
(tests/test_warped_force_kernel.py checks it against the twin).

The deformation gradients, F_i = I + sum_j (u_j - u_i) g_ij^T with the constant g_ij = S_i^-1 d_ij
(fem/materials/warping.py), walk the same slices with g stored per block (P, 3, C) and u copied (``copy_rows``) into
rows like w's (a row per lane and one more: cluster_force_kernel.input_rows): nine C-wide FMAs per position. Lane l of
slice s writes column C s + l of F (9, S C), so the polar iteration that follows runs over contiguous lanes in slice
order. The row loop it replaced took 5.6 ns per block, most of the rotations' time.

What a build injects: nothing here is called by an unbound name. The two slice kernels are numba intrinsics
(LLVM IR from llvm_ir.py); cluster_force_kernel.slice_sweep builds the loop over every slice around each, binding
the kernel as that loop's global ``slice_kernel``.
"""
from __future__ import annotations

from llvmlite import ir
from numba import prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from .cluster_force_kernel import slice_sweep
from .cluster_slices import W_ROW
from .llvm_ir import (F64, accumulating_loop, double_data, fused_multiply_add, gathered_rows, i64, lane_values,
                      position_entries, slice_kernel_args, slice_kernel_typing, store_lane_rows, vector_at)
from ...numba_config import serial_and_parallel

# Doubles per vertex in the rotations' kernel copy: three rows of (R_a0, R_a1, R_a2, padding); a multiple of
# W_ROW, so R_j's rows start at (ROT_ROW / W_ROW) w_at.
ROT_ROW = 12


_WARPED_SPECS = (("w_at", 2, types.int64), ("blocks", 3, types.float64), ("offsets", 3, types.float64),
                 ("w", 2, types.float64), ("rot4", 2, types.float64), ("lane_vertex", 1, types.int64),
                 ("owner", 1, types.int64), ("out", 2, types.float64))


@intrinsic(prefer_literal=True)
def _warped_slice(typingctx, lanes, s, p0, p1, per_position, common):
    """out[owner[C s + l]] <- e of lane l's vertex (module docstring) over positions p0..p1 of slice s;
    per_position = (w_at, blocks, offsets), common = (w, rot4, lane_vertex, owner, out).

    ``lanes`` (C, a literal) rows at once. Per slice: the C rows' own w_i and R_i (lane_vertex[C s + l]; for a
    padding lane any vertex: its blocks and offsets are zero). Per position: w_j and the three rows of R_j
    gathered (w at w_at = 3 j, the rotation's rows of 4 at 4 w_at) and transposed into C-wide vectors, then the
    block's nine entries and three offsets as C-wide loads; FMAs in a fixed order, so serial and threaded
    builds agree to the bit. w_at (P, C) int64, blocks (P, 9, C), offsets (P, 3, C), w (S C + 1, 3)
    (input_rows), rot4 (n, 12), lane_vertex and owner (S C,) int64, out (S C, 3), all C-contiguous
    (checked at typing); the caller checks the shapes.
    """
    C, sig = slice_kernel_typing("_warped_slice", lanes, s, p0, p1, per_position, common, _WARPED_SPECS)
    VC = ir.VectorType(F64, C)

    def codegen(context, builder, signature, args):
        sv, p0v, p1v, arrays = slice_kernel_args(context, builder, signature, args)
        atp, lvp, ownp = arrays[0].data, arrays[5].data, arrays[6].data
        blkp, offp, wp, rp, outp = (double_data(builder, arrays[k]) for k in (1, 2, 3, 4, 7))
        mul, sub, add = builder.fmul, builder.fsub, builder.fadd

        def fma(a, b, c):
            return fused_multiply_add(builder, a, b, c)

        def gathered(w_offsets):
            """w_j (3 vectors) and R_j (3 x 3 vectors, [a][b] = R[a, b]) of the lanes' w offsets W_ROW j."""
            r_at = [builder.mul(at, i64(ROT_ROW // W_ROW)) for at in w_offsets]
            return (gathered_rows(builder, wp, w_offsets),
                    [gathered_rows(builder, rp, [builder.add(at, i64(4 * a)) for at in r_at]) for a in range(3)])

        first_lane = builder.mul(sv, i64(C))
        wi, ri = gathered([builder.mul(i, i64(W_ROW)) for i in lane_values(builder, lvp, first_lane, C)])
        zero = ir.Constant(VC, [0.0] * C)

        def position(p, acc):
            f, g = acc[:3], acc[3:]
            wj, rj = gathered(lane_values(builder, atp, builder.mul(p, i64(C)), C))
            K = position_entries(builder, blkp, p, 9, VC)
            d = position_entries(builder, offp, p, 3, VC)
            z = [sub(wj[c], wi[c]) for c in range(3)]
            y = [sub(fma(ri[2][b], z[2], fma(ri[1][b], z[1], mul(ri[0][b], z[0]))), d[b]) for b in range(3)]
            t = [sub(z[a], fma(ri[a][2], d[2], fma(ri[a][1], d[1], mul(ri[a][0], d[0])))) for a in range(3)]
            f = [fma(K[3 * a + 2], y[2], fma(K[3 * a + 1], y[1], fma(K[3 * a], y[0], f[a]))) for a in range(3)]
            q = [fma(rj[2][b], t[2], fma(rj[1][b], t[1], mul(rj[0][b], t[0]))) for b in range(3)]
            pk = [fma(K[3 * a + 2], q[2], fma(K[3 * a + 1], q[1], mul(K[3 * a], q[0]))) for a in range(3)]
            g = [fma(rj[a][2], pk[2], fma(rj[a][1], pk[1], fma(rj[a][0], pk[0], g[a]))) for a in range(3)]
            return f + g

        acc = accumulating_loop(builder, p0v, p1v, 1, [zero] * 6, position)
        f, g = acc[:3], acc[3:]
        half = ir.Constant(VC, [0.5] * C)
        e = [mul(half, add(fma(ri[a][2], f[2], fma(ri[a][1], f[1], mul(ri[a][0], f[0]))), g[a])) for a in range(3)]
        store_lane_rows(builder, outp, ownp, first_lane, e)
        return context.get_dummy_value()

    return sig, codegen


# warped_sweep(sh_ptr, (sh_w_at, sh_blocks, sh_offsets), (bd_w_at, bd_blocks, bd_offsets),
#              (w, rot4, lane_vertex, owner, out)): out[i] <- e_i for every vertex i (padding lanes' rows: zero)
warped_sweep_serial, warped_sweep_parallel = slice_sweep(_warped_slice, "warped")


_GRADIENT_SPECS = (("w_at", 2, types.int64), ("grads", 3, types.float64), ("u_rows", 2, types.float64),
                   ("lane_vertex", 1, types.int64), ("F", 2, types.float64))


@intrinsic(prefer_literal=True)
def _gradient_slice(typingctx, lanes, s, p0, p1, per_position, common):
    """F[:, C s + l] <- F_i of lane l's vertex i (module docstring) over positions p0..p1 of slice s;
    per_position = (w_at, grads), common = (u_rows, lane_vertex, F). Its own u_i (lane_vertex), per position C
    rows of u_rows gathered at w_at = 3 j and transposed, three C-wide loads of g and nine FMAs in position
    order. w_at (P, C) int64, grads (P, 3, C), u_rows (S C + 1, 3) (input_rows), lane_vertex (S C,) int64,
    F (9, S C), C-contiguous (checked at typing); the caller checks the shapes."""
    C, sig = slice_kernel_typing("_gradient_slice", lanes, s, p0, p1, per_position, common, _GRADIENT_SPECS)
    VC = ir.VectorType(F64, C)

    def codegen(context, builder, signature, args):
        sv, p0v, p1v, arrays = slice_kernel_args(context, builder, signature, args)
        atp, lvp = arrays[0].data, arrays[3].data
        gp, up, fp = (double_data(builder, arrays[k]) for k in (1, 2, 4))
        columns = cgutils.unpack_tuple(builder, arrays[4].shape, 2)[1]

        first_lane = builder.mul(sv, i64(C))
        ui = gathered_rows(builder, up, [builder.mul(i, i64(W_ROW)) for i in lane_values(builder, lvp, first_lane, C)])

        def position(p, acc):
            uj = gathered_rows(builder, up, lane_values(builder, atp, builder.mul(p, i64(C)), C))
            e = [builder.fsub(uj[c], ui[c]) for c in range(3)]
            g = position_entries(builder, gp, p, 3, VC)
            return [fused_multiply_add(builder, e[a], g[b], acc[3 * a + b]) for a in range(3) for b in range(3)]

        acc = accumulating_loop(builder, p0v, p1v, 1, [ir.Constant(VC, [0.0] * C)] * 9, position)
        one = ir.Constant(VC, [1.0] * C)
        for a in range(9):
            value = builder.fadd(acc[a], one) if a % 4 == 0 else acc[a]
            at = builder.add(builder.mul(i64(a), columns), first_lane)
            builder.store(value, vector_at(builder, fp, at, VC), align=8)
        return context.get_dummy_value()

    return sig, codegen


# gradient_sweep(sh_ptr, (sh_w_at, sh_grads), (bd_w_at, bd_grads), (u_rows, lane_vertex, F)): F[:, k] <- the
# deformation gradient of lane k's vertex (the identity in padding lanes)
gradient_sweep_serial, gradient_sweep_parallel = slice_sweep(_gradient_slice, "gradient")


def _copy_rows(u, u_rows):
    """u_rows[:n] <- u (n, 3), element by element: u_rows has the rows after the last vertex's that the
    sweeps' 4-wide row loads need (they read one double past a row); u itself has none."""
    uf = u.reshape(-1)              # one view per statement (see cluster_force_kernel._kernel_input)
    rf = u_rows.reshape(-1)
    for k in prange(uf.shape[0]):
        rf[k] = uf[k]


copy_rows_serial, copy_rows_parallel = serial_and_parallel(_copy_rows)
