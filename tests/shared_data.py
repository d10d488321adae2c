"""The real data beside the checkout (../shared/data), wherever the checkout is."""
from pathlib import Path

SHARED = Path(__file__).resolve().parents[2] / "shared"
CMU_WALK = SHARED / "data" / "mocap" / "cmu_06_01_walk.bvh"
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
