"""The package's layers and import graph, read from the sources with ast (nothing is imported to check imports).

Layers, imports one way only (clusterfem_ros/__init__.py):
  the numerical core, every module below nodes/: no rclpy, no ROS message packages, no msg_adapters, no nodes,
    and inside it each part imports only the parts below it (ALLOWED);
  msg_adapters: numpy arrays <-> ROS messages, no physics (no numba, scipy, pinocchio) and nothing of the core;
  nodes: wire the two.
No module of the installed package imports benchmarks/ or tests/ (they are not installed), and no modules
import each other in a circle.
"""
from __future__ import annotations

import ast
import importlib
import inspect
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("clusterfem_ros", "msg_adapters", "benchmarks")
INSTALLED = ("clusterfem_ros", "msg_adapters")

# part of the core -> the parts it may import besides itself ('' = the modules directly in clusterfem_ros/)
ALLOWED = {
    "errors": set(),
    "numba_cache": set(),                         # where numba's cache lives (the package keys it at import)
    "numba_config": set(),                        # numba build flags for every part that compiles code
    "data_dirs": set(),                           # where data files given by name are looked for
    "registries": set(),                          # the name tables the registered kinds of things live in
    "topics": {"registries"},                     # the topics and output streams, declared once
    "recording": {"errors", "topics"},            # a leaf: it records bytes, knows no physics and no scene
    # the numerical core's own layers, bottom up (clusterfem_ros/fem/__init__.py); 'fem' is its modules model.py
    # and stability.py, which the materials and integrators share
    "fem.mesh": {"errors", "numba_config"},
    "fem.linear": {"errors", "fem.mesh"},
    "fem.kernels": {"errors", "numba_config", "fem.mesh", "fem.linear"},
    "fem": {"errors", "numba_config", "fem.mesh", "fem.linear", "fem.kernels"},
    "fem.materials": {"errors", "numba_config", "registries", "fem.mesh", "fem.linear", "fem.kernels", "fem"},
    "fem.integrators": {"errors", "numba_config", "registries", "fem.mesh", "fem.linear", "fem.kernels", "fem",
                        "fem.materials"},
}
FEM = {p for p in ALLOWED if p.split(".")[0] == "fem"}
ALLOWED.update({
    "skeleton": {"errors", "numba_config", "data_dirs", "registries"} | FEM,      # the jelly body's mesh; URDF mesh files
    "body": {"errors", "numba_config", "data_dirs", "registries", "skeleton"} | FEM,
    "": {"errors", "numba_cache", "numba_config", "data_dirs", "registries", "topics", "recording", "skeleton",
         "body", ""} | FEM,  # config, scene, ...
})
PHYSICS = {"numba", "scipy", "pinocchio", "llvmlite"}
def module_files(root: Path = ROOT, packages=PACKAGES) -> dict[str, Path]:
    """Dotted module name -> file, for every .py of the packages (a package by its __init__.py)."""
    out = {}
    for top in packages:
        for f in sorted((root / top).rglob("*.py")):
            parts = f.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def imports_of(name: str, path: Path, known) -> set[str]:
    """Every module ``name`` imports, anywhere in the file (in functions too: a lazy import is still a
    dependency), relative imports made absolute; ``from p import x`` gives p.x when that is a module of
    ``known``, else p."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level > len(package):
                raise ValueError(f"{path}:{node.lineno}: relative import above the top package")
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            out |= {f"{module}.{a.name}" if f"{module}.{a.name}" in known else module for a in node.names}
    return out


def import_graph(root: Path = ROOT, packages=PACKAGES) -> dict[str, set[str]]:
    files = module_files(root, packages)
    return {name: imports_of(name, path, files) for name, path in files.items()}


def part(module: str, graph: dict) -> str:
    """The core part a module of clusterfem_ros belongs to: its subpackage ('fem', 'skeleton', ...), 'errors',
    or '' for the other modules directly in clusterfem_ros/."""
    parts = module.split(".")
    if len(parts) == 1:
        return ""
    if parts[1] == "fem" and len(parts) > 2 and f"fem.{parts[2]}" in ALLOWED:
        return f"fem.{parts[2]}"                      # a sub-package of the core, or a module of one
    if parts[1] in ALLOWED or len(parts) > 2 or any(m.startswith(module + ".") for m in graph):
        return parts[1]
    return ""


def is_ros(top: str) -> bool:
    return (top in {"rclpy", "rcl", "rmw", "rosbag2_py", "launch", "launch_ros"} or top.startswith("rosidl")
            or top.endswith(("_msgs", "_srvs", "_interfaces")))


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    """What each module imports against the layers (module docstring), one line per import."""
    bad = []
    for module, imported in sorted(graph.items()):
        top = module.split(".")[0]
        for imp in sorted(imported):
            itop = imp.split(".")[0]
            if top in INSTALLED and itop in ("benchmarks", "tests"):
                bad.append(f"{module} imports {imp}: {itop}/ is not installed with the package")
            if top == "msg_adapters":
                if itop == "clusterfem_ros":
                    bad.append(f"{module} imports {imp}: msg_adapters converts messages and knows nothing of the core")
                if itop in PHYSICS:
                    bad.append(f"{module} imports {imp}: msg_adapters holds no physics")
            if top != "clusterfem_ros" or module.startswith("clusterfem_ros.nodes"):
                continue
            if is_ros(itop) or itop == "msg_adapters":
                bad.append(f"{module} imports {imp}: the core (below nodes/) imports no ROS and no msg_adapters")
            if itop == "clusterfem_ros" and imp != "clusterfem_ros":
                if imp.startswith("clusterfem_ros.nodes"):
                    bad.append(f"{module} imports {imp}: the core never imports nodes/")
                    continue
                own, other = part(module, graph), part(imp, graph)
                if other != own and other not in ALLOWED[own]:
                    bad.append(f"{module} imports {imp}: {own or 'clusterfem_ros/'} may import only "
                               f"{sorted(ALLOWED[own]) or 'nothing of the package'}")
    return bad


def circles(graph: dict[str, set[str]]) -> list[frozenset]:
    """The strongly connected components of the import graph with more than one module, or a module importing
    itself (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start] & graph.keys())))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, edges = work[-1]
            w = next(edges, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w] & graph.keys()))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.add(w)
                    if w == v:
                        break
                if len(component) > 1 or v in graph[v]:
                    found.append(frozenset(component))
    return found


