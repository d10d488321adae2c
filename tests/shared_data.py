"""The real data beside the checkout (../shared/data) or under $CLUSTERFEM_DATA, checked against the sha256 of its
manifest; a test whose data is absent is skipped, naming the manifest that says where to get it.

``CLUSTERFEM_SHARED`` (tests only) stands for ../shared: pointed at an empty folder, the suite runs as on a
checkout without it (test_shared_data.py does so).
"""
import os
from pathlib import Path

SHARED = Path(os.environ.get("CLUSTERFEM_SHARED") or Path(__file__).resolve().parents[2] / "shared")
CMU_WALK = SHARED / "data" / "mocap" / "cmu_06_01_walk.bvh"      # where the README's commands read the walk
CLIP_MANIFEST = Path(__file__).resolve().parent / "data" / "mocap_clips.yaml"
CHARACTER_SCENE = Path(__file__).resolve().parents[1] / "config" / "character_walk.yaml"
CHARACTER_MANIFEST = Path(__file__).resolve().parents[1] / "config" / "character_data.md"


def character_mesh() -> Path:
    """The MakeHuman body the character scene reads (under $CLUSTERFEM_DATA or ../shared/data), checked against the
    sha256 of its manifest; the calling test is skipped, naming the manifest, when it is absent."""
    import hashlib
    import re

    import pytest

    from clusterfem_ros.body.fit import FitError, find_data_file
    from clusterfem_ros.config import load_scene_file
    name = load_scene_file(CHARACTER_SCENE)["body.surface_file"]
    try:
        path = find_data_file(name)
    except FitError as exc:
        pytest.skip(f"the character mesh is absent ({exc}); {CHARACTER_MANIFEST.name} in config/ says where it comes "
                    "from and where to put it")
    row = next(line for line in CHARACTER_MANIFEST.read_text().splitlines() if line.startswith(f"| `{name}`"))
    want = re.findall(r"\b[0-9a-f]{64}\b", row)[0]
    got = hashlib.sha256(path.read_bytes()).hexdigest()
    assert got == want, f"{path} has sha256 {got}, config/{CHARACTER_MANIFEST.name} says {want}: fetch it again"
    return path


def walk_clip(beside_only: bool = False) -> Path:
    """The CMU walk (the manifest's ``walk`` entry) from ../shared/data/mocap or, unless ``beside_only`` (what the
    README's commands read), $CLUSTERFEM_DATA/mocap, checked against the manifest's sha256; the calling test is
    skipped, naming the manifest, when it is absent."""
    import hashlib

    import pytest
    import yaml
    entry = yaml.safe_load(CLIP_MANIFEST.read_text())["walk"]
    dirs = [SHARED / "data" / "mocap"]
    if os.environ.get("CLUSTERFEM_DATA") and not beside_only:
        dirs.append(Path(os.environ["CLUSTERFEM_DATA"]) / "mocap")
    found = [d / f"{entry['name']}.bvh" for d in dirs if (d / f"{entry['name']}.bvh").is_file()]
    if not found:
        pytest.skip(f"the walk clip {entry['name']}.bvh is absent from {' and '.join(str(d) for d in dirs)}: entry "
                    f"'walk' of tests/data/{CLIP_MANIFEST.name} says where it comes from ({entry['path']} at commit "
                    f"{entry['commit']} of {entry['repository']}) and where to put it")
    got = hashlib.sha256(found[0].read_bytes()).hexdigest()
    assert got == entry["sha256"], (f"{found[0]} has sha256 {got}, tests/data/{CLIP_MANIFEST.name} says "
                                    f"{entry['sha256']}: copy {entry['path']} at commit {entry['commit']} of "
                                    f"{entry['repository']} again")
    return found[0]


def manifest_clip(name: str) -> Path:
    """The clip ``name`` of tests/data/mocap_clips.yaml, found where benchmarks/clips.py looks and checked against
    its sha256; the calling test is skipped, naming the manifest entry, when it is absent."""
    import pytest

    from benchmarks.clips import find_clip, load_manifest, missing_message
    clip = next(c for c in load_manifest() if c.name == name)
    path = find_clip(clip)
    if path is None:
        pytest.skip(missing_message(clip))
    return path


def manifest_clips() -> list[Path]:
    """Every clip of tests/data/mocap_clips.yaml that is present (sha256-checked), in manifest order."""
    from benchmarks.clips import find_clip, load_manifest
    return [p for p in (find_clip(c) for c in load_manifest()) if p is not None]
