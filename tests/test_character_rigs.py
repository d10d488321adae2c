"""Every character of tests/data/character_meshes.yaml bound by ``skeleton.bind_pose: auto`` on captures of different
rigs (CMU, Mixamo, Bandai Namco) and played as ``scripts/run --scene config/character_walk.yaml --bvh CLIP --set
body.surface_file=meshes/X`` plays it (benchmarks.clip_soak.headless_soak, the mesh's file and group from the
manifest, its unit and axes read from its shape: benchmarks.characters.walk_overrides): no reset, nothing withheld, the volume
within 5 %. Skipped, naming the manifest entry, where a mesh or a clip is absent. The tets come from the user's
mesh cache (the first run meshes each mesh: up to a minute each on 2 cores under load).

Without ``-m soak``: each mesh under one of the three rigs in turn, 1 s at 1500 tets; with it, each under all
three for 3 s at the scene's 5000 tets (docs/benchmarks.md, "Other characters", has the table of these).
"""
import pytest

from tests.shared_data import CHARACTER_SCENE

RIGS = ("cmu_06_01_walk", "mixamo_rig_freebvh", "bandai_namco_walk")


def _entries():
    from benchmarks.characters import load_manifest
    return load_manifest()


def _mesh(entry):
    from benchmarks.characters import find_mesh, missing_message
    path = find_mesh(entry)
    if path is None:
        pytest.skip(missing_message(entry))
    return path


def _clip(name: str):
    from benchmarks.clips import find_clip, load_manifest, missing_message
    if name == "cmu_06_01_walk":
        from tests.shared_data import walk_clip
        return walk_clip()
    clip = next(c for c in load_manifest() if c.name == name)
    path = find_clip(clip)
    if path is None:
        pytest.skip(missing_message(clip))
    return path


def _walk(entry, rig: str, tets: int, seconds: float):
    from benchmarks.characters import walk_overrides
    from benchmarks.clip_soak import headless_soak
    r = headless_soak(_clip(rig), walk_overrides(_mesh(entry), entry, tets), seconds, CHARACTER_SCENE)
    print(entry.name, rig, r)
    assert r.resets == 0, r.first_problem
    assert r.withheld == 0 and r.shown >= 100 * seconds
    assert r.worst_volume <= 0.05, r.worst_volume
    # every limb's bones lie within 20 cm of the middle of the mesh's limb (the bind's own report)
    assert r.limbs and max(worst for _, worst in r.limbs.values()) < 0.2, r.limbs
    return r


@pytest.mark.parametrize("k", range(8))
def test_each_character_walks_under_a_capture_of_another_rig(k):
    entries = _entries()
    assert len(entries) == 8
    _walk(entries[k], RIGS[k % len(RIGS)], 1500, 1.0)


@pytest.mark.soak
@pytest.mark.parametrize("rig", RIGS)
@pytest.mark.parametrize("k", range(8))
def test_each_character_walks_under_three_rigs(k, rig):
    _walk(_entries()[k], rig, 5000, 3.0)
