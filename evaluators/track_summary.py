"""The track summary: what the trackers did with the data, from their flags alone (no truth).

Reads only ``flags`` (R, K[, T]), ``track_id`` (R, K, T), ``innovation`` and
``innovation_covariance`` of the output vocabulary (``docs/contract.md``), so it applies to every
tracker of every family, with or without truth. Track life, read from the flags of one slot
(a family without a track axis has one slot per run):

* the slot holds a track at every scan whose flags lack ``NO_TRACK``;
* a track **starts** at the first scan the slot holds it: after a scan without a track, after a
  scan flagged ``DELETED``, or where ``track_id`` changes;
* it is **tentative** while flagged ``INITIALISING`` and **confirmed** from its first scan
  without it (a track never flagged ``INITIALISING`` is confirmed at its start);
* it is **deleted** at a scan flagged ``DELETED`` (its last scan, or the empty scan right after
  it); a track held at the last scan and not deleted there is **open**; a track that ends any
  other way (the slot empties or changes identity without ``DELETED``) ended **unflagged**;
* its **lifetime** runs from its first to its last scan held: ``last − first + 1`` scans and
  ``t_last − t_first`` seconds (an open track's is cut at the last scan).

The mean NIS over all N updates (scans with a track and a finite normalised innovation, coasted
scans left out: they used no measurement) of an m-dimensional innovation is, for a consistent
filter, χ²(N·m)/N, whose two-sided 95 % interval it is compared with (Bar-Shalom, Li &
Kirubarajan 2001, §5.4). See ``docs/evaluation.md``.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.evaluators.confidence import jackknife, mean_interval
from trackreplay.evaluators.consistency import average_bounds, whitened_innovations
from trackreplay.vocabulary import COASTED, DELETED, INITIALISING, NO_TRACK

#: the per-run counts, in the order they are reported, and the event of :func:`track_life` each counts
COUNTS = {"tracks_started": "start", "tracks_confirmed": "confirm", "tracks_deleted": "deleted",
          "tracks_open": "open", "tracks_ended_unflagged": "unflagged"}
#: every metric name the summary may report (the counts carry the suffix ``_per_run``)
METRICS = (*(f"{c}_per_run" for c in COUNTS), "scans_to_confirmation",
           "track_lifetime_scans", "track_lifetime_scans_iqr", "track_lifetime_s", "track_lifetime_s_iqr",
           "mean_nis", "mean_nis_low", "mean_nis_high", "mean_nis_inside", "nis_updates")
SCHEMA = {"tracker": pl.String, "metric": pl.String, "scope": pl.String, "value": pl.Float64,
          "se": pl.Float64, "ci_low": pl.Float64, "ci_high": pl.Float64}


def _slots(a):
    """(R, K) → (R, K, 1): a family without a track axis has one slot per run."""
    a = np.asarray(a)
    return a[:, :, None] if a.ndim == 2 else a


def _flag_bits(flags):
    """``flags`` (R, K, T) in an integer type the bits can be tested in: their own where they
    are integers (a copy of (R, K, T) as int64 would cost more than every test of a bit)."""
    f = _slots(flags)
    return f if f.dtype.kind in "iu" else f.astype(np.int64)


def _nonzero(mask):
    """``np.nonzero`` of an (R, K, T) mask, from its flat (C-order) indices: the same index
    arrays in the same order, without numpy's slow multi-index walk over a 3-d array."""
    flat = np.flatnonzero(mask)
    return np.unravel_index(flat, mask.shape)


