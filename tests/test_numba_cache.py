"""Every cached numba kernel can be loaded from the on-disk cache by a new process, safely.

- numba keys a cache entry by the pickled closure cells of the function, and a compiled function pickles with
  a per-process id: a kernel that closes over another compiled function misses the cache in every new process
  and is compiled again (the warped step's kernels took 9 s on each start of the node before
  numba_config.compiled replaced such closures).
- A cached kernel that called a separately compiled threaded kernel crashed the process that loaded it when it
  had been compiled in a process that loaded its threaded callee from the cache (numba_config.PARALLEL): every
  threaded kernel is inlined into its callers, which are threaded themselves, so none makes that call.
- Threaded kernels are cached: a process loads what another compiled, and computes the same bits.
- The cache directory is keyed on the sources compiled code can read (numba re-checks a cached kernel only
  against its own file, so an edited callee would otherwise leave stale callers in the cache)."""
import importlib
import importlib.util
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba.core.caching import NullCache
from numba.core.registry import CPUDispatcher

import clusterfem_ros
from clusterfem_ros.numba_config import contains_threads

CHILD = Path(__file__).with_name("test_numba_cache_child.py")


def _cached_dispatchers():
    found = {}
    for pkg in ("fem", "skeleton", "body"):                  # and every sub-package of theirs
        base = importlib.import_module(f"clusterfem_ros.{pkg}")
        for info in pkgutil.walk_packages(base.__path__, f"{base.__name__}."):
            module = importlib.import_module(info.name)
            for name, obj in vars(module).items():
                for i, d in enumerate(obj if isinstance(obj, tuple) else (obj,)):
                    if isinstance(d, CPUDispatcher) and not isinstance(d._cache, NullCache):   # cache=True
                        found[f"{module.__name__}.{name}" + (f"[{i}]" if isinstance(obj, tuple) else "")] = d
    found.update(_model_step_builds())
    return found


def _model_step_builds() -> dict:
    """The clustered step's builds around every registered material model (made when a model is first run,
    not at import: clustered_explicit.step_builds), on a small body."""
    from clusterfem_ros.fem.integrators.clustered_explicit import step_builds
    from clusterfem_ros.fem.materials.registry import MODELS
    from clusterfem_ros.fem.model import build_model
    from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
    from clusterfem_ros.fem.linear.material import Material
    model = build_model(box_mesh((0.1, 0.1, 0.1), (2, 2, 2)), Material())
    found = {}
    for name, material in MODELS.items():
        built = step_builds(material.clustered(model))
        for k, d in enumerate([b for pair in built if pair is not None for b in pair]):
            found[f"clustered_explicit.step_builds({name!r})[{k}]"] = d
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
def test_no_kernel_calls_a_separately_compiled_threaded_kernel(name):
    d = _cached_dispatchers()[name]
    g = d.py_func.__globals__
    for callee in (n for n in d.py_func.__code__.co_names if contains_threads(g.get(n))):
        options = g[callee].targetoptions
        assert options.get("inline") == "always" and "parallel" in options, (
            f"{name} calls the threaded {callee} as a separate function: a process that compiles {name} after "
            "loading that callee from the cache saves an entry the next process crashes on")
        assert contains_threads(d) and "parallel" in d.targetoptions, (
            f"{name} inlines the threaded {callee} but is not built parallel: its loops would run serial")


