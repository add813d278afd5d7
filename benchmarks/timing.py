"""Timing helpers shared by the benchmark scripts (run as ``python benchmarks/bench_X.py``, so
this folder is on ``sys.path``)."""

from __future__ import annotations

import statistics
import time


def time_repeats(fn, repeats: int):
    """Run ``fn`` ``repeats`` times; return (median seconds, every time in seconds, last result)."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times, result


def timed(fn, repeats: int):
    """(median seconds, last result) of ``repeats`` runs of ``fn``."""
    median, _, result = time_repeats(fn, repeats)
    return median, result
