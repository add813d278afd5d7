"""Each family's table rows → the arrays its simulator builds, with the rules of that family
(``docs/importers.md``, one section per family): which rows form a scan, what truth and prior
the table may carry, what is refused.

One reader per family, named in the family's entry of
:data:`trackreplay.recorders.table_formats.TABLE_FORMATS` and called by
:func:`trackreplay.recorders.tables.dataset_from_table` with the table (and the sensors table
of tdoa-fdoa) as :class:`~trackreplay.recorders.table_rows._Rows`. The rules every table follows
are in :mod:`trackreplay.recorders.table_rows`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.recorders.simulated import SimulatedData
from trackreplay.recorders.table_rows import (
    _COLORED, _COLORED_TRUTH, _EMITTER_TRUTH, _MEAS, _PEAK_RATE, _PEAK_TRUTH, _PEAKS, _PLOTS, _PRIOR, _PRIOR_XY,
    _RADAR_TRUTH, _SENSORS, _TRUTH_XY, _XCORR_TRUTH, AXES, MAX_SENSORS, _group_of, _markers, _n, _per_scan, _ragged,
    _require_every_scan, _require_min_scans, _Rows, _Scans, _scans)


def read_radar_plots(t: _Rows) -> SimulatedData:
    """A radar-plots table → the plots (range, bearing) of every scan and, with the truth columns,
    the truth: one state a scan, or with ``truth_id`` a set of targets (:func:`_radar_truth_set`)."""
    t.require(("time_s", "time"), "range_m", ("bearing_deg", "bearing_rad"))
    sc = _scans(t)
    rng, rng_empty = t.floats("range_m")
    brg, brg_empty, bname = t.angle("bearing_rad")
    # a long table of many targets has rows of truth alone, any number in a scan
    marker = _markers(t, sc, {"range_m": rng_empty, bname: brg_empty}, "plot", several=t.has("truth_id"))
    plot = ~marker
    spec = vocab.VALUES["radar_plots"]
    t.within("range_m", rng, spec["range_m"], plot)
    t.within(bname, brg, spec["bearing_rad"], plot)
    arrays, counts = _ragged(sc, plot, {"range_m": (rng, np.nan, np.float64), "bearing_rad": (brg, np.nan, np.float64)})
    data = SimulatedData(times=sc.times, ragged={_PLOTS: (arrays, counts)})
    _require_min_scans(t, sc)
    if t.has("truth_id"):
        return _radar_truth_set(t, sc, data, plot)
    if _group_of(t, _TRUTH_XY, "truth"):
        values = [t.filled(n) for n in _TRUTH_XY]
        for n, v in zip(_TRUTH_XY, values):
            t.within(n, v, vocab.VALUES["radar_truth"]["state"])
        _require_every_scan(t, sc, np.bincount(sc.key, minlength=sc.n_runs * sc.n_scans),
                            "with truth columns every run needs a row at every scan time; a row with range and "
                            "bearing empty marks a scan without plots")
        state = _per_scan(t, sc, list(_TRUTH_XY), values)
        data.fixed[_RADAR_TRUTH] = {"state": state.reshape(sc.n_runs, sc.n_scans, 4)}
    return data


def _radar_truth_set(t: _Rows, sc: _Scans, data: SimulatedData, plot: np.ndarray) -> SimulatedData:
    """Truth as a set of targets per scan from a long table with ``truth_id``: each row naming a
    target gives its state at that scan; a plot on such a row came from it (``origin``), a plot on
    a row without one from no known target (−1)."""
    named = ~t.floats("truth_id")[1]
    ident = t.integers("truth_id", 0, vocab.VALUES["radar_truth"]["target_id"].high, "target identities",
                       rows_mask=named)
    values = []
    for n in _TRUTH_XY:
        v, empty = t.floats(n)
        gap = named & empty
        if gap.any():
            i = int(np.argmax(gap))
            raise t.error(f"column {n!r} is empty at data row {t.row(i)}, which names target {ident[i]} (a row with "
                          "truth_id gives all four truth columns)")
        stray = ~named & ~empty
        if stray.any():
            i = int(np.argmax(stray))
            raise t.error(f"column {n!r} holds a value at data row {t.row(i)}, which names no target (truth_id is "
                          "empty)")
        t.within(n, v, vocab.VALUES["radar_truth"]["state"], named)
        values.append(v)
    rows = np.flatnonzero(named)
    # one entry per (run, scan, target): rows repeating a target in its scan must agree
    key = (sc.key[rows] * (int(ident[rows].max(initial=0)) + 1) + ident[rows]) if rows.size else rows
    order = np.argsort(key, kind="stable")
    first = np.r_[True, key[order][1:] != key[order][:-1]] if rows.size else np.zeros(0, bool)
    for j, (name, v) in enumerate(zip(_TRUTH_XY, values)):
        vs = v[rows][order]
        differ = ~first[1:] & (vs[1:] != vs[:-1]) if rows.size else np.zeros(0, bool)
        if differ.any():
            p = int(np.argmax(differ))
            a, b = int(rows[order][p]), int(rows[order][p + 1])
            raise t.error(f"column {name!r} differs between data rows {t.row(a)} and {t.row(b)}, which give target "
                          f"{ident[a]} at {sc.where(sc.run[a], sc.scan[a])}; a target has one state a scan")
    unique = np.zeros(t.n, bool)
    unique[rows[order][first]] = True
    state = np.stack(values, axis=-1)
    arrays, counts = _ragged(sc, unique, {"state": (state, np.nan, np.float64), "target_id": (ident, -1, np.int64)})
    # targets in identity order within each scan, as the simulator writes them
    by_id = np.argsort(np.where(arrays["target_id"] >= 0, arrays["target_id"], np.iinfo(np.int64).max), axis=-1,
                       kind="stable")
    arrays = {"state": np.take_along_axis(arrays["state"], by_id[..., None], axis=2),
              "target_id": np.take_along_axis(arrays["target_id"], by_id, axis=2)}
    data.ragged[_RADAR_TRUTH] = (arrays, counts)
    origin = np.where(named, ident, -1)
    plots, plot_counts = data.ragged[_PLOTS]
    extra, _ = _ragged(sc, plot, {"origin": (origin, -1, np.int64)})
    data.ragged[_PLOTS] = ({**plots, "origin": extra["origin"]}, plot_counts)
    return data


def _peak_truth_columns(t: _Rows) -> tuple[list[str], list[str]]:
    """Canonical (radian) names of the truth bearing and rate columns, targets 0 … N−1."""
    found = {}
    for c in t.df.columns:
        for kind, pattern in (("bearing", _PEAK_TRUTH), ("rate", _PEAK_RATE)):
            m = pattern.match(c)
            if m:
                found.setdefault(kind, set()).add(int(m.group(1)))
    targets = sorted(found.get("bearing", ()))
    if targets and targets != list(range(len(targets))):
        raise t.error(f"truth bearing columns for targets {targets}: number the targets 0, 1, … without gaps")
    rates = sorted(found.get("rate", ()))
    if rates and rates != targets:
        raise t.error(f"truth bearing rate columns for targets {rates} but bearings for {targets}: give the rate of "
                      "every target or of none")
    return ([f"truth{i}_bearing_rad" for i in targets], [f"truth{i}_bearing_rate_radps" for i in rates])


def read_bearing_peaks(t: _Rows) -> SimulatedData:
    """A bearing-peaks table → the peaks (bearing, amplitude, origin) of every scan and, with the
    truth columns, each target's true bearing (and rate) a scan."""
    t.require(("time_s", "time"), ("bearing_deg", "bearing_rad"), "amplitude")
    sc = _scans(t)
    brg, brg_empty, bname = t.angle("bearing_rad")
    amp, amp_empty = t.floats("amplitude")
    empties = {bname: brg_empty, "amplitude": amp_empty}
    if t.has("origin"):
        empties["origin"] = t.floats("origin")[1]
    marker = _markers(t, sc, empties, "peak")
    peak = ~marker
    spec = vocab.VALUES["xcorr_peaks"]
    t.within(bname, brg, spec["bearing_rad"], peak)
    t.within("amplitude", amp, spec["amplitude"], peak)
    origin = (t.integers("origin", -1, int(spec["origin"].high), "origins are target indices or −1", peak)
              if t.has("origin") else np.full(t.n, -1, np.int64))
    arrays, counts = _ragged(sc, peak, {"bearing_rad": (brg, np.nan, np.float64),
                                        "amplitude": (amp, np.nan, np.float64),
                                        "origin": (origin, -1, np.int32)})
    data = SimulatedData(times=sc.times, ragged={_PEAKS: (arrays, counts)})
    _require_min_scans(t, sc)
    bearings, rates = _peak_truth_columns(t)
    if bearings:
        _require_every_scan(t, sc, np.bincount(sc.key, minlength=sc.n_runs * sc.n_scans),
                            "with truth columns every run needs a row at every scan time; a row with bearing and "
                            "amplitude empty marks a scan without peaks")
        truth = {}
        for array, names in (("bearing_rad", bearings), ("bearing_rate_radps", rates)):
            if not names:
                continue
            values, given_names = [], []
            for n in names:
                v, empty, given = t.angle(n)
                if empty.any():
                    raise t.error(f"column {given!r} is empty at data row {t.row(np.argmax(empty))}")
                t.within(given, v, vocab.VALUES["xcorr_truth"][array])
                values.append(v)
                given_names.append(given)
            truth[array] = _per_scan(t, sc, given_names, values).reshape(sc.n_runs, sc.n_scans, len(names))
        data.fixed[_XCORR_TRUTH] = truth
    return data


