"""The TDOA/FDOA family's tables (``docs/importers.md``, "TDOA/FDOA measurements"): one row per
sensor pair of a measurement epoch, and a second table of the sensors' positions and velocities
per epoch; their format (:data:`FORMAT`: columns, notes, ``replay convert tdoa-fdoa … --sensors``,
samples), the reader of both (:func:`read_tdoa_fdoa`), the exporter (:func:`export_tdoa_fdoa`)
and what the data imply when the table has no prior fix (:func:`grid_start_without_prior`).

The measurement model and the localisation: ``docs/papers/tdoa-fdoa.md``. numpy, polars and the
shared table helpers are imported by the functions that use them: ``replay --help`` lists the
convert commands from :data:`FORMAT` without them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.recorders.table_formats import RUN, TRUTH_XY, TableColumn, TableFormat, truth_xy_columns

if TYPE_CHECKING:
    import numpy as np

    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import _Rows, _Scans

MEASUREMENTS, SENSORS = vocab.CHANNELS["emitter_measurements"], vocab.CHANNELS["emitter_sensors"]
PRIOR, TRUTH = vocab.CHANNELS["emitter_prior"], vocab.CHANNELS["emitter_truth"]
PRIOR_XY = ("prior_x_m", "prior_y_m", "prior_vx_mps", "prior_vy_mps")
MAX_SENSORS = 1 << 16  # the contract's bound on a pair's sensor index


def read_tdoa_fdoa(t: _Rows, s: _Rows | None) -> SimulatedData:
    """A tdoa-fdoa table and its sensors table → the measurements of every epoch (one pair list),
    the sensors' positions and velocities (:func:`_sensors`) and, with their columns, the
    emitter's truth and the prior fix."""
    import numpy as np

    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import (_group_of, _per_scan, _require_every_scan, _require_min_scans,
                                                  _scans)

    t.require(("time_s", "time"), "sensor_a", "sensor_b", "tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz",
              "carrier_hz")
    if s is None:
        raise t.error("a tdoa-fdoa table needs its sensors table (replay convert tdoa-fdoa FILE --sensors SENSORS)")
    sc = _scans(t)
    spec = vocab.VALUES["emitter_measurements"]
    hi = MAX_SENSORS - 1
    a = t.integers("sensor_a", 0, hi, "sensor indices count from 0")
    b = t.integers("sensor_b", 0, hi, "sensor indices count from 0")
    same = a == b
    if same.any():
        i = int(np.argmax(same))
        raise t.error(f"data row {t.row(i)} pairs sensor {a[i]} with itself")
    values = {}
    for name in ("tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz", "carrier_hz"):
        values[name] = t.filled(name)
        t.within(name, values[name], spec[name], positive=name.startswith("sigma") or name == "carrier_hz")
    size = sc.n_runs * sc.n_scans
    key = sc.key
    # the pair list of the first epoch (run 0, first time), in file order, is the file's
    first = np.flatnonzero(key == 0)
    if first.size == 0:
        raise t.error(f"no row for {sc.where(0, 0)} (every run lists every epoch)")
    ref = list(zip(a[first].tolist(), b[first].tolist()))
    seen = {}
    for row, (i, j) in zip(first, ref):
        u = (min(i, j), max(i, j))
        if u in seen:
            raise t.error(f"pair {i}–{j} repeated in {sc.where(0, 0)} (data rows {t.row(seen[u])} and {t.row(row)})")
        seen[u] = row
    code = a * MAX_SENSORS + b
    ref_code = np.array([i * MAX_SENSORS + j for i, j in ref], np.int64)
    sorter = np.argsort(ref_code)
    pos = np.searchsorted(ref_code, code, sorter=sorter)
    pos = sorter[np.minimum(pos, ref_code.size - 1)]
    foreign = ref_code[pos] != code
    if foreign.any():
        i = int(np.argmax(foreign))
        listed = ", ".join(f"{p}–{q}" for p, q in ref)
        raise t.error(f"pair {a[i]}–{b[i]} at data row {t.row(i)} ({sc.where(sc.run[i], sc.scan[i])}) is not among "
                      f"the pairs of the first epoch ({listed}): every epoch lists the same pairs")
    P = len(ref)
    cell = key * P + pos
    dup = np.bincount(cell, minlength=size * P)
    if dup.max() > 1:
        order = np.argsort(cell, kind="stable")
        cs = cell[order]
        p = int(np.flatnonzero(cs[1:] == cs[:-1])[0])
        i, j = int(order[p]), int(order[p + 1])
        raise t.error(f"pair {a[j]}–{b[j]} repeated in {sc.where(sc.run[j], sc.scan[j])} (data rows {t.row(i)} and "
                      f"{t.row(j)}; duplicated (run, time, pair))")
    per = np.bincount(key, minlength=size)
    _require_every_scan(t, sc, per, "every run lists every epoch")
    short = per < P
    if short.any():
        c = int(np.argmax(short))
        have = {int(v) for v in pos[key == c]}
        lacking = next(q for q in range(P) if q not in have)
        raise t.error(f"{sc.where(*divmod(c, sc.n_scans))} lacks the pair {ref[lacking][0]}–{ref[lacking][1]} "
                      "(every epoch lists the same pairs)")
    _require_min_scans(t, sc)
    grid = lambda v: _place(v, cell, size * P).reshape(sc.n_runs, sc.n_scans, P)  # noqa: E731
    shared = ["carrier_hz"]
    carrier = _per_scan(t, sc, shared, [values["carrier_hz"]]).reshape(sc.n_runs, sc.n_scans)
    pairs = np.broadcast_to(np.array(ref, np.int32), (sc.n_runs, sc.n_scans, P, 2))
    meas = {"tdoa_s": grid(values["tdoa_s"]), "fdoa_hz": grid(values["fdoa_hz"]),
            "sigma_tdoa_s": grid(values["sigma_tdoa_s"]), "sigma_fdoa_hz": grid(values["sigma_fdoa_hz"]),
            "pairs": pairs, "carrier_hz": carrier}
    data = SimulatedData(times=sc.times, fixed={MEASUREMENTS: meas})
    data.fixed[SENSORS] = _sensors(s, sc, a, b, t)
    for names, topic, what, value_key in ((TRUTH_XY, TRUTH, "truth", "emitter_truth"),
                                          (PRIOR_XY, PRIOR, "prior", "emitter_prior")):
        if _group_of(t, names, what):
            vals = [t.filled(n) for n in names]
            for n, v in zip(names, vals):
                t.within(n, v, vocab.VALUES[value_key]["state"])
            data.fixed[topic] = {"state": _per_scan(t, sc, list(names), vals).reshape(sc.n_runs, sc.n_scans, 4)}
    return data


