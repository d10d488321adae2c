"""Speed-vs-error report: the error metric, its convergence, and the files the report writes."""
import csv
import math
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks import scenarios as S
from benchmarks import speed_error_report as R
from clusterfem_ros.fem.integrators import make_integrator
from clusterfem_ros.fem.mesh.voxel_mesh import box_mesh
from clusterfem_ros.method_choice import METRICS, pareto_front, read_points


@pytest.fixture(scope="module")
def small():
    """A 3 x 3 x 6 voxel column (bottom held) sagging under gravity for 0.08 s, and its references."""
    mesh = box_mesh((0.05, 0.05, 0.1), (3, 3, 6), (-0.025, -0.025, 0.0))
    sc = S.shape_scenario("column", 0.08, 0.004, mesh=mesh)
    ref = S.reference(sc, "linear")
    return sc, R.reference_data(sc, ref, corotated=False)


def test_a_rigidly_translated_run_has_its_shift_as_error_and_no_stress_or_volume_error(small):
    """Every vertex shifted by (0.3, 0.4, 0) mm at every sample: the position error is that shift (0.5 mm at every
    vertex, so rel_l2 = 0.5 mm sqrt(samples x vertices) / the reference's norm, written out here), while a
    translation changes neither the stress nor the volume (round-off only)."""
    sc, ref = small
    u = ref.run.u + np.array([3e-4, 4e-4, 0.0])
    e = R.errors(sc, u, ref, corotated=False)
    assert set(e) == set(METRICS)
    samples, n = ref.run.u.shape[:2]
    norm = math.sqrt(sum(float(x) ** 2 for x in ref.run.u.ravel()))
    assert ref.norm == pytest.approx(norm, rel=1e-12) and norm > 0
    assert e["max_mm"] == pytest.approx(0.5, rel=1e-9)
    assert e["rel_l2"] == pytest.approx(5e-4 * math.sqrt(samples * n) / norm, rel=1e-9)
    assert e["von_mises_rel"] < 1e-8 and e["volume_pct"] < 1e-9, e
    assert np.isfinite(ref.run.u).all()


def test_a_perturbed_run_has_the_expected_errors(small):
    sc, ref = small
    u = ref.run.u.copy()
    u[:, 5, 0] += 1e-4                      # one vertex off by 0.1 mm at every sample
    e = R.errors(sc, u, ref, corotated=False)
    assert e["max_mm"] == pytest.approx(0.1, rel=1e-9)
    assert e["rel_l2"] == pytest.approx(1e-4 * math.sqrt(len(u)) / ref.norm, rel=1e-9)
    assert e["von_mises_rel"] > 0 and e["volume_pct"] > 0
    nan = R.errors(sc, np.full_like(u, np.nan), ref, corotated=False)
    assert all(math.isnan(v) for v in nan.values())


def test_implicit_error_converges_at_first_order(small):
    sc, ref = small
    hs = np.array([1e-3, 5e-4, 2.5e-4])        # asymptotic range (errors 12 % and below)
    err = []
    for h in hs:
        run = S.simulate(sc, make_integrator("implicit_direct", sc.model), h, timed=False)
        err.append(R.errors(sc, run.u, ref, corotated=False)["rel_l2"])
    rate = np.polyfit(np.log(hs), np.log(err), 1)[0]
    assert 0.85 < rate < 1.15, f"observed rate {rate:.3f} (errors {err})"


def test_clustered_equals_standard_explicit_and_beats_implicit(small):
    """Lossless: the clustered and assembled explicit steps give the same errors; both beat implicit Euler."""
    sc, ref = small
    e = {m: R.errors(sc, S.simulate(sc, make_integrator(m, sc.model), 2e-3, timed=False).u, ref, False)
         for m in ("clustered", "standard_explicit", "implicit_direct")}
    for m in METRICS:
        assert e["clustered"][m] == pytest.approx(e["standard_explicit"][m], rel=1e-8, abs=1e-15)
    assert e["clustered"]["rel_l2"] < e["implicit_direct"]["rel_l2"]


