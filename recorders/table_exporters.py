"""Each family's data set → its tables in exactly the import format (``docs/importers.md``,
"The way back: replay export --table"): importing them gives the same arrays bit for bit.

One exporter per family, named in the family's entry of
:data:`trackreplay.recorders.table_formats.TABLE_FORMATS` and called by
:func:`trackreplay.recorders.tables.tables_from_dataset`; :func:`write_table` writes a table
atomically. A ragged channel (plots, peaks) becomes one row per item and one row with the
measurement empty per scan without items; times get the data set's ``first_time_s`` back.
"""

from __future__ import annotations

import numpy as np
import polars as pl

from trackreplay.errors import InputError
from trackreplay.recorders.table_rows import (
    _COLORED, _COLORED_TRUTH, _EMITTER_TRUTH, _MEAS, _PEAKS, _PLOTS, _PRIOR, _PRIOR_XY, _RADAR_TRUTH, _SENSORS,
    _TRUTH_XY, _XCORR_TRUTH, AXES)


def _first_time(dataset) -> float:
    raw = dataset.scenario.get("params", {}).get("first_time_s", 0.0)
    try:
        value = float(raw)
    except (TypeError, ValueError):
        raise InputError(f"scenario record: first_time_s {raw!r} is not a number", dataset.path) from None
    if not np.isfinite(value):
        raise InputError("scenario record: first_time_s must be finite", dataset.path)
    return value


def _times(dataset, ch) -> np.ndarray:
    t = ch.times()
    t0 = _first_time(dataset)
    return t + t0 if t0 != 0 else t


def _fixed_grid(dataset, topic: str, name: str, shape: tuple, inner: tuple | None = None) -> np.ndarray:
    """``name`` of ``topic`` as (runs, scans, ...), complete and finite, covering ``shape``."""
    ch = dataset.channel(topic)
    ch.require_every_frame(*shape)
    a = ch.grid(name)
    if a.shape[:2] != shape:
        raise InputError(f"{topic} covers {a.shape[:2]} run×scan, the measurements {shape}", dataset.path)
    if inner is not None and a.shape[2:] != inner:
        raise InputError(f"{topic} {name} has frames of shape {a.shape[2:]}, expected {inner}", dataset.path)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{topic} {name} holds NaN/Inf: no table value for it", dataset.path)
    return a


def _frames_to_rows(counts: np.ndarray):
    """Row layout of ragged frames: every item a row, an empty frame one marker row.

    Returns (run, scan, slot, is_item) per row, run-major, then scan, then slot.
    """
    n = np.maximum(counts, 1).ravel()
    frame = np.repeat(np.arange(counts.size), n)
    slot = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    run, scan = np.divmod(frame, counts.shape[1])
    return run, scan, slot, slot < counts.ravel()[frame]


def _ragged_column(a: np.ndarray, run, scan, slot, item) -> np.ndarray:
    out = np.full(run.size, np.nan)
    if a.shape[2]:
        out[item] = a[run[item], scan[item], slot[item]]
    return out


def _series(name: str, values: np.ndarray, item: np.ndarray | None = None, dtype=pl.Float64) -> pl.Series:
    s = pl.Series(name, values, dtype=dtype)
    if item is not None and not item.all():
        s = s.scatter(np.flatnonzero(~item), None)
    return s


def export_radar_plots(dataset) -> dict:
    """A data set's radar plots (and truth) → ``{"measurements": DataFrame}``: a row per plot, a row
    with range and bearing empty per scan without plots."""
    ch = dataset.channel(_PLOTS)
    rng, counts = ch.ragged("range_m")
    brg, _ = ch.ragged("bearing_rad")
    times = _times(dataset, ch)
    run, scan, slot, item = _frames_to_rows(counts)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            _series("range_m", _ragged_column(rng, run, scan, slot, item), item),
            _series("bearing_rad", _ragged_column(brg, run, scan, slot, item), item)]
    if _RADAR_TRUTH in dataset.channels:
        state = _fixed_grid(dataset, _RADAR_TRUTH, "state", counts.shape, (4,))
        cols += [pl.Series(n, state[run, scan, j], pl.Float64) for j, n in enumerate(_TRUTH_XY)]
    return {"measurements": pl.DataFrame(cols)}


