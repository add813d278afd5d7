"""The standard evaluation measures, for every tracker of every family, from the output vocabulary.

Reads only ``state``, ``covariance``, ``track_id``, ``innovation`` and
``innovation_covariance`` (``docs/contract.md``) and the truth in the tracker's state space, so it
applies to any tracker, built in or plugged:

* filter consistency (:mod:`trackreplay.evaluators.consistency`): ANEES and ANIS per scan with their χ²
  bounds for the runs present, the fraction of scans inside, time averages with bounds, and the
  whiteness of the innovations;
* OSPA and GOSPA per scan with GOSPA's parts (:mod:`trackreplay.evaluators.set_distances`);
* assignment metrics over whole runs (:mod:`trackreplay.evaluators.assignment_metrics`);
* a 95 % interval over Monte Carlo runs on every number (:mod:`trackreplay.evaluators.confidence`).

With several targets, the NEES pairs each target with the track matched to it at that scan (the
same gated assignment the assignment metrics use); targets without a match add nothing.
See ``docs/evaluation.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import polars as pl

from trackreplay.evaluators import hota as hota_module, siap as siap_module
from trackreplay.evaluators.assignment_metrics import (_single_target_matches, _single_target_metrics, assignment_metrics,
                                           gated_pairs, scan_matches)
from trackreplay.evaluators.confidence import group_totals, jackknife, mean_interval, ratio_jackknife, rms_interval, run_groups
from trackreplay.evaluators.consistency import (_whiteness_of_whitened, consistency_summary, normalised_squared,
                                   whitened_innovations)
from trackreplay.evaluators.hota import SUM_KEYS as HOTA_SUMS, hota_sums, pooled_hota
from trackreplay.evaluators.set_distances import gospa_switching, one_identity_per_run, pairs_within
from trackreplay.evaluators.set_distances_shared import single_pair_view
from trackreplay.evaluators.set_distances_fast import _gospa_switching_single
from trackreplay.evaluators.siap import SUM_KEYS as SIAP_SUMS, pooled_siap, siap_sums
from trackreplay.evaluators.tracking_metrics import nanmean
from trackreplay.batched_linalg import all_finite, sum_squares
from trackreplay.vocabulary import DELETED, INITIALISING, NO_TRACK

# What a tracker reports is its confirmed tracks: a tentative track (INITIALISING) is a hypothesis
# under test, not yet an estimate a user would see, and scoring it would charge a multi-target
# tracker a false track for every clutter plot it starts from. NOT_ESTIMATED marks NaN
# components, which count as absent by themselves.
NOT_A_TRACK = NO_TRACK | DELETED | INITIALISING


@dataclass(frozen=True)
class EvaluationSpace:
    """How a family's states compare with its truth.

    Attributes
    ----------
    truth_components : tuple of int
        State components the truth gives (e.g. all four for radar, the bearing alone for array).
    position_components : tuple of int
        Components of the space OSPA/GOSPA and the assignment work in.
    angular : bool
        Position components are angles (differences wrap).
    cutoff : float
        OSPA/GOSPA cut-off c in the space's units.
    gate : float
        Largest distance of a track-to-truth match.
    order : float
        OSPA/GOSPA order p.
    unit : str
        Unit of the distances as reported (suffix of the metric names, e.g. ``m``, ``deg``).
    scale : float
        Factor from the space's SI units to ``unit`` (180/π for angles reported in degrees).
    hota_distance : float, optional
        HOTA's ``d₀``, where the point similarity reaches 0 (:mod:`trackreplay.evaluators.hota`); default
        ``cutoff``.
    gospa_switch_penalty : float, optional
        γ of the per-scan GOSPA switching term (:func:`trackreplay.evaluators.set_distances.gospa_switching`);
        default ``cutoff``.
    siap_gate : float, optional
        Largest distance of a SIAP track-to-target association (:mod:`trackreplay.evaluators.siap`); default
        ``gate``.
    velocity_components : tuple of int, optional
        Components holding the velocities of the positions (the SIAP velocity accuracy); None
        where the space has none.
    """

    truth_components: tuple
    position_components: tuple
    angular: bool
    cutoff: float
    gate: float
    order: float = 2.0
    unit: str = "m"
    scale: float = 1.0
    hota_distance: float | None = None
    gospa_switch_penalty: float | None = None
    siap_gate: float | None = None
    velocity_components: tuple | None = None


def _velocity_components(truth_components, position_components):
    """The velocity of each position component: the next component in a state laid out per axis
    ([p, v, a] per axis), else the block after the positions ([x, y, vx, vy]); None when the
    truth has neither."""
    truth, positions = tuple(truth_components), tuple(position_components)
    for velocities in (tuple(c + 1 for c in positions), tuple(c + len(positions) for c in positions)):
        if all(v in truth and v not in positions for v in velocities):
            return velocities
    return None


def position_space(design: dict, truth_components, position_components) -> EvaluationSpace:
    """A space of positions in metres, its cut-off, gate and order from the design values
    ``ospa_cutoff_m``, ``assignment_gate_m`` and ``ospa_order``."""
    return EvaluationSpace(truth_components=tuple(truth_components), position_components=tuple(position_components),
                           angular=False, cutoff=float(design["ospa_cutoff_m"]),
                           gate=float(design["assignment_gate_m"]), order=float(design["ospa_order"]),
                           hota_distance=_optional(design, "hota_distance_m"),
                           gospa_switch_penalty=_optional(design, "gospa_switch_penalty_m"),
                           siap_gate=_optional(design, "siap_gate_m"),
                           velocity_components=_velocity_components(truth_components, position_components))


def _optional(design: dict, key: str, scale: float = 1.0):
    """A design value that a family may leave out (None: the space's default)."""
    return None if design.get(key) is None else float(design[key]) * scale


def bearing_space(design: dict) -> EvaluationSpace:
    """The space of one wrapped angle (state component 0), reported in degrees, from the design
    values ``ospa_cutoff_deg``, ``assignment_gate_deg`` and ``ospa_order``."""
    return EvaluationSpace(truth_components=(0,), position_components=(0,), angular=True,
                           cutoff=float(np.deg2rad(design["ospa_cutoff_deg"])),
                           gate=float(np.deg2rad(design["assignment_gate_deg"])), order=float(design["ospa_order"]),
                           unit="deg", scale=float(np.rad2deg(1.0)),
                           hota_distance=_optional(design, "hota_distance_deg", np.deg2rad(1.0)),
                           gospa_switch_penalty=_optional(design, "gospa_switch_penalty_deg", np.deg2rad(1.0)),
                           siap_gate=_optional(design, "siap_gate_deg", np.deg2rad(1.0)))

def _as_slots(a, extra_dims: int):
    """(R, K, n...) → (R, K, 1, n...) for single-track families; slot families pass through.
    ``extra_dims`` counts the per-track dimensions (1 for a state vector, 0 for flags)."""
    a = np.asarray(a)
    a = a if a.dtype.kind in "iu" else np.asarray(a, float)
    return a if a.ndim == 3 + extra_dims else a[:, :, None]


def as_slots_with_ids(out: dict, absent_flags: int, position_components):
    """A tracker's reported positions ``(R, K, S, d)`` (NaN where a slot reports no track: its
    flags carry one of ``absent_flags``) and track identities ``(R, K, S)`` (−1 there), from
    ``track_id`` or, without it, the slot index."""
    state = _as_slots(out["state"], 1)
    absent = (_as_slots(out["flags"], 0).astype(np.int64) & absent_flags) > 0
    positions = np.where(absent[..., None], np.nan, _components(state, list(position_components)))
    if "track_id" in out:
        ids = _as_slots(np.asarray(out["track_id"])[..., None], 1)[..., 0].astype(np.int64)
    else:
        ids = np.broadcast_to(np.arange(state.shape[2]), state.shape[:3])
    absent |= ~np.isfinite(positions).all(axis=-1)
    return positions, np.where(absent, -1, ids)


def _any_flag(flags, bits: int):
    """Where ``flags`` carry any of ``bits``, tested in the flags' own integer type where it
    holds the bits (the bits of an integer are the same in a wider one: an int64 copy of a
    tracker's flags, 5 MB at 10,000 radar runs, would change no answer)."""
    if flags.dtype.kind in "iu" and bits <= np.iinfo(flags.dtype).max:
        return (flags & flags.dtype.type(bits)) > 0
    return (flags.astype(np.int64) & bits) > 0


def _with_ci(name: str, metric: str, value, se, lo, hi, scope: str = "overall") -> dict:
    """A summary record; an interval that does not exist (a bound, a count with no spread over
    runs) is null rather than NaN, so that it reads as absent."""
    finite = lambda v: float(v) if np.isfinite(v) else None
    return {"tracker": name, "metric": metric, "scope": scope, "value": finite(value), "se": finite(se),
            "ci_low": finite(lo), "ci_high": finite(hi)}


def _components(a, which):
    """``a[..., which]``: a view when ``which`` is a run of consecutive components (the usual
    case, e.g. positions 0 and 1), a copy otherwise."""
    which = list(which)
    if which and which == list(range(which[0], which[0] + len(which))):
        return a[..., which[0]:which[0] + len(which)]
    return a[..., which]


def _slot_mean(a):
    """Mean over the slot axis 2 of (R, K, S), NaN left out; with one slot, that slot (the same
    values, without a copy)."""
    return a[:, :, 0] if a.shape[2] == 1 else nanmean(a, axis=2)


def _time_average(per_run_scan, groups: int = 10):
    """The mean of the finite values of (R, K) over every run and scan, with its grouped
    jackknife interval over runs, from per-run sums and counts."""
    finite = np.isfinite(per_run_scan)
    return ratio_jackknife(np.sum(per_run_scan, axis=1, where=finite), np.sum(finite, axis=1), groups)


#: the set distances (:func:`trackreplay.evaluators.set_distances.gospa_switching`) averaged over
#: runs per scan, and those averaged over scans per run, for the per-scan table and the summary
SCAN_MEAN_KEYS = ("ospa", "gospa", "localisation", "missed", "false", "gospa_switching", "half_switches")
RUN_MEAN_KEYS = ("ospa", "gospa", "gospa_switching")


class _ScanMeans:
    """``nanmean(values, axis=0)`` of an (R, K) array given a block of runs at a time, in the
    order of the runs (the values as floats, as ``values.astype(float)``).

    numpy adds an (R, K) array over its first axis run after run; here each block is added
    onto the total so far in the same way (the total as the block's first row), so the sums,
    the counts and their ratios are those of :func:`trackreplay.evaluators.tracking_metrics.nanmean`
    over the whole array, to the bit (tests/test_evaluation_speed_paths.py), without it ever
    being held.
    """

    def __init__(self):
        self.total = self.count = None

    def add(self, block) -> None:
        block = np.asarray(block)
        R = block.shape[0]
        # the total so far above the block's runs, the values written once as floats (in place
        # of a converted copy and then a joined one); made per block, not kept: a buffer held
        # across blocks leaves the other temporaries fresh pages to fault in
        rows = np.empty((R + 1,) + block.shape[1:])
        values = rows[1:]
        values[...] = block
        if block.dtype.kind == "f":
            missing = np.isnan(values)
            count = R - np.sum(missing, axis=0, dtype=np.intp)
            if missing.any():
                np.copyto(values, 0.0, where=missing)        # as np.nanmean leaves them out
        else:
            count = np.full(block.shape[1:], R, np.intp)      # counts and flags are never NaN
        if self.total is None:
            self.total, self.count = np.add.reduce(values, axis=0), count
        else:
            rows[0] = self.total
            self.total = np.add.reduce(rows, axis=0)
            self.count = self.count + count

    def mean(self):
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.total / self.count


def _small_slots(match, slots: int):
    """Slot indices of the matches (−1 none) in the smallest integer type that holds them: the
    NEES reads them after every block is joined (5 MB as int64 at 10,000 radar runs)."""
    return match.astype(np.int8 if slots < 128 else np.int32 if slots < 2**31 else np.int64)


#: values of the largest (R, K, S, T) intermediate of the set distances per block of runs
SET_BLOCK = 1 << 17


def _in_run_blocks(function, n_runs: int, per_run: int):
    """``function(slice of runs)`` over blocks of runs, its per-run results (arrays with a
    leading run axis, in dicts and tuples as ``function`` gives them) joined along the run
    axis: the assignment's temporaries, a few copies of the sets each, then stay a few MB at
    any number of runs."""
    step = max(1, SET_BLOCK // max(per_run, 1))
    first = function(slice(0, step))
    if step >= n_runs:
        return first
    # each block is written into arrays allocated once: joining a list of blocks would hold the
    # results twice at its end (75 MB at 10,000 radar runs)
    joined = _allocate_runs(first, n_runs)
    _put_runs(joined, first, slice(0, step))
    for start in range(step, n_runs, step):
        _put_runs(joined, function(slice(start, start + step)), slice(start, start + step))
    return joined


def _allocate_runs(part, n_runs: int):
    """Empty arrays shaped like ``part``'s (in dicts and tuples) with ``n_runs`` on the run axis."""
    if isinstance(part, dict):
        return {k: _allocate_runs(v, n_runs) for k, v in part.items()}
    if isinstance(part, tuple):
        return tuple(_allocate_runs(v, n_runs) for v in part)
    return np.empty((n_runs,) + part.shape[1:], part.dtype)


def _put_runs(joined, part, runs: slice) -> None:
    """Write the block ``part`` into ``joined`` at ``runs``."""
    if isinstance(part, dict):
        for k, v in part.items():
            _put_runs(joined[k], v, runs)
    elif isinstance(part, tuple):
        for j, v in zip(joined, part):
            _put_runs(j, v, runs)
    else:
        joined[runs] = part


#: values of the estimation errors :func:`_matched_nees` holds at once
NEES_BLOCK = 1 << 18


def _matched_nees(estimate, truth, covariance, match, pos, angular: bool):
    """The NEES (R, K, T) of the matched estimates (NaN where a target has no match) and their
    squared position errors, a few scans at a time: the errors ``estimate − truth`` (wrapped
    for angles, NaN where unmatched) are never held whole (20 MB at 10,000 radar runs), and
    every value is computed as on the whole array (element by element)."""
    shape = np.broadcast_shapes(estimate.shape, truth.shape)
    R, K = shape[:2]
    nees, sq = np.empty(shape[:-1]), np.empty(shape[:-1])
    step = max(1, NEES_BLOCK // max(R * int(np.prod(shape[2:], dtype=np.int64)), 1))   # scans a block
    # one buffer for every block's errors, laid out as the estimates are (a tracker's buffer holds
    # the runs fastest, as its covariances do: the whitening then reads both along the runs)
    first = estimate[:, :step]
    block_shape = (R, first.shape[1]) + shape[2:]
    buffer = np.empty_like(first) if first.shape == block_shape else np.empty(block_shape)
    for start in range(0, K, step):
        scans = slice(start, start + step)
        err = np.subtract(estimate[:, scans], truth[:, scans], out=buffer[:, :min(step, K - start)])
        if angular:
            err[..., pos] = (err[..., pos] + np.pi) % (2 * np.pi) - np.pi
        err[match[:, scans] < 0] = np.nan                       # in place: no second copy of the errors
        nees[:, scans] = normalised_squared(err, covariance[:, scans])
        sq[:, scans] = sum_squares(_components(err, pos))       # NaN where unmatched, as err is
    return nees, sq


def _pooled_jackknife(pooled, sums: dict, keys, n_runs: int, groups: int = 10):
    """:func:`trackreplay.evaluators.confidence.jackknife` of ``pooled(sums, runs)`` (a measure formed from
    per-run sums added over ``runs``: HOTA, SIAP) from the totals of each group of runs
    (:func:`trackreplay.evaluators.confidence.group_totals`): a group left out is all groups but one, so
    the G + 1 poolings add G totals instead of nearly every run G + 1 times. The same
    estimates up to the order of the additions."""
    G = len(run_groups(n_runs, groups))
    if G < 2:
        return jackknife(lambda runs: pooled(sums, runs), n_runs, groups)
    totals = {key: group_totals(np.asarray(sums[key]), G) for key in keys}
    # each group a pseudo-run: leaving one out is the jackknife's group left out
    return jackknife(lambda parts: pooled(totals, parts), G, G)


def truth_one_identity_per_run(truth, space: EvaluationSpace, truth_ids=None) -> bool:
    """Whether every run's truth is one target in one slot with one identity wherever its
    positions are finite (:func:`trackreplay.evaluators.set_distances.one_identity_per_run`):
    the truth's half of the single-target case of :func:`evaluate_standard`, the same for every
    tracker scored against it (a replay finds it once, ``truth_single``)."""
    tr = _as_slots(truth, 1)
    if tr.shape[2] != 1:
        return False
    comps = list(space.truth_components)
    true_positions = _components(tr, [comps.index(c) for c in space.position_components])
    slot_ids = None if truth_ids is None else _as_slots(np.asarray(truth_ids)[..., None], 1)[..., 0]
    return one_identity_per_run(slot_ids, all_finite(true_positions))


def evaluate_standard(times, tracks: dict, truth, space: EvaluationSpace, prob: float = 0.95,
                      innovations: dict | None = None, truth_ids=None, truth_single: bool | None = None):
    """Standard measures of every tracker.

    Parameters
    ----------
    times : ndarray (K,)
    tracks : dict
        ``name -> outputs`` in the vocabulary.
    truth : ndarray (R, K, [T,] n_t) or None
        True values of ``space.truth_components`` per target; NaN where a target is absent.
        Without truth only the innovation-based measures are computed.
    space : EvaluationSpace
    prob : float
        Level of every interval and bound.
    innovations : dict, optional
        ``name ->`` :func:`trackreplay.evaluators.consistency.whitened_innovations`, when already computed.
    truth_ids : ndarray of int (R, K, [T]), optional
        Target identity of every truth slot (−1 empty) when the truth is a set per scan whose
        slots change hands; default: truth slot t is target t for the whole run. With it the
        CLEAR and identity measures follow TrackEval's convention
        (:mod:`trackreplay.evaluators.assignment_metrics`).
    truth_single : bool, optional
        :func:`truth_one_identity_per_run` of ``truth`` and ``truth_ids``, when already found.

    Returns
    -------
    per_scan : polars.DataFrame
        ``tracker, scan, time_s`` and ANEES/ANIS with bounds, OSPA, GOSPA and its parts, the
        per-scan GOSPA with switching and its half switches.
    summary : polars.DataFrame
        Long form ``tracker, metric, scope, value, se, ci_low, ci_high``.
    """
    per_scan, rows = [], []
    comps = list(space.truth_components)
    pos = [comps.index(c) for c in space.position_components]
    for name, out in tracks.items():
        if "state" not in out:
            continue  # an estimator's side outputs, not a tracker
        state = _as_slots(out["state"], 1)
        R, K, S, n = state.shape
        # a slot holds a track only where its flags say it exists and was estimated
        absent = _any_flag(_as_slots(out["flags"], 0), NOT_A_TRACK) if "flags" in out else np.zeros((R, K, S), bool)
        cols = {"tracker": [name] * K, "scan": np.arange(K), "time_s": np.asarray(times, float)}
        # ---- innovation consistency (needs no truth)
        given = (innovations or {}).get(name)
        w_and_nis = given if given is not None else whitened_innovations(out)
        if w_and_nis is not None:
            nu = _as_slots(out["innovation"], 1)
            w_nu, nis = w_and_nis                                   # (R, K, S, m), (R, K, S)
            m = nu.shape[-1]
            nis_run = _slot_mean(nis)                              # average over slots
            c = consistency_summary(nis_run, m, prob, white=True)  # a correct filter's innovations are white
            cols.update(anis=c["per_scan"], anis_low=c["low"], anis_high=c["high"])
            rows.append(_with_ci(name, "anis_inside_fraction", c["inside_fraction"], np.nan, c["inside_low"],
                                 c["inside_high"]))
            rows.append(_with_ci(name, "nis_time_average", *_time_average(nis_run)))
            rows.append(_with_ci(name, "nis_time_average_low", c["time_low"], np.nan, np.nan, np.nan))
            rows.append(_with_ci(name, "nis_time_average_high", c["time_high"], np.nan, np.nan, np.nan))
            # slots are independent sequences: pool them as if they were more runs
            w = _whiteness_of_whitened(np.swapaxes(w_nu, 1, 2).reshape(R * S, K, m),
                                       np.swapaxes(nis, 1, 2).reshape(R * S, K))
            rows.append(_with_ci(name, "whiteness_lags_outside", w["outside"], np.nan, np.nan, np.nan))
            rows.append(_with_ci(name, "whiteness_max_abs_rho", np.nanmax(np.abs(w["rho"])) if np.isfinite(w["rho"]).any()
                                 else np.nan, np.nan, np.nan, np.nan))
        else:
            rows.append({"tracker": name, "metric": "nis", "scope": "no innovation covariance", "value": None,
                         "se": None, "ci_low": None, "ci_high": None})
        if truth is None:
            per_scan.append(pl.DataFrame(cols))
            continue
        tr = _as_slots(truth, 1)                                   # (R, K, T, n_t)
        compared = _components(state, comps)
        true_positions = _components(tr, pos)
        ids = out.get("track_id")
        # a slot's identity counts only while it holds a reported track (as its state does)
        ids = None if ids is None else np.where(absent, -1, _as_slots(ids[..., None], 1)[..., 0].astype(np.int64))

        def sets_and_matches(part):
            """OSPA/GOSPA per run and scan, the matches of every scan and the assignment metrics
            over whole runs (from those matches, which the NEES pairs use too) of some runs."""
            # the track positions, NaN where a slot holds no track; for the single-target forms
            # laid out as the tracker's buffer (runs fastest), which they read through
            # single_pair_view whatever the layout: copied without a transpose
            if single:
                positions = _components(compared[part], pos)
                X = np.empty_like(positions)
                np.copyto(X, positions)
                np.copyto(X, np.nan, where=absent[part][..., None])
            else:
                X = np.where(absent[part][..., None], np.nan, _components(compared[part], pos))
            Y = true_positions[part]
            part_ids = None if ids is None else ids[part]
            part_truth_ids = None if truth_ids is None else truth_slot_ids[part]
            siap_gate = space.gate if space.siap_gate is None else space.siap_gate
            d0 = space.cutoff if space.hota_distance is None else space.hota_distance
            vel = (None, None) if velocity is None else (_components(compared[part], velocity),
                                                         _components(tr[part], velocity))
            if single:
                return one_pair_measures(X, Y, part_ids, part_truth_ids, d0, siap_gate, vel)
            g = gospa_switching(X, Y, space.cutoff, space.order, space.gospa_switch_penalty, part_ids, part_truth_ids,
                                space.angular)
            # the pairs within the gate, found once for the matching, the identity pairing (with
            # target identities, TrackEval's convention) and SIAP's associations (at the same
            # gate); found out to HOTA's d₀ when that is wider, HOTA starts from them too
            pairs = wide = None
            if part_truth_ids is not None or siap_gate == space.gate:
                # (HOTA's plain form, on small sets, searches none: the gate is enough there)
                sparse = Y[..., 0].size * X.shape[2] >= hota_module.SPARSE_FROM_PAIRS
                wide = gated_pairs(X, Y, max(space.gate, d0) if sparse else space.gate, space.angular, part_ids,
                                   part_truth_ids)
                pairs = pairs_within(wide, space.gate)
                wide = wide if sparse else None
            match, dist = scan_matches(X, Y, space.gate, space.angular, part_ids, part_truth_ids, pairs=pairs)
            a = assignment_metrics(X, Y, space.gate, part_ids, space.angular, matches=(match, dist),
                                   truth_ids=part_truth_ids, pairs=pairs)
            h = hota_sums(X, Y, d0, part_ids, part_truth_ids, space.angular, pairs=wide)
            si = siap_sums(X, Y, siap_gate, times, part_ids, part_truth_ids, space.angular, *vel,
                           pairs=pairs if siap_gate == space.gate else None)
            return (reduce_sets(g), _small_slots(match, S), a, {key: h[key] for key in HOTA_SUMS},
                    {key: si[key] for key in SIAP_SUMS})

        def one_pair_measures(X, Y, part_ids, part_truth_ids, d0, siap_gate, vel):
            """:func:`sets_and_matches` where every run holds one target and one track identity
            in one slot each: the single-target forms beside each measure, on the one distance
            per (run, scan) (the same values as the general forms, tested)."""
            # the presences and the one distance (target − track, as the pairs are), found once
            view = single_pair_view(X, Y, part_ids, part_truth_ids, space.angular)
            g = _gospa_switching_single(X, Y, space.cutoff, space.order, space.gospa_switch_penalty, part_ids,
                                        part_truth_ids, space.angular, view=view)
            match, dist = _single_target_matches(X, Y, space.gate, space.angular, part_ids, part_truth_ids, view=view)
            a = _single_target_metrics(X, Y, space.gate, part_ids, space.angular, matches=(match, dist),
                                       truth_ids=part_truth_ids, view=view)
            h = hota_module._sums_single(X, Y, d0, part_ids, part_truth_ids, space.angular, view=view)
            si = siap_module._sums_single(X, Y, siap_gate, times, part_ids, part_truth_ids, space.angular, *vel,
                                          view=view)
            return (reduce_sets(g), _small_slots(match, S), a, {key: h[key] for key in HOTA_SUMS},
                    {key: si[key] for key in SIAP_SUMS})

        # a block of runs at a time: the assignments' temporaries stay a few MB at any number of runs
        truth_slot_ids = None if truth_ids is None else _as_slots(np.asarray(truth_ids)[..., None], 1)[..., 0]
        # one target and one track identity a run in one slot each (a single-target family): every
        # measure follows from the one distance per scan
        single = (S == 1 and tr.shape[2] == 1 and K > 0
                  and one_identity_per_run(ids, ~absent & all_finite(_components(compared, pos)))
                  and (one_identity_per_run(truth_slot_ids, all_finite(true_positions)) if truth_single is None
                       else truth_single))
        velocity = None
        if space.velocity_components is not None and all(c in comps for c in space.velocity_components):
            velocity = [comps.index(c) for c in space.velocity_components]
        # the per-scan means over runs of the set distances are added up block by block, in the
        # order of the runs (the same sums as over the whole (R, K) arrays, which are never held:
        # 46 MB at 10,000 radar runs); the blocks keep only the per-run means
        scan_means = {key: _ScanMeans() for key in SCAN_MEAN_KEYS}

        def reduce_sets(g):
            for key, acc in scan_means.items():
                acc.add(g[key])
            return {key: nanmean(g[key], axis=1) for key in RUN_MEAN_KEYS}

        g, match, a, h, si = _in_run_blocks(sets_and_matches, R, K * S * tr.shape[2])
        g.update({f"scan_{key}": acc.mean() for key, acc in scan_means.items()})
        u, scale = space.unit, space.scale
        # ---- OSPA / GOSPA per run and scan
        for key in ("ospa", "gospa", "localisation"):
            column = key if key in ("ospa", "gospa") else f"gospa_{key}"
            cols[f"{column}_{u}"] = scale * g[f"scan_{key}"]
        for key in ("missed", "false"):
            cols[f"gospa_{key}"] = g[f"scan_{key}"]
        for key in ("ospa", "gospa"):
            rows.append(_with_ci(name, f"{key}_mean_{u}", *(scale * v for v in mean_interval(g[key]))))
        # per-scan switching (not trajectory GOSPA): GOSPA plus γ^p/2 per half switch
        cols[f"gospa_switching_{u}"] = scale * g["scan_gospa_switching"]
        cols["gospa_half_switches"] = g["scan_half_switches"]
        rows.append(_with_ci(name, f"gospa_switching_mean_{u}",
                             *(scale * v for v in mean_interval(g["gospa_switching"]))))
        del g
        # ---- assignment over whole runs
        for key in ("mota", "idf1"):
            rows.append(_with_ci(name, key, *mean_interval(a[key])))
        rows.append(_with_ci(name, f"motp_{u}", *(scale * v for v in mean_interval(a["motp"]))))
        for key in ("mostly_tracked", "partially_tracked", "mostly_lost", "track_breaks", "id_switches",
                    "false_tracks", "misses", "false_positives"):
            rows.append(_with_ci(name, f"{key}_per_run", *mean_interval(a[key].astype(float))))
        for key in ("idp", "idr"):
            rows.append(_with_ci(name, key, *mean_interval(a[key])))
        # ---- HOTA: counts and sums added over runs, never per-run HOTA averaged; the interval
        # re-pools the runs with each group left out (grouped jackknife)
        parts = ("hota", "deta", "assa", "loca")
        hota_ci = _pooled_jackknife(lambda sums, runs: [pooled_hota(sums, runs)[key] for key in parts], h, HOTA_SUMS,
                                    R, 10)
        for i, key in enumerate(parts):
            rows.append(_with_ci(name, key, *(v[i] for v in hota_ci)))
        # ---- SIAP (evaluators/siap.py): sums over runs, the same grouped jackknife as HOTA
        siap_rows = {"completeness": "siap_completeness", "ambiguity": "siap_ambiguity",
                     "spuriousness": "siap_spuriousness", "position_accuracy": f"siap_position_accuracy_{u}",
                     "velocity_accuracy": f"siap_velocity_accuracy_{u}/s",
                     "track_number_change_rate": "siap_track_number_change_rate",
                     "longest_track_segment": "siap_longest_track_segment"}
        if velocity is None:
            del siap_rows["velocity_accuracy"]
        siap_ci = _pooled_jackknife(lambda sums, runs: [pooled_siap(sums, runs)[key] for key in siap_rows], si,
                                    SIAP_SUMS, R, 10)
        for i, (key, metric) in enumerate(siap_rows.items()):
            factor = scale if key == "position_accuracy" else 1.0
            rows.append(_with_ci(name, metric, *(factor * v[i] for v in siap_ci)))
        # ---- NEES on matched pairs
        if "covariance" in out:
            P = _as_slots(out["covariance"], 2)                                     # (R, K, S, c, c)
            if comps != list(range(P.shape[-1])):
                P = P[..., comps, :][..., :, comps]
            # a match is a slot that holds a track, so the states need no masking of their own
            if S == 1:
                est_m, P_m = compared, P   # one slot: every match is slot 0, and it broadcasts over targets
            else:
                sel = np.maximum(match, 0)
                est_m = np.take_along_axis(compared, sel[..., None], axis=2)
                P_m = np.take_along_axis(P, sel[..., None, None], axis=2)
            nees_slots, sq = _matched_nees(est_m, tr, P_m, match, pos, space.angular)
            nees = _slot_mean(nees_slots)                          # (R, K)
            # per run: the mean squared position error over its matched scans (NaN where unmatched)
            matched_ms = nanmean(sq, axis=(1, 2))
            del est_m, P_m, sq
            # errors correlate over scans: the time average's bounds come from the runs
            c = consistency_summary(nees, len(comps), prob, white=False)
            cols.update(anees=c["per_scan"], anees_low=c["low"], anees_high=c["high"])
            rows.append(_with_ci(name, "anees_inside_fraction", c["inside_fraction"], np.nan, c["inside_low"],
                                 c["inside_high"]))
            rows.append(_with_ci(name, "nees_time_average", c["time_average"], c["time_se"], c["time_ci_low"],
                                 c["time_ci_high"]))
            rows.append(_with_ci(name, "nees_time_average_low", c["time_low"], np.nan, np.nan, np.nan))
            rows.append(_with_ci(name, "nees_time_average_high", c["time_high"], np.nan, np.nan, np.nan))
            rows.append(_with_ci(name, f"rmse_matched_position_{u}", *(scale * v for v in rms_interval(matched_ms))))
        else:
            rows.append({"tracker": name, "metric": "nees", "scope": "no covariance", "value": None,
                         "se": None, "ci_low": None, "ci_high": None})
        per_scan.append(pl.DataFrame(cols))
    schema = {"tracker": pl.String, "metric": pl.String, "scope": pl.String, "value": pl.Float64,
              "se": pl.Float64, "ci_low": pl.Float64, "ci_high": pl.Float64}
    summary = pl.DataFrame(rows, schema=schema) if rows else pl.DataFrame(schema=schema)
    return (pl.concat(per_scan, how="diagonal") if per_scan else pl.DataFrame()), summary
