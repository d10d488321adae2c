"""Hard cases x methods (the stability table, small): every run stays bounded or refuses at set-up."""
import numpy as np
import pytest

from clusterfem_ros.bench import stability_table as st

STEPS = 40
# Stiffness warping with a vertex teleported 10 voxels and held there: eq. 10's blocks R_i K_ij R_i^T are
# not symmetric, so in the torn state the force circulates energy (with the rotations frozen it grows
# exponentially; updated, it stays 1.5-3x the budget). It stays finite (checked) but exceeds the budget:
# a known limit of eq. 10 (README, Known gaps); per-element corotation settles the same case.
ENERGY_CAN_GROW = {("teleport 0.5 m", "clustered+warp")}


@pytest.fixture(scope="module")
def results():
    out = {(c.name, m): st.run(m, c, scale=1.0, steps=STEPS, max_substeps=1000) for c in st.CASES for m in st.METHODS}
    print("\n" + st.table(st.HEADERS, [st.row(r) for r in out.values()]))
    return out


def test_every_run_is_bounded_or_refused_at_set_up(results):
    for (case, method), r in results.items():
        where = f"{case} / {method}: {r.outcome} {r.message}"
        if r.outcome == "refused":
            assert method in st.EXPLICIT, where
            assert "sub-steps" in r.message and "implicit" in r.message, where     # names the limit and the way out
            continue
        assert r.outcome != "diverged", where
        assert np.isfinite(r.energy_ratio) and np.isfinite(r.volume_error), where
        if (case, method) in ENERGY_CAN_GROW:
            print(f"known: {where}, max E / budget {r.energy_ratio:.2f}")
            continue
        assert r.outcome == "bounded" and r.energy_ratio <= st.ENERGY_SLACK, where


def test_unconditionally_stable_methods_never_refuse(results):
    for (case, method), r in results.items():
        if method not in st.EXPLICIT:
            assert r.outcome == "bounded" and r.substeps == 1, f"{case} / {method}: {r.outcome}"


def test_explicit_refuses_slivers_and_near_incompressibility_but_runs_the_rest(results):
    for method in st.EXPLICIT:
        assert results[("nu=0.499", method)].outcome == "refused"
        assert results[("slivers 1%", method)].outcome == "refused"
        assert results[("nu=0.49", method)].substeps > results[("h=1/30", method)].substeps / (10 / 3) > 1


def test_clustered_equals_standard_explicit_on_every_case(results):
    for case in st.CASES:
        a, b = results[(case.name, "clustered")], results[(case.name, "standard explicit")]
        assert a.outcome == b.outcome
        if a.outcome == "bounded":
            assert a.volume_error == pytest.approx(b.volume_error, rel=1e-8, abs=1e-12)
            assert a.energy_ratio == pytest.approx(b.energy_ratio, rel=1e-8)


def test_warping_removes_the_linear_volume_error_under_large_rotation(results):
    for case in ("twist 180", "teleport 0.5 m", "h=1/30"):
        lin, warp = results[(case, "clustered")].volume_error, results[(case, "clustered+warp")].volume_error
        print(f"{case}: volume error linear {lin * 100:.2f} %, warped {warp * 100:.2f} %")
        assert warp < 0.5 * lin


def test_free_fall_keeps_shape_and_follows_gravity():
    case = next(c for c in st.CASES if c.name == "free fall")
    for method in ("clustered", "modal 30"):
        r = st.run(method, case, steps=10)
        assert r.outcome == "bounded" and r.volume_error < 1e-9