def export_bearing_peaks(dataset) -> dict:
    """A data set's peaks (and the targets' true bearings and rates) → ``{"measurements": DataFrame}``:
    a row per peak, a row with bearing and amplitude empty per scan without peaks."""
    ch = dataset.channel(_PEAKS)
    brg, counts = ch.ragged("bearing_rad")
    amp, _ = ch.ragged("amplitude")
    times = _times(dataset, ch)
    run, scan, slot, item = _frames_to_rows(counts)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            _series("bearing_rad", _ragged_column(brg, run, scan, slot, item), item),
            _series("amplitude", _ragged_column(amp, run, scan, slot, item), item)]
    if "origin" in ch.arrays:
        origin, _ = ch.ragged("origin")
        o = _ragged_column(origin, run, scan, slot, item)
        cols.append(_series("origin", np.where(item, o, 0).astype(np.int64), item, pl.Int64))
    truth = dataset.channels.get(_XCORR_TRUTH)
    if truth is not None and "bearing_rad" in truth.arrays:
        b = _fixed_grid(dataset, _XCORR_TRUTH, "bearing_rad", counts.shape)
        if b.ndim != 3:
            raise InputError(f"{_XCORR_TRUTH} bearing_rad must hold one bearing per target", dataset.path)
        cols += [pl.Series(f"truth{j}_bearing_rad", b[run, scan, j], pl.Float64) for j in range(b.shape[2])]
        if "bearing_rate_radps" in truth.arrays:
            rate = _fixed_grid(dataset, _XCORR_TRUTH, "bearing_rate_radps", counts.shape, b.shape[2:])
            cols += [pl.Series(f"truth{j}_bearing_rate_radps", rate[run, scan, j], pl.Float64)
                     for j in range(b.shape[2])]
    return {"measurements": pl.DataFrame(cols)}


def export_tdoa_fdoa(dataset) -> dict:
    """A data set's TDOA/FDOA measurements (truth, prior) and sensors → ``{"measurements": ...,
    "sensors": ...}``: a row per pair and epoch, a row per sensor and epoch."""
    ch = dataset.channel(_MEAS)
    shape = (ch.n_runs, ch.n_scans)
    times = _times(dataset, ch)
    pairs_all = _fixed_grid(dataset, _MEAS, "pairs", shape)
    if pairs_all.ndim != 4 or pairs_all.shape[3] != 2:
        raise InputError(f"{_MEAS} pairs must be (P, 2) per frame", dataset.path)
    pairs = pairs_all[0, 0].astype(np.int64)
    if np.any(pairs_all != pairs):
        raise InputError(f"{_MEAS} pairs change between frames: a table lists one pair list", dataset.path)
    P = pairs.shape[0]
    values = {n: _fixed_grid(dataset, _MEAS, n, shape, (P,))
              for n in ("tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz")}
    carrier = _fixed_grid(dataset, _MEAS, "carrier_hz", shape, ())
    R, K = shape
    run = np.repeat(np.arange(R), K * P)
    scan = np.tile(np.repeat(np.arange(K), P), R)
    q = np.tile(np.arange(P), R * K)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            pl.Series("sensor_a", pairs[q, 0], pl.Int64), pl.Series("sensor_b", pairs[q, 1], pl.Int64)]
    cols += [pl.Series(n, v[run, scan, q], pl.Float64) for n, v in values.items()]
    cols.append(pl.Series("carrier_hz", carrier[run, scan], pl.Float64))
    for names, topic in ((_TRUTH_XY, _EMITTER_TRUTH), (_PRIOR_XY, _PRIOR)):
        if topic in dataset.channels:
            state = _fixed_grid(dataset, topic, "state", shape, (4,))
            cols += [pl.Series(n, state[run, scan, j], pl.Float64) for j, n in enumerate(names)]
    pos = _fixed_grid(dataset, _SENSORS, "position_m", shape)
    if pos.ndim != 4 or pos.shape[3] != 2:
        raise InputError(f"{_SENSORS} position_m must be (S, 2) per frame", dataset.path)
    vel = _fixed_grid(dataset, _SENSORS, "velocity_mps", shape, pos.shape[2:])
    S = pos.shape[2]
    srun = np.repeat(np.arange(R), K * S)
    sscan = np.tile(np.repeat(np.arange(K), S), R)
    sensor = np.tile(np.arange(S), R * K)
    sensors = pl.DataFrame([pl.Series("run", srun, pl.Int64), pl.Series("time_s", times[sscan], pl.Float64),
                            pl.Series("sensor", sensor, pl.Int64),
                            pl.Series("x_m", pos[srun, sscan, sensor, 0], pl.Float64),
                            pl.Series("y_m", pos[srun, sscan, sensor, 1], pl.Float64),
                            pl.Series("vx_mps", vel[srun, sscan, sensor, 0], pl.Float64),
                            pl.Series("vy_mps", vel[srun, sscan, sensor, 1], pl.Float64)])
    return {"measurements": pl.DataFrame(cols), "sensors": sensors}