def _child(cache: Path, out: Path, *what: str) -> dict[str, tuple[int, int]]:
    """Run test_numba_cache_child.py with ``cache`` as numba's cache; (hits, misses) per threaded build."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache),        # the child imports benchmarks/ from the repo root
               PYTHONPATH=os.pathsep.join(filter(None, [str(CHILD.parents[1]), os.environ.get("PYTHONPATH")])))
    run = subprocess.run([sys.executable, str(CHILD), str(out), *what], env=env, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, f"{what} exited with {run.returncode} (a negative code is a signal):\n{run.stderr[-3000:]}"
    counts = {}
    for line in run.stdout.splitlines():
        build, _, hits, _, misses = line.split()
        counts[build] = (int(hits), int(misses))
    return counts


def test_threaded_kernels_load_from_a_cache_that_other_processes_filled(tmp_path):
    """One process caches the threaded force kernels, a second the threaded steps (which hold the same
    threaded code, inlined), a third loads everything: every process exits cleanly, the third compiles
    nothing, and all agree with the serial builds to the bit."""
    from tests.test_numba_cache_child import forces, sphere_and_state, steps

    cache = tmp_path / "numba_cache"
    first = _child(cache, tmp_path / "1.npz", "forces")
    second = _child(cache, tmp_path / "2.npz", "steps")
    third = _child(cache, tmp_path / "3.npz", "forces", "steps")
    assert all(misses > 0 for _, misses in (*first.values(), *second.values())), (first, second)
    assert all(hits > 0 and misses == 0 for hits, misses in third.values()), third

    model, u, v = sphere_and_state()
    serial = {**forces(model, u, v, threads=False), **steps(model, u, v, threads=False)}
    loaded = dict(np.load(tmp_path / "3.npz"))
    compiled_here = {**np.load(tmp_path / "1.npz"), **np.load(tmp_path / "2.npz")}
    assert sorted(loaded) == sorted(serial) == sorted(compiled_here)
    for key, value in serial.items():
        assert np.abs(value).max() > 0, key
        assert np.array_equal(loaded[key], value) and np.array_equal(compiled_here[key], value), key


def test_the_source_key_follows_every_file_compiled_code_can_read_and_no_other(tmp_path):
    """A kernel module, the modules it imports (at any depth, relative or absolute) and their packages'
    __init__.py are keyed; a module that only imports a kernel (a node, the scene) is not, so editing it keeps
    the cache, and one that starts using numba joins the key."""
    from clusterfem_ros.numba_cache import kernel_sources, source_key
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    files = {"__init__.py": "", "kern.py": "import numba\nfrom .consts import C\n",
             "consts.py": "from pkg.sub import deeper\nC = 1\n", "sub/__init__.py": "", "sub/deeper.py": "D = 2\n",
             "node.py": "from .kern import C\n", "sub/other.py": "x = 1\n", "notes.txt": "not code\n"}
    for name, text in files.items():
        (pkg / name).write_text(text)
    assert [str(f.relative_to(pkg)) for f in kernel_sources(pkg)] == [
        "__init__.py", "consts.py", "kern.py", "sub/__init__.py", "sub/deeper.py"]
    first = source_key(pkg)
    assert len(first) == 12 and source_key(pkg) == first
    for name in ("node.py", "sub/other.py", "notes.txt"):         # outside: edits keep the cache
        (pkg / name).write_text(files[name] + "# edited\n")
        assert source_key(pkg) == first, name
    (pkg / "sub" / "deeper.py").write_text("D = 3\n")             # a constant two imports away
    second = source_key(pkg)
    assert second != first
    (pkg / "node.py").write_text("from numba import njit\n")     # a new kernel module
    assert source_key(pkg) not in (first, second)


def test_without_numba_cache_dir_the_cache_is_keyed_on_the_package_source(tmp_path):
    """numba re-checks a cached kernel only against its own file: a bare pytest run after editing a callee
    could load stale kernels. the package keys the directory on its source when first imported (numba_cache)."""
    code = ("import os, sys\n"
            "from clusterfem_ros.fem.kernels.cluster_force_kernel import force_kernel_serial as k\n"
            "print(os.environ['NUMBA_CACHE_DIR']); print(k._cache._cache_path); print(sys.prefix)\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    cache_dir, kernel_dir, prefix = run.stdout.split()
    from clusterfem_ros.numba_cache import source_key
    assert Path(cache_dir) == Path(prefix) / "numba_cache" / source_key(Path(clusterfem_ros.__file__).parent)
    assert Path(kernel_dir).is_relative_to(cache_dir)
    given = subprocess.run([sys.executable, "-c", code], env=dict(env, NUMBA_CACHE_DIR=str(tmp_path)),
                           capture_output=True, text=True, timeout=120)
    assert given.returncode == 0 and given.stdout.split()[0] == str(tmp_path)          # the user's wins


def test_keying_keeps_the_two_caches_used_last_besides_its_own(tmp_path):
    """Two checkouts sharing one environment must not wipe each other's cache at every start; older keys go."""
    root = tmp_path / "numba_cache"
    for age, name in enumerate(("oldest", "older", "recent")):
        (root / name).mkdir(parents=True)
        os.utime(root / name, (1e9 + age, 1e9 + age))
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "a.py").write_text("x = 1\n")
    code = ("import os, sys\nfrom pathlib import Path\n"
            "from clusterfem_ros import numba_cache as c\n"
            "os.environ.pop('NUMBA_CACHE_DIR')\n"
            "print(c.key_the_cache(Path(sys.argv[1]), Path(sys.argv[2])), os.environ['NUMBA_CACHE_DIR'])\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    run = subprocess.run([sys.executable, "-c", code, str(pkg), str(root)], env=env, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    from clusterfem_ros.numba_cache import source_key
    returned, exported = run.stdout.split()
    assert returned == exported == str(root / source_key(pkg))
    assert sorted(p.name for p in root.iterdir()) == sorted([source_key(pkg), "older", "recent"])



def _fresh_module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_is_cached_tells_a_build_that_will_compile_from_one_that_will_load(tmp_path):
    """A cached numba function seen for the first time is not cached; after its first call it is, also for a
    new dispatcher of the same source (a later process). A function numba does not cache: cannot tell."""
    from clusterfem_ros.numba_cache import is_cached
    src = tmp_path / "tiny_kernel.py"
    src.write_text("import numba\n\n@numba.njit(cache=True)\ndef f(x):\n    return x + 1\n\n"
                   "@numba.njit\ndef g(x):\n    return x + 1\n")
    first = _fresh_module(src, "tiny_kernel_a")
    assert is_cached(first.f) is False
    assert first.f(1) == 2
    assert is_cached(first.f) is True
    assert is_cached(_fresh_module(src, "tiny_kernel_b").f) is True
    assert is_cached(first.g) is None and is_cached(object()) is None


def test_a_scene_whose_step_will_compile_says_so_and_how_long_it_takes(tmp_path, monkeypatch):
    """The first start of a source compiles the step for 15-30 s with nothing else to show: the scene says so
    before. With the step's kernels cached it says it loads them."""
    from clusterfem_ros.config import SceneConfig
    from clusterfem_ros.fem.integrators.clustered_explicit import ClusteredExplicit
    from clusterfem_ros.scene import Scene
    config = SceneConfig().with_values(skeleton__source="none", body__kind="sphere")
    Scene.build(config)                         # compiles the step if this source's cache does not hold it yet
    said = []
    Scene.build(config, progress=said.append)
    assert "loading compiled kernels" in said and not any("compiling" in s for s in said)
    src = tmp_path / "uncached_kernel.py"
    src.write_text("import numba\n\n@numba.njit(cache=True)\ndef f(x):\n    return x\n")
    uncached = _fresh_module(src, "uncached_kernel").f
    monkeypatch.setattr(ClusteredExplicit, "kernels", property(lambda self: (uncached,)))
    said = []
    Scene.build(config, progress=said.append)
    assert any("compiling the step's kernels" in s and "15-30 s" in s for s in said), said


def test_importing_the_flags_and_the_cache_modules_sets_nothing_up(tmp_path):
    """numba_config and numba_cache, loaded on their own (not through the package, whose first import keys the
    cache), neither point numba's cache anywhere nor create or delete a directory: setting up is the package's
    explicit call (clusterfem_ros/__init__.py)."""
    package = Path(clusterfem_ros.__file__).parent
    code = ("import importlib.util, os, sys\n"
            "for name in ('numba_config', 'numba_cache'):\n"
            "    spec = importlib.util.spec_from_file_location(name, os.path.join(sys.argv[1], name + '.py'))\n"
            "    spec.loader.exec_module(importlib.util.module_from_spec(spec))\n"
            "print(os.environ.get('NUMBA_CACHE_DIR', 'unset'))\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    before = sorted((Path(sys.prefix) / "numba_cache").glob("*"))
    run = subprocess.run([sys.executable, "-c", code, str(package)], env=env, cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["unset"]
    assert sorted((Path(sys.prefix) / "numba_cache").glob("*")) == before