def _place(values: np.ndarray, cell: np.ndarray, size: int) -> np.ndarray:
    import numpy as np

    out = np.full(size, np.nan)
    out[cell] = values
    return out


def _sensors(s: _Rows, msc: _Scans, a: np.ndarray, b: np.ndarray, t: _Rows) -> dict:
    """The sensors table → ``position_m``, ``velocity_mps`` (runs, epochs, S, 2) on the
    measurement table's epochs (``msc``), checked against the pairs' sensors ``a``, ``b``."""
    import numpy as np

    from trackreplay.recorders.table_rows import _n, _scans

    s.require(("time_s", "time"), "sensor", "x_m", "y_m", "vx_mps", "vy_mps")
    sc = _scans(s)
    if sc.n_runs != msc.n_runs:
        raise s.error(f"{sc.n_runs} run(s), but the measurement table {Path(str(t.path)).name} has {msc.n_runs}")
    sensor = s.integers("sensor", 0, MAX_SENSORS - 1, "sensor indices count from 0")
    # the sensors' times must be the measurement epochs
    k = np.searchsorted(msc.times, sc.times)
    inside = k < msc.n_scans
    match = np.zeros(sc.n_scans, bool)
    match[inside] = msc.times[k[inside]] == sc.times[inside]
    if not match.all():
        extra = int(np.argmax(~match))
        i = int(np.argmax(sc.scan == extra))
        raise s.error(f"time {_n(sc.times[extra])} s at data row {s.row(i)} is not an epoch of the measurement table")
    scan = k[sc.scan]
    S = int(sensor.max()) + 1
    size = msc.n_runs * msc.n_scans
    cell = (sc.run * msc.n_scans + scan) * S + sensor
    dup = np.bincount(cell, minlength=size * S)
    if dup.max() > 1:
        order = np.argsort(cell, kind="stable")
        cs = cell[order]
        p = int(np.flatnonzero(cs[1:] == cs[:-1])[0])
        i, j = int(order[p]), int(order[p + 1])
        raise s.error(f"sensor {sensor[j]} listed twice for {msc.where(sc.run[j], scan[j])} (data rows {s.row(i)} and "
                      f"{s.row(j)}; duplicated (run, time, sensor))")
    missing = dup.reshape(size, S) == 0
    if missing.any():
        c, q = (int(v[0]) for v in np.nonzero(missing))
        r, e = divmod(c, msc.n_scans)
        lacking = "no rows" if missing[c].all() else f"no row for sensor {q}"
        raise s.error(f"{lacking} for {msc.where(r, e)} (every epoch lists sensors 0 … {S - 1})")
    unlisted = (a >= S) | (b >= S)
    if unlisted.any():
        i = int(np.argmax(unlisted))
        raise t.error(f"data row {t.row(i)} names sensor {max(a[i], b[i])}, but the sensors table "
                      f"{Path(str(s.path)).name} lists sensors 0 … {S - 1} (bad sensor index)")
    spec = vocab.VALUES["emitter_sensors"]
    out = {}
    for array, names in (("position_m", ("x_m", "y_m")), ("velocity_mps", ("vx_mps", "vy_mps"))):
        cols = []
        for n in names:
            v = s.filled(n)
            s.within(n, v, spec[array])
            cols.append(_place(v, cell, size * S).reshape(msc.n_runs, msc.n_scans, S))
        out[array] = np.stack(cols, axis=-1)
    return out


