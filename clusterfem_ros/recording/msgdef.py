"""Message definitions from the installed interface files, as rosbag2 puts them in MCAP schemas.

No rclpy and no *_msgs import: the `.msg` and `.json` files are found under `share/<pkg>/msg/` of
each prefix in AMENT_PREFIX_PATH, then of the running Python environment (PyPI wheels put them
in `<venv>/share`).
"""
from __future__ import annotations

import json
import os
import re
import sys
from functools import cache
from pathlib import Path

SEPARATOR = "=" * 80
PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
                        "int32", "uint32", "int64", "uint64", "string", "wstring", "time", "duration"})


def normalize_type(msg_type: str) -> str:
    """'pkg/Type' or 'pkg/msg/Type' -> 'pkg/msg/Type'."""
    parts = msg_type.strip().split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or parts[1] != "msg" or not all(parts):
        raise ValueError(f"message type {msg_type!r} is not of the form 'pkg/msg/Type' (e.g. 'sensor_msgs/msg/JointState')")
    return "/".join(parts)


def _share_roots() -> list[Path]:
    roots = [Path(p) / "share" for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return roots + [Path(sys.prefix) / "share"]


@cache
def interface_file(msg_type: str, suffix: str) -> Path:
    """Path of `share/<pkg>/msg/<Type><suffix>` for the first prefix that has it."""
    pkg, _, name = normalize_type(msg_type).split("/")
    roots = _share_roots()
    for root in roots:
        path = root / pkg / "msg" / f"{name}{suffix}"
        if path.is_file():
            return path
    raise FileNotFoundError(f"no {pkg}/msg/{name}{suffix} under {[str(r) for r in roots]}: install the "
                            f"package that provides {msg_type} or add its prefix to AMENT_PREFIX_PATH")


def dependencies(msg_type: str, text: str) -> list[str]:
    """Non-primitive field types of a .msg text, as 'pkg/Type', in order of first use."""
    pkg = normalize_type(msg_type).split("/")[0]
    deps: list[str] = []
    for line in text.splitlines():
        tokens = line.split("#", 1)[0].split()
        if len(tokens) < 2:  # blank or comment line
            continue
        base = re.sub(r"<=\d+$", "", re.sub(r"\[[^\]]*\]$", "", tokens[0]))  # drop [..] and string bounds
        if base in PRIMITIVES:
            continue
        if base == "Header":
            dep = "std_msgs/Header"
        elif "/" in base:
            parts = base.split("/")
            dep = f"{parts[0]}/{parts[-1]}"
        else:
            dep = f"{pkg}/{base}"
        if dep not in deps:
            deps.append(dep)
    return deps


@cache
def message_definition(msg_type: str) -> str:
    """The `ros2msg` schema text: the type's .msg text, then each dependency once (depth first)
    as '\\n' + '=' * 80 + '\\nMSG: pkg/Type\\n' + its .msg text."""
    root = normalize_type(msg_type)
    parts = [interface_file(root, ".msg").read_text(encoding="utf-8")]
    seen = {root}

    def visit(owner: str, text: str) -> None:
        for dep in dependencies(owner, text):
            full = normalize_type(dep)
            if full in seen:
                continue
            seen.add(full)
            dep_text = interface_file(full, ".msg").read_text(encoding="utf-8")
            parts.append(f"\n{SEPARATOR}\nMSG: {dep}\n{dep_text}")
            visit(full, dep_text)

    visit(root, parts[0])
    return "".join(parts)


@cache
def type_hash(msg_type: str) -> str:
    """The type's 'RIHS01_...' hash from share/<pkg>/msg/<Type>.json."""
    full = normalize_type(msg_type)
    data = json.loads(interface_file(full, ".json").read_text(encoding="utf-8"))
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == full:
            return str(entry["hash_string"])
    raise ValueError(f"{interface_file(full, '.json')} has no type hash for {full}")
