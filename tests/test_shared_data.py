"""Tests that need data from outside the repository skip, naming the manifest, when it is absent, and refuse a
file whose sha256 is not the manifest's."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

import tests.shared_data as shared_data

ROOT = Path(__file__).resolve().parents[1]


def test_the_walk_clip_is_checked_by_sha256_and_skips_naming_the_manifest_when_absent(tmp_path, monkeypatch):
    monkeypatch.setattr(shared_data, "SHARED", tmp_path / "no_shared")
    monkeypatch.setenv("CLUSTERFEM_DATA", str(tmp_path / "empty"))
    with pytest.raises(pytest.skip.Exception, match=r"entry 'walk' of tests/data/mocap_clips.yaml says where it "
                                                    r"comes from \(MyBVH/animFiles/06/06_01.bvh at commit 543bbdd"):
        shared_data.walk_clip()
    mocap = tmp_path / "empty" / "mocap"
    mocap.mkdir(parents=True)
    (mocap / "cmu_06_01_walk.bvh").write_text("HIERARCHY\n")              # another file under the clip's name
    with pytest.raises(AssertionError, match="has sha256 .* says fa33f300"):
        shared_data.walk_clip()
    with pytest.raises(pytest.skip.Exception, match="mocap_clips.yaml"):
        shared_data.walk_clip(beside_only=True)                              # the README reads ../shared only


def test_the_tests_on_the_walk_skip_naming_the_manifest_on_a_checkout_without_shared(tmp_path):
    """test_docs' README commands and the clip soak's walk, run as on a checkout without ../shared and without
    CLUSTERFEM_DATA: skipped with the manifest named, not failed."""
    env = dict(os.environ, CLUSTERFEM_SHARED=str(tmp_path / "no_shared"))
    env.pop("CLUSTERFEM_DATA", None)
    tests = ["tests/test_docs.py::test_the_readme_node_commands_run_together",
             "tests/test_clip_soak.py::test_the_headless_soak_reports_inverted_states_consistently",
             "tests/test_loop_seam.py::test_the_cmu_walk_loops_into_the_scene_without_a_teleport"]
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", *tests], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "3 skipped" in run.stdout and "SKIPPED [3]" in run.stdout and "mocap_clips.yaml" in run.stdout, run.stdout