def export_tdoa_fdoa(dataset) -> dict:
    """A data set's TDOA/FDOA measurements (truth, prior) and sensors → ``{"measurements": ...,
    "sensors": ...}``: a row per pair and epoch, a row per sensor and epoch."""
    import numpy as np
    import polars as pl

    from trackreplay.recorders.table_exporters import _fixed_grid, _times

    ch = dataset.channel(MEASUREMENTS)
    shape = (ch.n_runs, ch.n_scans)
    times = _times(dataset, ch)
    pairs_all = _fixed_grid(dataset, MEASUREMENTS, "pairs", shape)
    if pairs_all.ndim != 4 or pairs_all.shape[3] != 2:
        raise InputError(f"{MEASUREMENTS} pairs must be (P, 2) per frame", dataset.path)
    pairs = pairs_all[0, 0].astype(np.int64)
    if np.any(pairs_all != pairs):
        raise InputError(f"{MEASUREMENTS} pairs change between frames: a table lists one pair list", dataset.path)
    P = pairs.shape[0]
    values = {n: _fixed_grid(dataset, MEASUREMENTS, n, shape, (P,))
              for n in ("tdoa_s", "fdoa_hz", "sigma_tdoa_s", "sigma_fdoa_hz")}
    carrier = _fixed_grid(dataset, MEASUREMENTS, "carrier_hz", shape, ())
    R, K = shape
    run = np.repeat(np.arange(R), K * P)
    scan = np.tile(np.repeat(np.arange(K), P), R)
    q = np.tile(np.arange(P), R * K)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            pl.Series("sensor_a", pairs[q, 0], pl.Int64), pl.Series("sensor_b", pairs[q, 1], pl.Int64)]
    cols += [pl.Series(n, v[run, scan, q], pl.Float64) for n, v in values.items()]
    cols.append(pl.Series("carrier_hz", carrier[run, scan], pl.Float64))
    for names, topic in ((TRUTH_XY, TRUTH), (PRIOR_XY, PRIOR)):
        if topic in dataset.channels:
            state = _fixed_grid(dataset, topic, "state", shape, (4,))
            cols += [pl.Series(n, state[run, scan, j], pl.Float64) for j, n in enumerate(names)]
    pos = _fixed_grid(dataset, SENSORS, "position_m", shape)
    if pos.ndim != 4 or pos.shape[3] != 2:
        raise InputError(f"{SENSORS} position_m must be (S, 2) per frame", dataset.path)
    vel = _fixed_grid(dataset, SENSORS, "velocity_mps", shape, pos.shape[2:])
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


