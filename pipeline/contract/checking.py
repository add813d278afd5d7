"""Checking what a file holds beyond its bytes: :func:`check_values` (the values table
:data:`trackreplay.vocabulary.VALUES`, scan times, duplicated frames, parallel lists) and the
rules every channel read meets (indices within the file's layout record and a sane maximum,
grids not mostly padding, scan times increasing, every scan held).

Each rule raises an :class:`~trackreplay.errors.InputError` naming the channel and the first
offending run and scan (docs/contract.md, "Reading").
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.contract.dataset import ChannelData
from trackreplay.contract.layout import FIXED, IRREGULAR, MAX_INDEX, MAX_SPARSITY, METADATA_LAYOUT, RAGGED, _BadData
from trackreplay.errors import InputError


def _check_indices(runs_max: int, scan: int, topic: str, layout: dict | None) -> None:
    if runs_max >= MAX_INDEX or scan >= MAX_INDEX:
        raise _BadData(f"a frame on {topic} claims run {runs_max} scan {scan}; this reader accepts indices "
                       f"below {MAX_INDEX}")
    if layout is not None and topic in layout:
        runs, scans = layout[topic]["runs"], layout[topic]["scans"]
        if runs_max >= runs or scan >= scans:
            raise _BadData(f"a frame on {topic} claims run {runs_max} scan {scan}, but the file's "
                           f"{METADATA_LAYOUT} record declares {runs} run(s) × {scans} scan(s)")


def _check_time_order(ch: ChannelData) -> None:
    """Refuse scan times that do not increase from scan to scan (a tracker's time step would be
    zero or negative; the table importers refuse the same). Scans a channel does not hold are
    skipped."""
    t = ch.times()
    t = t[np.isfinite(t)]
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0])
        raise InputError(f"{ch.topic}: scan times must increase, but a scan at {t[k + 1]:g} s follows one at "
                         f"{t[k]:g} s", ch.path)


def _check_scans_held(ch: ChannelData) -> None:
    """Refuse a measurement channel on which no frame holds some scan below its last: that scan's
    time is unknown, a filter cannot step over it, and no output could be written for it (such a
    file was accepted by ``eval`` and failed in ``replay``). A missing truth frame is the stage's
    to name; a file read with ``recover`` keeps the gaps its lost chunks leave."""
    if not any(ch.topic in family.inputs for family in vocab.FAMILIES.values()):
        return
    held = np.zeros(ch.n_scans, bool)
    held[ch._blocks.scan if ch._blocks is not None else ch._scan] = True  # per message where it can
    if not held.all():
        k = int(np.argmin(held))
        raise InputError(f"{ch.topic}: no frame holds scan {k} (the channel's scans run 0 … {ch.n_scans - 1}), so "
                         "its time is unknown; a scan without measurements is still a frame, with none", ch.path)


def _check_density(ch: ChannelData) -> None:
    """Refuse run/scan indices that would size a [run, scan] grid far beyond the frames present."""
    frames = ch.n_frames
    cells = ch.n_runs * ch.n_scans
    if cells > MAX_SPARSITY * max(frames, 1):
        raise InputError(f"{ch.topic}: its frames claim runs up to {ch.n_runs - 1} and scans up to {ch.n_scans - 1}, "
                         f"a {ch.n_runs} × {ch.n_scans} grid, but the channel holds {frames} frame(s); "
                         f"refusing a grid with more than {MAX_SPARSITY} cells per frame", ch.path)


def check_values(channels: Mapping[str, "ChannelData"], path=None) -> None:
    """Refuse input values outside the declared table :data:`trackreplay.vocabulary.VALUES`
    (wrong number kind, NaN/Inf, out of range) and scan times that are not finite, negative or
    beyond :data:`trackreplay.vocabulary.TIME_LIMIT_S` (times count from the recording's start, as
    every importer writes them: an MCAP log time is unsigned, so no output could carry a
    negative one).

    Raises
    ------
    InputError
        Naming the channel, the array and the first offending run and scan.
    """
    from trackreplay import vocabulary as vocab

    topic_key = {topic: key for key, topic in vocab.CHANNELS.items()}
    for topic, ch in channels.items():
        t = np.asarray(ch.time_s, float)
        bad = ~np.isfinite(t) | (np.abs(t) > vocab.TIME_LIMIT_S)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"{topic}: scan time {float(t[i])!r} s at run {ch.run[i]} scan {ch.scan[i]} is not a finite "
                             f"time within ±{vocab.TIME_LIMIT_S:g} s", path)
        if np.any(t < 0):
            i = int(np.argmax(t < 0))
            raise InputError(f"{topic}: scan time {t[i]:g} s at run {ch.run[i]} scan {ch.scan[i]} is negative; scan "
                             "times count from the recording's start (MCAP log times cannot be negative)", path)
        if ch.n_frames and not ch._scan_major():  # (every run and scan once: nothing to look for)
            # one frame per run and scan: a second one would silently replace or shadow the first
            key = ch.run.astype(np.int64) * (int(ch.scan.max()) + 1) + ch.scan.astype(np.int64)
            order = np.argsort(key, kind="stable")
            same = np.flatnonzero(np.diff(key[order]) == 0)
            if same.size:
                i = order[same[0] + 1]
                raise InputError(f"{topic} holds {same.size} duplicated frame(s), the first at run {ch.run[i]} "
                                 f"scan {ch.scan[i]}", path)
        parallel = [n for n in vocab.PARALLEL.get(topic_key.get(topic), ()) if n in ch.arrays]
        if len(parallel) > 1:
            lengths = [_item_counts(ch, n) for n in parallel]
            for name, length in zip(parallel[1:], lengths[1:]):
                bad = np.flatnonzero(length != lengths[0])
                if bad.size:
                    i = bad[0]
                    raise InputError(f"{topic}: {parallel[0]} and {name} list different numbers of items at run "
                                     f"{ch.run[i]} scan {ch.scan[i]} ({lengths[0][i]} vs {length[i]})", path)
        specs = vocab.VALUES.get(topic_key.get(topic), {})
        for name, spec in specs.items():
            if name not in ch.arrays:
                continue
            column = ch._column(name)
            # in bulk where the file stores the array as one block (v2); frame by frame otherwise,
            # and always frame by frame to name the first offending frame
            if column is not None and column.kind != IRREGULAR:
                block = column.values
            else:  # frames decoded one by one (v1, irregular): check them joined, in one pass
                items = ch.array(name)
                kinds = {np.asarray(a).dtype.kind for a in items}
                block = (np.concatenate([np.ravel(a) for a in items]) if len(kinds) == 1 and items
                         else None)
            if block is not None and _values_problem(block, spec) is None:
                continue
            for i, a in enumerate(ch.array(name)):
                problem = _values_problem(np.asarray(a), spec)
                if problem is not None:
                    raise InputError(f"{topic} {name} {problem} at run {ch.run[i]} scan {ch.scan[i]}", path)


def _item_counts(ch: "ChannelData", name: str) -> np.ndarray:
    """Items (length of the first axis) of array ``name`` in each frame, in bulk where the file
    stores it as one block."""
    column = ch._column(name)
    if column is not None and column.frames is None:
        if column.kind == RAGGED:
            return column.lengths()
        if column.kind == FIXED:
            return np.full(column.count, column.values.shape[1] if column.values.ndim > 1 else 1)
    return np.array([np.shape(a)[0] if np.ndim(a) else 1 for a in ch.array(name)])


#: Values per block of :func:`_values_problem`: its temporaries (a complex array's magnitudes)
#: stay a few MB however large the column.
VALUES_CHECK_BLOCK = 1 << 19


def _values_problem(a: np.ndarray, spec) -> str | None:
    """What is wrong with the values ``a`` under ``spec`` (see :func:`check_values`), or None."""
    if a.size == 0:
        return None
    if a.dtype.kind not in spec.kinds:
        return f"holds {a.dtype} values (expected {'/'.join(_KIND_NAMES[k] for k in spec.kinds)})"
    flat = a.reshape(-1)
    blocks = [flat[i:i + VALUES_CHECK_BLOCK] for i in range(0, flat.size, VALUES_CHECK_BLOCK)]
    if spec.finite and not all(np.isfinite(b).all() for b in blocks):
        return f"holds {sum(int(np.count_nonzero(~np.isfinite(b))) for b in blocks)} NaN/Inf value(s)"
    low = high = 0
    with np.errstate(invalid="ignore"):
        for b in blocks:
            magnitude = np.abs(b) if a.dtype.kind == "c" else b
            if spec.low is not None and a.dtype.kind != "c":
                low += int(np.count_nonzero(magnitude < spec.low))
            if spec.high is not None:
                high += int(np.count_nonzero(magnitude > spec.high))
    if low:
        return f"holds {low} negative value(s)" if spec.low == 0 else f"holds {low} value(s) below {spec.low:g}"
    if high:
        return f"holds {high} value(s) above {spec.high:g}"
    return None


_KIND_NAMES = {"f": "float", "i": "integer", "u": "unsigned integer", "c": "complex", "b": "boolean"}


def _check_frame_time(topic: str, run: int, scan: int, t: float, path: Path) -> None:
    """The scan-time rule of :func:`check_values` for one frame read by :func:`iter_frames` (whose
    frames are written again, and an MCAP log time cannot hold a negative or non-finite time)."""
    from trackreplay.vocabulary import TIME_LIMIT_S

    if not (math.isfinite(t) and 0 <= t <= TIME_LIMIT_S):
        raise InputError(f"{topic}: scan time {t:g} s at run {run} scan {scan} is not a time from the recording's "
                         f"start within 0 … {TIME_LIMIT_S:g} s", path)
