"""The radar family's table (``docs/importers.md``, "Radar plots"): one row per radar plot
(range, bearing) of a scan, with the truth of one target or, with ``truth_id``, of many; its
format (:data:`FORMAT`: columns, notes, ``replay convert plots``, samples), its reader
(:func:`read_radar_plots`), its exporter (:func:`export_radar_plots`) and what a foreign MCAP's
mapping of it may add (a ``[truth]`` list of targets; a message without plots is a scan).

The radar and its trackers: ``docs/papers/radar.md``. numpy, polars and the shared table
helpers are imported by the functions that use them: ``replay --help`` lists the convert
commands from :data:`FORMAT` without them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from trackreplay import vocabulary as vocab
from trackreplay.recorders.table_formats import RUN, TIME, TRUTH_XY, TableColumn, TableFormat, truth_xy_columns

if TYPE_CHECKING:
    import numpy as np

    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import _Rows, _Scans

PLOTS, TRUTH = vocab.CHANNELS["radar_plots"], vocab.CHANNELS["radar_truth"]


def read_radar_plots(t: _Rows) -> SimulatedData:
    """A radar table → the plots (range, bearing) of every scan and, with the truth columns,
    the truth: one state a scan, or with ``truth_id`` a set of targets (:func:`_radar_truth_set`)."""
    import numpy as np

    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import (_group_of, _markers, _per_scan, _ragged, _require_every_scan,
                                                  _require_min_scans, _scans)

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
    data = SimulatedData(times=sc.times, ragged={PLOTS: (arrays, counts)})
    _require_min_scans(t, sc)
    if t.has("truth_id"):
        return _radar_truth_set(t, sc, data, plot)
    if _group_of(t, TRUTH_XY, "truth"):
        values = [t.filled(n) for n in TRUTH_XY]
        for n, v in zip(TRUTH_XY, values):
            t.within(n, v, vocab.VALUES["radar_truth"]["state"])
        _require_every_scan(t, sc, np.bincount(sc.key, minlength=sc.n_runs * sc.n_scans),
                            "with truth columns every run needs a row at every scan time; a row with range and "
                            "bearing empty marks a scan without plots")
        state = _per_scan(t, sc, list(TRUTH_XY), values)
        data.fixed[TRUTH] = {"state": state.reshape(sc.n_runs, sc.n_scans, 4)}
    return data


def _radar_truth_set(t: _Rows, sc: _Scans, data: SimulatedData, plot: np.ndarray) -> SimulatedData:
    """Truth as a set of targets per scan from a long table with ``truth_id``: each row naming a
    target gives its state at that scan; a plot on such a row came from it (``origin``), a plot on
    a row without one from no known target (−1)."""
    import numpy as np

    from trackreplay.recorders.table_rows import _ragged

    named = ~t.floats("truth_id")[1]
    ident = t.integers("truth_id", 0, vocab.VALUES["radar_truth"]["target_id"].high, "target identities",
                       rows_mask=named)
    values = []
    for n in TRUTH_XY:
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
    for j, (name, v) in enumerate(zip(TRUTH_XY, values)):
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
    data.ragged[TRUTH] = (arrays, counts)
    origin = np.where(named, ident, -1)
    plots, plot_counts = data.ragged[PLOTS]
    extra, _ = _ragged(sc, plot, {"origin": (origin, -1, np.int64)})
    data.ragged[PLOTS] = ({**plots, "origin": extra["origin"]}, plot_counts)
    return data


def export_radar_plots(dataset) -> dict:
    """A data set's radar plots (and truth) → ``{"measurements": DataFrame}``: a row per plot, a row
    with range and bearing empty per scan without plots."""
    import polars as pl

    from trackreplay.recorders.table_exporters import _fixed_grid, _frames_to_rows, _ragged_column, _series, _times

    ch = dataset.channel(PLOTS)
    rng, counts = ch.ragged("range_m")
    brg, _ = ch.ragged("bearing_rad")
    times = _times(dataset, ch)
    run, scan, slot, item = _frames_to_rows(counts)
    cols = [pl.Series("run", run, pl.Int64), pl.Series("time_s", times[scan], pl.Float64),
            _series("range_m", _ragged_column(rng, run, scan, slot, item), item),
            _series("bearing_rad", _ragged_column(brg, run, scan, slot, item), item)]
    if TRUTH in dataset.channels:
        state = _fixed_grid(dataset, TRUTH, "state", counts.shape, (4,))
        cols += [pl.Series(n, state[run, scan, j], pl.Float64) for j, n in enumerate(TRUTH_XY)]
    return {"measurements": pl.DataFrame(cols)}


#: the radar family's table format
FORMAT = TableFormat(
    "radar", "plots", "radar_plots", "one row per radar plot (range, bearing) of a scan",
    {"measurements": (
        RUN, TIME,
        TableColumn("range_m", "m", True, "plot range, ≥ 0"),
        TableColumn("bearing_rad | bearing_deg", "rad | °", True,
                    "plot bearing, counter-clockwise from +x (x = r cos θ, y = r sin θ)"),
        *truth_xy_columns("true target"),
        TableColumn("truth_id", "index", False,
                    "identity of the target the row's truth columns describe (many targets: a long "
                    "table, one row per plot and per target; a plot on the same row came from it)"),
    )},
    ("Several rows of one run and time are several plots of that scan.",
     "With truth_id, the truth is a set of targets per scan: every row naming a target gives its state "
     "(the same on every row of that target and scan); rows with range and bearing empty carry truth "
     "alone, rows with the truth columns empty a plot alone (clutter, or of no known target).",
     "A row with range and bearing both empty marks a scan without plots (it may carry the truth); "
     "it may not share its scan with plots or with another such row.",
     "Refused: a negative range; a scan whose truth columns disagree between rows; with truth, a run "
     "without a row at one of the scan times; fewer than 3 scans."),
    min_scans=3, read=read_radar_plots, export=export_radar_plots,
    aliases=("plots-csv",), title="Radar plots", item_word="plots", samples={"measurements": "radar_plots.csv"},
    sample_sensor_values={"sigma_range_m": 100, "sigma_bearing_deg": 1, "scan_period_s": 5},
    # a row (or a foreign message with an empty list) without range and bearing is a scan without plots
    empty_scan_columns=("range_m", "bearing_rad", "bearing_deg"),
    # a foreign MCAP may carry the truth of many targets as a list of its own, one row per target
    truth_list=("truth_id", *TRUTH_XY))
