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
    """A name the package gives a config or a scene's values: config, self.config, c, cfg, frames.scene, ..."""
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
    return name in ("c", "cfg") or "config" in name or "scene" in name


def _read_key(node: ast.AST) -> tuple[ast.expr, object] | None:
    """(object, key) of a read by a constant key: ``x["key"]`` (not a store) or ``x.get("key", ...)``."""
    if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load) and isinstance(node.slice, ast.Constant):
        return node.value, node.slice.value
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
            and node.args and isinstance(node.args[0], ast.Constant)):
        return node.func.value, node.args[0].value
    return None


def string_key_reads(path: Path) -> list[tuple[int, str]]:
    """(line, parameter) of every read of scene values by a parameter's name in a file: a section's dotted name
    on any mapping (config["body.kind"], values.get("output.colormap")), a name outside the sections on a config
    or scene (config["method"]); not the overrides a dict of values sets, not a CSV row's columns."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        read = _read_key(node)
        if read is None or read[1] not in NAMES:
            continue
        if "." in read[1] or is_config(read[0]):
            out.append((node.lineno, read[1]))
    return out


def test_the_finder_sees_a_string_key_read(tmp_path):
    path = tmp_path / "probe.py"
    path.write_text('def f(self, c, row, out, frames, d):\n    out["method"] = row["method"]\n'
                    '    return self.config["body.kind"], c["physics.step"], c["not.a.parameter"]\n'
                    'def g(frames, d, row):\n'
                    '    return frames.scene.get("method", ""), d.get("output.colormap"), row.get("method")\n')
    assert sorted(string_key_reads(path)) == [(3, "body.kind"), (3, "physics.step"), (5, "method"),
                                              (5, "output.colormap")]


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
