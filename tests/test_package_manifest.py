"""package.xml declares every runtime dependency by a rosdep key that exists for jazzy: each pip requirement of
setup.py that has one (the others named in its comment, for pip), and each ROS package or third-party module the
installed code imports; requirements.lock pins every pip requirement."""
from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CODE = [ROOT / "clusterfem_ros", ROOT / "msg_adapters"]

# The keys package.xml may use: `rosdep install` fails for the whole workspace on a key it cannot resolve. Checked
# in ros/rosdistro (commit 8468e88ccd523427f9131e39d2af0938f1c298b2): the ROS packages released into jazzy
# (jazzy/distribution.yaml) and the keys of rosdep/python.yaml. Add a key here only after finding it there.
JAZZY_PACKAGES = {"rclpy", "geometry_msgs", "sensor_msgs", "visualization_msgs", "diagnostic_msgs", "std_msgs",
                  "builtin_interfaces", "rcl_interfaces", "ament_index_python", "pinocchio"}
PYTHON_KEYS = {"python3-numpy", "python3-scipy", "python3-numba", "python3-meshio", "python3-yaml",
               "python3-matplotlib", "python3-imageio", "python3-collada", "python3-pil", "python3-trimesh-pip",
               "python3-rtree", "python3-pyvista-pip", "python3-rosbags-pip", "python3-platformdirs",
               "python3-pytest", "python3-websockets", "mcap-ros2-support"}
KNOWN_KEYS = JAZZY_PACKAGES | PYTHON_KEYS
# pip name (setup.py, its extras too) -> package.xml key; None: rosdistro has no key for it (python3-mcap-pip,
# python3-pytetwild-pip, ... do not exist; example-robot-data is not released into jazzy), so pip installs it from
# requirements.lock and package.xml's comment names it
ROSDEP = {"numpy": "python3-numpy", "scipy": "python3-scipy", "numba": "python3-numba", "pin": "pinocchio",
          "mcap": None, "meshio": "python3-meshio", "pyyaml": "python3-yaml",
          "matplotlib": "python3-matplotlib", "pillow": "python3-pil", "imageio": "python3-imageio",
          "imageio-ffmpeg": None, "trimesh": "python3-trimesh-pip", "rtree": "python3-rtree",
          "pytetwild": None, "pyvista": "python3-pyvista-pip", "fast_simplification": None,
          "rosbags": "python3-rosbags-pip", "foxglove-sdk": None, "platformdirs": "python3-platformdirs",
          "pycollada": "python3-collada", "pytest": "python3-pytest", "websockets": "python3-websockets",
          "mcap-ros2-support": "mcap-ros2-support", "example-robot-data": None}
# imported module -> pip name
MODULES = {"numpy": "numpy", "scipy": "scipy", "numba": "numba", "llvmlite": "numba", "pinocchio": "pin",
           "mcap": "mcap", "meshio": "meshio", "yaml": "pyyaml", "matplotlib": "matplotlib",
           "mpl_toolkits": "matplotlib", "PIL": "pillow", "imageio": "imageio", "imageio_ffmpeg": "imageio-ffmpeg",
           "trimesh": "trimesh", "rtree": "rtree", "pytetwild": "pytetwild", "pyvista": "pyvista",
           "fast_simplification": "fast_simplification", "rosbags": "rosbags", "foxglove": "foxglove-sdk",
           "collada": "pycollada",
           "platformdirs": "platformdirs"}
OURS = {"clusterfem_ros", "msg_adapters"}


def _setup_keywords() -> dict:
    """setup()'s literal keyword arguments in setup.py."""
    call = next(n for n in ast.walk(ast.parse((ROOT / "setup.py").read_text()))
                if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    out = {}
    for k in call.keywords:
        try:
            out[k.arg] = ast.literal_eval(k.value)
        except ValueError:
            pass                                # computed (data_files, packages)
    return out


def _setup_requires() -> list[str]:
    return list(_setup_keywords()["install_requires"])


def _requirements() -> dict[str, str]:
    """Every pip requirement of setup.py -> its package.xml tag: exec_depend, or test_depend for the test extra."""
    kw = _setup_keywords()
    out = {req: "exec_depend" for req in kw["install_requires"]}
    for extra, reqs in kw["extras_require"].items():
        out.update({req: "test_depend" if extra == "test" else "exec_depend" for req in reqs})
    return out


def _package_xml(tag: str) -> set[str]:
    return {e.text for e in ET.parse(ROOT / "package.xml").getroot().iter(tag)}


def _package_xml_comments() -> str:
    text = (ROOT / "package.xml").read_text()
    return " ".join(re.findall(r"<!--(.*?)-->", text, re.S))


def _imports() -> set[str]:
    names = set()
    for folder in CODE:
        for path in folder.rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names |= {a.name.split(".")[0] for a in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names.add(node.module.split(".")[0])
    return names - OURS - set(sys.stdlib_module_names)


DEPEND_TAGS = ("depend", "exec_depend", "build_depend", "build_export_depend", "test_depend", "buildtool_depend")


def test_every_package_xml_key_is_a_rosdep_key_of_jazzy():
    for tag in DEPEND_TAGS:
        unknown = sorted(_package_xml(tag) - KNOWN_KEYS)
        assert not unknown, (f"package.xml <{tag}> {unknown}: not keys of ros/rosdistro for jazzy (rosdep install "
                             "fails on them); use the key rosdep/python.yaml has, or leave a pip-only requirement out "
                             "of package.xml and name it in its comment (requirements.lock pins it)")
    assert {k for k in ROSDEP.values() if k} <= KNOWN_KEYS, "ROSDEP maps to a key not checked in rosdistro"


def test_every_pip_requirement_is_in_package_xml_or_named_there_as_pip_only_and_pinned():
    lock = (ROOT / "requirements.lock").read_text().split()
    pinned = {line.split("==")[0].lower().replace("_", "-") for line in lock}
    comments = _package_xml_comments()
    for req, tag in _requirements().items():
        assert req in ROSDEP, f"setup.py requires {req!r}: find its key in ros/rosdistro (or None) for ROSDEP"
        key = ROSDEP[req]
        if key is None:
            named = re.search(rf"(?<![\w-]){re.escape(req)}(?![\w-])", comments)
            assert named, f"setup.py requires {req!r}, which has no rosdep key: name it in package.xml's comment (pip)"
        else:
            assert key in _package_xml(tag), f"setup.py requires {req!r}: declare {key!r} in package.xml <{tag}>"
        assert req.lower().replace("_", "-") in pinned, f"setup.py requires {req!r}: pin it in requirements.lock"


def test_every_import_of_the_installed_code_is_declared():
    declared = _package_xml("exec_depend")
    requires = set(_setup_requires())
    for module in sorted(_imports()):
        if module in MODULES:
            assert MODULES[module] in requires, f"{module} is imported: add {MODULES[module]!r} to install_requires"
        else:                                   # a ROS package (rclpy, *_msgs, ament_index_python)
            assert module in declared, f"{module} is imported: declare it in package.xml (exec_depend)"