def read_tdoa_fdoa(t: _Rows, s: _Rows | None) -> SimulatedData:
    """A tdoa-fdoa table and its sensors table → the measurements of every epoch (one pair list),
    the sensors' positions and velocities (:func:`_sensors`) and, with their columns, the
    emitter's truth and the prior fix."""
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
    data = SimulatedData(times=sc.times, fixed={_MEAS: meas})
    data.fixed[_SENSORS] = _sensors(s, sc, a, b, t)
    for names, topic, what, value_key in ((_TRUTH_XY, _EMITTER_TRUTH, "truth", "emitter_truth"),
                                          (_PRIOR_XY, _PRIOR, "prior", "emitter_prior")):
        if _group_of(t, names, what):
            vals = [t.filled(n) for n in names]
            for n, v in zip(names, vals):
                t.within(n, v, vocab.VALUES[value_key]["state"])
            data.fixed[topic] = {"state": _per_scan(t, sc, list(names), vals).reshape(sc.n_runs, sc.n_scans, 4)}
    return data


def _place(values: np.ndarray, cell: np.ndarray, size: int) -> np.ndarray:
    out = np.full(size, np.nan)
    out[cell] = values
    return out


def _sensors(s: _Rows, msc: _Scans, a: np.ndarray, b: np.ndarray, t: _Rows) -> dict:
    """The sensors table → ``position_m``, ``velocity_mps`` (runs, epochs, S, 2) on the
    measurement table's epochs (``msc``), checked against the pairs' sensors ``a``, ``b``."""
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


