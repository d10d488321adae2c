"""Numba flags in one place. Kernels are compiled twice from one source: serial and multi-threaded.

``prange`` is a plain ``range`` in the serial build, so the two builds cannot drift apart. Both builds are
cached on disk, in a directory keyed on the sources compiled code can read (``key_the_cache``, run at import).
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import sys
import types
from pathlib import Path

import numba


_NUMBA = re.compile(r"^[ \t]*(?:import|from)[ \t]+numba\b", re.M)
# "from .x import (a, b)" / "import a.b as c": the module and the names (a name may be a submodule)
_FROM = re.compile(r"^[ \t]*from[ \t]+(\.*)([\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)", re.M)
_IMPORT = re.compile(r"^[ \t]*import[ \t]+([^\n]+)", re.M)


def _imported_modules(text: str, package: list[str]) -> list[str]:
    """Dotted names a module of the package ``package`` (its dotted parts; an __init__.py's own) imports, with
    each imported name appended (it may be a submodule), relative imports made absolute. Read by pattern, not
    parsed: ast.parse took 0.2 s for the package at every start. An import-like line in a docstring can
    only add a file, never drop one."""
    names: list[str] = []
    for dots, module, what in _FROM.findall(text):
        base = package[:len(package) - len(dots) + 1] if dots else []
        mod = ".".join(base + ([module] if module else []))
        names.append(mod)
        names += [f"{mod}.{w.split()[0]}" for w in what.strip("()").replace("\\", " ").split(",") if w.split()]
    for what in _IMPORT.findall(text):
        names += [w.split()[0] for w in what.split(",") if w.split()]
    return names


def kernel_sources(package: Path) -> list[Path]:
    """The files of ``package`` that compiled code can read: every module that uses numba, every module of the
    package they import (a kernel freezes the globals it reads, constants from other modules included),
    transitively, and the __init__.py of their packages. Sorted."""
    text = {f: f.read_text() for f in package.rglob("*.py")}
    parts = {f: f.relative_to(package.parent).with_suffix("").parts for f in text}
    module = {".".join(p[:-1] if p[-1] == "__init__" else p): f for f, p in parts.items()}
    todo = [f for f, t in text.items() if ("import numba" in t or "from numba" in t) and _NUMBA.search(t)]
    seen: set[Path] = set()
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        here = list(parts[f][:-1])
        todo += [module[m] for m in _imported_modules(text[f], here) if m in module]
        todo += [module[".".join(here[:k])] for k in range(1, len(here) + 1)]       # the packages' __init__.py
    return sorted(seen)


def source_key(package: Path) -> str:
    """12 hex digits of the sha1 of the package's kernel sources (kernel_sources: names and contents)."""
    h = hashlib.sha1()
    for f in kernel_sources(package):
        h.update(str(f.relative_to(package)).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:12]


KEEP_OTHER_KEYS = 2


def key_the_cache(package: Path = Path(__file__).resolve().parents[1], root: Path | None = None) -> str | None:
    """Point numba's on-disk cache at <root>/<source_key> (root: <environment>/numba_cache) unless
    NUMBA_CACHE_DIR is set;
    returns the directory (None when left to numba or the user). Of the other keys' directories the
    KEEP_OTHER_KEYS used last are kept (two checkouts sharing one environment do not wipe each other's cache
    at every start), the rest removed.

    numba re-checks a cached function only against its own file, not against the kernels it calls or
    inlines from other files: after an edit to cluster_force_kernel.py the cached step would keep the old
    sweep (and, inlined, the old threaded code) with no warning. Keyed on every source compiled code can
    read (source_key), an edit to one of them or a pull starts a fresh cache, for the README's commands and
    for a bare ``pytest`` alike; an edit elsewhere (the node, the scene, the config, recording) keeps it,
    instead of 15-30 s of compiling at the next start. The variable is set too, so child processes share
    the directory."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    root = Path(sys.prefix) / "numba_cache" if root is None else root
    key = source_key(package)
    try:
        (root / key).mkdir(parents=True, exist_ok=True)
    except OSError:                     # a read-only environment: numba's default (beside the sources)
        return None
    os.utime(root / key)                # marks it used
    others = sorted((d for d in root.iterdir() if d.name != key and d.is_dir()), key=lambda d: d.stat().st_mtime)
    for old in others[:max(len(others) - KEEP_OTHER_KEYS, 0)]:
        shutil.rmtree(old, ignore_errors=True)
    os.environ["NUMBA_CACHE_DIR"] = str(root / key)
    numba.config.reload_config()
    return os.environ["NUMBA_CACHE_DIR"]


key_the_cache()               # before any kernel below or in the modules that import these flags is made


def is_cached(build) -> bool | None:
    """Whether numba's on-disk cache holds a compiled version of ``build`` (a numba dispatcher): False means
    its first call compiles it (after an install or an update of this source: 15-30 s for a step with its
    kernels). None when it cannot tell (not a cached build, or numba's internals changed)."""
    try:
        return bool(build._cache._cache_file._load_index())
    except Exception:           # noqa: BLE001 (a private numba API: any failure means "cannot tell")
        return None


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
