"""The Neo-Hookean pass's arithmetic and memory floor on this host: what a tet's force must cost at least.

Flops per tet, counted from the source of the pass (fem/materials/neohookean.py ``_chunk_forces`` and the element
passes' shared steps in fem/materials/element_warping.py; a multiply or an add is one flop, a fused multiply-add two, a
square root or a min/max one), for one element of one sub-step:

    differences of u and of w at three corners         18
    F = I + grad u and G = grad w (lane_gradient x 2)  96
    Z = G - F                                            9
    cof F and J                                         32
    the tangent bound (4 square roots)                  69
    E' = sym(F^T Z), its trace, S_d                     72
    P = F (mu I + S_d) + k cof F, times V               74
    corner forces P g_c and the fourth corner           54
    the 12 corner forces added to their vertex rows     12
                                                       ---
                                                       436

of which the elastic force alone (no damping, no bound: differences of u, F, cof F and J, mu F + k cof F times
V, the corner forces and their sums by vertex) is about 190. That is a step's first sub-step, whose bounds the
step plans from; its later sub-steps run the pass without the bound (367). Bytes per tet streamed from memory or
L2 each sub-step: the corner indices (4 x 8), the rest gradients (9 x 8) and volume (8), the corner forces
written to their element slots (12 x 8; the serial pass adds them to the vertex rows while they are in L1,
fem/materials/neohookean.py ``_fused_e``): 208; the vertex rows of u and w it reads (4 corners x 2 x 3 x 8 = 192)
and the padded force rows it adds to (4 corners x 4 x 8, read and written: 256) come from L1/L2 (a vertex is
shared by about 20 tets).

The host's peak is counted: vector lanes (4 with AVX2, 8 with AVX-512) x 2 flops per FMA x 2 FMA pipes x the
clock /proc/cpuinfo gives (the nominal one: a core may run faster). Beside it the rate a compiled loop of
independent FMAs reaches (``fma_rate``), as numba builds it (LLVM's preferred vector width: 256-bit on AVX-512
parts, as the pass's lane loop): what the pass's arithmetic can run at. The bandwidth is measured, a numpy copy
of 1 MB (L2) and of 64 MB (memory), read plus write bytes over the median time. The floor is the larger of flops
/ the measured FMA rate and bytes / bandwidth; a pass of adds and multiplies that do not pair into FMAs reaches
at most half of it.

``pieces_line``: the serial pass by piece, each timed over the body's chunks in interleaved rounds: the corner
differences of u and w (fem/materials/corner_rows.py: 8 row loads, 6 row subtractions, 10.5 shuffles and 4.5
stores a tet, all 4-wide, as the IR writes them; LLVM trades some shuffles for 2-wide stores), the lane loop (F, the bound, the damping, P, the corner forces: vectors across tets,
bound by the FMA pipes), the same loop without the bound (a step's later sub-steps), and the corner forces'
sums by vertex (3 column loads, 8 shuffles and 4 padded-row read-modify-writes a tet, 4-wide). The floor above
counts the flops alone; the two row pieces are bound by their row loads and read-modify-writes, not by flops or
bytes.
"""
from __future__ import annotations

import re
import statistics
import time
from pathlib import Path

import numba
import numpy as np

from clusterfem_ros.fem.materials import neohookean as nh
from clusterfem_ros.fem.materials.corner_rows import add_corner_rows, corner_row_differences_of_two
from clusterfem_ros.fem.materials.element_rotation import LANES
from clusterfem_ros.fem.materials.element_warping import ElementFrames
from .timing import interleaved_seconds

FLOPS = {"differences of u and w": 18, "F and G": 96, "Z = G - F": 9, "cof F and J": 32, "tangent bound": 69,
         "damping stress": 72, "stress P times V": 74, "corner forces": 54, "sums by vertex": 12}
FLOPS_PER_TET = sum(FLOPS.values())
BYTES_PER_TET = 4 * 8 + 9 * 8 + 8 + 12 * 8