def read_colored_positions(t: _Rows) -> SimulatedData:
    """A positions table → the measured position (1 to 3 axes) at every time and, with the truth
    columns, the true state (position, velocity, acceleration) and AR(1) coefficient per axis."""
    t.require(("time_s", "time"), "x_m")
    if t.has("z_m") and not t.has("y_m"):
        raise t.error("column 'z_m' without 'y_m': the axes are x, y, z in order")
    axes = [a for a in AXES if t.has(f"{a}_m")]
    for a in AXES:
        if a not in axes and any(t.has(n) for n in (f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2",
                                                    f"truth_alpha_{a}")):
            raise t.error(f"truth columns for the axis {a} but no '{a}_m' measurements")
    sc = _scans(t)
    per = np.bincount(sc.key, minlength=sc.n_runs * sc.n_scans)
    if per.max() > 1:
        order = np.argsort(sc.key, kind="stable")
        ks = sc.key[order]
        p = int(np.flatnonzero(ks[1:] == ks[:-1])[0])
        i, j = int(order[p]), int(order[p + 1])
        raise t.error(f"{sc.where(sc.run[j], sc.scan[j])} on data rows {t.row(i)} and {t.row(j)}: one row per run "
                      "and time (duplicated time)")
    _require_every_scan(t, sc, per, "every run has a row at every time")
    shape = (sc.n_runs, sc.n_scans)
    order = sc.key  # one row per (run, scan)
    spec = vocab.VALUES["colored_measurements"]["position_m"]

    def grid(values):
        out = np.empty(sc.n_runs * sc.n_scans)
        out[order] = values
        return out.reshape(shape)

    z = []
    for a in axes:
        v = t.filled(f"{a}_m")
        t.within(f"{a}_m", v, spec)
        z.append(grid(v))
    data = SimulatedData(times=sc.times, fixed={_COLORED: {"position_m": np.stack(z, axis=-1)}})
    _require_min_scans(t, sc)
    dt = np.diff(sc.times)
    if not (dt[0] > 0 and np.all(np.abs(dt - dt[0]) <= 1e-9 * max(abs(dt[0]), 1.0))):
        k = int(np.argmax(np.abs(dt - dt[0]) > 1e-9 * max(abs(dt[0]), 1.0)))
        raise t.error(f"the times are not evenly spaced: step {_n(dt[k])} s after {_n(sc.times[k])} s, but "
                      f"{_n(dt[0])} s at first (the filters step at one period)")
    groups = [(f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2") for a in axes]
    given = [_group_of(t, g, f"the axis {a}'s truth") for a, g in zip(axes, groups)]
    alphas = [f"truth_alpha_{a}" for a in axes]
    have_alpha = [t.has(n) for n in alphas]
    if any(given) and not all(given):
        raise t.error(f"truth for the axis {axes[given.index(False)]} is missing: give the truth of every axis or "
                      "of none")
    if any(have_alpha) and not all(given):
        raise t.error("truth_alpha columns need the truth state columns (truth_<axis>_m, truth_v<axis>_mps, "
                      "truth_a<axis>_mps2)")
    if all(given):
        tspec = vocab.VALUES["colored_truth"]
        cols = []
        for g in groups:
            for n in g:
                v = t.filled(n)
                t.within(n, v, tspec["state"])
                cols.append(grid(v))
        truth = {"state": np.stack(cols, axis=-1)}
        if any(have_alpha):
            if not all(have_alpha):
                raise t.error(f"missing column {alphas[have_alpha.index(False)]!r}: the AR coefficient of every axis "
                              "or of none")
            cols = []
            for n in alphas:
                v = t.filled(n)
                t.within(n, v, tspec["alpha"])
                cols.append(grid(v))
            truth["alpha"] = np.stack(cols, axis=-1)
        data.fixed[_COLORED_TRUTH] = truth
    return data
