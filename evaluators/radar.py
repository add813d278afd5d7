"""Metrics of the TWS radar trackers: RMSE of position and velocity, NPE, gain behaviour.

Scopes in the summary:

``overall``                    every run and every filtered scan;
``cross_range_above_nominal``  scans whose true cross-range error std r·σ_θ exceeds the design
                               value the fixed gains assume (where adaptive gains should help);
``cross_range_below_nominal``  the other filtered scans.

Scans before a track is filtered (the two start-up plots) are left out everywhere.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.evaluators.confidence import group_totals
from trackreplay.evaluators.tracking_metrics import long_form, nanmean, npe_from_sums, root, squared_error
from trackreplay import vocabulary as vocab

SCOPES = ("overall", "cross_range_above_nominal", "cross_range_below_nominal")


def filtered_mask(flags: np.ndarray) -> np.ndarray:
    """Scans that carry a filtered estimate (track started and updated or coasted)."""
    return (flags & (vocab.NO_TRACK | vocab.INITIALISING)) == 0


def evaluate(times, tracks: dict, measured_xy, truth_state=None, cross_range_std=None,
             nominal_cross_range_m: float | None = None, pcrb_position_var=None, groups: int | None = None,
             left_out: bool = False, records: bool = False):
    """Per-scan and summary tables.

    Parameters
    ----------
    times : ndarray (scans,)
    tracks : dict
        ``tracker -> outputs`` in the output vocabulary (``state``, ``flags``; the paper's ``alpha``,
        ``beta``, ``lambda_cross`` and the converted-plot ``innovation`` with ``measurement`` where a
        tracker has them; ``docs/contract.md``).
    measured_xy : ndarray (runs, scans, 2)
        Converted plot per scan (NaN when missed), for NPE; a tracker's own ``measurement``
        (the plot it used, which differs when a scan holds several) takes precedence.
    truth_state : ndarray (runs, scans, 4), optional
        Without truth only innovation statistics are reported.
    cross_range_std : ndarray (runs, scans), optional
        True r·σ_θ per scan, for the above/below-nominal scopes.
    pcrb_position_var : ndarray (scans,), optional
        Trace of the position block of the posterior Cramér–Rao bound per scan (Tichavský,
        Muravchik & Nehorai 1998): reported as ``pcrb_position_m`` and, over the filtered
        scans, as ``position_efficiency`` = bound RMS / RMSE (≤ 1 up to Monte Carlo error, higher
        is better: the efficiency of every family, ``docs/evaluation.md``).
    groups : int, optional
        Also return the summary of each of ``groups`` round-robin groups of runs
        (:func:`trackreplay.evaluators.confidence.run_groups`), as this function would give it on the
        group's runs alone, or with ``left_out`` on all runs but the group's
        (``score_groups`` of :func:`trackreplay.evaluators.confidence.summary_intervals`).
    left_out : bool
    records : bool
        Give each group's summary as records ``(tracker, metric, scope, value)`` (the rows of its
        table, which :func:`trackreplay.evaluators.confidence.summary_intervals` reads alike)
        instead of a table: the G tables cost more to make than their values.

    Returns
    -------
    per_scan : polars.DataFrame
        One row per tracker × scan.
    summary : polars.DataFrame
        Long form: ``tracker, metric, scope, value``.
    group_summaries : list of polars.DataFrame
        Only with ``groups``: one summary per group.

    Notes
    -----
    Every summary value is a function of per-scan sums over runs (of squared errors, their
    counts, flags), so the sums are taken once per group of runs (one pass over the outputs)
    and the all-runs and group values are read from them alike: the groups cost no
    re-scoring.
    """
    K = len(times)
    G = groups or 1
    # per-scan sums over the runs of each group (G, K), taken once: a selection of runs (all of
    # them, a group, all but a group) reads its values from them (:func:`_selection`)
    sums_of = lambda a: group_totals(a, G)  # noqa: E731
    cross = None
    if cross_range_std is not None and nominal_cross_range_m is not None:
        cross = _masked_sums(cross_range_std, True, sums_of)
    # each tracker's sums a block of runs at a time (_tracker_sums_in_blocks): the sums of
    # _tracker_sums to the bit, without its (runs, scans) arrays of errors and masks
    stats = {name: _tracker_sums_in_blocks(out, measured_xy, truth_state, G) for name, out in tracks.items()}
    rows_of = lambda pick: _summary_rows(stats, pick, cross, nominal_cross_range_m,  # noqa: E731
                                         pcrb_position_var, truth_state is not None)
    per_scan = pl.concat([_per_scan(name, out, stats[name], times, pcrb_position_var)
                          for name, out in tracks.items()], how="diagonal")
    summary = rows_of(_selection())
    if groups is None:
        return per_scan, summary
    if records:
        return per_scan, summary, [_records(_summary_rows(stats, _selection(g, left_out), cross, nominal_cross_range_m,
                                                         pcrb_position_var, truth_state is not None, table=False))
                                   for g in range(G)]
    return per_scan, summary, [rows_of(_selection(g, left_out)) for g in range(G)]


def _tracker_sums(out: dict, measured_xy, truth_state, sums_of) -> dict:
    """A tracker's per-scan sums over the runs of each group, ``sums_of(values)`` (G, K): of its
    filtered, clamped and coasted scans, of its squared innovations, position and velocity
    errors where filtered and finite (with their counts), and the NPE's sums over the runs
    where both the estimate and the plot exist."""
    flags = out["flags"]
    ok = filtered_mask(flags)
    clamped = (flags & vocab.CLAMPED) > 0
    sums = {"ok": sums_of(ok), "clamped": sums_of(clamped), "coasted": sums_of((flags & vocab.COASTED) > 0)}
    if "innovation" in out and "measurement" in out:
        # innovation of the converted plot (x, y) in metres: trackers that report the plot they used
        sums["innovation"] = _masked_sums(squared_error(out["innovation"], 0.0), ok, sums_of, own=True)[0]
    if truth_state is not None:
        # squared errors once per tracker; every RMSE is a ratio of sums of these
        se_pos = squared_error(out["state"][..., :2], truth_state[..., :2])
        # (se_pos is zeroed where not valid: the NPE's sums below keep a subset of the valid scans)
        sums["position"], valid_pos = _masked_sums(se_pos, ok, sums_of, own=True)
        sums["velocity"] = _masked_sums(squared_error(out["state"][..., 2:], truth_state[..., 2:]), ok, sums_of,
                                        own=True)[0]
        sm = squared_error(out.get("measurement", measured_xy), truth_state[..., :2])
        # NPE compares like with like: the runs where both the estimate and the plot exist
        both = valid_pos & np.isfinite(sm)
        np.logical_not(both, out=valid_pos)                   # (valid_pos is not needed again)
        np.copyto(se_pos, 0.0, where=valid_pos)
        np.copyto(sm, 0.0, where=valid_pos)
        sums["npe"] = (sums_of(se_pos), sums_of(sm), sums_of(both))
    return sums


def _tracker_sums_in_blocks(out: dict, measured_xy, truth_state, groups: int, block: int | None = None) -> dict:
    """:func:`_tracker_sums` with ``sums_of`` the group totals, a block of runs at a time: each
    block's errors and masks are made as there (element by element) and its rows added onto
    the totals so far in the order of the runs (:class:`_GroupTotals`), so the sums are the
    same to the bit (tests/test_evaluation_speed_paths.py) while no (runs, scans) array is
    held; a block stays in cache from one step to the next."""
    flags = out["flags"]
    R, K = flags.shape[:2]
    G = groups
    rows = G * max(1, (block or SUMS_BLOCK) // max(1, G * int(np.prod(flags.shape[1:], dtype=np.int64))))
    whole = R // G * G
    # blocks of whole groups of runs, then the runs left over (added last, as group_totals adds them)
    bounds = [(a, min(a + rows, whole)) for a in range(0, whole, rows)] + ([(whole, R)] if whole < R else [])
    measurement = out.get("measurement", measured_xy)
    keys = ["ok", "clamped", "coasted"]
    have_innovation = "innovation" in out and "measurement" in out
    if have_innovation:
        keys += ["innovation", "innovation_n"]
    if truth_state is not None:
        keys += ["position", "position_n", "velocity", "velocity_n", "npe_e", "npe_m", "npe_n"]
    totals = {key: _GroupTotals(G, R) for key in keys}
    for a, b in bounds:
        runs = slice(a, b)
        f = flags[runs]
        ok = filtered_mask(f)
        part = {"ok": ok, "clamped": (f & vocab.CLAMPED) > 0, "coasted": (f & vocab.COASTED) > 0}
        if have_innovation:
            se = squared_error(out["innovation"][runs], 0.0)
            part["innovation"], part["innovation_n"] = _zero_invalid(se, ok)
        if truth_state is not None:
            truth = truth_state[runs]
            se_pos = squared_error(out["state"][runs, ..., :2], truth[..., :2])
            part["position"], valid_pos = _zero_invalid(se_pos, ok)
            part["position_n"] = valid_pos.copy()
            part["velocity"], part["velocity_n"] = _zero_invalid(
                squared_error(out["state"][runs, ..., 2:], truth[..., 2:]), ok)
            # the block's position errors are added to the position sums before the NPE's
            # zeroes: the totals copy what they add
            totals["position"].add(se_pos)
            del part["position"]
            sm = squared_error(measurement[runs], truth[..., :2])
            both = valid_pos & np.isfinite(sm)
            np.logical_not(both, out=valid_pos)
            np.copyto(se_pos, 0.0, where=valid_pos)
            np.copyto(sm, 0.0, where=valid_pos)
            part["npe_e"], part["npe_m"], part["npe_n"] = se_pos, sm, both
        for key, values in part.items():
            totals[key].add(values)
    t = {key: acc.total for key, acc in totals.items()}
    sums = {key: t[key] for key in ("ok", "clamped", "coasted")}
    if have_innovation:
        sums["innovation"] = (t["innovation"], t["innovation_n"])
    if truth_state is not None:
        sums["position"] = (t["position"], t["position_n"])
        sums["velocity"] = (t["velocity"], t["velocity_n"])
        sums["npe"] = (t["npe_e"], t["npe_m"], t["npe_n"])
    return sums


#: values of a block of runs of :func:`_tracker_sums_in_blocks`
SUMS_BLOCK = 1 << 14


def _zero_invalid(values, keep):
    """``values`` zeroed in place where not finite or not ``keep``, and the mask of those kept
    (:func:`_masked_sums` with ``own``, before the sums)."""
    valid = np.isfinite(values)
    valid &= keep
    np.copyto(values, 0.0, where=~valid)
    return values, valid


class _GroupTotals:
    """:func:`trackreplay.evaluators.confidence.group_totals` of (R, ...) values given a block of
    runs at a time, in the order of the runs: blocks of whole groups of runs (a multiple of G
    rows), then the runs left over as the last block.

    numpy adds the (whole, G, ...) rows over their first axis one after another; each block's
    rows are added onto the totals so far in the same way (the totals as the block's first
    row), and the runs left over are added at the end, as group_totals adds them: the same
    additions in the same order, so the same sums.
    """

    def __init__(self, groups: int, runs: int):
        self.G, self.whole = groups, runs // groups * groups
        self.total, self.seen = None, 0

    def add(self, block) -> None:
        n = block.shape[0]
        if self.seen < self.whole:
            grouped = block.reshape((n // self.G, self.G) + block.shape[1:])
            if self.total is None:
                self.total = np.add.reduce(grouped, axis=0, dtype=float)
            else:
                rows = np.empty((grouped.shape[0] + 1,) + grouped.shape[1:])
                rows[0] = self.total
                rows[1:] = grouped
                self.total = np.add.reduce(rows, axis=0)
        else:
            if self.total is None:                      # fewer runs than groups
                self.total = np.zeros((self.G,) + block.shape[1:])
            self.total[:n] += block
        self.seen += n


def _selection(group: int | None = None, left_out: bool = False):
    """Per-scan sums over a selection of runs from the sums of every group (G, K): all runs
    (``group`` None), the group's runs, or with ``left_out`` all runs but the group's."""
    if group is None:
        return lambda sums: sums.sum(axis=0)
    if left_out:
        return lambda sums: sums.sum(axis=0) - sums[group]
    return lambda sums: sums[group]


def _masked_sums(values, keep, sums_of, own: bool = False):
    """Sums of the finite ``values`` (runs, scans) where ``keep``, and their counts; with
    ``own`` (``values`` a temporary of the caller's) the values left out are zeroed in place
    instead of in a copy, and the mask of the values kept is returned beside the sums."""
    valid = np.isfinite(values)
    valid &= keep
    if not own:
        return sums_of(np.where(valid, values, 0.0)), sums_of(valid)
    np.copyto(values, 0.0, where=~valid)
    return (sums_of(values), sums_of(valid)), valid


def _ratio(total, count):
    """``total / count``, NaN where nothing is counted (an average over no run)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / count


def _per_scan(name: str, out: dict, sums: dict, times, pcrb_position_var) -> pl.DataFrame:
    """One tracker's per-scan table on all runs."""
    every = _selection()
    cols = {"tracker": [name] * len(times), "scan": np.arange(len(times)), "time_s": times}
    # the paper's gain diagnostics, where a tracker has them (the α-β strategies and the Kalman reference)
    for key in ("alpha", "beta"):
        if key in out:
            cols[f"{key}_along"] = _nanmean0(out[key][..., 0])
            cols[f"{key}_cross"] = _nanmean0(out[key][..., 1])
    if "lambda_cross" in out:
        cols["lambda_cross"] = _nanmean0(out["lambda_cross"])
    cols["clamped_fraction"] = every(sums["clamped"]) / len(out["flags"])
    if "innovation" in sums:
        cols["rms_innovation_m"] = root(_ratio(*map(every, sums["innovation"])))
    if "position" in sums:
        cols["rmse_position_m"] = root(_ratio(*map(every, sums["position"])))
        cols["rmse_velocity_mps"] = root(_ratio(*map(every, sums["velocity"])))
        cols["npe"] = npe_from_sums(*map(every, sums["npe"]))
        if pcrb_position_var is not None:
            cols["pcrb_position_m"] = np.sqrt(pcrb_position_var)
    return pl.DataFrame(cols)


def _records(rows: list) -> list:
    """The rows of :func:`_summary_rows`'s table as records ``(tracker, metric, scope, value)``
    (a metric a row lacks has none; the order is the table's no more, which nothing reads)."""
    return [(row["tracker"], metric, row["scope"], value) for row in rows for metric, value in row.items()
            if metric not in ("tracker", "scope") and value is not None]


def _summary_rows(stats: dict, pick, cross, nominal_cross_range_m, pcrb_position_var, have_truth: bool,
                  table: bool = True):
    """The summary of every tracker over the runs that ``pick`` (:func:`_selection`) sums (its
    rows as dicts without ``table``)."""
    if cross is not None:
        above_scan = _ratio(*map(pick, cross)) > nominal_cross_range_m   # a scan no run covers: not above
    else:
        above_scan = np.zeros(next(iter(stats.values()))["ok"].shape[1], bool)
    rows = []
    for name, sums in stats.items():
        filtered = pick(sums["ok"]) > 0                                  # scans some run has filtered
        row = {"tracker": name, "scope": "overall", "clamped_scans": float(pick(sums["clamped"]).sum()),
               "coasted_scans": float(pick(sums["coasted"]).sum())}
        if "innovation" in sums:
            total, count = map(pick, sums["innovation"])
            row["rms_innovation_m"] = float(root(_ratio(total.sum(), count.sum()))) if filtered.any() else np.nan
        rows.append(row)
        if not have_truth:
            continue
        pos, vel = tuple(map(pick, sums["position"])), tuple(map(pick, sums["velocity"]))
        npe = npe_from_sums(*map(pick, sums["npe"]))
        row.update(rmse_position_m=float(root(_ratio(pos[0].sum(), pos[1].sum()))),
                   rmse_velocity_mps=float(root(_ratio(vel[0].sum(), vel[1].sum()))),
                   npe_max=float(np.nanmax(npe)), npe_mean=float(nanmean(npe)),
                   scans_npe_ge_1=float(np.sum(npe >= 1.0)))
        if pcrb_position_var is not None:
            bounded = filtered & np.isfinite(pcrb_position_var)
            bound = float(np.sqrt(np.mean(pcrb_position_var[bounded]))) if bounded.any() else np.nan
            row.update(pcrb_position_m=bound, position_efficiency=bound / row["rmse_position_m"])
        for scope, sel in (("cross_range_above_nominal", above_scan), ("cross_range_below_nominal", ~above_scan)):
            if not (sel & filtered).any():
                continue
            rows.append({"tracker": name, "scope": scope,
                         "rmse_position_m": float(root(_ratio(pos[0][sel].sum(), pos[1][sel].sum()))),
                         "rmse_velocity_mps": float(root(_ratio(vel[0][sel].sum(), vel[1][sel].sum()))),
                         "npe_mean": float(nanmean(npe[sel])), "scans": float(sel.sum())})
    if not table:
        return rows
    # one table for every tracker and scope: the metrics a row lacks are null and dropped, and
    # the metric order is that of first appearance, as the per-tracker tables had it
    summary = long_form(pl.DataFrame(rows, infer_schema_length=None), ["tracker", "scope"]).drop_nulls("value")
    return summary.select("tracker", "metric", "scope", "value")


def _nanmean0(a):
    return nanmean(a, axis=0)
