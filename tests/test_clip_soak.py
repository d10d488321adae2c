"""Soak: every fetched clip (tests/data/mocap_clips.yaml) for its whole length on the default scene, headless
and through the node. Targets: no reset, nothing published farther than output.max_bone_distance from the
bones. A clip that is not present is skipped with the file and manifest entry to fetch."""
import pytest

from benchmarks.clips import find_clip, load_manifest, missing_message

CLIPS = load_manifest()


def _path(clip):
    path = find_clip(clip)
    if path is None:
        pytest.skip(missing_message(clip))
    return path


def test_the_manifest_names_each_clip_with_its_provenance():
    """Runs in CI without the clips: at least six clips, each with repository, commit, path and sha256."""
    assert len(CLIPS) >= 6 and len({c.name for c in CLIPS}) == len(CLIPS)
    for c in CLIPS:
        assert len(c.commit) == 40 and len(c.sha256) == 64 and c.path.endswith(".bvh") and "/" in c.repository
    assert any("3dsMax" in c.motion for c in CLIPS)


@pytest.mark.soak
@pytest.mark.parametrize("clip", CLIPS, ids=[c.name for c in CLIPS])
def test_a_clip_played_headless_never_diverges(clip):
    from benchmarks.clip_soak import headless_soak
    r = headless_soak(_path(clip))
    print(r)
    assert r.resets == 0, r.first_problem
    assert r.worst_distance <= 0.3 and r.worst_volume < 0.5


@pytest.mark.soak
@pytest.mark.ros
@pytest.mark.parametrize("clip", CLIPS, ids=[c.name for c in CLIPS])
def test_a_clip_played_through_the_node_publishes_nothing_torn(clip):
    from benchmarks.node_soak import node_soak
    r = node_soak(_path(clip))
    print(r)
    assert r.markers > 0 and r.markers_far == 0, r
    assert r.resets == 0, r
