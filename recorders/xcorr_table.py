"""The cross-correlation family's table (``docs/importers.md``, "Cross-correlation peaks"):
one row per peak (bearing, amplitude, origin) of a scan, with each target's true bearing (and
rate) in numbered columns; its format (:data:`FORMAT`: columns, notes, ``replay convert peaks``,
samples), its reader (:func:`read_bearing_peaks`), its exporter (:func:`export_bearing_peaks`),
the check of the peaks against the sensor's field recorded with them (:func:`check_peak_field`)
and what a foreign MCAP's mapping of it may add (a message without peaks is a scan).

A peak's bearing is θ = arccos(C·D/d) of the cross-correlation delay (``docs/papers/xcorr.md``).
numpy, polars and the shared table helpers are imported by the functions that use them:
``replay --help`` lists the convert commands from :data:`FORMAT` without them.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.recorders.table_formats import RUN, TIME, TableColumn, TableFormat

if TYPE_CHECKING:
    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import _Rows

PEAKS, TRUTH = vocab.CHANNELS["xcorr_peaks"], vocab.CHANNELS["xcorr_truth"]
# the true bearing and bearing rate of target t, one column each per target
PEAK_TRUTH = re.compile(r"^truth(\d+)_bearing_(rad|deg)$")
PEAK_RATE = re.compile(r"^truth(\d+)_bearing_rate_(radps|degps)$")


def _peak_truth_columns(t: _Rows) -> tuple[list[str], list[str]]:
    """Canonical (radian) names of the truth bearing and rate columns, targets 0 … N−1."""
    found = {}
    for c in t.df.columns:
        for kind, pattern in (("bearing", PEAK_TRUTH), ("rate", PEAK_RATE)):
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
    """A xcorr table → the peaks (bearing, amplitude, origin) of every scan and, with the
    truth columns, each target's true bearing (and rate) a scan."""
    import numpy as np

    from trackreplay.recorders.simulated import SimulatedData
    from trackreplay.recorders.table_rows import (_markers, _per_scan, _ragged, _require_every_scan,
                                                  _require_min_scans, _scans)

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
    data = SimulatedData(times=sc.times, ragged={PEAKS: (arrays, counts)})
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
        data.fixed[TRUTH] = truth
    return data


def export_bearing_peaks(dataset) -> dict:
    """A data set's peaks (and the targets' true bearings and rates) → ``{"measurements": DataFrame}``:
    a row per peak, a row with bearing and amplitude empty per scan without peaks."""
    import numpy as np
    import polars as pl

    from trackreplay.recorders.table_exporters import _fixed_grid, _frames_to_rows, _ragged_column, _series, _times

    ch = dataset.channel(PEAKS)
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
    truth = dataset.channels.get(TRUTH)
    if truth is not None and "bearing_rad" in truth.arrays:
        b = _fixed_grid(dataset, TRUTH, "bearing_rad", counts.shape)
        if b.ndim != 3:
            raise InputError(f"{TRUTH} bearing_rad must hold one bearing per target", dataset.path)
        cols += [pl.Series(f"truth{j}_bearing_rad", b[run, scan, j], pl.Float64) for j in range(b.shape[2])]
        if "bearing_rate_radps" in truth.arrays:
            rate = _fixed_grid(dataset, TRUTH, "bearing_rate_radps", counts.shape, b.shape[2:])
            cols += [pl.Series(f"truth{j}_bearing_rate_radps", rate[run, scan, j], pl.Float64)
                     for j in range(b.shape[2])]
    return {"measurements": pl.DataFrame(cols)}


def check_peak_field(data: SimulatedData, params: dict, path) -> None:
    """Refuse peaks outside the sensor's field (``field_min_deg`` … ``field_max_deg`` of
    ``params``), which the replay would refuse, naming the first peak with its run and time
    (``data``'s own times)."""
    import numpy as np

    from trackreplay.recorders.table_rows import _n

    arrays, counts = data.ragged[PEAKS]
    # an unknown field is the whole of what a bearing θ = arccos(C·D/d) can be (the stage's too)
    lo, hi = float(params.get("field_min_deg", 0.0)), float(params.get("field_max_deg", 180.0))
    b = arrays["bearing_rad"]
    have = np.arange(b.shape[2]) < counts[..., None]
    outside = have & ((b < np.deg2rad(lo) - 1e-12) | (b > np.deg2rad(hi) + 1e-12))
    if outside.any():
        r, k, j = (int(v[0]) for v in np.nonzero(outside))
        raise InputError(f"peak bearing {np.rad2deg(b[r, k, j]):.6g}° (run {r}, time {_n(data.times[k])} s) lies "
                         f"outside the sensor's field [{lo:g}°, {hi:g}°] the replay uses; give the field with --set "
                         "field_min_deg=… --set field_max_deg=…", path)


#: the cross-correlation family's table format
FORMAT = TableFormat(
    "xcorr", "peaks", "bearing_peaks", "one row per cross-correlation peak (bearing, amplitude) of a scan",
    {"measurements": (
        RUN, TIME,
        TableColumn("bearing_rad | bearing_deg", "rad | °", True,
                    "peak bearing θ = arccos(C·D/d), within the sensor's field "
                    "(field_min_deg … field_max_deg)"),
        TableColumn("amplitude", "-", True, "peak amplitude, ≥ 0"),
        TableColumn("origin", "index", False,
                    "target a true peak came from (0, 1, …), −1 for clutter or unknown (default −1); for "
                    "judging only, trackers never read it"),
        TableColumn("truth<t>_bearing_rad | truth<t>_bearing_deg", "rad | °", False,
                    "true bearing of target t = 0, 1, … at the scan, for scoring; the same on every row of "
                    "one run and time"),
        TableColumn("truth<t>_bearing_rate_radps | truth<t>_bearing_rate_degps", "rad/s | °/s", False,
                    "its bearing rate (with the bearings, for every target or none)"),
    )},
    ("Several rows of one run and time are several peaks of that scan, kept in the order of the file.",
     "A row with bearing, amplitude (and origin) empty marks a scan without peaks.",
     "Refused: a negative amplitude, an origin below −1, a bearing outside the sensor's field recorded "
     "for the replay, truth that disagrees within a scan, fewer than 3 scans."),
    min_scans=3, read=read_bearing_peaks, export=export_bearing_peaks,
    name_patterns=(PEAK_TRUTH, PEAK_RATE), title="Cross-correlation peaks", item_word="peaks",
    samples={"measurements": "bearing_peaks.csv"},
    sample_sensor_values={"strong_sigma_p_deg": 1.3, "weak_sigma_p_deg": 1.8, "field_min_deg": 70,
                          "field_max_deg": 110},
    # a row (or a foreign message with an empty list) without bearing and amplitude is a scan without peaks
    empty_scan_columns=("bearing_rad", "bearing_deg", "amplitude", "origin"),
    check_values=check_peak_field)
