"""The tracker interface: what every tracker, built in or plugged, implements and returns.

A tracker is a class with four class attributes and one method (see ``docs/trackers.md``)::

    class MyTracker(Tracker):
        name = "my_tracker"            # how the CLI, tables and output channels name it
        family = "radar"         # the measurement family it consumes (vocabulary.FAMILIES)
        form = "batch"                 # "batch": all runs at once; "run": one run at a time
        params = (Param("sigma_range_m", 50.0, "m", "plot range noise"),)

        def track(self, plots):        # form "batch"; form "run" implements track_run instead
            ...
            return {"state": ..., "flags": ..., "covariance": ...}

Design values (``params``) arrive as attributes (``self.sigma_range_m``) and in ``self.design``;
a value of the same name recorded in the data set, or given with ``replay --set``, overrides the
default exactly as it does for the built-in trackers.

The **batch** form receives the family's measurement object with a leading run axis and returns
arrays of shape ``(runs, scans, ...)``: one Python call per data set, so a vectorised tracker
costs what its numpy kernels cost. The **run** form receives the same object for one run (no
run axis) and returns ``(scans, ...)`` arrays; the pipeline loops over runs and stacks the
results, which costs one Python call per run on top of the tracker's own work (measured by
``benchmarks/bench_tracker_forms.py``). Outputs follow :data:`trackreplay.vocabulary.OUTPUTS`.
"""

from __future__ import annotations

import dataclasses
import traceback
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.batched_linalg import cholesky_lower, positive_definite
from trackreplay.errors import DesignValueError, InputError


@dataclass(frozen=True)
class Param:
    """A design parameter of a tracker.

    Attributes
    ----------
    name : str
        Name used by ``--set name=value``; angles in degrees end in ``_deg``.
    default : bool, int, float or str
        Default value; its type is the type ``--set`` parses into.
    unit : str
        Unit shown by ``replay trackers``.
    doc : str
        One-line meaning.
    low, high : float, optional
        Bounds of a numeric value, open unless ``closed``; the base class refuses a value outside
        them (or not finite, or not a number) when the tracker is constructed, so a tracker need
        not check its own ranges (only relations between its values, which no one Param holds).
    closed : bool
        Whether ``low`` and ``high`` themselves are accepted.
    """

    name: str
    default: object
    unit: str = ""
    doc: str = ""
    low: float | None = None
    high: float | None = None
    closed: bool = False

    def check(self, value) -> None:
        """Raise :class:`~trackreplay.errors.DesignValueError` (an input error that is also a
        ``ValueError``) for a value this parameter does not accept: a number that is not finite,
        or outside the open bounds (``low``, ``high``) where it has them.

        The one check of a design value (``docs/trackers.md``): a tracker's parameters are
        checked when it is constructed, a stage's own (:attr:`trackreplay.stages.base.Stage.params`,
        the evaluation's design values) when a data set's design values are resolved
        (:func:`trackreplay.design_values.check`). The messages read ``name = value must …``,
        so that the resolution can prefix them with ``design value``.
        """
        if isinstance(value, float) and not np.isfinite(value):
            raise DesignValueError(f"{self.name} = {value} must be finite")
        if self.low is None and self.high is None:
            return
        if value is None:
            raise DesignValueError(f"{self.name} has no value: pass it, or replay a data set whose scenario records it")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise DesignValueError(f"{self.name} = {value!r} must be a number") from None
        above = self.low is None or (number >= self.low if self.closed else number > self.low)
        below = self.high is None or (number <= self.high if self.closed else number < self.high)
        if not (np.isfinite(number) and above and below):
            low = "-inf" if self.low is None else f"{self.low:g}"
            high = "inf" if self.high is None else f"{self.high:g}"
            if self.closed and self.high is None:
                raise DesignValueError(f"{self.name} = {number:g} must be ≥ {low}")
            left, right = ("[", "]") if self.closed else ("(", ")")
            raise DesignValueError(f"{self.name} = {number:g} must be in {left}{low}, {high}{right}")


