"""Method choice from measured points: cheapest per simulated second, Pareto front, file round trip."""
import math

import numpy as np
import pytest

from clusterfem_ros.method_choice import (METRICS, ChoiceError, MeasuredPoint, choose, choose_from_file,
                                          pareto_front, read_points, write_points)


def pt(method, h, ms, max_mm, scene="sphere", k=0, **info):
    errs = {m: max_mm * 1e-2 for m in METRICS}
    errs["max_mm"] = max_mm
    errs["rel_l2"] = max_mm * 0.1
    return MeasuredPoint(scene, method, h, k, ms, errs, info)


POINTS = [
    pt("implicit_direct", 1e-3, 0.5, 0.9),          # cost 500 ms/s
    pt("implicit_direct", 5e-3, 0.5, 2.9),          # cost 100
    pt("clustered", 1e-3, 0.05, 0.13),              # cost 50
    pt("clustered", 5e-3, 0.09, 0.26),              # cost 18
    pt("clustered_warp", 2e-3, 0.2, 0.135),         # cost 100
    pt("modal_30", 5e-3, 0.18, 3.0, k=30),          # cost 36
    pt("modal_30", 1e-3, 0.18, 0.95, k=30),         # cost 180
    pt("clustered", 1e-2, 0.1, math.nan),           # diverged: never chosen
]


def test_cost_is_per_simulated_second():
    assert POINTS[0].cost == pytest.approx(500.0)
    assert POINTS[3].cost == pytest.approx(18.0)


def test_choose_picks_the_cheapest_that_meets_the_budget():
    c = choose(POINTS, 1.0, "max_mm", "sphere")
    assert c.point is POINTS[3]                     # cost 18 and 0.26 mm <= 1 mm
    assert c.candidates == 5
    c = choose(POINTS, 0.2, "max_mm")
    assert c.point is POINTS[2]                     # only clustered h=1e-3 (cost 50) and warp (100) meet 0.2
    # brute force: no cheaper point meets the budget
    for budget in (0.14, 0.5, 1.0, 3.0, 10.0):
        c = choose(POINTS, budget)
        ok = [p for p in POINTS if p.ok and p.errors["max_mm"] <= budget]
        assert c.point.cost == min(p.cost for p in ok)


def test_ties_in_cost_go_to_the_smaller_error():
    a, b = pt("clustered", 1e-3, 0.05, 0.4), pt("standard_explicit", 1e-3, 0.05, 0.2)
    assert choose([a, b], 1.0).point is b


def test_no_point_meets_the_budget_names_the_best_achievable():
    with pytest.raises(ChoiceError, match=r"best achievable is 0\.13.*clustered at h = 0\.001"):
        choose(POINTS, 0.01, "max_mm", "sphere")


def test_best_achievable_names_the_cheaper_of_two_points_equal_to_round_off():
    same = [pt("standard_explicit", 1e-3, 0.3, 0.13 * (1 - 1e-13)), pt("clustered", 1e-3, 0.05, 0.13)]
    with pytest.raises(ChoiceError, match=r"best achievable is 0\.13 \(clustered at h = 0\.001"):
        choose(same, 0.01, "max_mm", "sphere")


@pytest.mark.parametrize("budget", [0.0, -1.0, math.nan, math.inf, "1"])
def test_bad_budget_is_refused(budget):
    with pytest.raises(ChoiceError, match="budget"):
        choose(POINTS, budget)


def test_unknown_scene_and_metric_are_refused():
    with pytest.raises(ChoiceError, match=r"no measured points for scene 'torus'.*sphere"):
        choose(POINTS, 1.0, scene="torus")
    with pytest.raises(ChoiceError, match="unknown error metric 'mm'"):
        choose(POINTS, 1.0, metric="mm")


def test_failed_runs_are_never_chosen():
    only_failed = [pt("clustered", 1e-2, 0.1, math.nan)]
    with pytest.raises(ChoiceError, match="every run failed"):
        choose(only_failed, 1e9)


def test_pareto_front_is_non_dominated_and_dominates_the_rest():
    rng = np.random.default_rng(7)
    pts = [pt("clustered", float(h), float(ms), float(e)) for h, ms, e in
           zip(rng.choice([5e-4, 1e-3, 2e-3], 60), rng.uniform(0.01, 2, 60), rng.lognormal(0, 1, 60))]
    front = pareto_front(pts, "max_mm")
    assert front, "a non-empty set has a front"

    def dominates(a, b):
        return (a.cost <= b.cost and a.errors["max_mm"] <= b.errors["max_mm"]
                and (a.cost < b.cost or a.errors["max_mm"] < b.errors["max_mm"]))

    for f in front:
        assert not any(dominates(p, f) for p in pts), f"front point {f.describe()} is dominated"
    for p in pts:
        if not any(p is f for f in front):
            assert any(dominates(f, p) or (f.cost == p.cost and f.errors == p.errors) for f in front)
    costs = [f.cost for f in front]
    errs = [f.errors["max_mm"] for f in front]
    assert costs == sorted(costs) and errs == sorted(errs, reverse=True)


def test_overrides_name_scene_parameters():
    assert POINTS[3].overrides == {"method": "clustered", "physics.step": 5e-3, "warping": False}
    assert POINTS[4].overrides == {"method": "clustered", "physics.step": 2e-3, "warping": True,
                                   "warping_model": "element"}
    nh = MeasuredPoint("jelly_man", "clustered_neohookean", 1e-3, 0, 0.3, POINTS[4].errors)
    assert nh.overrides == {"method": "clustered", "physics.step": 1e-3, "warping": True, "warping_model": "neohookean"}
    assert POINTS[5].overrides == {"method": "modal", "physics.step": 5e-3, "warping": False, "modal.k": 30}


def test_file_round_trip_and_choose_from_file(tmp_path):
    pts = [MeasuredPoint(p.scene, p.method, p.h, p.k, p.ms_per_step, p.errors, {"status": "ok", "substeps": 2})
           for p in POINTS]
    path = write_points(tmp_path / "points.csv", pts)
    back = read_points(path)
    assert len(back) == len(pts)
    for a, b in zip(pts, back):
        assert (a.scene, a.method, a.h, a.k) == (b.scene, b.method, b.h, b.k)
        assert b.ms_per_step == pytest.approx(a.ms_per_step, rel=1e-5)
        for m in METRICS:
            assert (math.isnan(a.errors[m]) and math.isnan(b.errors[m])) or b.errors[m] == pytest.approx(a.errors[m], rel=1e-5)
        assert b.info["substeps"] == "2"
    assert choose_from_file(path, "sphere", 1.0).point.method == "clustered"


def test_bad_files_give_clear_errors(tmp_path):
    with pytest.raises(ChoiceError, match="not found.*speed_error_report"):
        read_points(tmp_path / "missing.csv")
    p = tmp_path / "cols.csv"
    p.write_text("scene,method\nsphere,clustered\n")
    with pytest.raises(ChoiceError, match="missing column"):
        read_points(p)
    good = write_points(tmp_path / "good.csv", POINTS[:2]).read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([good[0], good[1].replace("0.001", "fast", 1)]) + "\n")
    with pytest.raises(ChoiceError, match="line 2"):
        read_points(bad)