def track_life(flags, track_id=None) -> dict:
    """Where tracks start, are confirmed and end, per run, scan and slot.

    Parameters
    ----------
    flags : ndarray (R, K[, T])
        Flag bits of the vocabulary.
    track_id : ndarray (R, K, T), optional
        Identity of the track in each slot; a change starts a new track.

    Returns
    -------
    dict
        Boolean arrays (R, K, T): ``held`` (the slot holds a track), ``start``, ``confirm`` (the
        track's first confirmed scan), ``last`` (the track's last scan held), ``deleted``,
        ``open`` and ``unflagged`` (at the last scan of tracks that ended that way); and
        ``first`` (R, K, T) int, the scan at which the track held at each scan started (−1
        where the slot is empty), in the smallest integer type that holds the scans.
    """
    f = _flag_bits(flags)
    R, K, T = f.shape
    held = (f & NO_TRACK) == 0
    deleted_flag = (f & DELETED) > 0
    # shifts by one scan are slices written into arrays made once (no concatenated copies)
    # a new track where the slot was empty, the previous track was deleted, or the identity changed
    fresh = np.empty((R, K, T), bool)
    fresh[:, 0] = True
    np.logical_or(~held[:, :-1], deleted_flag[:, :-1], out=fresh[:, 1:])
    if track_id is not None:
        ids = _slots(track_id)
        fresh[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    start = held & fresh
    after = fresh                                                  # (fresh is not needed again)
    np.logical_or(start[:, 1:], ~held[:, 1:], out=after[:, :-1])   # the next scan is not this track's
    after[:, -1] = True
    last = held & after
    # deleted at its last scan, or at the empty scan right after it (a tracker may flag the
    # deletion where the slot is already empty)
    next_deleted = np.empty((R, K, T), bool)
    np.logical_and(deleted_flag[:, 1:], ~held[:, 1:], out=next_deleted[:, :-1])
    next_deleted[:, -1] = False
    next_deleted |= deleted_flag
    deleted = last & next_deleted
    not_deleted = last & ~deleted
    # open: held at the last scan and not deleted there; unflagged: every other end
    open_ = np.zeros((R, K, T), bool)
    open_[:, -1] = not_deleted[:, -1]
    unflagged = not_deleted
    unflagged[:, -1] = False
    # scan numbers in the smallest integer type that holds them and −1 (the maxima are the same)
    index = np.int16 if K < 2**15 else np.int64
    scans = np.arange(K, dtype=index)[None, :, None]
    minus_one = index(-1)
    first = _running_max_over_scans(np.where(start, scans, minus_one))
    first[~held] = -1
    # confirmed at the first scan of the track without INITIALISING: the latest such scan
    # before this one must lie before the track's start
    confirmed_scan = held & ((f & INITIALISING) == 0)
    latest = _running_max_over_scans(np.where(confirmed_scan, scans, minus_one))
    confirm = np.empty((R, K, T), bool)
    confirm[:, 0] = True                                           # nothing before the first scan (−1 < first)
    np.less(latest[:, :-1], first[:, 1:], out=confirm[:, 1:])
    confirm &= confirmed_scan
    return {"held": held, "start": start, "confirm": confirm, "last": last, "deleted": deleted, "open": open_,
            "unflagged": unflagged, "first": first}


#: the fewest entries a scan's row (runs × slots) holds for :func:`_running_max_over_scans` to go
#: scan by scan: on one run × 100,000 scans the loop took 0.4 s where the accumulation takes 1 ms
SCAN_ROW_MIN = 256


def _running_max_over_scans(a):
    """``np.maximum.accumulate(a, axis=1)`` of integers (R, K, T), as a view of a scan-major
    copy: each scan's running maximum is then one operation over a contiguous row of every run
    and slot, where numpy's accumulation along the middle axis steps through the runs one by
    one (the same integers either way). A scan whose row is short (few runs and slots, as on one
    long recording) would cost a call for a few numbers: there numpy's accumulation is the fast one."""
    if a.shape[0] * a.shape[2] < SCAN_ROW_MIN:
        return np.maximum.accumulate(a, axis=1)
    rows = np.ascontiguousarray(a.transpose(1, 0, 2))
    for k in range(1, rows.shape[0]):
        np.maximum(rows[k - 1], rows[k], out=rows[k])
    return rows.transpose(1, 0, 2)


def mean_nis_bounds(nis, dim: int, prob: float = 0.95):
    """The mean of the finite NIS values and the two-sided ``prob`` interval of the mean of N
    independent χ²(``dim``) values, ``χ²(N·dim)/N``.

    Returns
    -------
    mean, low, high : float
        NaN where there is no finite value.
    count : int
        N.
    """
    v = np.asarray(nis, float)
    ok = np.isfinite(v)
    n = int(np.count_nonzero(ok))
    if n == 0:
        return np.nan, np.nan, np.nan, 0
    lo, hi = average_bounds(dim, n, prob)   # the ANIS bounds over one pooled count
    return float(v[ok].mean()), float(lo), float(hi), n


def _nis_of_updates(nis, dim: int, prob: float):
    """:func:`mean_nis_bounds` of the NIS (R, K, T) with its sums (``np.nansum``) and counts of
    finite values per run, the finite values found once and the NaNs zeroed in place (``nis``
    is the caller's temporary) for the sums: the same values (tests/test_track_summary.py)."""
    finite = np.isfinite(nis)
    n = int(np.count_nonzero(finite))
    per_run_n = np.sum(finite, axis=(1, 2))
    if n == 0:
        mean = low = high = np.nan
    else:
        lo, hi = average_bounds(dim, n, prob)
        mean, low, high = float(nis[finite].mean()), float(lo), float(hi)
    np.copyto(nis, 0.0, where=np.isnan(nis))               # as np.nansum's copy has them
    return mean, low, high, n, np.sum(nis, axis=(1, 2)), per_run_n


def _row(name: str, metric: str, value, se=np.nan, lo=np.nan, hi=np.nan) -> dict:
    finite = lambda v: float(v) if v is not None and np.isfinite(v) else None  # noqa: E731
    return {"tracker": name, "metric": metric, "scope": "overall", "value": finite(value), "se": finite(se),
            "ci_low": finite(lo), "ci_high": finite(hi)}


def _iqr(values):
    return float(np.subtract(*np.percentile(values, [75, 25]))) if len(values) else np.nan


def tracker_summary(name: str, times, out: dict, prob: float = 0.95, groups: int = 10,
                    innovations=None) -> list[dict]:
    """The track summary rows of one tracker's outputs (see :func:`track_summary`).

    Parameters
    ----------
    name : str
        The tracker, as its rows name it.
    times : ndarray (K,)
        Scan times, s.
    out : dict
        Its outputs in the vocabulary (``flags`` required).
    prob : float
        Level of every interval.
    groups : int
        Groups of runs of the jackknife.
    innovations : tuple, optional
        :func:`trackreplay.evaluators.consistency.whitened_innovations` of ``out``, when already computed.

    Returns
    -------
    list of dict
        Records ``tracker, metric, scope, value, se, ci_low, ci_high``.
    """
    times = np.asarray(times, float)
    life = track_life(out["flags"], out.get("track_id"))
    R, K, T = life["held"].shape
    rows = []
    for count, event in COUNTS.items():
        per_run = life[event].sum(axis=(1, 2)).astype(float)
        rows.append(_row(name, f"{count}_per_run", *mean_interval(per_run, prob=prob)))
    # one entry per track (at its last scan) and per confirmation, with its run for the jackknife
    r_end, k_end, s_end = _nonzero(life["last"])
    k_first = life["first"][r_end, k_end, s_end]
    scans = (k_end - k_first + 1).astype(float)
    seconds = times[k_end] - times[k_first]
    r_conf, k_conf, s_conf = _nonzero(life["confirm"])
    to_confirm = (k_conf - life["first"][r_conf, k_conf, s_conf]).astype(float)

    def over_runs(statistic, run_of, values):
        """``statistic`` of the entries of the runs given, with a grouped-jackknife interval
        over runs (the runs, not the tracks, are independent)."""
        if not len(values):
            return np.nan, np.nan, np.nan, np.nan

        def of_runs(idx):
            kept = np.zeros(R, bool)  # a mask over runs: one gather, not a set operation per group
            kept[idx] = True
            chosen = values[kept[run_of]]
            return statistic(chosen) if len(chosen) else np.nan

        return jackknife(of_runs, R, groups=groups, prob=prob)

    rows.append(_row(name, "scans_to_confirmation", *over_runs(np.mean, r_conf, to_confirm)))
    rows.append(_row(name, "track_lifetime_scans", *over_runs(np.median, r_end, scans)))
    rows.append(_row(name, "track_lifetime_scans_iqr", _iqr(scans)))
    rows.append(_row(name, "track_lifetime_s", *over_runs(np.median, r_end, seconds)))
    rows.append(_row(name, "track_lifetime_s_iqr", _iqr(seconds)))
    innovations = innovations if innovations is not None else whitened_innovations(out)
    if innovations is not None:
        w, nis = innovations                                              # (R, K, T, m), (R, K, T)
        m = w.shape[-1]
        flags = _flag_bits(out["flags"])
        # an update is a scan with a track that used a measurement
        nis = np.where(life["held"] & ((flags & COASTED) == 0), nis, np.nan)
        mean, low, high, n, per_run_sum, per_run_n = _nis_of_updates(nis, m, prob)
        _, se, lo, hi = jackknife(lambda idx: per_run_sum[idx].sum() / per_run_n[idx].sum()
                                  if per_run_n[idx].sum() else np.nan, R, groups=groups, prob=prob)
        rows.append(_row(name, "mean_nis", mean, se, lo, hi))
        rows.append(_row(name, "mean_nis_low", low))
        rows.append(_row(name, "mean_nis_high", high))
        rows.append(_row(name, "mean_nis_inside", float(low <= mean <= high) if n else np.nan))
        rows.append(_row(name, "nis_updates", float(n)))
    return rows


def track_summary(times, tracks: dict, prob: float = 0.95, innovations: dict | None = None) -> pl.DataFrame:
    """The track summary of every tracker: long form ``tracker, metric, scope, value, se,
    ci_low, ci_high`` (scope ``overall``).

    Parameters
    ----------
    times : ndarray (K,)
        Scan times, s.
    tracks : dict
        ``name -> outputs`` in the vocabulary; entries without ``state`` and ``flags`` (an
        estimator's side outputs) are left out.
    prob : float
        Level of every interval.
    innovations : dict, optional
        ``name ->`` :func:`trackreplay.evaluators.consistency.whitened_innovations`, when already computed.

    Returns
    -------
    polars.DataFrame
        Per tracker: ``tracks_started_per_run``, ``tracks_confirmed_per_run``,
        ``tracks_deleted_per_run``, ``tracks_open_per_run`` (alive at the last scan),
        ``tracks_ended_unflagged_per_run`` (means over runs, Student-t intervals);
        ``scans_to_confirmation`` (mean over confirmed tracks), ``track_lifetime_scans`` and
        ``track_lifetime_s`` (medians over tracks; grouped-jackknife intervals over runs) with
        their interquartile ranges ``*_iqr``; and, where the tracker gives its innovations,
        ``mean_nis`` over all updates with the χ² interval ``mean_nis_low``/``mean_nis_high``
        of a consistent filter, ``mean_nis_inside`` (1 or 0) and ``nis_updates`` (N).
    """
    rows = []
    for name, out in tracks.items():
        if "state" in out and "flags" in out:
            rows += tracker_summary(name, times, out, prob, innovations=(innovations or {}).get(name))
    return pl.DataFrame(rows, schema=SCHEMA) if rows else pl.DataFrame(schema=SCHEMA)
