"""The fetched motion-capture clips of tests/data/mocap_clips.yaml: where each file is, checked by sha256.

No clip is in this repository: each is fetched by its manifest entry (repository, commit, path, sha256, licence)
into a data folder. ``find_clip(entry)`` looks for ``<name>.bvh`` in ``mocap/`` of each data folder
(clusterfem_ros/data_dirs.py: ``$CLUSTERFEM_DATA``, ``../shared/data`` beside the checkout, the user data folder); ``missing_message`` names the
file and the manifest entry to fetch it from.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from clusterfem_ros.config import SceneConfig

REPO = Path(__file__).resolve().parents[1]
MANIFEST = REPO / "tests" / "data" / "mocap_clips.yaml"


@dataclass(frozen=True)
class Clip:
    name: str
    motion: str
    repository: str
    commit: str
    path: str
    sha256: str
    source: str = ""                # who made the capture or rig
    licence: str = ""               # the file's terms ('' : the manifest's top-level licence)


def load_manifest(path: Path = MANIFEST) -> list[Clip]:
    import yaml
    doc = yaml.safe_load(Path(path).read_text())
    return [Clip(**{k: str(v) for k, v in c.items()}) for c in doc["clips"]]


def clip_dirs() -> list[Path]:
    """Where clips are looked for, in order: ``mocap/`` of each data folder (clusterfem_ros/data_dirs.py)."""
    from clusterfem_ros.data_dirs import data_roots
    return [root / "mocap" for root in data_roots()]


def find_fetched(dirs: list[Path], name: str, entry, manifest: Path) -> Path | None:
    """The first ``dirs/name`` that exists, checked against the manifest ``entry``'s sha256 (another hash raises
    ValueError naming where to copy it from: the entry's path, commit and repository); None when absent."""
    for d in dirs:
        f = d / name
        if f.is_file():
            digest = hashlib.sha256(f.read_bytes()).hexdigest()
            if digest != entry.sha256:
                raise ValueError(f"{f} has sha256 {digest}, the manifest ({manifest.name}) says {entry.sha256}: "
                                 f"copy {entry.path} at commit {entry.commit} of {entry.repository} again")
            return f
    return None


def find_clip(clip: Clip) -> Path | None:
    """The clip's file if present with the manifest's sha256 (a file with another hash raises ValueError)."""
    return find_fetched(clip_dirs(), f"{clip.name}.bvh", clip, MANIFEST)


def missing_message(clip: Clip) -> str:
    where = " or ".join(str(d) for d in clip_dirs()) + ("" if os.environ.get("CLUSTERFEM_DATA") else
                                                         " (or $CLUSTERFEM_DATA/mocap)")
    return (f"clip {clip.name}.bvh not found in {where}: it is {clip.path} at commit {clip.commit} of "
            f"{clip.repository} (entry '{clip.name}' of {MANIFEST.relative_to(REPO)})")


MIN_SECONDS = 13.0          # a clip shorter than this is looped until it has played this long


def played_seconds(duration: float, seconds: float | None) -> float:
    """How long a clip of ``duration`` [s] is played: ``seconds`` if given, else its length or MIN_SECONDS."""
    return max(duration, MIN_SECONDS) if seconds is None else float(seconds)


def clip_config(overrides: dict | None = None, scene: Path | None = None, bvh: Path | None = None) -> SceneConfig:
    """The default scene (or the scene file ``scene``) on a BVH's own skeleton, what ``scripts/run --bvh`` runs:
    the jelly man built on it (in the pose motion.capture_bind_pose chooses for the clip ``bvh``), or the scene's
    character fitted to it."""
    from clusterfem_ros.config import load_scene_file
    from clusterfem_ros.motion import on_capture_skeleton
    base = (SceneConfig() if scene is None else load_scene_file(scene)).with_values(overrides or {})
    said = on_capture_skeleton(base, bvh, lambda line: print(f"[clip_soak] {line}", flush=True))
    return said.with_values(overrides or {})
