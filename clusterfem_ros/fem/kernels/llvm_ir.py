"""LLVM IR building blocks for the hand-vectorised kernels (numba intrinsics): vector types, constants, fused
multiply-adds, an accumulating loop, and the slice kernels' common parts (gathering C rows into C-wide vectors,
loading a position's entries, storing the lanes' sums, and the typing checks and argument unpacking every slice
kernel makes). Written as IR because numba's pipeline runs no SLP vectorizer. Used by the linear force kernel
(cluster_force_kernel.py), the warped passes (warped_force_kernel.py) and the benchmark's wide read
(benchmarks/core_benchmark.py). Compiles nothing itself: every function here emits IR into a builder it is given.
"""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.errors import TypingError

F64 = ir.DoubleType()
V4 = ir.VectorType(F64, 4)
I64 = ir.IntType(64)
I32 = ir.IntType(32)


def i64(x):
    return ir.Constant(I64, x)


def shuffle_mask(idx):
    return ir.Constant(ir.VectorType(I32, len(idx)), list(idx))


def fused_multiply_add(builder, a, b, c):
    """a * b + c, one rounding (llvm.fma: exact on every target, no fastmath flag involved)."""
    name = f"llvm.fma.v{a.type.count}f64"
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(a.type, [a.type] * 3), name)
    return builder.call(fn, [a, b, c])


def vector_at(builder, p, offset, vtype):
    return builder.bitcast(builder.gep(p, [offset]), vtype.as_pointer())


def accumulating_loop(builder, start, stop, step, zeros, body):
    """LLVM IR for ``accs = zeros; for i in range(start, stop, step): accs = body(i, accs)``; returns the final
    accumulators (the zeros when the range is empty). start, stop: i64 values; step: a Python int; body gets
    the i64 index and the accumulators' current values and returns their next values. Shared by the slice
    kernel and the benchmark's wide read (benchmarks/core_benchmark.py)."""
    entry = builder.basic_block
    loop = builder.function.append_basic_block("acc.loop")
    done = builder.function.append_basic_block("acc.done")
    builder.cbranch(builder.icmp_signed("<", start, stop), loop, done)
    builder.position_at_end(loop)
    i = builder.phi(I64)
    i.add_incoming(start, entry)
    accs = [builder.phi(z.type) for z in zeros]
    for a, z in zip(accs, zeros):
        a.add_incoming(z, entry)
    new = body(i, accs)
    i_next = builder.add(i, i64(step))
    loop_end = builder.basic_block
    i.add_incoming(i_next, loop_end)
    for a, val in zip(accs, new):
        a.add_incoming(val, loop_end)
    builder.cbranch(builder.icmp_signed("<", i_next, stop), loop, done)
    builder.position_at_end(done)
    totals = []
    for z, val in zip(zeros, new):
        total = builder.phi(z.type)
        total.add_incoming(z, entry)
        total.add_incoming(val, loop_end)
        totals.append(total)
    return totals


def transpose_rows(builder, rows):
    """C rows (x, y, z, anything) of <4 x double> -> the C x's, y's and z's as three <C x double>."""
    level = rows
    while len(level) > 1:                      # concatenate pairwise: one <4C x double>
        n = level[0].type.count
        level = [builder.shuffle_vector(level[i], level[i + 1], shuffle_mask(range(2 * n)))
                 for i in range(0, len(level), 2)]
    every = level[0]
    return [builder.shuffle_vector(every, every, shuffle_mask([4 * lane + c for lane in range(len(rows))]))
            for c in range(3)]


def lane_values(builder, ptr, first, lanes):
    """The ``lanes`` int64 values ptr[first + l], l = 0..C-1: a position's column offsets (w_at), or a slice's
    per-lane vertices or output rows (first = C s)."""
    return [builder.load(builder.gep(ptr, [builder.add(first, i64(lane))]), align=8) for lane in range(lanes)]