class Tracker:
    """Base class of every tracker (see the module docstring and ``docs/trackers.md``)."""

    name: ClassVar[str] = ""
    family: ClassVar[str] = ""
    form: ClassVar[str] = "batch"
    params: ClassVar[tuple[Param, ...]] = ()
    label: ClassVar[str] = ""  # legend label in figures (default: name)
    #: the scene the tracker is made for: "one" target per run (it returns one track, or the
    #: paper's fixed slots) or "many" (tracks born and deleted among clutter, any number of
    #: slots); a replay runs the built-ins made for the data set's scene unless told which
    targets: ClassVar[str] = "one"
    #: whether a replay runs this built-in without being named (a variant of another built-in,
    #: e.g. the same association with a different filter, runs when asked: ``--trackers``)
    runs_by_default: ClassVar[bool] = True

    def __init__(self, **design):
        defaults = {p.name: p.default for p in self.params}
        unknown = sorted(set(design) - set(defaults))
        if unknown:
            raise TypeError(f"{type(self).__name__} has no design parameter(s) {', '.join(unknown)}")
        self.design = {**defaults, **design}
        for p in self.params:
            p.check(self.design[p.name])
        for key, value in self.design.items():
            setattr(self, key, value)

    def track(self, measurements) -> dict:  # pragma: no cover - interface
        """Batch form: all runs at once; returns ``(runs, scans, ...)`` arrays."""
        raise NotImplementedError(f"{type(self).__name__} implements neither track nor track_run")

    def track_run(self, measurements) -> dict:  # pragma: no cover - interface
        """Run form: one run's scans in, ``(scans, ...)`` arrays out."""
        raise NotImplementedError(f"{type(self).__name__} implements neither track nor track_run")


def tracker_name(cls) -> str:
    return getattr(cls, "name", "") or cls.__name__.lower()


# --------------------------------------------------------------------------- measurements
# One object per family. Fields marked per_run carry a leading run axis in the batch form and
# none in the run form; the rest (scan times, sensor layout) are shared by all runs.


def _per_run(default=dataclasses.MISSING):
    if default is dataclasses.MISSING:
        return field(metadata={"per_run": True})
    return field(default=default, metadata={"per_run": True})


@dataclass
class Measurements:
    """Base of the per-family measurement objects."""

    def run(self, i: int):
        """The same measurements for run ``i`` alone (per-run fields lose their run axis)."""
        values = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            values[f.name] = v[i] if f.metadata.get("per_run") and v is not None else v
        return type(self)(**values)

    @property
    def n_runs(self) -> int:
        first = next(f for f in dataclasses.fields(self) if f.metadata.get("per_run"))
        return int(getattr(self, first.name).shape[0])

    @property
    def n_scans(self) -> int:
        return int(len(self.times_s))

    #: components of the state a tracker of the family returns (its ``state``'s last axis);
    #: the family's evaluators index them (``trackreplay.vocabulary.FAMILIES``)
    state_size = None


@dataclass
class RadarPlots(Measurements):
    """Radar plots, NaN-padded to the largest count of a scan.

    ``range_m``, ``bearing_rad`` : (R, K, W); ``counts`` : (R, K) real plots per scan;
    ``times_s`` : (K,); ``truth_state`` : (R, K, T, 4) ``[x, y, vx, vy]`` of the targets present
    (NaN in empty slots) or None, with ``truth_target_id`` (R, K, T) their identities (−1 empty).
    Bearing is measured from the x axis towards the y axis (x = r cos θ, y = r sin θ).
    """

    range_m: np.ndarray = _per_run()
    bearing_rad: np.ndarray = _per_run()
    counts: np.ndarray = _per_run()
    times_s: np.ndarray = None
    truth_state: np.ndarray | None = _per_run(None)
    truth_target_id: np.ndarray | None = _per_run(None)
    state_size = 4  # [x, y, vx, vy]


@dataclass
class BearingPeaks(Measurements):
    """Cross-correlation peaks, NaN-padded per scan.

    ``bearing_rad``, ``amplitude`` : (R, K, W); ``origin`` : (R, K, W) target index of a true peak,
    -1 for clutter or unknown; ``counts`` : (R, K); ``times_s`` : (K,); ``field_rad`` : (min, max)
    bearings the sensor can report; ``n_targets`` : track slots to fill;
    ``truth_bearing_rad``, ``truth_rate_radps`` : (R, K, T) or None.
    """

    bearing_rad: np.ndarray = _per_run()
    amplitude: np.ndarray = _per_run()
    origin: np.ndarray = _per_run()
    counts: np.ndarray = _per_run()
    times_s: np.ndarray = None
    field_rad: tuple = (0.0, np.pi)
    n_targets: int = 0
    truth_bearing_rad: np.ndarray | None = _per_run(None)
    truth_rate_radps: np.ndarray | None = _per_run(None)
    state_size = 2  # [bearing, bearing rate] per track slot


