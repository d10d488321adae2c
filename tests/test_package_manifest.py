"""package.xml declares every runtime dependency: each pip requirement of setup.py, and each ROS package or
third-party module the installed code imports; requirements.lock pins every pip requirement."""
from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CODE = [ROOT / "clusterfem_ros", ROOT / "msg_adapters"]

# pip name -> package.xml key (rosdep: a Debian python3-* package, or its -pip key when Debian has none)
ROSDEP = {"numpy": "python3-numpy", "scipy": "python3-scipy", "numba": "python3-numba-pip", "pin": "pinocchio",
          "mcap": "python3-mcap-pip", "meshio": "python3-meshio-pip", "pyyaml": "python3-yaml",
          "matplotlib": "python3-matplotlib", "pillow": "python3-pil", "imageio": "python3-imageio",
          "imageio-ffmpeg": "python3-imageio-ffmpeg-pip", "trimesh": "python3-trimesh", "rtree": "python3-rtree",
          "pytetwild": "python3-pytetwild-pip", "pyvista": "python3-pyvista",
          "fast_simplification": "python3-fast-simplification-pip", "rosbags": "python3-rosbags-pip",
          "foxglove-sdk": "python3-foxglove-sdk-pip", "platformdirs": "python3-platformdirs",
          "pycollada": "python3-collada"}
# imported module -> pip name
MODULES = {"numpy": "numpy", "scipy": "scipy", "numba": "numba", "llvmlite": "numba", "pinocchio": "pin",
           "mcap": "mcap", "meshio": "meshio", "yaml": "pyyaml", "matplotlib": "matplotlib",
           "mpl_toolkits": "matplotlib", "PIL": "pillow", "imageio": "imageio", "imageio_ffmpeg": "imageio-ffmpeg",
           "trimesh": "trimesh", "rtree": "rtree", "pytetwild": "pytetwild", "pyvista": "pyvista",
           "fast_simplification": "fast_simplification", "rosbags": "rosbags", "foxglove": "foxglove-sdk",
           "collada": "pycollada",
           "platformdirs": "platformdirs"}
OURS = {"clusterfem_ros", "msg_adapters"}


def _setup_requires() -> list[str]:
    text = (ROOT / "setup.py").read_text()
    block = re.search(r"install_requires=\[(.*?)\]", text, re.S).group(1)
    return re.findall(r'"([^"]+)"', block)


def _package_xml(tag: str) -> set[str]:
    return {e.text for e in ET.parse(ROOT / "package.xml").getroot().iter(tag)}


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


def test_every_pip_requirement_is_in_package_xml_and_pinned():
    declared = _package_xml("exec_depend")
    pinned = {line.split("==")[0].lower().replace("_", "-") for line in (ROOT / "requirements.lock").read_text().split()}
    for req in _setup_requires():
        assert ROSDEP.get(req) in declared, f"setup.py requires {req!r}: declare {ROSDEP.get(req)!r} in package.xml"
        assert req.lower().replace("_", "-") in pinned, f"setup.py requires {req!r}: pin it in requirements.lock"


def test_every_import_of_the_installed_code_is_declared():
    declared = _package_xml("exec_depend")
    requires = set(_setup_requires())
    for module in sorted(_imports()):
        if module in MODULES:
            assert MODULES[module] in requires, f"{module} is imported: add {MODULES[module]!r} to install_requires"
        else:                                   # a ROS package (rclpy, *_msgs, ament_index_python)
            assert module in declared, f"{module} is imported: declare it in package.xml (exec_depend)"