def test_runs_taking_turns_give_the_states_of_runs_one_after_the_other(small):
    """interleaved_runs: every run has its own integrator and state, so taking turns changes only when steps
    are timed. The samples equal those of a run start to end bit for bit; every step is timed but the first of
    each turn; a run that fails is reported by its error and the others finish."""
    sc, _ = small
    plan = {("clustered", 2e-3): ("clustered", {}), ("implicit_direct", 1e-3): ("implicit_direct", {}),
            ("modal_10", 4e-3): ("modal", {"k": 10})}
    runs = {key: S.RunInProgress(sc, make_integrator(m, sc.model, **o), key[1]) for key, (m, o) in plan.items()}

    class Failing:                                   # holds still, then diverges at its 8th step
        steps = 0

        def step(self, state, control, h):
            self.steps += 1
            if self.steps == 8:
                raise R.DivergenceError("the state has diverged at t = 0.03 s: lower h")
            return SimpleNamespace(substeps=1)
    runs["failing", 4e-3] = S.RunInProgress(sc, Failing(), 4e-3, timed=False)
    said = []
    out = R.interleaved_runs(runs, said.append)
    assert out["failing", 4e-3].startswith("DivergenceError: the state has diverged at t = 0.03 s")
    assert any("sample" in s and "runs in turn" in s for s in said)
    for key, (m, o) in plan.items():
        alone = S.simulate(sc, make_integrator(m, sc.model, **o), key[1], timed=False)
        assert np.array_equal(out[key].u, alone.u), key
        steps = sc.n_samples * runs[key].per
        turns = -(-sc.n_samples // -(-R.TURN_STEPS // runs[key].per))
        assert len(runs[key].times) == steps - turns and out[key].ms_per_step > 0


def test_step_must_divide_the_sample_interval(small):
    sc, _ = small
    with pytest.raises(ValueError, match="must divide the sample interval"):
        S.steps_per_sample(sc, 3e-3)


def test_report_writes_csv_markdown_and_pngs(tmp_path):
    cfg = dict(R.QUICK, scenes=("sphere",), steps=(5e-3, 1e-3), duration=0.04, quick=True)
    lines = []
    points, extras = R.run_report(cfg, progress=lines.append)
    assert len(points) == 2 * len(R.METHODS)
    assert any("sphere" in s and "ms/step" in s for s in lines), "progress lines are shown"
    paths = R.write_outputs(tmp_path, points, extras, cfg)
    for key in ("csv", "md", "png", "figure5"):
        assert paths[key].is_file() and paths[key].stat().st_size > 0, key
    assert paths["png"].read_bytes()[:4] == b"\x89PNG" and paths["figure5"].read_bytes()[:4] == b"\x89PNG"
    back = read_points(paths["csv"])
    assert len(back) == len(points)
    for p in back:
        assert p.info["status"] == "ok", (p.method, p.h, p.info["status"])
        assert np.isfinite(p.ms_per_step) and p.ms_per_step > 0
        assert all(np.isfinite(v) for v in p.errors.values())
    with open(paths["csv"]) as fh:
        assert {"scene", "method", "h", "ms_per_step", "max_mm", "status"} <= set(next(csv.reader(fh)))
    md = paths["md"].read_text()
    assert "Table 1 beside ours" in md and "sphere" in md and "Pareto" in md
    assert len(pareto_front(back)) >= 1


def test_only_a_full_run_replaces_the_shipped_points(tmp_path):
    from clusterfem_ros.method_choice import SHIPPED_POINTS
    assert R.points_destination(False, None, None) == SHIPPED_POINTS
    assert SHIPPED_POINTS.is_file() and SHIPPED_POINTS.parent.name == "data"     # package data, installed
    assert R.points_destination(True, None, None) is None                           # --quick: <out>/
    assert R.points_destination(False, ["sphere"], None) is None                    # --scenes: <out>/
    assert R.points_destination(False, None, str(tmp_path / "p.csv")) == tmp_path / "p.csv"


@pytest.mark.soak
def test_quick_command_end_to_end(tmp_path):
    assert R.main(["--quick", "--out", str(tmp_path)]) == 0
    pts = read_points(tmp_path / "speed_error.csv")
    assert {p.scene for p in pts} == {"sphere", "jelly_man"}
    assert (tmp_path / "speed_error.png").is_file() and (tmp_path / "figure5.png").is_file()
    md = (tmp_path / "speed_error.md").read_text()
    peer = md[md.index("## A peer: MuJoCo"):]                      # the peer runs in the same run (pinned)
    row = next(line for line in peer.splitlines() if line.startswith("| sphere ("))
    ours_ms, mujoco_ms = (float(c) for c in row.split("|")[2:4])
    assert ours_ms > 0 and mujoco_ms > 0


def test_mujoco_peer_runs_the_same_mesh_when_installed(small):
    mujoco = pytest.importorskip("mujoco", reason="optional peer: pip install mujoco to run it")
    from benchmarks.peer_mujoco import run_mujoco
    sc, ref = small
    r = run_mujoco(mujoco, sc, 1e-3, "Euler")
    assert r["u"].shape == ref.run.u.shape and np.isfinite(r["u"]).all()
    assert np.abs(r["u"][:, sc.model.fixed]).max() < 1e-9           # pinned vertices stay at rest (9-digit MJCF)
    assert r["u"][-1][:, 2].min() < 0.0                             # it sags under gravity
