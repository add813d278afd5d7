"""Tables of measurements (CSV, Parquet) in and out: ``replay convert plots|peaks|tdoa-fdoa|positions``
and ``replay export --table`` (recorders/tables.py, docs/importers.md).

* simulate → export → import gives every input array, and every truth array the tables carry,
  exactly (same dtype, same bits, NaN where NaN), for every family and both formats;
* every bad table is one line ``replay: error: <file>: …`` naming the file at fault, exit 2, no
  traceback, the input unchanged and nothing written;
* the shipped samples are what their documented commands give, and each converts and replays.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner

from trackreplay.contract import read_dataset
from trackreplay.face.cli import main
from trackreplay.recorders.tables import TABLE_FORMATS, dataset_from_table, read_table, tables_from_dataset

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "data" / "samples"


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def ok(res):
    assert res.exit_code == 0, res.output
    return res


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- round trip

# (scenario, overrides, family, command, runs): small, with empty scans where a family has them
ROUND_TRIPS = [
    ("radar-tws", ["detection_probability=0.7", "n_scans=20"], "radar", "plots"),
    ("xcorr-crossing", ["crossing_angle_deg=40", "detection_probability=0.5", "background_clutter_per_gate=0.2",
                        "strong_clutter_per_gate=0.2", "weak_clutter_per_gate=0.2"], "xcorr", "peaks"),
    ("tdoa-fdoa", ["n_epochs=3", "noise_scales=1,2,4"], "tdoa-fdoa", "tdoa-fdoa"),
    ("colored-circle", ["n_samples=25"], "colored", "positions"),
    ("colored-imm", ["n_samples=30"], "colored", "positions"),
]
# arrays of the simulated channels the tables do not carry (none of them is read by a stage)
NOT_CARRIED = {"/xcorr/truth": {"detected", "strength"}, "/emitter/prior": {"std"}, "/colored/truth": {"noise_m"}}


def assert_same_frames(imported, simulated) -> None:
    """Every channel of ``imported`` equals ``simulated``'s frame for frame, array for array,
    dtype and bits (NaN where NaN), and carries every array but the documented ones."""
    assert set(imported.channels) == set(simulated.channels)
    for topic, ch in imported.channels.items():
        ref = simulated.channels[topic]
        np.testing.assert_array_equal(ch.run, ref.run)
        np.testing.assert_array_equal(ch.scan, ref.scan)
        assert np.array_equal(ch.time_s, ref.time_s), topic
        assert set(ch.arrays) == set(ref.arrays) - NOT_CARRIED.get(topic, set()), topic
        for name in ch.arrays:
            mine, theirs = ch.array(name), ref.array(name)
            assert len(mine) == len(theirs), (topic, name)
            for a, b in zip(mine, theirs):
                assert a.dtype == b.dtype and a.shape == b.shape, (topic, name, a.dtype, b.dtype)
                assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), (topic, name)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
@pytest.mark.parametrize("scenario, sets, family, command", ROUND_TRIPS, ids=[r[0] for r in ROUND_TRIPS])
def test_simulate_export_import_gives_the_same_arrays(tmp_path, scenario, sets, family, command, fmt):
    data = tmp_path / "sim.mcap"
    ok(invoke("simulate", scenario, "--runs", 3, "--seed", 4, "-o", data, *[a for s in sets for a in ("--set", s)]))
    ok(invoke("export", "--table", data, "-o", tmp_path / "t", "--format", fmt))
    stem = TABLE_FORMATS[family].stem
    table = tmp_path / "t" / f"{stem}.{fmt}"
    sensors = ["--sensors", tmp_path / "t" / f"{stem}_sensors.{fmt}"] if family == "tdoa-fdoa" else []
    out = tmp_path / "imported.mcap"
    res = ok(invoke("convert", command, table, *sensors, "-o", out))
    assert "with truth" in res.output
    simulated, imported = read_dataset(data), read_dataset(out)
    assert_same_frames(imported, simulated)
    # and back out again: the tables of the imported data set are the tables it came from
    for key, df in tables_from_dataset(imported, family).items():
        assert df.equals(tables_from_dataset(simulated, family)[key]), key
    params = imported.scenario["params"]
    assert params["source_table"] == table.name and params["first_time_s"] == 0.0


def test_a_table_without_truth_and_with_absolute_times_round_trips_through_the_api(tmp_path):
    """Times of a recording (not starting at 0, degrees) come in shifted to 0 with the first time
    recorded, and go out with it added back."""
    rows = pl.DataFrame({"time": [1000.5, 1000.5, 1005.5, 1010.5, 1015.5], "range_m": [9e3, 9.1e3, None, 9.2e3, 9.3e3],
                         "bearing_deg": [30.0, 31.0, None, 32.0, 33.0]})
    (tmp_path / "p.csv").write_text(rows.write_csv())
    res = ok(invoke("convert", "plots", tmp_path / "p.csv", "-o", tmp_path / "p.mcap"))
    assert "4 plots; no truth" in res.output and "1 run(s) × 4 scan(s)" in res.output
    ds = read_dataset(tmp_path / "p.mcap")
    np.testing.assert_array_equal(ds.channel("/radar/plots").times(), [0.0, 5.0, 10.0, 15.0])
    rng, counts = ds.channel("/radar/plots").ragged("range_m")
    np.testing.assert_array_equal(counts, [[2, 0, 1, 1]])
    assert ds.scenario["params"]["first_time_s"] == 1000.5
    back = tables_from_dataset(ds, "radar")["measurements"]
    assert back["time_s"].to_list() == [1000.5, 1000.5, 1005.5, 1010.5, 1015.5]
    assert back["range_m"].to_list() == rows["range_m"].to_list()
    np.testing.assert_array_equal(back["bearing_rad"].to_numpy(), np.deg2rad(rows["bearing_deg"].to_numpy()))


def test_plots_csv_is_an_alias_of_plots(tmp_path):
    (tmp_path / "p.csv").write_text("time,range_m,bearing_deg,run\n0,1000,10,0\n0,1001,10,1\n5,1002,11,0\n5,1003,11,1\n"
                                    "10,1004,12,0\n10,1005,12,1\n")
    ok(invoke("convert", "plots", tmp_path / "p.csv", "-o", tmp_path / "a.mcap"))
    ok(invoke("convert", "plots-csv", tmp_path / "p.csv", "-o", tmp_path / "b.mcap"))
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_set_changes_the_recorded_design_and_a_table_without_prior_starts_from_a_grid(tmp_path):
    ok(invoke("convert", "tdoa-fdoa", SAMPLES / "tdoa_fdoa.csv", "--sensors", SAMPLES / "tdoa_fdoa_sensors.csv",
              "-o", tmp_path / "a.mcap", "--set", "iterations=5"))
    params = read_dataset(tmp_path / "a.mcap").scenario["params"]
    # only what the user gave is recorded: the replay's own default (a prior) starts the estimators
    assert params["iterations"] == 5 and "initial_guess" not in params
    rows = read_table(SAMPLES / "tdoa_fdoa.csv").drop("prior_x_m", "prior_y_m", "prior_vx_mps", "prior_vy_mps")
    rows.write_csv(tmp_path / "noprior.csv")
    res = ok(invoke("convert", "tdoa-fdoa", tmp_path / "noprior.csv", "--sensors", SAMPLES / "tdoa_fdoa_sensors.csv",
                    "-o", tmp_path / "b.mcap"))
    assert "initial_guess=grid" in res.output
    ds = read_dataset(tmp_path / "b.mcap")
    assert ds.scenario["params"]["initial_guess"] == "grid" and "/emitter/prior" not in ds.channels


# --------------------------------------------------------------------------- bad tables

RADAR = "run,time_s,range_m,bearing_rad\n0,0,1000,0.1\n0,5,1010,0.1\n0,10,1020,0.1\n"
RADAR_TRUTH = ("run,time_s,range_m,bearing_rad,truth_x_m,truth_y_m,truth_vx_mps,truth_vy_mps\n"
               "0,0,1000,0.1,995,99,10,0\n0,0,1500,0.2,995,99,10,0\n0,5,,,1045,99,10,0\n0,10,1020,0.1,1095,99,10,0\n")
PEAKS = ("time_s,bearing_deg,amplitude,origin,truth0_bearing_deg\n0,90,2e4,0,90\n0,95,3e3,-1,90\n1,90.5,2e4,0,90.5\n"
         "2,91,2e4,0,91\n")
MEAS = ("time_s,sensor_a,sensor_b,tdoa_s,fdoa_hz,sigma_tdoa_s,sigma_fdoa_hz,carrier_hz\n"
        "0,0,1,1e-6,5,1e-8,10,1e9\n0,1,2,-2e-6,3,1e-8,10,1e9\n0,0,2,-1e-6,8,1e-8,10,1e9\n"
        "1,0,1,1e-6,5,1e-8,10,1e9\n1,1,2,-2e-6,3,1e-8,10,1e9\n1,0,2,-1e-6,8,1e-8,10,1e9\n")
SENSORS = ("time_s,sensor,x_m,y_m,vx_mps,vy_mps\n0,0,-3000,0,300,0\n0,1,0,0,300,0\n0,2,3000,0,300,0\n"
           "1,0,-2700,0,300,0\n1,1,300,0,300,0\n1,2,3300,0,300,0\n")
POS = "time_s,x_m,truth_x_m,truth_vx_mps,truth_ax_mps2\n0,1,0,1,0\n0.5,2,0.5,1,0\n1,3,1,1,0\n1.5,4,1.5,1,0\n"

BASES = {"plots": RADAR, "plots-truth": RADAR_TRUTH, "peaks": PEAKS, "tdoa-fdoa": MEAS, "positions": POS}


def _case(command, table, fragment, sensors=SENSORS, at="table", suffix=".csv"):
    return (command, table, sensors, fragment, at, suffix)


BAD = [
    # radar plots
    _case("plots", RADAR.replace("run,", "runs,"), "unknown column(s) 'runs' (did you mean 'run'?)"),
    _case("plots", "time_s,range_m\n0,1000\n5,1000\n10,1000\n", "missing column(s) bearing_deg or bearing_rad"),
    _case("plots", RADAR.replace("1010", "abc"), "column 'range_m' holds text 'abc' at data row 2"),
    _case("plots", RADAR.replace("1010", "NaN"), "column 'range_m' holds NaN at data row 2"),
    _case("plots", RADAR.replace("0,10,", "0,2,"), "time_s goes back within run 0 at data row 3"),
    _case("plots", RADAR.replace("1010", "-5"), "column 'range_m' holds a negative value -5 at data row 2"),
    _case("plots", RADAR.replace("0,5,", "2,5,"), "no rows for run 1"),
    _case("plots", RADAR.replace("0,5,", "0.5,5,"), "column 'run' holds a non-integer value 0.5 at data row 2"),
    _case("plots", RADAR.replace("0,5,1010,0.1", "0,5,1010,"), "column 'bearing_rad' is empty at data row 2"),
    _case("plots", RADAR.replace("0,10,1020,0.1", "0,7,,\n0,7,,\n0,10,1020,0.1"), "another row marks it too"),
    _case("plots", RADAR.replace("0,10,1020,0.1", "0,5,,\n0,10,1020,0.1"), "the scan has plots (duplicated scan)"),
    _case("plots", RADAR.replace("0,10,", "0,1e15,"), "scan time 1e+15 s at data row 3 is beyond any recording"),
    _case("plots", "run,time_s,range_m,bearing_rad\n0,0,1000,0.1\n0,5,1010,0.1\n", "2 scan time(s)"),
    _case("plots", RADAR_TRUTH.replace("0,0,1500,0.2,995", "0,0,1500,0.2,996"), "column 'truth_x_m' differs within one "
          "scan (run 0 at time 0.0 s): 995.0 at data row 1 but 996.0 at data row 2"),
    _case("plots", RADAR_TRUTH.replace(",truth_vy_mps", "").replace(",0\n", "\n"), "truth columns need all of"),
    _case("plots", RADAR_TRUTH + "1,0,1000,0.1,995,99,10,0\n1,10,1000,0.1,995,99,10,0\n",
          "no row for run 1 at time 5.0 s (with truth columns every run needs a row at every scan time"),
    _case("plots", "run,time_s,range_m,bearing_rad\n", "no rows (a header only)"),
    _case("plots", "", "empty file"),
    _case("plots", RADAR, "not a CSV or Parquet file", suffix=".txt"),
    _case("plots", "\x00\x01garbage\x02", "binary content", suffix=".csv"),
    _case("plots", "PAR1 not really", "unreadable Parquet file", suffix=".parquet"),
    # cross-correlation peaks
    _case("peaks", PEAKS.replace("amplitude", "amp"), "missing column(s) amplitude; unknown: 'amp'"),
    _case("peaks", PEAKS.replace("3e3", "x3"), "column 'amplitude' holds text 'x3' at data row 2"),
    _case("peaks", PEAKS.replace("3e3", "nan"), "column 'amplitude' holds NaN at data row 2"),
    _case("peaks", PEAKS.replace("3e3", "-3e3"), "column 'amplitude' holds a negative value -3000 at data row 2"),
    _case("peaks", PEAKS.replace("2,91,", "0.5,91,"), "time_s goes back within run 0 at data row 4"),
    _case("peaks", PEAKS.replace(",-1,", ",-2,"), "column 'origin' holds -2 at data row 2"),
    _case("peaks", PEAKS.replace("0,95,3e3,-1,90", "0,95,3e3,-1,91"), "column 'truth0_bearing_deg' differs"),
    # a field the table does not give is all a bearing arccos(C·D/d) can be, 0° … 180°
    _case("peaks", PEAKS.replace("0,95,", "0,190,"), "outside the sensor's field [0°, 180°]"),
    _case("peaks", PEAKS.replace("0,95,3e3,-1", "0,,,"), "the scan has peaks (duplicated scan)"),
    # TDOA/FDOA: the measurement table
    _case("tdoa-fdoa", MEAS.replace(",carrier_hz", "").replace(",1e9\n", "\n"), "missing column(s) carrier_hz"),
    _case("tdoa-fdoa", MEAS.replace("1,1,2,-2e-6", "1,1,5,-2e-6"), "pair 1–5 at data row 5"),
    _case("tdoa-fdoa", MEAS.replace("1,0,2,", "1,0,5,").replace("0,0,2,", "0,0,5,"), "names sensor 5, but the "
          "sensors table sensors.csv lists sensors 0 … 2 (bad sensor index)"),
    _case("tdoa-fdoa", MEAS.replace("0,1,2,-2e-6", "0,1,1,-2e-6"), "data row 2 pairs sensor 1 with itself"),
    _case("tdoa-fdoa", MEAS.replace("0,0,2,-1e-6", "0,0,1,-1e-6"), "pair 0–1 repeated in run 0 at time 0.0 s"),
    _case("tdoa-fdoa", MEAS.replace("1,0,2,-1e-6", "1,0,1,-1e-6"), "duplicated (run, time, pair)"),
    _case("tdoa-fdoa", MEAS.replace("1,0,2,-1e-6,8,1e-8", "1,0,2,-1e-6,8,0"),
          "column 'sigma_tdoa_s' holds a non-positive value 0 at data row 6"),
    _case("tdoa-fdoa", MEAS.replace("10,1e9\n1,0,1", "10,2e9\n1,0,1"), "column 'carrier_hz' differs within one scan"),
    _case("tdoa-fdoa", MEAS.replace("1,0,1,1e-6", "1,0,1,abc"), "column 'tdoa_s' holds text 'abc' at data row 4"),
    _case("tdoa-fdoa", MEAS.replace("0,1,2,-2e-6,3", "0,1,2,-2e-6,inf"), "column 'fdoa_hz' holds Inf at data row 2"),
    _case("tdoa-fdoa", MEAS.replace("1,0,1,", "-1,0,1,"), "time_s goes back within run 0 at data row 4"),
    _case("tdoa-fdoa", MEAS.replace("1,1,2,-2e-6,3,1e-8,10,1e9\n", ""), "run 0 at time 1.0 s lacks the pair 1–2"),
    _case("tdoa-fdoa", MEAS.replace("1,0,1,", "1,-1,1,"), "column 'sensor_a' holds -1 at data row 4"),
    # TDOA/FDOA: the sensors table (the message names it)
    _case("tdoa-fdoa", MEAS, "sensor 1 listed twice for run 0 at time 0.0 s", at="sensors",
          sensors=SENSORS.replace("0,2,3000", "0,1,3000")),
    _case("tdoa-fdoa", MEAS, "no rows for run 0 at time 1.0 s", at="sensors", sensors=SENSORS.split("1,0,-2700")[0]),
    _case("tdoa-fdoa", MEAS, "time 2.0 s at data row 6 is not an epoch", at="sensors",
          sensors=SENSORS.replace("1,2,3300", "2,2,3300")),
    _case("tdoa-fdoa", MEAS, "column 'x_m' holds NaN at data row 2", at="sensors",
          sensors=SENSORS.replace("0,1,0,", "0,1,nan,")),
    _case("tdoa-fdoa", MEAS, "column 'sensor' holds a non-integer value 1.5", at="sensors",
          sensors=SENSORS.replace("0,1,0,", "0,1.5,0,")),
    _case("tdoa-fdoa", MEAS, "missing column(s) vy_mps", at="sensors", sensors=SENSORS.replace("vy_mps", "vz_mps")),
    _case("tdoa-fdoa", MEAS, "time_s goes back within run 0 at data row 4", at="sensors",
          sensors=SENSORS.replace("1,0,-2700", "-1,0,-2700")),
    _case("tdoa-fdoa", MEAS, "empty file", at="sensors", sensors=""),
    # positions in coloured noise
    _case("positions", POS.replace("x_m,", "y_m,", 1), "missing column(s) x_m"),
    _case("positions", POS.replace("0.5,2,", "0,2,"), "run 0 at time 0.0 s on data rows 1 and 2: one row per run and "
          "time (duplicated time)"),
    _case("positions", POS.replace("1.5,4,", "1.6,4,"), "the times are not evenly spaced"),
    _case("positions", POS.replace("1,3,", "1,three,"), "column 'x_m' holds text 'three' at data row 3"),
    _case("positions", POS.replace("1,3,", "1,NaN,"), "column 'x_m' holds NaN at data row 3"),
    _case("positions", POS.replace("1,3,", "0.2,3,"), "time_s goes back within run 0 at data row 3"),
    _case("positions", POS.replace(",truth_ax_mps2", "").replace(",0\n", "\n"), "truth columns need all of"),
    _case("positions", POS.replace("1.5,4,1.5,1,0\n", ""), "3 scan time(s); the colored trackers need at "
          "least 4"),
    _case("positions", POS.replace("truth_x_m", "truth_alpha_x"), "truth columns need all of"),
]
# every converter: an empty file, a header only, a file that is no table
BAD += [case for command, base in (("peaks", PEAKS), ("tdoa-fdoa", MEAS), ("positions", POS)) for case in (
    _case(command, "", "empty file"),
    _case(command, base.splitlines()[0] + "\n", "no rows (a header only)"),
    _case(command, base, "not a CSV or Parquet file", suffix=".xlsx"),
    _case(command, "\x00PK\x03\x04", "binary content"),
)]


@pytest.mark.parametrize("command, table, sensors, fragment, at, suffix", BAD,
                         ids=[f"{c[0]}-{i}" for i, c in enumerate(BAD)])
def test_a_bad_table_is_one_line_naming_the_file_and_row(tmp_path, command, table, sensors, fragment, at, suffix):
    path = tmp_path / f"table{suffix}"
    path.write_bytes(table.encode())
    extra = []
    if command == "tdoa-fdoa":
        (tmp_path / "sensors.csv").write_bytes(sensors.encode())
        extra = ["--sensors", tmp_path / "sensors.csv"]
    inputs = [p for p in tmp_path.iterdir()]
    before = {p: sha(p) for p in inputs}
    out = tmp_path / "out.mcap"
    res = invoke("convert", command, path, *extra, "-o", out)
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    named = tmp_path / ("sensors.csv" if at == "sensors" else path.name)
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and lines[0].startswith(f"replay: error: {named}: "), res.stderr
    assert fragment in lines[0], lines[0]
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit)
    assert {p: sha(p) for p in inputs} == before and not out.exists()


@pytest.mark.parametrize("name", BASES)
def test_the_tables_the_bad_cases_start_from_convert(tmp_path, name):
    """Each bad case above breaks one thing in a table that converts."""
    path = tmp_path / "table.csv"
    path.write_text(BASES[name])
    command = name.split("-truth")[0]
    extra = ["--sensors", tmp_path / "s.csv"] if command == "tdoa-fdoa" else []
    if extra:
        (tmp_path / "s.csv").write_text(SENSORS)
    ok(invoke("convert", command, path, *extra, "-o", tmp_path / "out.mcap", "--set", "initial_guess=grid")
       if command == "tdoa-fdoa" else invoke("convert", command, path, *extra, "-o", tmp_path / "out.mcap"))


def test_the_api_names_the_path_it_is_given():
    rows = pl.DataFrame({"time_s": [0.0, 5.0, 10.0], "range_m": [1.0, -1.0, 2.0], "bearing_rad": [0.0, 0.0, 0.0]})
    with pytest.raises(Exception) as info:
        dataset_from_table("radar", rows, "from/a/mapping.mcap")
    assert str(info.value) == "from/a/mapping.mcap: column 'range_m' holds a negative value -1 at data row 2"


# --------------------------------------------------------------------------- export refusals


def test_export_table_refusals(tmp_path):
    data = tmp_path / "r.mcap"
    ok(invoke("simulate", "radar-tws", "--runs", 1, "--set", "n_scans=5", "-o", data))
    ok(invoke("export", "--table", data, "-o", tmp_path / "t"))
    before = sha(tmp_path / "t" / "radar_plots.csv")
    cases = [
        (["export", "--table", data, "-o", tmp_path / "t"], "exists; add --force"),
        (["export", "--table", data, "-o", tmp_path / "t", "--runs", "0"], "--runs and --data belong to --foxglove"),
        (["export", "--table", "--foxglove", data, "-o", tmp_path / "t"], "choose one format"),
        (["export", "--table", data, "-o", data], "is a file"),
        (["export", "--table", tmp_path / "none.mcap", "-o", tmp_path / "u"], "no such file"),
    ]
    for args, fragment in cases:
        res = invoke(*args)
        lines = [line for line in res.stderr.splitlines() if line.strip()]
        assert res.exit_code == 2 and len(lines) == 1 and fragment in lines[0], (args, res.output)
    assert sha(tmp_path / "t" / "radar_plots.csv") == before and not (tmp_path / "u").exists()
    ok(invoke("simulate", "array-crossing", "--runs", 1, "-o", tmp_path / "a.mcap", "--set", "n_scans=3"))
    res = invoke("export", "--table", tmp_path / "a.mcap", "-o", tmp_path / "u")
    assert res.exit_code == 2 and "no channels of a family with a table format" in res.stderr
    assert not (tmp_path / "u").exists()


# --------------------------------------------------------------------------- samples, help, docs

SAMPLE_COMMANDS = [
    (["simulate", "radar-tws", "--runs", "3", "--seed", "1", "--set", "detection_probability=0.9"],
     [["--format", "csv"], ["--format", "parquet"]]),
    (["simulate", "xcorr-crossing", "--runs", "1", "--seed", "1", "--set", "crossing_angle_deg=20"], [[]]),
    (["simulate", "tdoa-fdoa", "--runs", "20", "--seed", "1", "--set", "n_epochs=3"], [[]]),
    (["simulate", "colored-imm", "--runs", "1", "--seed", "1", "--set", "n_samples=1000"], [[]]),
]
SAMPLE_FILES = ["radar_plots.csv", "radar_plots.parquet", "bearing_peaks.csv", "tdoa_fdoa.csv", "tdoa_fdoa_sensors.csv",
                "colored_positions.csv"]


def test_the_samples_are_what_their_documented_commands_give(tmp_path):
    docs = (REPO / "docs" / "importers.md").read_text()
    for simulate, exports in SAMPLE_COMMANDS:
        data = tmp_path / f"{simulate[1]}.mcap"
        ok(invoke(*simulate, "-o", data))
        assert " ".join(["replay", *simulate]) in docs, simulate
        for extra in exports:
            ok(invoke("export", "--table", data, "-o", tmp_path / "s", *extra))
    for name in SAMPLE_FILES:
        shipped, made = SAMPLES / name, tmp_path / "s" / name
        assert shipped.stat().st_size < 200_000, name
        if name.endswith(".csv"):
            assert shipped.read_bytes() == made.read_bytes(), name
        else:
            assert pl.read_parquet(shipped).equals(pl.read_parquet(made)), name


@pytest.mark.parametrize("command, files", [
    ("plots", ["radar_plots.csv"]), ("plots", ["radar_plots.parquet"]), ("peaks", ["bearing_peaks.csv"]),
    ("tdoa-fdoa", ["tdoa_fdoa.csv", "--sensors", "tdoa_fdoa_sensors.csv"]), ("positions", ["colored_positions.csv"]),
])
def test_each_sample_converts_and_replays(tmp_path, command, files):
    args = [SAMPLES / f if f.endswith((".csv", ".parquet")) else f for f in files]
    from trackreplay.face.cli_convert_tables import SAMPLE_SENSOR_VALUES, TABLE_COMMANDS

    # the sensor values the samples were simulated with: a recording says them, or they are unknown
    given = [f"--set={k}={v}" for k, v in SAMPLE_SENSOR_VALUES.get(TABLE_COMMANDS[command][0], {}).items()]
    ok(invoke("convert", command, *args, "-o", tmp_path / "d.mcap", *given))
    res = ok(invoke(tmp_path / "d.mcap", "--no-rrd", "--out", tmp_path / "o" / "tracks.mcap"))
    assert "rmse" in res.output  # the samples carry truth: errors are scored


def test_help_and_docs_list_every_column():
    docs = (REPO / "docs" / "importers.md").read_text()
    for family, fmt in TABLE_FORMATS.items():
        text = invoke("convert", fmt.command, "--help").output
        assert "Example" in text
        for columns in fmt.tables.values():
            for column in columns:
                for name in column.name.split(" | "):
                    assert name in text, (fmt.command, name)
                    assert f"`{name}`" in docs, (family, name)
        assert f"replay convert {fmt.command}" in docs


@pytest.mark.parametrize("name", ["radar_plots.csv", "radar_plots.parquet"])
def test_replaying_a_table_directly_says_how_to_convert_it(name):
    from click.testing import CliRunner

    from trackreplay.face.cli import main

    res = CliRunner().invoke(main, [str(SAMPLES / name), "--no-rrd"])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.output.count("\n") == 1 and "replay convert plots|peaks|tdoa-fdoa|positions FILE" in res.output
