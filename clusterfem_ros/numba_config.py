"""Numba flags in one place, for every part of the package that compiles code (fem/, skeleton/, body/).
Kernels are compiled twice from one source: serial and multi-threaded.

``prange`` is a plain ``range`` in the serial build, so the two builds cannot drift apart. Both builds are
cached on disk, in a directory keyed on the sources compiled code can read (numba_cache.key_the_cache, which
the package runs once when it is first imported, before any kernel is made). Importing this module has no
side effect.
"""
from __future__ import annotations

import types

import numba


SERIAL = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
# Threaded builds are cached too, each one self-contained. A cached function that calls a separately compiled
# threaded function crashed the process that loaded it when it had been compiled in a process that loaded the
# threaded callee from the cache: numba names a threaded function's parallel parts in the order a process
# compiles them (segfault on the warped jelly man's threaded step after a test run had filled the cache, every
# time; numba issues #4807, #8578). So ``compiled`` never lets that call happen: a threaded build is inlined
# into every caller (numba IR, inline="always"), and a build that calls one is threaded itself, so its parallel
# loops are its own and it calls only serial code. Keeping threaded builds out of the cache instead would
# compile the warped step at every start of the node (8-10 s, against 0.2 s to load it).
PARALLEL = dict(SERIAL, parallel=True)
# Only a step kernel lets the GIL go. The compiled functions the physics thread calls between its steps
# (kinematics, the driver's targets, the stretch bound, the output checks: microseconds to tens of them) keep
# it: a thread that lets it go waits its turn to get it back, behind the executor thread and, with several
# bodies in one process, every other body's physics thread, for no gain. Four bodies in one process
# (`python -m clusterfem_ros.nodes.demo --duration 15 --bodies 4 --no-record --no-video --no-png`, 2-core Zen 3
# VM) keep a mean real-time factor of 0.37-0.48 this way, 0.28-0.36 when kinematics, the driver's targets and
# the stretch bound let it go too. tests/test_scene_setup.py fails if the step loop calls one that lets it go.
HOLDS_GIL = dict(SERIAL, nogil=False)

# Below this many vertices the bare force kernels (clustered_force, warped_force, vertex_rotations) run
# serial. On an idle 2-core machine the threaded builds can pay already at the jelly man's 1803 vertices
# (warped step 0.56 -> 0.35 ms, linear 0.137 -> 0.116 ms), but with another process on one core every
# parallel region waits for the scheduler (~8 ms per step, 20-60x slower), so a fixed threshold stays high.
PARALLEL_MIN_VERTICES = 20000
# The clustered integrator (threads=None) instead times both builds from this size on and keeps the faster
# (integrators/clustered_explicit.ThreadChoice); below it one step is ~0.1 ms and threads never paid.
AUTO_THREADS_MIN_VERTICES = 1000


def simd_lanes() -> int:
    """Doubles per vector register on the running CPU: 8 with AVX-512, else 4 (AVX2; LLVM splits wider vectors on
    anything narrower, so any choice computes the same numbers). The cluster slices take one row per lane."""
    import llvmlite.binding as llvm
    llvm.initialize_native_target()
    return 8 if llvm.get_host_cpu_features().get("avx512f", False) else 4


def compiled(fn, suffix: str = "", flags: dict = SERIAL, **names):
    """numba build of a copy of ``fn`` named ``<qualname><suffix>``, its global ``names`` bound to the objects
    given (the compiled functions it calls).

    This is how one kernel source calls different builds (serial or threaded sweeps, the real slice kernel or
    the benchmark's control) without being a closure. numba keys its on-disk cache by the pickled closure
    cells, and a compiled function pickles with a per-process id: every closure over one missed the cache and
    was compiled again in every process (the warped step's kernels: 9 s on each start of the node). The suffix
    keeps each binding's cache entries apart (the cache keys by qualified name, signature and code, not by
    the globals). Bind after every global ``fn`` uses is defined: the copy sees the module's globals as they
    are at the call. Like any cached numba function that calls another, a build is not recompiled when only
    its callee's file changes: key_the_cache keys the cache directory by every source compiled code can read for that.
    A build is threaded if ``flags`` say parallel or it binds a threaded build; a threaded build is parallel
    and inlined into its callers (see PARALLEL), so call it only from threaded builds or from Python."""
    threaded = bool(flags.get("parallel")) or any(contains_threads(obj) for obj in names.values())
    if threaded:                                    # see PARALLEL; a new options dict per build (numba empties it)
        # fusion off: numba would merge adjacent loops of inlined callees into one parallel region; each stays
        # the region it is in its callee's own build
        flags = dict(flags, parallel={"fusion": False}, inline="always")
    if names or suffix:
        g = dict(fn.__globals__)
        g.update(names)
        copy = types.FunctionType(fn.__code__, g, fn.__name__ + suffix, fn.__defaults__, fn.__closure__)
        copy.__qualname__ = fn.__qualname__ + suffix
        copy.__module__ = fn.__module__
        copy.__doc__ = fn.__doc__
        fn = copy
    build = numba.njit(**flags)(fn)
    build.runs_threads = threaded
    return build


def contains_threads(obj) -> bool:
    """Whether ``obj`` is a build of ``compiled`` that runs threaded code or calls a build that does."""
    return getattr(obj, "runs_threads", False)


def serial_and_parallel(fn, suffix: str = "", serial: dict | None = None, parallel: dict | None = None):
    """(serial, parallel) numba builds of one kernel source, ``serial`` / ``parallel``: the global names each
    build binds (``compiled``).

    The parallel build is a copy named ``<name>_parallel``: numba's on-disk cache keys an entry by the
    function's qualified name, signature and closure, not by its flags, so two cached builds of the same
    function object share one entry and the parallel dispatcher silently loaded the serial code.
    """
    return (compiled(fn, suffix, SERIAL, **(serial or {})),
            compiled(fn, suffix + "_parallel", PARALLEL, **(parallel or {})))
