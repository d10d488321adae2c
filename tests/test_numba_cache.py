"""Every cached numba kernel can be loaded from the on-disk cache by a new process, safely.

- numba keys a cache entry by the pickled closure cells of the function, and a compiled function pickles with
  a per-process id: a kernel that closes over another compiled function misses the cache in every new process
  and is compiled again (the warped step's kernels took 9 s on each start of the node before
  numba_config.compiled replaced such closures).
- A cached kernel that reaches threaded code crashed the process that loaded it when it had been compiled in a
  process that loaded its threaded callee from the cache (numba_config.PARALLEL): no cached kernel may."""
import importlib
import pkgutil

import pytest
from numba.core.caching import NullCache
from numba.core.registry import CPUDispatcher

import clusterfem_ros


def _cached_dispatchers():
    found = {}
    for pkg in ("fem", "fem.integrators", "skeleton", "body"):
        base = importlib.import_module(f"clusterfem_ros.{pkg}")
        for info in pkgutil.iter_modules(base.__path__):
            module = importlib.import_module(f"{base.__name__}.{info.name}")
            for name, obj in vars(module).items():
                for i, d in enumerate(obj if isinstance(obj, tuple) else (obj,)):
                    if isinstance(d, CPUDispatcher) and not isinstance(d._cache, NullCache):   # cache=True
                        found[f"{module.__name__}.{name}" + (f"[{i}]" if isinstance(obj, tuple) else "")] = d
    return found


def test_the_package_has_cached_kernels_to_check():
    names = _cached_dispatchers()
    assert any("stiffness_slices" in n for n in names) and any("warped_kernel" in n for n in names)
    assert clusterfem_ros.__name__ == "clusterfem_ros"


@pytest.mark.parametrize("name", sorted(_cached_dispatchers()))
def test_no_cached_kernel_is_a_closure(name):
    d = _cached_dispatchers()[name]
    cells = d.py_func.__closure__
    assert cells is None, (f"{name} closes over {[c.cell_contents for c in cells]}: numba's cache misses it in "
                           "every new process; bind the callees with numba_config.compiled instead")


@pytest.mark.parametrize("name", sorted(_cached_dispatchers()))
def test_no_cached_kernel_reaches_threaded_code(name):
    seen, todo = set(), [(name, _cached_dispatchers()[name])]
    while todo:
        path, d = todo.pop()
        if id(d) in seen:
            continue
        seen.add(id(d))
        assert not d.targetoptions.get("parallel"), (
            f"{path} runs threads but is reached from the cached {name}: a process that compiles {name} after "
            "loading the threaded part from the cache saves an entry the next process crashes on")
        g = d.py_func.__globals__
        todo += [(f"{path} -> {n}", g[n]) for n in d.py_func.__code__.co_names if isinstance(g.get(n), CPUDispatcher)]