def export_colored_positions(dataset) -> dict:
    """A data set's positions (truth, AR coefficients) → ``{"measurements": DataFrame}``: a row per
    run and time."""
    ch = dataset.channel(_COLORED)
    shape = (ch.n_runs, ch.n_scans)
    z = _fixed_grid(dataset, _COLORED, "position_m", shape)
    if z.ndim == 2:
        z = z[..., None]
    if z.ndim != 3 or not 1 <= z.shape[2] <= len(AXES):
        raise InputError(f"{_COLORED} position_m must hold 1 to {len(AXES)} axes per frame for a table", dataset.path)
    axes = AXES[: z.shape[2]]
    times = _times(dataset, ch)
    R, K = shape
    run, scan = np.repeat(np.arange(R), K), np.tile(np.arange(K), R)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64)]
    cols += [pl.Series(f"{a}_m", z[run, scan, j], pl.Float64) for j, a in enumerate(axes)]
    truth = dataset.channels.get(_COLORED_TRUTH)
    if truth is not None and "state" in truth.arrays:
        state = _fixed_grid(dataset, _COLORED_TRUTH, "state", shape, (3 * len(axes),))
        for j, a in enumerate(axes):
            for c, n in enumerate((f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2")):
                cols.append(pl.Series(n, state[run, scan, 3 * j + c], pl.Float64))
        if "alpha" in truth.arrays:
            alpha = _fixed_grid(dataset, _COLORED_TRUTH, "alpha", shape)
            if alpha.ndim == 2:
                alpha = alpha[..., None]
            if alpha.shape[2:] != (len(axes),):
                raise InputError(f"{_COLORED_TRUTH} alpha has frames of shape {alpha.shape[2:]}, expected "
                                 f"({len(axes)},)", dataset.path)
            cols += [pl.Series(f"truth_alpha_{a}", alpha[run, scan, j], pl.Float64) for j, a in enumerate(axes)]
    return {"measurements": pl.DataFrame(cols)}


def write_table(df: pl.DataFrame, path, fmt: str) -> None:
    """Write a table atomically as ``csv`` or ``parquet`` (floats written so they read back
    exactly)."""
    from trackreplay.contract import atomic_output

    if fmt not in ("csv", "parquet"):
        raise InputError(f"unknown table format {fmt!r} (csv or parquet)")
    with atomic_output(path) as f:
        if fmt == "csv":
            df.write_csv(f)
        else:
            df.write_parquet(f)