def host_peak() -> tuple[float, int, float]:
    """(peak flops per second of one core, vector lanes, clock GHz) from /proc/cpuinfo (nan where unreadable)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return float("nan"), 0, float("nan")
    flags = set(re.search(r"^flags\s*:(.*)$", text, re.M).group(1).split()) if "flags" in text else set()
    lanes = 8 if "avx512f" in flags else 4 if "avx2" in flags else 2
    mhz = re.search(r"^cpu MHz\s*:\s*([\d.]+)", text, re.M)
    ghz = float(mhz.group(1)) / 1e3 if mhz else float("nan")
    return lanes * 2 * 2 * ghz * 1e9, lanes, ghz


FMA_CHAIN = 16             # fused multiply-adds an element per pass of _fma_loop (written out there)


@numba.njit(cache=True, fastmath={"contract"})
def _fma_loop(x, reps):
    """x[i] <- FMA_CHAIN fused multiply-adds of x[i], reps times: independent elements, so LLVM vectorizes the
    loop and the out-of-order core keeps both FMA pipes busy (x stays in L1)."""
    for _ in range(reps):
        for i in range(x.shape[0]):
            a = x[i]        # written out: an inner loop would be the one LLVM vectorizes (a chain: it cannot)
            a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3  # noqa: E702
            a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3  # noqa: E702
            a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3  # noqa: E702
            a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3; a = a * 0.999 + 1e-3  # noqa: E702
            x[i] = a


def fma_rate(repeats: int = 25) -> float:
    """Flops per second (2 an FMA) of one core running _fma_loop: the fastest of ``repeats`` runs of ~4 ms (the
    fastest, not the median: a peak, which other jobs on the host can only lower)."""
    x = np.ones(2048)
    reps = 2000
    _fma_loop(x, 1)                                 # compiled or loaded before timing
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        _fma_loop(x, reps)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * FMA_CHAIN * x.size * reps / best


def copy_bandwidth(nbytes: int, reps: int = 20) -> float:
    """Bytes per second of a numpy copy of ``nbytes`` (read + write), median of ``reps``."""
    a = np.ones(nbytes // 8)
    b = np.empty_like(a)
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        np.copyto(b, a)
        times.append(time.perf_counter() - t0)
    return 2.0 * a.nbytes / float(np.median(times))


def roofline_line(body: str, tets: int, seconds: float, linear_seconds: float) -> str:
    """One line: the Neo-Hookean step on ``body`` (``seconds`` per step, serial) against its floor."""
    peak, lanes, ghz = host_peak()
    rate = fma_rate()
    l2, memory = copy_bandwidth(1 << 20), copy_bandwidth(64 << 20, reps=5)
    compute = FLOPS_PER_TET / rate
    stream = BYTES_PER_TET / l2
    floor = max(compute, stream)
    per_tet = seconds / tets
    return (f"roofline, Neo-Hookean step on the {body} ({tets} tets): {FLOPS_PER_TET} flops and {BYTES_PER_TET} "
            f"bytes per tet (benchmarks/roofline.py); this host {lanes} lanes x 2 FMA pipes at {ghz:.2f} GHz = "
            f"{peak / 1e9:.0f} Gflop/s counted, {rate / 1e9:.0f} Gflop/s measured (a numba FMA loop), copy "
            f"{l2 / 1e9:.0f} GB/s in L2, {memory / 1e9:.0f} GB/s from memory; floor {floor * 1e9:.1f} ns per tet "
            f"(compute at the measured rate {compute * 1e9:.1f}, at the counted peak "
            f"{FLOPS_PER_TET / peak * 1e9:.1f}, L2 {stream * 1e9:.1f}; all-FMA, so "
            f"{2 * compute * 1e9:.1f} at half the measured rate); measured {per_tet * 1e9:.1f} ns per tet = "
            f"{per_tet / floor:.1f}x the floor, {(seconds - linear_seconds) / tets * 1e9:.1f} ns over the linear step")


@numba.njit(cache=True)
def _differences(corner, u, w, D, DW, reps):
    for _ in range(reps):
        for c in range(corner.shape[0]):
            corner_row_differences_of_two(corner[c], u, w, D, DW)


@numba.njit(cache=True)
def _lane_loops(grad, vol, lam, mu, kept, fe, D, DW, planned, reps):
    for _ in range(reps):
        for c in range(grad.shape[0]):
            if planned:
                nh._chunk_forces(D, DW, grad[c], vol[c], lam, mu, fe[c], kept[c])
            else:
                nh._chunk_forces_unplanned(D, DW, grad[c], vol[c], lam, mu, fe[c], kept[c])


@numba.njit(cache=True)
def _sums(corner, fe, rows, m, reps):
    for _ in range(reps):
        for c in range(corner.shape[0]):
            add_corner_rows(corner[c], fe[c], min(LANES, m - c * LANES), rows)


def pass_pieces(model, u: np.ndarray, reps: int = 50) -> dict[str, float]:
    """Median seconds of one pass over the body's elements of each piece of the serial Neo-Hookean pass at
    displacement u (pieces_line), and of the whole pass and sums ('pass'), timed in interleaved rounds. The lane
    loops run in every chunk on the differences the last chunk left (the same arithmetic, with no gather).
    ``u`` is taken as it is (rows of the model's vertices, float64); w is u plus the rest shape and a velocity.
    """
    frames = ElementFrames.from_model(model)
    corner, grad, vol, (lam, mu) = frames.elems
    kept, buf, _, _, fe, _, rows = frames.work
    D, DW = buf[0, 0], buf[0, 1]
    w = frames.w
    w[:-1] = model.rest + u + model.material.zeta * np.ones_like(u)
    calls = {"differences": lambda: _differences(corner, u, w, D, DW, reps),
             "lane loop": lambda: _lane_loops(grad, vol, lam, mu, kept, fe, D, DW, True, reps),
             "without the bound": lambda: _lane_loops(grad, vol, lam, mu, kept, fe, D, DW, False, reps),
             "sums by vertex": lambda: _sums(corner, fe, rows, frames.m, reps),
             "pass": lambda: [nh.neohookean_e_serial(frames.elems, frames.gather, u, w, frames.work)
                              for _ in range(reps)]}
    samples = interleaved_seconds(calls)
    return {name: statistics.median(ts) / reps for name, ts in samples.items()}


def pieces_line(body: str, model, u: np.ndarray, step_seconds: float) -> str:
    """One line: the serial Neo-Hookean pass on ``body`` by piece (pass_pieces), us and ns a tet."""
    t = pass_pieces(model, u)
    m = model.mesh.n_tets
    part = lambda k: f"{k} {t[k] * 1e6:.1f} us ({t[k] / m * 1e9:.1f} ns a tet)"  # noqa: E731
    return (f"Neo-Hookean serial pass on the {body} by piece (benchmarks/roofline.py): "
            + ", ".join(part(k) for k in ("differences", "lane loop", "without the bound", "sums by vertex"))
            + f"; the whole pass {t['pass'] * 1e6:.1f} us (the step in the table: {step_seconds * 1e6:.1f} us)")
