"""An element chunk's corner rows on vectors: the vertex differences it starts from and the corner forces it ends
with, moved between per-vertex rows and the chunk's lane-major arrays four lanes at a time.

The element passes (fem/materials/element_warping.py, fem/materials/neohookean.py) compute on LANES elements by
lane: entry k of lane l at k LANES + l. Their input is per vertex, rows (x, y, z) of u and of w; their output,
the corner forces, is summed per vertex. Done one scalar at a time, a tet's corner differences are 24 loads and
18 stores and its sums 12 read-modify-writes, bound by the load and store ports (benchmarks/roofline.py). Here
a vertex row is one 4-wide load and a corner's force one 4-wide read-modify-write of a padded row, and four
lanes' rows are transposed into (or out of) the lane-major arrays with vector shuffles:

- ``corner_row_differences(corner, p, out)``: out[3 (c - 1) + a, l] <- p[i_c, a] - p[i_0, a] (c = 1, 2, 3;
  i_c = corner[c, l]), for every lane; ``corner_row_differences_of_two(corner, p, q, out, out_q)`` the same of
  two arrays with one load of the indices. Differences, so the round-off is relative to the element's size,
  not to its distance from the origin.
- ``add_corner_rows(corner, fe, lanes, rows)``: rows[i_c, :3] += component (3 c + a) of fe, lanes 0..lanes-1
  in order, corners 0..3 within a lane.

The arithmetic is the scalar code's, entry by entry (one subtraction, one addition each, in the same order:
each vertex's sums in ascending lane order), so the results are the same bits. p's rows are read with a
masked 4-wide load (the fourth double is not read: p may have no row after its last), and ``rows`` is (k, 4):
a force row of x, y, z and a zero that the sums leave at zero. LLVM IR (numba intrinsics) because numba's
pipeline runs no SLP vectorizer; fem/kernels/llvm_ir.py holds the shared pieces.
"""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import intrinsic

from ..kernels.llvm_ir import V4, accumulating_loop, double_data, i64, shuffle_mask, transpose_rows, vector_at
from .element_rotation import LANES

GROUP = 4          # lanes transposed at a time: one 4-wide row per lane, one 4-wide column per entry
ROW = 4            # doubles per padded force row (add_corner_rows)
assert LANES % GROUP == 0
_I1 = ir.IntType(1)
_XYZ = ir.Constant(ir.VectorType(_I1, 4), [1, 1, 1, 0])


def _check(name: str, what: str, a, ndim: int, dtype) -> None:
    if not (isinstance(a, types.Array) and a.ndim == ndim and a.dtype == dtype and a.layout == "C"):
        raise TypingError(f"{name}: {what} must be a C-contiguous {ndim}-d {dtype} array, got {a}")


def _masked_row(builder, data, at):
    """The row of 3 doubles at ``at`` as (x, y, z, 0); the fourth double is not read."""
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4.as_pointer(), ir.IntType(32),
                                                                           _XYZ.type, V4]),
                                        "llvm.masked.load.v4f64.p0")
    return builder.call(fn, [vector_at(builder, data, at, V4), ir.Constant(ir.IntType(32), 8), _XYZ,
                             ir.Constant(V4, [0.0] * 4)])


def _rows(builder, x, y, z):
    """Three 4-wide vectors (x's, y's, z's of four lanes) -> the four lanes' rows (x, y, z, 0)."""
    sh = builder.shuffle_vector
    zero = ir.Constant(V4, [0.0] * 4)
    xy_lo, xy_hi = sh(x, y, shuffle_mask([0, 4, 2, 6])), sh(x, y, shuffle_mask([1, 5, 3, 7]))
    z0_lo, z0_hi = sh(z, zero, shuffle_mask([0, 4, 2, 6])), sh(z, zero, shuffle_mask([1, 5, 3, 7]))
    return (sh(xy_lo, z0_lo, shuffle_mask([0, 1, 4, 5])), sh(xy_hi, z0_hi, shuffle_mask([0, 1, 4, 5])),
            sh(xy_lo, z0_lo, shuffle_mask([2, 3, 6, 7])), sh(xy_hi, z0_hi, shuffle_mask([2, 3, 6, 7])))


def _lane_corners(builder, cp, first, k):
    """[corner c] = corner[c, first + k], as i64 values: lane first + k's vertices."""
    return [builder.load(builder.gep(cp, [builder.add(i64(c * LANES + k), first)]), align=8) for c in range(4)]


def _corner_indices(builder, cp, first):
    """[lane k][corner c] = corner[c, first + k] (k < GROUP), as i64 values."""
    return [_lane_corners(builder, cp, first, k) for k in range(GROUP)]


