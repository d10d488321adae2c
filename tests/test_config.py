"""Scene configuration: the shipped default file, value checks with messages that name the value."""
import math

import pytest

from clusterfem_ros.config import (PARAMS, ConfigError, SceneConfig, check_value, default_scene_path, from_mapping,
                                   load_scene_file, scene_file_text)


def test_the_shipped_default_scene_is_exactly_the_built_in_defaults():
    assert load_scene_file(default_scene_path()).values == SceneConfig().values


def test_every_parameter_has_a_description_and_a_valid_default():
    for p in PARAMS:
        assert p.description and check_value(p.name, p.default) == p.default


@pytest.mark.parametrize("name, value, words", [
    ("material.poisson_ratio", 0.5, ["poisson_ratio", "0.5", "outside [0, 0.499]"]),
    ("material.young_modulus", math.nan, ["young_modulus", "nan"]),
    ("method", "fast", ["'fast'", "choose one of clustered"]),
    ("body.target_tets", 12.5, ["target_tets", "12.5", "expected int"]),
    ("warping", "yes", ["warping", "'yes'", "expected bool"]),
    ("physics.stepp", 0.001, ["unknown scene parameter 'physics.stepp'"]),
    ("stepp", 0.001, ["unknown scene parameter"]),
])
def test_bad_values_are_refused_naming_the_value_and_the_range(name, value, words):
    with pytest.raises(ConfigError) as e:
        check_value(name, value)
    for w in words:
        assert w in str(e.value)


@pytest.mark.parametrize("values, words", [
    ({"binding.level_radii": [0.06, 0.035]}, "strictly increasing"),
    ({"binding.kp": [1.0]}, "one value per level"),
    ({"body.kind": "mesh"}, "needs body.mesh_file"),
    ({"skeleton.source": "none"}, "built around a skeleton"),
    ({"binding.sliding_levels": 3}, "only 2 levels"),
    ({"binding.sliding_levels": 2, "binding.kinematic_core": True}, "kinematic_core prescribes it"),
])
def test_inconsistent_combinations_are_refused(values, words):
    with pytest.raises(ConfigError, match=words):
        from_mapping(values)


def test_a_scene_written_out_reads_back_identically(tmp_path):
    c = SceneConfig().with_values(body__kind="torus", skeleton__source="none", physics__step=2e-4,
                                  binding__level_radii=[0.02, 0.05])
    f = tmp_path / "scene.yaml"
    f.write_text(scene_file_text(c))
    assert load_scene_file(f).values == c.values


def test_unreadable_or_sectionless_files_say_what_is_missing(tmp_path):
    with pytest.raises(ConfigError, match="cannot read scene file"):
        load_scene_file(tmp_path / "missing.yaml")
    f = tmp_path / "other.yaml"
    f.write_text("some_node:\n  ros__parameters:\n    x: 1\n")
    with pytest.raises(ConfigError, match="clusterfem: ros__parameters"):
        load_scene_file(f)


def test_no_parameter_name_is_a_group_of_another():
    # 'a' and 'a.b' cannot both be written as nested YAML (and ros2 param dump would clash)
    names = {p.name for p in PARAMS}
    for n in names:
        parts = n.split(".")
        for i in range(1, len(parts)):
            assert ".".join(parts[:i]) not in names, n