GRAPH = import_graph()


def test_the_graph_reads_every_kind_of_import(tmp_path):
    """The reader sees absolute, relative (any depth), 'from . import module' and function-level imports, and
    the checks flag each kind of breach, so a clean result below means something."""
    files = {"clusterfem_ros/__init__.py": "", "clusterfem_ros/nodes/__init__.py": "",
             "clusterfem_ros/nodes/node.py": "import rclpy\nfrom ..fem import kern\n",
             "clusterfem_ros/fem/__init__.py": "", "clusterfem_ros/fem/kern.py": "import numpy\n",
             "clusterfem_ros/fem/bad.py": "def f():\n    from ..nodes.node import x\n    import sensor_msgs.msg\n",
             "clusterfem_ros/fem/up.py": "from ..scene import Scene\n",
             "clusterfem_ros/fem/mesh/__init__.py": "",
             "clusterfem_ros/fem/mesh/low.py": "from ..materials import neo\n",
             "clusterfem_ros/fem/materials/__init__.py": "",
             "clusterfem_ros/fem/materials/neo.py": "from ..mesh import low\n",
             "clusterfem_ros/recording/__init__.py": "", "clusterfem_ros/recording/rec.py": "from .. import scene\n",
             "clusterfem_ros/scene.py": "from .fem import up\nfrom clusterfem_ros.recording import rec\n",
             "msg_adapters/__init__.py": "", "msg_adapters/m.py": "import numba\nfrom clusterfem_ros.fem import kern\n"}
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    g = import_graph(tmp_path, ("clusterfem_ros", "msg_adapters"))
    assert g["clusterfem_ros.nodes.node"] == {"rclpy", "clusterfem_ros.fem.kern"}
    assert g["clusterfem_ros.fem.bad"] == {"clusterfem_ros.nodes.node", "sensor_msgs.msg"}
    assert g["clusterfem_ros.recording.rec"] == {"clusterfem_ros.scene"}
    bad = "\n".join(layer_violations(g))
    for expected in ("fem.bad imports clusterfem_ros.nodes.node: the core never imports nodes/",
                     "fem.bad imports sensor_msgs.msg: the core (below nodes/) imports no ROS",
                     "fem.up imports clusterfem_ros.scene: fem may import only ['errors', 'fem.kernels', "
                     "'fem.linear', 'fem.mesh', 'numba_config']",
                     "fem.mesh.low imports clusterfem_ros.fem.materials.neo: fem.mesh may import only ['errors', "
                     "'numba_config']",
                     "recording.rec imports clusterfem_ros.scene: recording may import only ['errors', 'topics']",
                     "msg_adapters.m imports numba: msg_adapters holds no physics",
                     "msg_adapters.m imports clusterfem_ros.fem.kern: msg_adapters converts messages"):
        assert expected in bad, expected
    assert "nodes.node" not in bad.replace("imports clusterfem_ros.nodes.node", "")     # nodes may import ROS
    assert set(circles(g)) == {frozenset({"clusterfem_ros.scene", "clusterfem_ros.fem.up",
                                          "clusterfem_ros.recording.rec"}),
                               frozenset({"clusterfem_ros.fem.mesh.low", "clusterfem_ros.fem.materials.neo"})}


