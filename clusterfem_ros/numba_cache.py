"""Where numba's on-disk cache lives: a directory keyed on every source compiled code can read.

``key_the_cache`` points the cache there; clusterfem_ros/__init__.py calls it once, when the package is first
imported, so that it runs before any kernel is made (numba fixes a kernel's cache path when it decorates it).
Importing this module has no side effect, and it does not import numba.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import sys
from pathlib import Path


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


def key_the_cache(package: Path = Path(__file__).resolve().parent, root: Path | None = None) -> str | None:
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
    if "numba" in sys.modules:          # else numba reads the variable when it is first imported
        sys.modules["numba"].config.reload_config()
    return os.environ["NUMBA_CACHE_DIR"]




def is_cached(build) -> bool | None:
    """Whether numba's on-disk cache holds a compiled version of ``build`` (a numba dispatcher): False means
    its first call compiles it (after an install or an update of this source: 15-30 s for a step with its
    kernels). None when it cannot tell (not a cached build, or numba's internals changed)."""
    try:
        return bool(build._cache._cache_file._load_index())
    except Exception:           # noqa: BLE001 (a private numba API: any failure means "cannot tell")
        return None