def gathered_rows(builder, data, offsets):
    """The rows (x, y, z) that start at ``offsets`` in ``data`` (one per lane), each loaded as 4 doubles (the
    fourth is unused: a row of 3 and the next row's first, or a row's padding) and transposed (transpose_rows): their
    x's, y's and z's as three C-wide vectors. How every slice kernel gathers a per-vertex array."""
    return transpose_rows(builder, [builder.load(vector_at(builder, data, at, V4), align=8) for at in offsets])


def position_entries(builder, data, p, count, vtype):
    """The ``count`` C-wide vectors of position p of a (P, count, C) array: a block's nine entries, an
    offset's or a gradient weight's three."""
    base = builder.mul(p, i64(count * vtype.count))
    return [builder.load(vector_at(builder, data, builder.add(base, i64(e * vtype.count)), vtype), align=8)
            for e in range(count)]


def store_lane_rows(builder, out, owner, first_lane, totals):
    """out[owner[first_lane + l], c] <- lane l of totals[c] (c = 0, 1, 2): each lane's sums to its vertex's row
    of an (S C, 3) array."""
    lanes = totals[0].type.count
    for lane, own in enumerate(lane_values(builder, owner, first_lane, lanes)):
        row = builder.mul(own, i64(3))
        for c, total in enumerate(totals):
            builder.store(builder.extract_element(total, ir.Constant(I32, lane)),
                          builder.gep(out, [builder.add(row, i64(c))]), align=8)


def slice_kernel_typing(kernel, lanes, s, p0, p1, per_position, common, specs):
    """The typing checks every slice kernel makes; returns C and the kernel's signature. A slice kernel is
    called as ``kernel(lanes, s, p0, p1, per_position, common)`` (slice_sweep): ``lanes`` (C) a literal 2, 4
    or 8, slice s, positions p0..p1, and two tuples of C-contiguous arrays, per position (w_at first) and
    common; specs: (name, ndim, dtype) of every array of the two, in order."""
    if not isinstance(lanes, types.IntegerLiteral) or lanes.literal_value not in (2, 4, 8):
        raise TypingError(f"{kernel}: lanes must be the literal 2, 4 or 8, got {lanes}")
    for name, a in (("s", s), ("p0", p0), ("p1", p1)):
        if not isinstance(a, types.Integer):
            raise TypingError(f"{kernel}: {name} must be an integer, got {a}")
    for name, group in (("per_position", per_position), ("common", common)):
        if not isinstance(group, types.BaseTuple):
            raise TypingError(f"{kernel}: {name} must be a tuple of arrays, got {group}")
    arrays = [*per_position.types, *common.types]
    if len(arrays) != len(specs):
        raise TypingError(f"{kernel}: expected the arrays {[sp[0] for sp in specs]}, got {len(arrays)} arrays")
    for (name, ndim, dtype), a in zip(specs, arrays):
        if not (isinstance(a, types.Array) and a.ndim == ndim and a.dtype == dtype and a.layout == "C"):
            raise TypingError(f"{kernel}: {name} must be a C-contiguous {ndim}-d {dtype} array, got {a}")
    return lanes.literal_value, types.void(lanes, s, p0, p1, per_position, common)


def slice_kernel_args(context, builder, signature, args):
    """(s, p0, p1 as i64 values, the arrays of both tuples in order) inside a slice kernel's codegen."""
    sv, p0v, p1v = [context.cast(builder, a, t, types.int64) for a, t in zip(args[1:4], signature.args[1:4])]
    arrays = []
    for group, value in zip(signature.args[4:6], args[4:6]):
        for t, v in zip(group.types, cgutils.unpack_tuple(builder, value, len(group.types))):
            arrays.append(context.make_array(t)(context, builder, v))
    return sv, p0v, p1v, arrays


def double_data(builder, array):
    """An array struct's data as a double pointer."""
    return builder.bitcast(array.data, F64.as_pointer())
