"""The benchmark's timing helpers: interleaved rounds and paired ratios (what they compute, not how fast)."""
import itertools

import pytest

from benchmarks.core_benchmark import per_call
from benchmarks.timing import interleaved_seconds, paired_ratio


def test_every_round_times_each_function_in_turn():
    log = []
    fns = {name: (lambda name=name: log.append(name)) for name in "abc"}
    samples = interleaved_seconds(fns, min_time=0.003, rounds=5, warmup=2)
    assert list(samples) == list("abc") and all(len(s) == 5 and min(s) > 0 for s in samples.values())
    calibration = [name for name in "abc" for _ in range(2 + 1)]
    assert log[:len(calibration)] == calibration
    runs = [name for name, _ in itertools.groupby(log[len(calibration):])]
    assert runs == list("abc") * 5


def test_paired_ratio_cancels_a_spell_that_hits_both_sides():
    fast, slow = [1.0, 8.0, 1.0, 1.0, 9.0], [2.0, 16.0, 2.0, 2.0, 18.0]
    assert paired_ratio(fast, slow) == 0.5
    assert paired_ratio(slow, fast) == 2.0
    with pytest.raises(ValueError, match="equally long"):
        paired_ratio([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="non-empty"):
        paired_ratio([], [])


def test_per_call_divides_by_reps_and_takes_the_faster_read_per_round():
    samples = {"sweep": [20.0, 40.0], "stream4": [10.0, 30.0], "stream8": [12.0, 20.0], "one": [3.0, 4.0]}
    out = per_call(samples, {"sweep": 10, "stream4": 10, "stream8": 10})
    assert out["sweep"] == [2.0, 4.0]
    assert out["stream"] == [1.0, 2.0]
    assert out["one"] == [3.0, 4.0]
    assert "stream_slices" not in out
