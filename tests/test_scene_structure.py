"""How the scene's modules are written, read from their sources with ast: the package's own code reads the
config through its typed sections (config.body.kind, not config["body.kind"]), and the scene's building and
running modules import at module level (a reader sees every dependency at the top)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from clusterfem_ros.config import PARAMS

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "clusterfem_ros"
NAMES = {p.name for p in PARAMS}
# string-key reads left, with the reason: (file, parameter)
LEFT: set[tuple[str, str]] = set()


def is_config(node: ast.expr) -> bool:
    """A name the package gives a config: config, self.config, c, cfg, scene_config, ..."""
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
    return name in ("c", "cfg") or "config" in name


def string_key_reads(path: Path) -> list[tuple[int, str]]:
    """(line, parameter) of every read of a config by a parameter's name (config["body.kind"]) in a file (not
    the overrides a dict of values sets, not a CSV row's columns)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if (isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load) and is_config(node.value)
                and isinstance(node.slice, ast.Constant) and node.slice.value in NAMES):
            out.append((node.lineno, node.slice.value))
    return out


def test_the_finder_sees_a_string_key_read(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text('def f(self, c, row, out):\n    out["method"] = row["method"]\n'
                    '    return self.config["body.kind"], c["physics.step"], c["not.a.parameter"]\n')
    assert sorted(string_key_reads(path)) == [(3, "body.kind"), (3, "physics.step")]


def test_the_package_reads_its_config_through_typed_sections():
    config_module = PACKAGE / "config.py"     # it builds the sections from the flat table
    found = [(str(f.relative_to(PACKAGE)), line, name) for f in sorted(PACKAGE.rglob("*.py")) if f != config_module
             for line, name in string_key_reads(f)]
    assert [(f, name) for f, _, name in found if (f, name) not in LEFT] == [], found
    assert {(f, name) for f, _, name in found} == LEFT      # an entry of LEFT that is gone must leave LEFT


@pytest.mark.parametrize("name", ["scene.py", "scene_setup.py", "scene_build.py"])
def test_the_scene_modules_import_at_module_level_only(name):
    tree = ast.parse((PACKAGE / name).read_text())
    inner = [node.lineno for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
             for node in ast.walk(f) if isinstance(node, (ast.Import, ast.ImportFrom))]
    assert inner == [], f"{name} imports inside functions at lines {inner}"