def _differences_typing(name, corner, sources, outs):
    _check(name, "corner", corner, 2, types.int64)
    for k, (p, out) in enumerate(zip(sources, outs)):
        _check(name, f"source {k}", p, 2, types.float64)
        _check(name, f"output {k}", out, 1, types.float64)

    def codegen(context, builder, signature, args):
        arrays = [context.make_array(t)(context, builder, v) for t, v in zip(signature.args, args)]
        cp = arrays[0].data
        count = len(sources)
        srcs = [double_data(builder, a) for a in arrays[1:1 + count]]
        dsts = [double_data(builder, a) for a in arrays[1 + count:]]

        def group(first):
            # lane by lane: a lane's four row offsets serve every source and are then dead, so the group's sixteen
            # are never live at once (held together they spilled; lane by lane the pass is ~13 % shorter)
            diffs = [[] for _ in srcs]                      # [source][lane][c - 1]: (p_c - p_0) as a row
            for k in range(GROUP):
                at = [builder.mul(i, i64(3)) for i in _lane_corners(builder, cp, first, k)]
                for src, rows in zip(srcs, diffs):
                    r = [_masked_row(builder, src, a) for a in at]
                    rows.append([builder.fsub(r[c], r[0]) for c in (1, 2, 3)])
            for dst, rows in zip(dsts, diffs):
                for c in range(3):
                    cols = transpose_rows(builder, [rows[k][c] for k in range(GROUP)])
                    for a in range(3):
                        builder.store(cols[a], vector_at(builder, dst, builder.add(first, i64((3 * c + a) * LANES)),
                                                         V4), align=8)

        accumulating_loop(builder, i64(0), i64(LANES), GROUP, [], lambda first, _: group(first) or [])
        return context.get_dummy_value()

    return types.void(corner, *sources, *outs), codegen


@intrinsic
def corner_row_differences(typingctx, corner, p, out):
    """out[3 (c - 1) + a, l] <- p[i_c, a] - p[i_0, a] (c = 1, 2, 3; i_c = corner[c, l]) for l < LANES (module
    docstring). corner (4, LANES) int64, p (k, 3) float64 whose rows the corners index, out (9 LANES,) float64,
    C-contiguous (checked at typing); the caller keeps the indices below k."""
    return _differences_typing("corner_row_differences", corner, (p,), (out,))


@intrinsic
def corner_row_differences_of_two(typingctx, corner, p, q, out, out_q):
    """corner_row_differences of p into out and of q into out_q, the corner indices loaded once."""
    return _differences_typing("corner_row_differences_of_two", corner, (p, q), (out, out_q))


@intrinsic
def add_corner_rows(typingctx, corner, fe, lanes, rows):
    """rows[i_c, a] += fe[(3 c + a) LANES + l] (c = 0..3, a = 0..2, i_c = corner[c, l]) for the first ``lanes``
    lanes in order (module docstring). corner (4, LANES) int64, fe (12 LANES,) float64, rows (k, ROW) float64,
    C-contiguous (checked at typing); the caller keeps the indices below k and lanes <= LANES."""
    _check("add_corner_rows", "corner", corner, 2, types.int64)
    _check("add_corner_rows", "fe", fe, 1, types.float64)
    _check("add_corner_rows", "rows", rows, 2, types.float64)
    if not isinstance(lanes, types.Integer):
        raise TypingError(f"add_corner_rows: lanes must be an integer, got {lanes}")

    def codegen(context, builder, signature, args):
        ca, fa, ra = (context.make_array(signature.args[k])(context, builder, args[k]) for k in (0, 1, 3))
        cp, fp, rp = ca.data, double_data(builder, fa), double_data(builder, ra)
        n_lanes = context.cast(builder, args[2], signature.args[2], types.int64)
        full = builder.sdiv(n_lanes, i64(GROUP))

        def group(first, checked):
            """The group's lanes from ``first``; ``checked``: only those below n_lanes (the last, partial group)."""
            cols = [builder.load(vector_at(builder, fp, builder.add(first, i64(k * LANES)), V4), align=8)
                    for k in range(12)]
            corner_rows = [_rows(builder, *cols[3 * c:3 * c + 3]) for c in range(4)]     # [c][lane]
            index = _corner_indices(builder, cp, first)
            for k in range(GROUP):
                def add_lane():
                    for c in range(4):
                        at = vector_at(builder, rp, builder.mul(index[k][c], i64(ROW)), V4)
                        builder.store(builder.fadd(builder.load(at, align=8), corner_rows[c][k]), at, align=8)
                if checked:
                    with builder.if_then(builder.icmp_signed("<", builder.add(first, i64(k)), n_lanes)):
                        add_lane()
                else:
                    add_lane()

        accumulating_loop(builder, i64(0), builder.mul(full, i64(GROUP)), GROUP, [],
                          lambda first, _: group(first, False) or [])
        with builder.if_then(builder.icmp_signed(">", builder.srem(n_lanes, i64(GROUP)), i64(0))):
            group(builder.mul(full, i64(GROUP)), True)
        return context.get_dummy_value()

    return types.void(corner, fe, lanes, rows), codegen
