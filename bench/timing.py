"""The timing helpers every benchmark uses: warm-up calls, then the median of timed repeats; two
commits timed taking turns and summed up side by side; and the median of times of which some are
only lower bounds (a run that stopped on its budget)."""

from __future__ import annotations

import statistics
import time


def call_ms(fn) -> float:
    """Wall time of one call fn() in milliseconds."""
    start = time.perf_counter()
    fn()
    return 1e3 * (time.perf_counter() - start)


def median_ms(fn, repeats: int, *, warmup: int = 1) -> float:
    """Median wall time of fn() in milliseconds over `repeats` calls after `warmup` untimed calls."""
    for _ in range(warmup):
        fn()
    return statistics.median(call_ms(fn) for _ in range(repeats))


def turns(repeat: int) -> tuple[str, str]:
    """The order of "this" and "base" at repeat `repeat` when two commits take turns call by call
    (alternating, so that neither always runs first)."""
    return ("this", "base") if repeat % 2 == 0 else ("base", "this")


def side_by_side(this: list[float], base: list[float]) -> dict:
    """The medians of two commits' paired times and the median of the per-pair ratios this / base."""
    return {"this": statistics.median(this), "base": statistics.median(base),
            "ratio": statistics.median(a / b for a, b in zip(this, base, strict=True))}


def speedups(this: list[float], base: list[float]) -> list[float]:
    """The per-pair ratios base / this of two commits' paired times (> 1: this commit is faster);
    their median is the speed-up the benchmarks that report "base / this" give."""
    return [b / a for a, b in zip(this, base, strict=True)]


def median_bound(values: list[float], bounds: list[bool]) -> tuple[float, bool]:
    """(median, is a lower bound): values with bounds[i] True are lower bounds (inf: never). The
    median is a bound when a bound lies at or below its upper middle value (with an even count
    both middle values enter the median)."""
    med = statistics.median(values)
    upper = sorted(values)[len(values) // 2]
    return med, any(b and v <= upper for v, b in zip(values, bounds, strict=True))
