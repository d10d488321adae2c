"""The typed sections of the scene configuration: one field per parameter of the section, no defaults of their
own (PARAMS holds the one set), the values the flat table holds."""
import dataclasses

import pytest

from clusterfem_ros.config import PARAMS, SECTIONS, SceneConfig


@pytest.mark.parametrize("name", sorted(SECTIONS))
def test_a_section_has_a_field_for_every_parameter_it_names_and_no_default_of_its_own(name):
    fields = dataclasses.fields(SECTIONS[name])
    params = [p.name.split(".", 1)[1] for p in PARAMS if p.name.startswith(name + ".")]
    assert sorted(f.name for f in fields) == sorted(params)
    assert all(f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING for f in fields)


@pytest.mark.parametrize("name", sorted(SECTIONS))
def test_a_section_reads_the_values_of_its_config(name):
    changed = {p.name: p.default for p in PARAMS if p.name.startswith(name + ".")}
    numbers = [k for k, v in changed.items() if isinstance(v, float) and not isinstance(v, bool)]
    config = SceneConfig()
    if numbers:                                         # one value away from its default, inside its range
        p = next(p for p in PARAMS if p.name == numbers[0])
        value = p.default + 0.5 * ((p.hi if p.hi is not None else p.default + 1.0) - p.default)
        config = config.with_values({p.name: value})
    section = getattr(config, name)
    resolved = {p.name for p in PARAMS if p.or_auto}    # 'auto' or a number: the section holds the number it runs
    for f in dataclasses.fields(section):
        key = f"{name}.{f.name}"
        want = getattr(config, f.name) if key in resolved else config[key]
        assert getattr(section, f.name) == want, f.name
        if key in resolved:
            assert isinstance(want, float) and config.resolved()[key] == want
    if numbers:
        assert getattr(section, numbers[0].split(".", 1)[1]) != changed[numbers[0]]


def test_every_parameter_is_a_typed_attribute_of_the_config_a_section_field_or_a_top_level_one():
    """The package reads its config through typed attributes: every parameter is a field of its section
    (config.<section>.<field>) or, outside any section, an attribute of its own (config.method), with the value
    the flat table holds, changed values too."""
    config = SceneConfig().with_values(method="modal", warping=False, warping_model="vertex", modal__k=12)
    for p in PARAMS:
        section, _, name = p.name.rpartition(".")
        where = getattr(config, section) if section else config
        assert section in SECTIONS or not section, p.name
        held = config[p.name]
        if p.or_auto and held == "auto":                # the section holds what 'auto' runs (SceneConfig.resolved)
            held = config.resolved()[p.name]
        assert getattr(where, name) == held, p.name
    assert (config.method, config.warping, config.warping_model, config.modal.k) == ("modal", False, "vertex", 12)
