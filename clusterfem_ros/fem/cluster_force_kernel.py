"""The clustered elastic-damping force, one fused numba pass (eqs. 4-6).

    f = -D v - K u = -K (u + zeta v) - xi M v          (D = xi M + zeta K)

so one sweep over the K clusters serves both matrices: f_i = f_s + f_b, the shared clusters'
contribution plus the boundary clusters'. ``clustered_force`` is the checked public entry; the
``_`` kernels take arrays and scalars only. tests/naive.py holds the plain numpy twin.
"""
from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import prange, types
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import intrinsic

from .clusters import Clusters
from .numba_config import PARALLEL, PARALLEL_MIN_VERTICES, SERIAL, serial_and_parallel


_F64 = ir.DoubleType()
_V2 = ir.VectorType(_F64, 2)
_V4 = ir.VectorType(_F64, 4)
_I64 = ir.IntType(64)
_I32 = ir.IntType(32)


def _k(x):
    return ir.Constant(_I64, x)


def _lane(x):
    return ir.Constant(_I32, x)


def _pick(i0, i1):
    """Shuffle mask: (lane i0, lane i1) of the four lanes of two <2 x double> (0, 1 first, 2, 3 second)."""
    return ir.Constant(ir.VectorType(_I32, 2), [i0, i1])


def _fma(builder, a, b, c):
    """a * b + c, one rounding (llvm.fma: exact on every target, no fastmath flag involved)."""
    name = {_F64: "llvm.fma.f64", _V2: "llvm.fma.v2f64", _V4: "llvm.fma.v4f64"}[a.type]
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(a.type, [a.type] * 3), name)
    return builder.call(fn, [a, b, c])


def _load2(builder, p, offset):
    return builder.load(builder.bitcast(builder.gep(p, [_k(offset)]), _V2.as_pointer()), align=8)


def _load4(builder, p, offset):
    return builder.load(builder.bitcast(builder.gep(p, [_k(offset)]), _V4.as_pointer()), align=8)


def _block_fma(builder, blocks, cols, w, wstride, k, acc):
    """acc + the nine products of block k with w[cols[k]], elementwise (no sum yet).

    The block's nine numbers e0..e8 (row-major) pair with (wx wy wz wx | wy wz wx wy | wz): two 4-wide FMAs
    and one scalar FMA. w rows are padded to 4 numbers, so w[j] is one 32-byte load whose two shuffles give
    the 4-wide operands (and one 8-byte load gives wz for the scalar). acc: two <4 x double> and one double.
    Six loads per block (index, w, 4 + 4 + 1 entries, wz).
    """
    j = builder.load(builder.gep(cols, [k]), align=8)
    wrow = builder.gep(w, [builder.mul(j, wstride)])
    w4 = _load4(builder, wrow, 0)
    wz = builder.load(builder.gep(wrow, [_k(2)]), align=8)
    wa = builder.shuffle_vector(w4, w4, ir.Constant(ir.VectorType(_I32, 4), [0, 1, 2, 0]))
    wb = builder.shuffle_vector(w4, w4, ir.Constant(ir.VectorType(_I32, 4), [1, 2, 0, 1]))
    b = builder.gep(blocks, [builder.mul(k, _k(9))])
    return [_fma(builder, _load4(builder, b, 0), wa, acc[0]), _fma(builder, _load4(builder, b, 4), wb, acc[1]),
            _fma(builder, builder.load(builder.gep(b, [_k(8)]), align=8), wz, acc[2])]


def _zero_acc():
    return [ir.Constant(_V4, [0.0] * 4)] * 2 + [ir.Constant(_F64, 0.0)]


def _phis(builder, incoming):
    """One phi per accumulator, from [(values, block), ...]."""
    out = []
    for vals in zip(*[v for v, _ in incoming]):
        p = builder.phi(vals[0].type)
        for val, (_, blk) in zip(vals, incoming):
            p.add_incoming(val, blk)
        out.append(p)
    return out


def _check_array(name, a, ndim, dtype, layout="C"):
    if not (isinstance(a, types.Array) and a.ndim == ndim and a.dtype == dtype and a.layout == layout):
        raise TypingError(f"_row_force: {name} must be a {layout}-contiguous {ndim}-d {dtype} array, got {a}")


