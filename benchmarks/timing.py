"""Timing helpers shared by the benchmark commands: warm-up first (JIT excluded), then medians."""
from __future__ import annotations

import statistics
import time
from typing import Callable


def median_seconds(fn: Callable[[], object], min_time: float = 0.3, repeats: int = 7, warmup: int = 3) -> float:
    """Median over ``repeats`` batches of the time of one call; batches last about min_time / repeats."""
    return statistics.median(interleaved_seconds({"fn": fn}, min_time, repeats, warmup)["fn"])


def interleaved_seconds(fns: dict[str, Callable[[], object]], min_time: float = 0.3, rounds: int = 11,
                        warmup: int = 3) -> dict[str, list[float]]:
    """Seconds per call of each function, one sample per round. Every round times a batch of each function in
    turn (batches last about min_time / rounds), so a slow spell of the host falls on all of them alike instead
    of on whichever one was being timed; ``paired_ratio`` of two functions' samples then cancels any spell
    longer than a round. Timed one after the other, a slow spell on this shared 2-core VM once made the
    sphere's clustered step read 0.0098 instead of 0.0077 ms, and its implicit-direct ratio 17x, not 21-38x."""
    batch = {}
    for name, fn in fns.items():
        for _ in range(warmup):
            fn()
        t0 = time.perf_counter()
        fn()
        batch[name] = max(1, int(min_time / rounds / max(time.perf_counter() - t0, 1e-7)))
    samples: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            n = batch[name]
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            samples[name].append((time.perf_counter() - t0) / n)
    return samples


def paired_ratio(a: list[float], b: list[float]) -> float:
    """The median over rounds of a[r] / b[r]: two functions' time ratio with the host's slow spells cancelled
    (samples from interleaved_seconds)."""
    if len(a) != len(b) or not a:
        raise ValueError(f"paired_ratio needs two equally long, non-empty sample lists, got {len(a)} and {len(b)}")
    return statistics.median(x / y for x, y in zip(a, b))


def table(headers: list[str], rows: list[list[object]]) -> str:
    """A Markdown table (reads well in a terminal and pastes into the README)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    fmt = lambda r: "| " + " | ".join(c.rjust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    return "\n".join([fmt(cells[0]), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [fmt(r) for r in cells[1:]])