@dataclass
class ArraySnapshots(Measurements):
    """Narrowband snapshots of a uniform linear array: ``snapshots`` (R, K, M sensors,
    Ns snapshots) complex; ``times_s`` : (K,); ``spacing_wavelengths`` : the sensor spacing d/λ
    (angles θ from broadside, sensor 0 the phase reference: a_m(θ) = exp(j 2π m d/λ sin θ));
    ``truth_angle_rad`` : (R, K, T) or None."""

    snapshots: np.ndarray = _per_run()
    times_s: np.ndarray = None
    spacing_wavelengths: float = 0.5
    truth_angle_rad: np.ndarray | None = _per_run(None)
    state_size = 2  # [bearing, bearing rate] per track slot


@dataclass
class TdoaFdoa(Measurements):
    """TDOA/FDOA measurement vectors per epoch.

    ``measured`` : (R, E, 2P) TDOAs (s) then FDOAs (Hz) of the P ``pairs`` (P, 2);
    ``sigma`` : (R, E, 2P); ``carrier_hz`` : (R, E); ``sensor_position_m``,
    ``sensor_velocity_mps`` : (R, E, S, 2); ``times_s`` : (E,); ``prior_state`` : (R, E, 4) or None.
    """

    measured: np.ndarray = _per_run()
    sigma: np.ndarray = _per_run()
    carrier_hz: np.ndarray = _per_run()
    sensor_position_m: np.ndarray = _per_run()
    sensor_velocity_mps: np.ndarray = _per_run()
    times_s: np.ndarray = None
    pairs: np.ndarray = None
    prior_state: np.ndarray | None = _per_run(None)
    state_size = 4  # [x, y, vx, vy]


@dataclass
class ColoredPositions(Measurements):
    """Position measurements in coloured noise: ``position_m`` (R, K, axes), ``times_s`` (K,)
    evenly spaced; ``truth_state`` (R, K, 3·axes) ``[p, v, a]`` per axis or None."""

    position_m: np.ndarray = _per_run()
    times_s: np.ndarray = None
    truth_state: np.ndarray | None = _per_run(None)

    @property
    def state_size(self) -> int:
        return 3 * int(self.position_m.shape[-1])  # [p, v, a] per axis


# family name -> its measurement class, as the families' declaration names it
MEASUREMENTS = {f.name: globals()[f.measurement_class] for f in vocab.FAMILIES.values()}


# --------------------------------------------------------------------------- calling a tracker


class TrackerError(InputError):
    """A tracker failed or returned outputs outside the vocabulary; names the tracker."""