@intrinsic
def _row_force(typingctx, i, k0, k1, cols, blocks, w, v, mass, xi, out):
    """out[i] <- -sum_k blocks[k] w[cols[k]] - xi m_i v_i over the cluster blocks k0..k1 of vertex i.

    Written in LLVM IR because numba's pipeline runs no SLP vectorizer: the scalar loop issued 13 loads per
    block (9 entries, 3 gathered w, the index), the load ports were the limit. Here the entries are read as
    2 x 32 bytes + 8 and w as 32 + 8 bytes (6 loads, see _block_fma), with two sets of accumulators (even and
    odd blocks) so the FMA latency is not a chain. Fixed order: serial and threaded builds give the same bits.
    blocks (nb, 3, 3), cols (nb,), v and out (n, 3), mass (n,): C-contiguous (checked at typing); w (n, 4)
    C-contiguous, the 4th column padding (read, never used): callers check w.shape[1] == 4.
    """
    for name, a in (("i", i), ("k0", k0), ("k1", k1)):
        if not isinstance(a, types.Integer):
            raise TypingError(f"_row_force: {name} must be an integer, got {a}")
    _check_array("cols", cols, 1, types.int64)
    _check_array("blocks", blocks, 3, types.float64)
    _check_array("w", w, 2, types.float64)
    _check_array("v", v, 2, types.float64)
    _check_array("mass", mass, 1, types.float64)
    _check_array("out", out, 2, types.float64)
    sig = types.void(i, k0, k1, cols, blocks, w, v, mass, xi, out)

    def codegen(context, builder, signature, args):
        ints = [context.cast(builder, a, t, types.int64) for a, t in zip(args[:3], signature.args[:3])]
        iv, k0v, k1v = ints
        xiv = context.cast(builder, args[8], signature.args[8], types.float64)

        def arr(n):
            return context.make_array(signature.args[n])(context, builder, args[n])

        colp = arr(3).data
        blkp = builder.bitcast(arr(4).data, _F64.as_pointer())
        wa = arr(5)
        wp = builder.bitcast(wa.data, _F64.as_pointer())
        wstride = builder.lshr(cgutils.unpack_tuple(builder, wa.strides)[0], _k(3))
        vp = builder.bitcast(arr(6).data, _F64.as_pointer())
        mp = arr(7).data
        op = builder.bitcast(arr(9).data, _F64.as_pointer())
        fn = builder.function
        entry = builder.basic_block
        pair = fn.append_basic_block("row.pair")
        after = fn.append_basic_block("row.after")
        odd = fn.append_basic_block("row.odd")
        done = fn.append_basic_block("row.done")
        # blocks in pairs: even ones into acc_e, odd ones into acc_o
        builder.cbranch(builder.icmp_signed("<", builder.add(k0v, _k(1)), k1v), pair, after)
        builder.position_at_end(pair)
        k = builder.phi(_I64)
        k.add_incoming(k0v, entry)
        acc_e = _phis(builder, [(_zero_acc(), entry)])
        acc_o = _phis(builder, [(_zero_acc(), entry)])
        new_e = _block_fma(builder, blkp, colp, wp, wstride, k, acc_e)
        new_o = _block_fma(builder, blkp, colp, wp, wstride, builder.add(k, _k(1)), acc_o)
        k_next = builder.add(k, _k(2))
        pair_end = builder.basic_block
        k.add_incoming(k_next, pair_end)
        for p, val in zip(acc_e + acc_o, new_e + new_o):
            p.add_incoming(val, pair_end)
        builder.cbranch(builder.icmp_signed("<", builder.add(k_next, _k(1)), k1v), pair, after)
        # the last block of an odd count
        builder.position_at_end(after)
        k_last = builder.phi(_I64)
        k_last.add_incoming(k0v, entry)
        k_last.add_incoming(k_next, pair_end)
        even = _phis(builder, [(_zero_acc(), entry), (new_e, pair_end)])
        odd_acc = _phis(builder, [(_zero_acc(), entry), (new_o, pair_end)])
        builder.cbranch(builder.icmp_signed("<", k_last, k1v), odd, done)
        builder.position_at_end(odd)
        tail = _block_fma(builder, blkp, colp, wp, wstride, k_last, even)
        builder.branch(done)
        builder.position_at_end(done)
        acc = [builder.fadd(a, b) for a, b in zip(_phis(builder, [(even, after), (tail, odd)]), odd_acc)]
        # A = (e0 e1 e2 e3), B = (e4 e5 e6 e7), e8: f = (e0+e1+e2, e3+e4+e5, e6+e7+e8); out = -d v - f, d = xi m_i
        A, B = acc[0], acc[1]
        pair = ir.VectorType(_I32, 2)
        e03 = builder.shuffle_vector(A, B, ir.Constant(pair, [0, 3]))
        e14 = builder.shuffle_vector(A, B, ir.Constant(pair, [1, 4]))
        e25 = builder.shuffle_vector(A, B, ir.Constant(pair, [2, 5]))
        fxy = builder.fadd(builder.fadd(e03, e14), e25)
        fz = builder.fadd(builder.fadd(builder.extract_element(B, _lane(2)), builder.extract_element(B, _lane(3))),
                          acc[2])
        d = builder.fmul(xiv, builder.load(builder.gep(mp, [iv])))
        dd = builder.insert_element(ir.Constant(_V2, ir.Undefined), d, _lane(0))
        dd = builder.shuffle_vector(dd, dd, _pick(0, 0))
        row = builder.mul(iv, _k(3))
        vxy = builder.load(builder.bitcast(builder.gep(vp, [row]), _V2.as_pointer()), align=8)
        builder.store(_fma(builder, builder.fneg(dd), vxy, builder.fneg(fxy)),
                      builder.bitcast(builder.gep(op, [row]), _V2.as_pointer()), align=8)
        vz = builder.load(builder.gep(vp, [builder.add(row, _k(2))]))
        builder.store(_fma(builder, builder.fneg(d), vz, builder.fneg(fz)), builder.gep(op, [builder.add(row, _k(2))]))
        return context.get_dummy_value()

    return sig, codegen