def grid_start_without_prior(data: SimulatedData, params: dict) -> tuple[dict, list]:
    """Without prior columns the replay starts Gauss-Newton from a coarse grid search: recorded
    as ``initial_guess = "grid"`` (from the data) unless the user said otherwise."""
    if PRIOR in data.fixed or "initial_guess" in params:
        return {}, []
    return {"initial_guess": "grid"}, ["no prior columns: recorded initial_guess=grid (Gauss-Newton starts from a "
                                       "coarse grid search)"]


#: the TDOA/FDOA family's table format
FORMAT = TableFormat(
    "tdoa-fdoa", "tdoa-fdoa", "tdoa_fdoa", "one row per sensor pair of a measurement epoch",
    {"measurements": (
        RUN, TableColumn("time_s | time", "s", True, "epoch time; the rows of one run and time form one epoch"),
        TableColumn("sensor_a", "index", True, "first sensor of the pair (a sensor of the sensors table, from 0)"),
        TableColumn("sensor_b", "index", True, "second sensor of the pair"),
        TableColumn("tdoa_s", "s", True, "time difference of arrival (r_a − r_b)/c"),
        TableColumn("fdoa_hz", "Hz", True, "frequency difference of arrival f₀(ṙ_a − ṙ_b)/c"),
        TableColumn("sigma_tdoa_s", "s", True, "standard deviation of the TDOA, > 0"),
        TableColumn("sigma_fdoa_hz", "Hz", True, "standard deviation of the FDOA, > 0"),
        TableColumn("carrier_hz", "Hz", True, "the emitter's carrier f₀, > 0; the same on every row of an epoch"),
        *truth_xy_columns("true emitter"),
        TableColumn("prior_x_m", "m", False,
                    "a coarse fix Gauss-Newton may start from (initial_guess=prior); the same on every row "
                    "of an epoch; all four prior columns or none (without them the replay starts from a "
                    "grid search: initial_guess=grid)"),
        TableColumn("prior_y_m", "m", False, "the fix's y"),
        TableColumn("prior_vx_mps", "m/s", False, "the fix's x velocity"),
        TableColumn("prior_vy_mps", "m/s", False, "the fix's y velocity"),
     ),
     "sensors": (
        RUN, TableColumn("time_s | time", "s", True, "epoch time (the measurement table's epochs)"),
        TableColumn("sensor", "index", True, "sensor index, 0 … S−1 in every epoch"),
        TableColumn("x_m", "m", True, "sensor position x"),
        TableColumn("y_m", "m", True, "sensor position y"),
        TableColumn("vx_mps", "m/s", True, "sensor velocity x"),
        TableColumn("vy_mps", "m/s", True, "sensor velocity y"),
     )},
    ("Every epoch lists the same pairs (in any order; the first epoch's order is kept) and the sensors "
     "table lists every sensor once per epoch.",
     "Refused: a pair of a sensor with itself or repeated in an epoch, a sensor index the sensors table "
     "does not list, σ or carrier ≤ 0, an epoch missing from either table, a duplicated (run, time, "
     "sensor) or (run, time, pair), values that disagree within an epoch."),
    min_scans=1, read=read_tdoa_fdoa, export=export_tdoa_fdoa,
    title="TDOA/FDOA measurements", item_word="pair measurements",
    samples={"measurements": "tdoa_fdoa.csv", "sensors": "tdoa_fdoa_sensors.csv"},
    table_help={"sensors": "The sensors table (.csv or .parquet): positions and velocities per epoch."},
    data_values=grid_start_without_prior)