def _where_raised(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return ""
    last = frames[-1]
    return f" (at {last.filename.replace(chr(92), '/').rsplit('/', 1)[-1]}:{last.lineno})"


def call_tracker(tracker: Tracker, measurements, source: str | None = None) -> dict:
    """Run ``tracker`` over every run of ``measurements`` and check what it returns.

    Parameters
    ----------
    tracker : Tracker
        A constructed tracker of either form.
    measurements : Measurements
        The family's measurement object with its run axis.
    source : str, optional
        Where the tracker came from (named in error messages).

    Returns
    -------
    dict of ndarray
        Outputs with a leading ``(runs, scans)``, checked by :func:`validate_outputs`.

    Raises
    ------
    TrackerError
        The tracker raised, or its outputs break the vocabulary; the message names the tracker,
        and the run and scan where known.
    """
    name = tracker_name(type(tracker))
    where = source or name
    R = measurements.n_runs
    if tracker.form == "run":
        per_run = []
        for i in range(R):
            try:
                out = tracker.track_run(measurements.run(i))
            except (Exception, SystemExit) as exc:  # sys.exit() in a tracker is its failure, not the tool's exit
                raise TrackerError(f"tracker {name!r}: run {i}: raised {type(exc).__name__}: {exc}"
                                   f"{_where_raised(exc)}", where) from None
            if not isinstance(out, dict):
                raise TrackerError(f"tracker {name!r}: run {i}: track_run returned {type(out).__name__}, "
                                   "expected a dict of arrays", where)
            if per_run and set(out) != set(per_run[0]):
                raise TrackerError(f"tracker {name!r}: run {i} returned {sorted(out)} but run 0 {sorted(per_run[0])}",
                                   where)
            per_run.append(out)
        outputs = {}
        for key in per_run[0] if per_run else ():
            arrays = [np.asarray(o[key]) for o in per_run]
            bad = next((i for i, a in enumerate(arrays) if a.shape != arrays[0].shape), None)
            if bad is not None:
                raise TrackerError(f"tracker {name!r}: {key!r} has shape {arrays[0].shape} in run 0 but "
                                   f"{arrays[bad].shape} in run {bad}", where)
            outputs[key] = np.stack(arrays)
    else:
        try:
            outputs = tracker.track(measurements)
        except (Exception, SystemExit) as exc:  # sys.exit() in a tracker is its failure, not the tool's exit
            raise TrackerError(f"tracker {name!r}: raised {type(exc).__name__}: {exc}{_where_raised(exc)}",
                               where) from None
        if not isinstance(outputs, dict):
            raise TrackerError(f"tracker {name!r}: track returned {type(outputs).__name__}, expected a dict of "
                               "arrays", where)
    return validate_outputs(outputs, R, measurements.n_scans, name, where, measurements.state_size)


def _first(mask) -> str:
    idx = tuple(int(v[0]) for v in np.nonzero(mask))
    text = f"run {idx[0]} scan {idx[1]}"
    return text + (f" slot {idx[2]}" if len(idx) > 2 else "")


def validate_outputs(outputs: dict, n_runs: int, n_scans: int, name: str, where: str | None = None,
                     state_size: int | None = None) -> dict:
    """Check a tracker's outputs against the vocabulary; return them with flags as
    :data:`~trackreplay.vocabulary.FLAG_DTYPE`.

    Checks: the required names; every array ``(runs, scans, ...)`` and numeric; ``flags``
    shaped like ``state`` without its last axis; NaN in ``state`` only where the flags say
    ``NO_TRACK`` or ``NOT_ESTIMATED``; ``covariance`` symmetric positive definite wherever the
    state is finite. Paper-specific extra arrays pass through with the shape check alone.

    A covariance within rounding of positive semi-definite passes, but where it is not
    numerically positive definite (:data:`STRICT_DEFINITENESS`) its flags gain
    ``NOT_POSITIVE_DEFINITE``: every covariance written is positive definite or says it is not
    (``docs/contract.md``, Flags).
    """
    where = where or name
    out = {}
    for key in vocab.REQUIRED_OUTPUTS:
        if key not in outputs:
            raise TrackerError(f"tracker {name!r}: outputs lack {key!r} (have: {', '.join(sorted(outputs)) or 'none'})",
                               where)
    for key, value in outputs.items():
        a = np.asarray(value)
        if a.dtype.kind not in "biufc":
            raise TrackerError(f"tracker {name!r}: output {key!r} has dtype {a.dtype}, expected numbers", where)
        if a.ndim < 2 or a.shape[:2] != (n_runs, n_scans):
            raise TrackerError(f"tracker {name!r}: output {key!r} has shape {a.shape}, expected ({n_runs} runs, "
                               f"{n_scans} scans, ...)", where)
        out[key] = a
    state = out["state"]
    if state.ndim < 3 or state.dtype.kind not in "f":
        raise TrackerError(f"tracker {name!r}: state has shape {state.shape} and dtype {state.dtype}, expected "
                           "floats (runs, scans, [slots,] n)", where)
    if state_size is not None and state.shape[-1] != state_size:
        raise TrackerError(f"tracker {name!r}: state has {state.shape[-1]} components, the family's state has "
                           f"{state_size} (see `replay trackers` and docs/trackers.md)", where)
    flags = out["flags"]
    if flags.dtype.kind not in "iub" or flags.shape != state.shape[:-1]:
        raise TrackerError(f"tracker {name!r}: flags have shape {flags.shape} and dtype {flags.dtype}, expected "
                           f"integers of shape {state.shape[:-1]}", where)
    top = np.iinfo(np.dtype(vocab.FLAG_DTYPE)).max
    if flags.size and (flags.min() < 0 or flags.max() > top):
        raise TrackerError(f"tracker {name!r}: flags outside 0..{top} (see vocabulary.FLAGS)", where)
    flags = flags.astype(vocab.FLAG_DTYPE)
    out["flags"] = flags
    if np.isinf(state).any():
        raise TrackerError(f"tracker {name!r}: {_first(np.isinf(state).any(axis=-1))}: infinite state", where)
    excused = (flags & (vocab.NO_TRACK | vocab.NOT_ESTIMATED)) > 0
    bad = np.isnan(state).any(axis=-1) & ~excused
    if bad.any():
        raise TrackerError(f"tracker {name!r}: {_first(bad)}: NaN state without the NO_TRACK or NOT_ESTIMATED "
                           "flag", where)
    if "track_id" in out:
        out["track_id"] = _checked_track_ids(out["track_id"], flags, name, where)
    if "covariance" in out:
        # a covariance that passes but is not numerically positive definite is written flagged,
        # whichever tracker made it: the one place every output goes through
        singular = _check_covariance(out["covariance"], state, name, where)
        if singular is not None:
            out["flags"] = flags = flags | np.where(singular, vocab.NOT_POSITIVE_DEFINITE, 0).astype(flags.dtype)
    return out


def _checked_track_ids(ids, flags, name, where):
    """``track_id``: whole numbers shaped like ``flags`` with track slots, ≥ −1, and no identity
    twice in one scan of one run (two slots cannot hold the same track). Returned as int64."""
    if ids.shape != flags.shape or ids.ndim != 3:
        raise TrackerError(f"tracker {name!r}: track_id has shape {ids.shape}, expected (runs, scans, slots) "
                           f"{flags.shape if flags.ndim == 3 else '(the shape of flags, with a slot axis)'}", where)
    if ids.dtype.kind not in "iu":
        whole = ids.dtype.kind == "f" and np.isfinite(ids).all() and (ids == np.round(ids)).all()
        if not whole:
            raise TrackerError(f"tracker {name!r}: track_id must hold integers (got {ids.dtype})", where)
    ids = ids.astype(np.int64)
    if ids.size and ids.min() < -1:
        raise TrackerError(f"tracker {name!r}: {_first((ids < -1))}: track_id below −1 (−1 marks an empty slot)",
                           where)
    ordered = np.sort(ids, axis=-1)
    twice = (ordered[..., 1:] == ordered[..., :-1]) & (ordered[..., 1:] >= 0)
    if twice.any():
        run, scan = (int(v[0]) for v in np.nonzero(twice.any(axis=-1)))
        value = int(ordered[run, scan, 1:][twice[run, scan]][0])
        raise TrackerError(f"tracker {name!r}: run {run} scan {scan}: track_id {value} is in two slots", where)
    return ids


COVARIANCE_CHECK_BLOCK = 32768  # matrices per block: a few MB of temporaries, whatever the run count
#: A covariance is numerically positive definite when its smallest eigenvalue exceeds this times
#: n · trace: four times n units of roundoff of its largest eigenvalue (≤ trace), above the
#: error with which a backward-stable eigensolver or Cholesky factorisation can place it
#: (Golub & Van Loan 2013, Matrix Computations, §8.1.2 and §4.2.6), so no independent check finds
#: it singular. Below it (condition number beyond about 10¹³ for n = 4) it is flagged
#: ``NOT_POSITIVE_DEFINITE``.
STRICT_DEFINITENESS = 4 * np.finfo(float).eps


def _live_entries(block, live, everything: bool, scan_major: bool):
    """A copy of the live matrices of ``block`` (runs, scans[, slots], n, n) as their entries
    ``(n², count)``, and the position of each in the block's (run, scan) order.

    The entries are taken with the matrix axes first, a view where the axes merge (a copy
    otherwise), and gathered in one pass; ``scan_major`` reads the block scan by scan, which
    keeps every read a contiguous row when the runs are innermost.
    """
    n = block.shape[-1]
    position = np.arange(live.size).reshape(live.shape)
    entries = np.moveaxis(block, (-2, -1), (0, 1))
    entries = entries.reshape((n * n,) + entries.shape[2:])
    if scan_major:
        position, live, entries = position.T, live.T, entries.transpose(0, 2, 1)
    if not everything:
        # entry by entry: ``entries[:, live]`` would come out with the matrices outermost, (count, n²)
        # in memory, and every reduction over it would stride
        gathered = np.empty((n * n, int(np.count_nonzero(live))))
        for row, entry in zip(gathered, entries):
            row[...] = entry[live]
        return gathered, position[live]
    entries = entries.reshape(n * n, -1)
    # always a copy (one matrix alone would be a view): the caller adds δI to it
    return (entries.copy() if np.may_share_memory(entries, block) else entries), position.reshape(-1)


def _check_covariance(cov, state, name, where):
    """Finite, symmetric and positive semi-definite to rounding wherever the state is finite;
    checked in blocks of :data:`COVARIANCE_CHECK_BLOCK` matrices so that the temporaries stay
    small and in cache at any number of runs. A failure names the first offending matrix in
    (run, scan) order, whatever order a block is read in.

    Returns
    -------
    ndarray of bool (runs, scans[, slots]) or None
        Where a live covariance passed but is not numerically positive definite (its smallest
        eigenvalue below :data:`STRICT_DEFINITENESS` · n · trace); None when every one is.
    """
    n = state.shape[-1]
    if cov.shape != state.shape + (n,):
        raise TrackerError(f"tracker {name!r}: covariance has shape {cov.shape}, expected {state.shape + (n,)}", where)
    live_all = np.isfinite(state).all(axis=-1)
    singular = None

    def fail(index: int, problem: str):
        """``index``: the offending matrix in the flattened (runs, scans[, slots]) order."""
        bad = np.zeros(live_all.size, bool)
        bad[index] = True
        raise TrackerError(f"tracker {name!r}: {_first(bad.reshape(live_all.shape))}: {problem}", where)

    # blocks of whole runs: an output that is a strided view is copied a block at a time
    per_run = int(np.prod(live_all.shape[1:], dtype=np.int64))
    runs = max(1, COVARIANCE_CHECK_BLOCK // max(per_run, 1))
    # most trackers lay their outputs out with the runs innermost (a scan's runs side by side):
    # such a block is then read scan by scan, each matrix entry a contiguous row of runs
    scan_major = cov.ndim == 4 and abs(cov.strides[0]) < abs(cov.strides[1])
    for first_run in range(0, live_all.shape[0], runs):
        start = first_run * per_run
        live = live_all[first_run:first_run + runs]
        everything = live.all()
        if not everything and not live.any():
            continue
        entries, where_live = _live_entries(cov[first_run:first_run + runs], live, everything, scan_major)
        t = entries.reshape(n, n, -1)
        finite = np.logical_and.reduce(np.isfinite(entries), axis=0)
        if not finite.all():
            fail(start + where_live[~finite].min(), "covariance not finite where the state is")
        on_diagonal = (np.arange(n), np.arange(n))
        scale = np.maximum(np.maximum.reduce(np.abs(t[on_diagonal]), axis=0), np.finfo(float).tiny)
        upper, lower = np.triu_indices(n, 1)  # each pair of mirrored entries once
        asym = np.maximum.reduce(np.abs(t[upper, lower] - t[lower, upper]), axis=0) > 1e-8 * scale
        if asym.any():
            fail(start + where_live[asym].min(), "covariance not symmetric")
        # c − δI has a Cholesky factor only when c's smallest eigenvalue exceeds δ, a margin
        # above what rounding can move it by: one batched factorisation, entry by entry
        # (trackreplay.batched_linalg), clears the common case; the eigenvalues are computed only
        # for the matrices it does not clear
        trace = np.maximum(np.add.reduce(np.abs(t[on_diagonal]), axis=0), np.finfo(float).tiny)
        t[on_diagonal] -= STRICT_DEFINITENESS * n * trace  # t is now c − δI
        with np.errstate(invalid="ignore", divide="ignore"):
            factor = cholesky_lower(t)
        definite = positive_definite(factor)
        if definite.all():
            continue
        doubtful = np.flatnonzero(~definite)
        entries, _ = _live_entries(cov[first_run:first_run + runs], live, everything, scan_major)  # without δI
        lowest = np.linalg.eigvalsh(np.moveaxis(entries[:, doubtful].reshape(n, n, -1), -1, 0))[..., 0]
        # beyond rounding of positive semi-definite (−10⁻⁹ of the largest variance): refused
        indefinite = lowest <= -1e-9 * scale[doubtful]
        if indefinite.any():
            first = int(np.argmin(np.where(indefinite, where_live[doubtful], live_all.size)))
            fail(start + where_live[doubtful[first]],
                 f"covariance not positive definite (smallest eigenvalue {lowest[first]:.3g})")
        # within rounding of it: passed, and flagged where the eigenvalue confirms what the
        # shifted factorisation (itself subject to rounding) suggested
        flagged = doubtful[lowest <= STRICT_DEFINITENESS * n * trace[doubtful]]
        if flagged.size:
            if singular is None:
                singular = np.zeros(live_all.size, bool)
            singular[start + where_live[flagged]] = True
    return None if singular is None else singular.reshape(live_all.shape)
