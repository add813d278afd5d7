"""The coloured-noise family's table (``docs/importers.md``, "Positions in coloured noise"): one
row per run and time, the measured position on one to three axes, with the true state and the
AR(1) coefficient of each axis's noise; its format (:data:`FORMAT`: columns, notes,
``replay convert positions``, samples), its reader (:func:`read_colored_positions`) and its
exporter (:func:`export_colored_positions`).

The noise model and its filters: ``docs/papers/colored.md``. numpy, polars and the
shared table helpers are imported by the functions that use them: ``replay --help`` lists the
convert commands from :data:`FORMAT` without them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.recorders.table_formats import RUN, TableColumn, TableFormat

if TYPE_CHECKING:
    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import _Rows

MEASUREMENTS, TRUTH = vocab.CHANNELS["colored_measurements"], vocab.CHANNELS["colored_truth"]
AXES = ("x", "y", "z")


def read_colored_positions(t: _Rows) -> SimulatedData:
    """A positions table → the measured position (1 to 3 axes) at every time and, with the truth
    columns, the true state (position, velocity, acceleration) and AR(1) coefficient per axis."""
    import numpy as np

    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import _group_of, _n, _require_every_scan, _require_min_scans, _scans

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
    data = SimulatedData(times=sc.times, fixed={MEASUREMENTS: {"position_m": np.stack(z, axis=-1)}})
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
        data.fixed[TRUTH] = truth
    return data


def export_colored_positions(dataset) -> dict:
    """A data set's positions (truth, AR coefficients) → ``{"measurements": DataFrame}``: a row per
    run and time."""
    import numpy as np
    import polars as pl

    from trackreplay.recorders.table_exporters import _fixed_grid, _times

    ch = dataset.channel(MEASUREMENTS)
    shape = (ch.n_runs, ch.n_scans)
    z = _fixed_grid(dataset, MEASUREMENTS, "position_m", shape)
    if z.ndim == 2:
        z = z[..., None]
    if z.ndim != 3 or not 1 <= z.shape[2] <= len(AXES):
        raise InputError(f"{MEASUREMENTS} position_m must hold 1 to {len(AXES)} axes per frame for a table",
                         dataset.path)
    axes = AXES[: z.shape[2]]
    times = _times(dataset, ch)
    R, K = shape
    run, scan = np.repeat(np.arange(R), K), np.tile(np.arange(K), R)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64)]
    cols += [pl.Series(f"{a}_m", z[run, scan, j], pl.Float64) for j, a in enumerate(axes)]
    truth = dataset.channels.get(TRUTH)
    if truth is not None and "state" in truth.arrays:
        state = _fixed_grid(dataset, TRUTH, "state", shape, (3 * len(axes),))
        for j, a in enumerate(axes):
            for c, n in enumerate((f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2")):
                cols.append(pl.Series(n, state[run, scan, 3 * j + c], pl.Float64))
        if "alpha" in truth.arrays:
            alpha = _fixed_grid(dataset, TRUTH, "alpha", shape)
            if alpha.ndim == 2:
                alpha = alpha[..., None]
            if alpha.shape[2:] != (len(axes),):
                raise InputError(f"{TRUTH} alpha has frames of shape {alpha.shape[2:]}, expected "
                                 f"({len(axes)},)", dataset.path)
            cols += [pl.Series(f"truth_alpha_{a}", alpha[run, scan, j], pl.Float64) for j, a in enumerate(axes)]
    return {"measurements": pl.DataFrame(cols)}


#: the coloured-noise family's table format
FORMAT = TableFormat(
    "colored", "positions", "colored_positions", "one row per position measurement (run and time)",
    {"measurements": (
        RUN, TableColumn("time_s | time", "s", True, "measurement time, evenly spaced"),
        TableColumn("x_m", "m", True, "measured position, first axis"),
        TableColumn("y_m", "m", False, "second axis (a 2-D target)"),
        TableColumn("z_m", "m", False, "third axis (with y_m)"),
        TableColumn("truth_<axis>_m", "m", False,
                    "true position on each axis (truth_x_m, …), for scoring and the thesis's true start"),
        TableColumn("truth_v<axis>_mps", "m/s", False, "true velocity (truth_vx_mps, …)"),
        TableColumn("truth_a<axis>_mps2", "m/s²", False,
                    "true acceleration (truth_ax_mps2, …); the three truth columns of every axis or none"),
        TableColumn("truth_alpha_<axis>", "-", False,
                    "true AR(1) coefficient of the axis's measurement noise, in [−1, 1] (with the truth)"),
    )},
    ("One row per run and time: a duplicated (run, time) is refused.",
     "Refused: uneven time steps, fewer than 4 scans, truth for some axes only."),
    min_scans=4, read=read_colored_positions, export=export_colored_positions,
    extra_names=tuple(n for a in AXES for n in (f"truth_{a}_m", f"truth_v{a}_mps", f"truth_a{a}_mps2",
                                                f"truth_alpha_{a}")),
    title="Positions in coloured noise", item_word="positions", samples={"measurements": "colored_positions.csv"},
    sample_sensor_values={"measurement_variance_m2": 100})