def test_the_graph_holds_the_package():
    """The real graph, read: every part of the core is there and the known edges are found."""
    assert {part(m, GRAPH) for m in _core_modules()} == set(ALLOWED)
    assert "rclpy" in {i.split(".")[0] for i in GRAPH["clusterfem_ros.nodes.clusterfem_node"]}
    assert "clusterfem_ros.scene" in GRAPH["clusterfem_ros.replay"]
    assert "clusterfem_ros.fem.integrators.base" in GRAPH["clusterfem_ros.fem.integrators.clustered_explicit"]


def test_every_module_keeps_to_its_layer():
    bad = layer_violations(GRAPH)
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def test_no_import_circles():
    found = [sorted(c) for c in circles(GRAPH)]
    assert not found, f"modules importing each other in a circle: {found}"


def _core_modules():
    return sorted(m for m in GRAPH if m.startswith("clusterfem_ros") and not m.startswith("clusterfem_ros.nodes"))


def test_every_error_the_core_defines_derives_from_the_common_root():
    """Every exception class of the core (public: a private marker such as recording's _Reported is not an
    error the caller sees; a Warning category such as UnboundedWarpingWarning is not raised) is a
    ClusterFemError, and keeps a builtin base a caller may already catch."""
    from clusterfem_ros.errors import ClusterFemError
    found = []
    for name in _core_modules():
        module = importlib.import_module(name)
        for obj in vars(module).values():
            if (inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == name
                    and not obj.__name__.startswith("_") and not issubclass(obj, Warning)
                    and obj is not ClusterFemError):
                found.append(obj)
                assert issubclass(obj, ClusterFemError), f"{name}.{obj.__name__} does not derive from ClusterFemError"
                assert issubclass(obj, (ValueError, RuntimeError)), f"{name}.{obj.__name__} lost its builtin base"
    names = {e.__name__ for e in found}
    assert {"ConfigError", "DivergenceError", "StabilityError", "MeshError", "ChoiceError"} <= names, names


def test_no_module_imports_a_private_name_of_another():
    """What one module builds on in another is public there (a leading underscore says: nobody else uses it)."""
    found = []
    for top in INSTALLED:
        for f in sorted((ROOT / top).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text(), str(f))):
                if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").split(".")[0] in INSTALLED):
                    found += [f"{f.relative_to(ROOT)}:{node.lineno} imports {a.name}" for a in node.names
                              if a.name.startswith("_") and not a.name.startswith("__")]
    assert found == []
