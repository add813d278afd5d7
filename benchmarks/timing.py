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


def spread(values, scale: float = 1.0, digits: int = 3, unit: str = "") -> str:
    """``median [min–max]`` of ``values`` × ``scale`` with ``digits`` decimals, then ``unit``: how
    every benchmark prints a figure over its repeats."""
    v = sorted(scale * float(x) for x in values)
    text = f"{statistics.median(v):.{digits}f} [{v[0]:.{digits}f}–{v[-1]:.{digits}f}]"
    return f"{text} {unit}" if unit else text


def time_spread(times) -> str:
    """:func:`spread` of times in seconds, in s from one second up, else in ms."""
    median = statistics.median(times)
    if median >= 1.0:
        return spread(times, 1.0, 3, "s")
    return spread(times, 1e3, 1 if median >= 0.01 else 2, "ms")


def print_table(head, rows) -> None:
    """Rows of cells as left-aligned columns under ``head`` and a rule."""
    widths = [max(len(str(c)) for c in col) for col in zip(head, *rows)]
    print("  ".join(str(h).ljust(w) for h, w in zip(head, widths)))
    print("  ".join("-" * w for w in widths))
    for row in rows:
        print("  ".join(str(c).ljust(w) for c, w in zip(row, widths)))