def _force_rows_kernel(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks, w, v, mass, xi, out):
    """out <- -K w - xi M v from the clusters, w = u + zeta v given: shared rows, then boundary rows, in
    one loop (one parallel region in the threaded build). w: (n, 4), rows padded for one 32-byte load."""
    if w.shape[1] != 4:
        raise ValueError("the cluster force kernel needs w with 4 columns (x, y, z, padding)")
    ns = sh_rows.shape[0]
    for r in prange(ns + bd_rows.shape[0]):
        if r < ns:
            _row_force(sh_rows[r], sh_ptr[r], sh_ptr[r + 1], sh_cols, sh_blocks, w, v, mass, xi, out)
        else:
            b = r - ns
            _row_force(bd_rows[b], 4 * b, 4 * b + 4, bd_cols, bd_blocks, w, v, mass, xi, out)


force_rows_serial, force_rows_parallel = serial_and_parallel(_force_rows_kernel)


def _make_force_kernel(rows):
    def force_kernel(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks,
                     u, v, mass, zeta, xi, w, out):
        """w[:, :3] <- u + zeta v (w: (n, 4)), then the rows: the same row loop the clustered integrator runs
        (and the core benchmark times). Splitting shared and boundary rows into two loops measured ~8% faster serial,
        but costs the threaded build a second parallel region per sub-step."""
        n = u.shape[0]
        for i in prange(n):
            for c in range(3):
                w[i, c] = u[i, c] + zeta * v[i, c]
        rows(sh_rows, sh_ptr, sh_cols, sh_blocks, bd_rows, bd_cols, bd_blocks, w, v, mass, xi, out)
    return force_kernel


force_kernel_serial = numba.njit(**SERIAL)(_make_force_kernel(force_rows_serial))
force_kernel_parallel = numba.njit(**PARALLEL)(_make_force_kernel(force_rows_parallel))


def cluster_args(cl: Clusters) -> tuple:
    """The cluster arrays in kernel argument order."""
    return (cl.shared_rows, cl.shared_ptr, cl.shared_cols, cl.shared_blocks,
            cl.boundary_rows, cl.boundary_cols, cl.boundary_blocks)


def pick_kernel(n_vertices: int, threads: bool | None = None):
    """The serial build for small meshes, the threaded one for large (``threads`` forces a choice)."""
    use = n_vertices >= PARALLEL_MIN_VERTICES if threads is None else threads
    return force_kernel_parallel if use else force_kernel_serial


def clustered_force(cl: Clusters, u: np.ndarray, v: np.ndarray, mass: np.ndarray, zeta: float, xi: float,
                    out: np.ndarray | None = None, threads: bool | None = None) -> np.ndarray:
    """f = -K (u + zeta v) - xi M v, (n, 3), from the clusters. Checks shapes and finiteness."""
    n = cl.n_vertices
    u = np.ascontiguousarray(u, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    for name, a in (("u", u), ("v", v)):
        if a.shape != (n, 3):
            raise ValueError(f"{name} has shape {a.shape}, expected ({n}, 3) for this mesh")
    if out is None:
        out = np.empty((n, 3))
    w = np.zeros((n, 4))
    pick_kernel(n, threads)(*cluster_args(cl), u, v, np.ascontiguousarray(mass, dtype=np.float64),
                            float(zeta), float(xi), w, out)
    return out
