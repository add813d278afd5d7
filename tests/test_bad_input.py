"""Bad input gives one line ``replay: error: <file>: <problem>`` and exit 2, never a traceback.

Every data set here is written by hand with :func:`trackreplay.contract.write_dataset` (frames
as dicts), starting from a small valid set that replays cleanly, then broken in one way.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner

import trackreplay.face.cli
from trackreplay.face.cli import main

REPO = Path(__file__).resolve().parents[1]
from trackreplay.contract import ChannelData, METADATA_SCENARIO, scenario_metadata, write_dataset
from trackreplay.errors import InputError, check_all, require_finite_params
from trackreplay.recorders.scenarios import load_scenario

# --------------------------------------------------------------------------- helpers


def invoke(*args):
    return CliRunner().invoke(trackreplay.face.cli.main, [str(a) for a in args])


def assert_one_line_error(res, path, *fragments):
    """Exit 2, one error line on stderr naming the file and every fragment, no traceback."""
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert res.exit_code == 2, res.output
    assert len(errors) == 1 and res.stderr.strip().splitlines()[-1] == errors[0], res.output
    text = errors[0]
    assert text.startswith(f"replay: error: {path}: "), text
    for fragment in fragments:
        assert fragment in text, text
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit)


def write_frames(path: Path, channels: dict, metadata: dict | None = None) -> Path:
    """``channels``: topic -> list of ``(run, scan, time_s, {name: array})``."""
    with write_dataset(path, metadata) as w:
        for topic, frames in channels.items():
            for run, scan, t, arrays in frames:
                w.write(topic, run, scan, t, arrays)
    return path


def frames_from_simulated(data) -> dict:
    """Per-frame dicts of a recorder's in-memory output (the frames write_simulated writes)."""
    out = {}
    for k, t in enumerate(data.times):
        for topic, (arrays, counts) in data.ragged.items():
            for r in range(counts.shape[0]):
                out.setdefault(topic, []).append(
                    (r, k, float(t), {n: np.array(a[r, k, :counts[r, k]]) for n, a in arrays.items()}))
        for topic, arrays in data.fixed.items():
            for r in range(next(iter(arrays.values())).shape[0]):
                out.setdefault(topic, []).append((r, k, float(t), {n: np.array(a[r, k]) for n, a in arrays.items()}))
    return out


def replace_array(frames: list, name: str, make, where=lambda run, scan: True) -> list:
    """A copy of ``frames`` with array ``name`` replaced by ``make(old)`` (dropped if None) where chosen."""
    out = []
    for run, scan, t, arrays in frames:
        arrays = dict(arrays)
        if where(run, scan):
            new = make(arrays[name])
            if new is None:
                del arrays[name]
            else:
                arrays[name] = new
        out.append((run, scan, t, arrays))
    return out


# --- radar: plots (range, bearing) per scan, optional truth state

def radar_frames(n_scans: int = 5) -> dict:
    noise = np.random.default_rng(1).normal(size=(n_scans, 2)) * [100.0, 0.01]
    plots, truth = [], []
    for k in range(n_scans):
        x, y = 9000.0 + 30 * k, 3000.0 - 20 * k
        plots.append((0, k, 5.0 * k, {"range_m": np.array([np.hypot(x, y) + noise[k, 0]]),
                                       "bearing_rad": np.array([np.arctan2(y, x) + noise[k, 1]])}))
        truth.append((0, k, 5.0 * k, {"state": np.array([x, y, 6.0, -4.0])}))
    return {"/radar/plots": plots, "/radar/truth": truth}


#: the plots' noise of :func:`radar_frames` (100 m in range, 0.01 rad in bearing)
RADAR_FRAMES_SENSOR = {"sigma_range_m": 100.0, "sigma_bearing_deg": float(np.rad2deg(0.01))}


def radar_metadata(params: dict | str) -> dict:
    text = params if isinstance(params, str) else json.dumps(params)
    return {METADATA_SCENARIO: {"scenario": "radar-tws", "params": text, "seed": "0"}}


def xcorr_metadata(params: dict) -> dict:
    """A simulation record of the bundled xcorr-crossing scenario with ``params`` changed."""
    return {METADATA_SCENARIO: {"scenario": "xcorr-crossing", "params": json.dumps(params), "seed": "0"}}


# --- xcorr peaks: two targets at 85° and 95° (strong, weak) plus one clutter peak per scan

def xcorr_frames(n_scans: int = 6) -> dict:
    bearings = np.deg2rad([85.0, 95.0])
    peaks, truth = [], []
    for k in range(n_scans):
        peaks.append((0, k, float(k), {"bearing_rad": np.r_[bearings, np.deg2rad(100.0)],
                                       "amplitude": np.array([21000.0, 12000.0, 3000.0]),
                                       "origin": np.array([0, 1, -1], np.int32)}))
        truth.append((0, k, float(k), {"bearing_rad": bearings.copy(), "bearing_rate_radps": np.zeros(2)}))
    return {"/xcorr/peaks": peaks, "/xcorr/truth": truth}


@pytest.fixture(scope="module")
def emitter_frames():
    from trackreplay.recorders.tdoa_fdoa import simulate

    return frames_from_simulated(simulate(load_scenario("tdoa-fdoa").params, 2, 0))


@pytest.fixture(scope="module")
def colored_frames():
    from trackreplay.recorders.colored_noise import simulate

    params = dict(load_scenario("colored-imm").params, n_samples=12, manoeuvre_first_sample=4,
                  manoeuvre_last_sample=7)
    return frames_from_simulated(simulate(params, 2, 0)), params


# --------------------------------------------------------------------------- the valid sets replay


def test_the_hand_written_sets_replay_cleanly(tmp_path, monkeypatch, emitter_frames, colored_frames):
    """Controls: every breakage below starts from a set the replay accepts."""
    monkeypatch.chdir(tmp_path)  # the default replay-out/<name>/ lands here, not in the checkout
    frames, params = colored_frames
    # the radar and xcorr sets record the sensor values they were made with (a file that says
    # nothing about its sensor stops: tests/test_sensor_values.py, a file without a record)
    for name, channels, meta in [("radar", radar_frames(), radar_metadata(RADAR_FRAMES_SENSOR)),
                                 ("xcorr", xcorr_frames(), xcorr_metadata({})),
                                 ("emitter", emitter_frames, None),
                                 ("colored", frames, scenario_metadata("colored-imm", params, 0))]:
        res = invoke(write_frames(tmp_path / f"{name}.mcap", channels, meta), "--no-rrd")
        assert res.exit_code == 0, (name, res.output)


# --------------------------------------------------------------------------- ChannelData (contract)


def test_missing_array_names_channel_file_and_what_is_there(tmp_path):
    ch = radar_frames()
    ch["/radar/plots"] = replace_array(ch["/radar/plots"], "bearing_rad", lambda a: None)
    p = write_frames(tmp_path / "nobearing.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/radar/plots lacks array 'bearing_rad'", "(have: range_m)")


def test_array_missing_from_some_frames(tmp_path):
    ch = radar_frames()
    ch["/radar/plots"] = replace_array(ch["/radar/plots"], "bearing_rad", lambda a: None, lambda r, k: k == 2)
    p = write_frames(tmp_path / "gap.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/radar/plots array 'bearing_rad' is in 4 of 5 frames")


def test_scalar_frame_in_a_ragged_array(tmp_path):
    ch = radar_frames()
    ch["/radar/plots"] = replace_array(ch["/radar/plots"], "range_m", lambda a: np.float64(a[0]), lambda r, k: k == 3)
    p = write_frames(tmp_path / "scalar.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/radar/plots array 'range_m' is a scalar in run 0 scan 3")


def test_ragged_entries_that_change_shape(tmp_path):
    ch = radar_frames()
    ch["/radar/plots"] = replace_array(ch["/radar/plots"], "range_m", lambda a: np.repeat(a[:, None], 2, 1),
                                       lambda r, k: k == 1)
    p = write_frames(tmp_path / "tail.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/radar/plots array 'range_m' has entries of shape ()",
                          "but (2,) in run 0 scan 1")


def test_fixed_array_that_changes_shape_names_channel_not_api(tmp_path):
    ch = radar_frames()
    ch["/radar/truth"] = replace_array(ch["/radar/truth"], "state", lambda a: np.r_[a, 0.0], lambda r, k: k == 4)
    p = write_frames(tmp_path / "truthshape.mcap", ch)
    res = invoke(p, "--no-rrd")
    assert_one_line_error(res, p, "/radar/truth array 'state' has shape (4,)", "(5,) in run 0 scan 4")
    assert "ragged()" not in res.output


def test_channel_data_keeps_its_old_constructor_and_names_itself():
    ch = ChannelData(np.array([0, 0]), np.array([0, 1]), np.zeros(2), {"x": [np.zeros(2), np.ones(2)]})
    assert ch.grid("x").shape == (1, 2, 2)
    with pytest.raises(InputError, match=r"channel lacks array 'y' \(have: x\)"):
        ch.array("y")
    named = ChannelData(ch.run, ch.scan, ch.time_s, ch.arrays, topic="/t", path="f.mcap")
    with pytest.raises(InputError) as exc:
        named.grid("y")
    assert str(exc.value) == "f.mcap: /t lacks array 'y' (have: x)"


# --------------------------------------------------------------------------- recorded design values


def test_design_values_recorded_as_strings_are_parsed(tmp_path):
    """A file whose metadata holds " 60 " replays exactly as one holding 60.0."""
    typed = write_frames(tmp_path / "typed.mcap", radar_frames(8), radar_metadata({"nominal_cross_range_m": 60.0}))
    text = write_frames(tmp_path / "text.mcap", radar_frames(8), radar_metadata({"nominal_cross_range_m": " 60 "}))
    a, b = invoke("eval", typed, "--json"), invoke("eval", text, "--json")
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    assert json.loads(a.output) == json.loads(b.output)
    default = invoke("eval", write_frames(tmp_path / "none.mcap", radar_frames(8), radar_metadata({})), "--json")
    assert json.loads(default.output) != json.loads(a.output)  # the recorded value is used, not the default


def test_xcorr_gate_recorded_as_string(tmp_path):
    text = invoke("eval", write_frames(tmp_path / "s.mcap", xcorr_frames(), xcorr_metadata({"gate_deg": "5"})), "--json")
    typed = invoke("eval", write_frames(tmp_path / "f.mcap", xcorr_frames(), xcorr_metadata({"gate_deg": 5.0})), "--json")
    assert text.exit_code == 0, text.output
    assert json.loads(text.output) == json.loads(typed.output)


@pytest.mark.parametrize("params, fragment", [
    ({"sigma_bearing_deg": "abc"}, "scenario record: parameter 'sigma_bearing_deg': cannot read 'abc' as float"),
    ({"nominal_cross_range_m": None}, "scenario record: parameter 'nominal_cross_range_m': cannot read None"),
    ({"scan_period_s": True}, "scenario record: parameter 'scan_period_s': cannot read True as float"),
    ("{not json", "params is not valid JSON"),
    ("[1, 2]", "params must be a JSON object"),
])
def test_unreadable_recorded_design_values(tmp_path, params, fragment):
    p = write_frames(tmp_path / "meta.mcap", radar_frames(), radar_metadata(params))
    assert_one_line_error(invoke(p, "--no-rrd"), p, fragment)


# --------------------------------------------------------------------------- stage decode paths


def test_xcorr_origin_length_differs_from_bearings(tmp_path):
    ch = xcorr_frames()
    ch["/xcorr/peaks"] = replace_array(ch["/xcorr/peaks"], "origin", lambda a: a[:2], lambda r, k: k == 2)
    p = write_frames(tmp_path / "origin.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/xcorr/peaks: bearing_rad and origin list different numbers of items",
                          "run 0 scan 2 (3 vs 2)")


def test_xcorr_peaks_lacking_amplitude(tmp_path):
    ch = xcorr_frames()
    ch["/xcorr/peaks"] = replace_array(ch["/xcorr/peaks"], "amplitude", lambda a: None)
    p = write_frames(tmp_path / "noamp.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/xcorr/peaks lacks array 'amplitude'")


def test_xcorr_scalar_truth_frames(tmp_path):
    ch = xcorr_frames()
    ch["/xcorr/truth"] = replace_array(ch["/xcorr/truth"], "bearing_rad", lambda a: np.float64(a[0]))
    p = write_frames(tmp_path / "truth0d.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/xcorr/truth bearing_rad must be 1-D", "holds shape ()")
    # fit-peaks reads the truth through the same checks
    assert_one_line_error(invoke("fit-peaks", p, "--reference", "truth"), p, "/xcorr/truth bearing_rad must be 1-D")


def test_xcorr_truth_rate_shape_differs_from_bearings(tmp_path):
    ch = xcorr_frames()
    ch["/xcorr/truth"] = replace_array(ch["/xcorr/truth"], "bearing_rate_radps", lambda a: np.zeros(3))
    p = write_frames(tmp_path / "rate.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/xcorr/truth bearing_rate_radps has shape (1, 6, 3)",
                          "bearing_rad (1, 6, 2)")


def test_xcorr_missing_truth_frame(tmp_path):
    ch = xcorr_frames()
    ch["/xcorr/truth"] = [f for f in ch["/xcorr/truth"] if f[1] != 3]
    p = write_frames(tmp_path / "truthgap.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/xcorr/truth has no frame for run 0 scan 3")


@pytest.mark.parametrize("topic, name, make, fragment", [
    ("/emitter/prior", "state", lambda a: a[:3], "/emitter/prior state must be [x, y, vx, vy] (4 values) per frame"),
    ("/emitter/sensors", "position_m", lambda a: np.c_[a, np.zeros(len(a))],
     "/emitter/sensors position_m must be (sensors, 2) in every frame, got frames of shape (3, 3)"),
    ("/emitter/sensors", "velocity_mps", lambda a: a[:2],
     "/emitter/sensors velocity_mps (2, 2) and position_m (3, 2) differ in shape"),
    ("/emitter/measurements", "tdoa_s", lambda a: a[:, None],
     "/emitter/measurements tdoa_s must be 1-D (one value per pair) in every frame"),
    ("/emitter/measurements", "fdoa_hz", lambda a: np.float64(a[0]),
     "/emitter/measurements fdoa_hz must be 1-D (one value per pair) in every frame"),
    ("/emitter/measurements", "sigma_tdoa_s", lambda a: a[:2], "3 pairs but 2 TDOA σ / 3 FDOA σ values"),
    ("/emitter/measurements", "carrier_hz", lambda a: None, "/emitter/measurements lacks array 'carrier_hz'"),
    ("/emitter/truth", "state", lambda a: a[:2], "/emitter/truth state must be [x, y, vx, vy]"),
])
def test_emitter_inputs_of_the_wrong_shape(tmp_path, emitter_frames, topic, name, make, fragment):
    ch = dict(emitter_frames)
    ch[topic] = replace_array(ch[topic], name, make)
    p = write_frames(tmp_path / "emitter.mcap", ch)
    assert_one_line_error(invoke(p, "--no-rrd"), p, fragment)


def test_colored_noise_missing_truth_frame_is_an_error(tmp_path, colored_frames):
    frames, params = colored_frames
    ch = dict(frames)
    ch["/colored/truth"] = [f for f in ch["/colored/truth"] if (f[0], f[1]) != (1, 5)]
    p = write_frames(tmp_path / "gap.mcap", ch, scenario_metadata("colored-imm", params, 0))
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/colored/truth has no frame for run 1 scan 5")


def test_array_missing_truth_frame_is_named_as_such(tmp_path):
    """A truth frame the file lacks is named as a missing frame, not as NaN values (issue 30)."""
    from trackreplay.recorders.array_snapshots import simulate

    params = dict(load_scenario("array-crossing").params, n_scans=12)
    ch = frames_from_simulated(simulate(params, 2, 0))
    ch["/array/truth"] = [f for f in ch["/array/truth"] if (f[0], f[1]) != (1, 5)]
    p = write_frames(tmp_path / "gap.mcap", ch, scenario_metadata("array-crossing", params, 0))
    assert_one_line_error(invoke(p, "--no-rrd"), p, "/array/truth has no frame for run 1 scan 5")


@pytest.mark.parametrize("name", ["state", "alpha"])
def test_colored_noise_nonfinite_truth(tmp_path, colored_frames, name):
    frames, params = colored_frames
    ch = dict(frames)
    ch["/colored/truth"] = replace_array(ch["/colored/truth"], name, lambda a: np.full_like(a, np.nan),
                                         lambda r, k: (r, k) == (0, 2))
    p = write_frames(tmp_path / f"nan_{name}.mcap", ch, scenario_metadata("colored-imm", params, 0))
    assert_one_line_error(invoke(p, "--no-rrd"), p, f"/colored/truth {name} holds", "NaN/Inf")


# --------------------------------------------------------------------------- CLI


def test_rerun_run_must_not_be_negative(tmp_path):
    p = write_frames(tmp_path / "radar.mcap", radar_frames())
    res = invoke(p, "--no-rrd", "--rerun-run", "-1")
    assert res.exit_code == 2 and "--rerun-run" in res.output and "Traceback" not in res.output


def _study(tmp_path, spec, table) -> Path:
    study = tmp_path / "study"
    study.mkdir()
    (study / "sweep.json").write_text(spec if isinstance(spec, str) else json.dumps(spec))
    if isinstance(table, bytes):
        (study / "sweep.parquet").write_bytes(table)
    else:
        table.write_parquet(study / "sweep.parquet")
    return study


GOOD_TABLE = pl.DataFrame({"crossing_angle_deg": [10.0], "tracker": ["jpda"], "metric": ["success_rate"],
                           "value": [0.5]})


@pytest.mark.parametrize("spec, table, fragment", [
    ("{broken", GOOD_TABLE, "sweep.json is not readable JSON"),
    ({"scenario": "xcorr-crossing"}, GOOD_TABLE, "sweep.json names no swept parameters"),
    ({"params": {}}, GOOD_TABLE, "sweep.json names no swept parameters"),
    ([1, 2], GOOD_TABLE, "sweep.json names no swept parameters"),
    ({"params": {"crossing_angle_deg": [10]}}, b"not parquet", "sweep.parquet is unreadable"),
    ({"params": {"min_distance_deg": [1]}}, GOOD_TABLE, "sweep.parquet lacks column(s) min_distance_deg"),
    ({"params": {"crossing_angle_deg": [10]}}, GOOD_TABLE, "the sweep lacks metric(s) success_rate_stderr"),
])
def test_association_table_refuses_malformed_studies(tmp_path, spec, table, fragment):
    study = _study(tmp_path, spec, table)
    assert_one_line_error(invoke("association-table", study), study, fragment)


# --------------------------------------------------------------------------- shared checks


def test_check_all_reports_the_first_failed_check_with_the_file():
    check_all([(True, "fine"), (np.bool_(True), "fine too")])
    with pytest.raises(InputError) as exc:
        check_all([(True, "a"), (False, "b must be > 0"), (False, "c")], "f.toml")
    assert str(exc.value) == "f.toml: b must be > 0"


def test_require_finite_params_checks_floats_only():
    require_finite_params({"a": 1.0, "b": "nan", "c": [float("nan")], "d": 3})
    for bad in (float("nan"), float("inf"), np.float64(-np.inf)):
        with pytest.raises(InputError, match=r"^parameter 'x' must be finite$"):
            require_finite_params({"ok": 2.0, "x": bad})


def test_recorders_use_the_shared_checks(tmp_path):
    res = invoke("simulate", "radar-tws", "--runs", 1, "-o", tmp_path / "r.mcap", "--set", "design_sigma_v_mps2=inf")
    assert res.exit_code == 2 and "parameter 'design_sigma_v_mps2' must be finite" in res.output
    res = invoke("simulate", "radar-tws", "--runs", 1, "-o", tmp_path / "r.mcap", "--set", "sigma_range_m=0")
    assert res.exit_code == 2 and "sigma_range_m must be > 0" in res.output
    assert not (tmp_path / "r.mcap").exists()


@pytest.mark.parametrize("args", [
    ["{data}", "--out", "{data}", "--no-rrd"],
    ["{data}", "--out", "{out}", "--rrd", "{data}"],
    ["convert", "plots-csv", "{csv}", "-o", "{csv}"],
    ["simulate", "{toml}", "-o", "{toml}"],
    ["view", "{data}", "--screenshot", "{data}"],
])
def test_an_output_that_is_an_input_is_refused_and_the_input_kept(runner, tmp_path, sha, args):
    import shutil

    data = tmp_path / "in.mcap"
    shutil.copy(REPO / "data" / "radar_tws_demo.mcap", data)
    csv = tmp_path / "plots.csv"
    csv.write_text("time_s,range_m,bearing_deg\n0,1000,10\n5,1001,10\n10,1002,10\n")
    toml = tmp_path / "sc.toml"
    toml.write_text((REPO / "data" / "scenarios" / "radar-tws.toml").read_text())
    paths = {"data": data, "csv": csv, "toml": toml, "out": tmp_path / "o" / "tracks.mcap"}
    before = {p: sha(p) for p in (data, csv, toml)}
    res = runner.invoke(main, [a.format(**paths) for a in args])
    assert res.exit_code == 2, res.output
    lines = [l for l in res.output.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("replay: error:") and "input" in lines[0], res.output
    assert {p: sha(p) for p in (data, csv, toml)} == before
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, words", [
    (["simlate", "radar-tws", "-o", "x.mcap"], ["did you mean 'simulate'"]),
    (["simulate", "radar-tws", "--runs", "0", "-o", "x.mcap"], ["--runs"]),
    (["simulate", "radar-tws", "--seed", "-1", "-o", "x.mcap"], ["--seed"]),
    (["run", "--no-such-option"], ["--no-such-option"]),
    (["help", "swep"], ["did you mean 'sweep'"]),
])
def test_usage_errors_are_one_line(runner, args, words):
    res = runner.invoke(main, args)
    assert res.exit_code == 2
    lines = [l for l in res.output.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("replay: error:"), res.output
    assert all(w in lines[0] for w in words)


# ---- the declared value table (trackreplay.vocabulary.VALUES) at the read boundary


def _radar_frames(range_m=1000.0, bearing=0.3, t=0.0):
    return {"/radar/plots": [(0, k, t + 5.0 * k, {"range_m": np.array([range_m + k]), "bearing_rad": np.array([bearing])})
                             for k in range(4)]}


@pytest.mark.parametrize("case, frames, fragment", [
    ("bool", {"/radar/plots": [(0, k, 5.0 * k, {"range_m": np.array([True]), "bearing_rad": np.array([0.1])})
                               for k in range(4)]}, "range_m holds bool values (expected float/integer)"),
    ("complex", {"/radar/plots": [(0, k, 5.0 * k, {"range_m": np.array([1000 + 1j]), "bearing_rad": np.array([0.1])})
                                  for k in range(4)]}, "range_m holds complex128 values"),
    ("huge", _radar_frames(range_m=1e300), "range_m holds 1 value(s) above 1e+12"),
    ("negative", _radar_frames(range_m=-5000.0), "range_m holds 1 negative value(s)"),
], ids=lambda v: v if isinstance(v, str) else "")
def test_values_outside_the_declared_table_are_refused(tmp_path, case, frames, fragment, sha):
    path = write_frames(tmp_path / f"{case}.mcap", frames)
    before = sha(path)
    res = invoke(path, "--out", tmp_path / "o" / "tracks.mcap", "--no-rrd")
    assert_one_line_error(res, path, fragment)
    assert sha(path) == before and not (tmp_path / "o").exists()


def test_a_csv_time_beyond_any_recording_is_one_line(tmp_path, sha):
    csv = tmp_path / "plots.csv"
    csv.write_text("time,range_m,bearing_deg\n0,1000,10\n5,1001,10\n1e15,1002,10\n")
    before = sha(csv)
    res = invoke("convert", "plots-csv", csv, "-o", tmp_path / "p.mcap")
    assert res.exit_code == 2 and "scan time" in res.stderr and "Traceback" not in res.output, res.output
    assert len([l for l in res.stderr.splitlines() if l.strip()]) == 1
    assert sha(csv) == before and not (tmp_path / "p.mcap").exists()


# ---- environment and parameter failures: one line each, nothing written


def test_catalogue_of_environment_and_parameter_failures(tmp_path, sha):
    import wave

    data = tmp_path / "d.mcap"
    data.write_bytes((REPO / "data" / "radar_tws_demo.mcap").read_bytes())
    (tmp_path / "afile").write_text("")
    (tmp_path / "bad.toml").write_text('name = "x"\nrecorder = "radar-tws"\n[params]\nn_scans = "abc"\n')
    (tmp_path / "typo.toml").write_text('name = "x"\nrecorder = "radar-tws"\n[params]\nscan_perod_s = 4.0\n')
    (tmp_path / "frac.csv").write_text("time,range_m,bearing_deg,run\n0,1000,10,0.5\n5,1001,10,0\n10,1002,10,0\n")
    with wave.open(str(tmp_path / "short.wav"), "wb") as w:
        w.setnchannels(4), w.setsampwidth(2), w.setframerate(16000)
        w.writeframes(np.zeros((4000, 4), "<i2").tobytes())
    cases = [
        ([data, "--out", tmp_path / "afile" / "x" / "tracks.mcap", "--no-rrd"], "Not a directory"),
        (["simulate", tmp_path / "bad.toml", "-o", tmp_path / "x.mcap"], "cannot read 'abc' as int"),
        (["simulate", tmp_path / "typo.toml", "-o", tmp_path / "y.mcap"], "unknown parameter(s) 'scan_perod_s'"),
        (["convert", "plots-csv", tmp_path / "frac.csv", "-o", tmp_path / "f.mcap"], "non-integer"),
        (["convert", "array-wav", tmp_path / "short.wav", "-o", tmp_path / "w.mcap", "--spacing-m", "0.05",
          "--frequency-hz", "2000", "--nfft", "10000000"], "longer than the recording"),
    ]
    inputs = [data, tmp_path / "bad.toml", tmp_path / "typo.toml", tmp_path / "frac.csv", tmp_path / "short.wav"]
    before = {p: sha(p) for p in inputs}
    for args, fragment in cases:
        res = invoke(*args)
        lines = [l for l in res.stderr.splitlines() if l.strip()]
        assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("replay: error:"), (args, res.output)
        assert fragment in lines[0] and "Traceback" not in res.output, (args, lines[0])
    assert {p: sha(p) for p in inputs} == before
    assert not any((tmp_path / n).exists() for n in ("x.mcap", "y.mcap", "f.mcap", "w.mcap"))


@pytest.mark.parametrize("case", ["duplicate", "mismatch"])
def test_duplicated_frames_and_unequal_item_lists_are_refused(tmp_path, case, sha):
    frames = [(0, k, 5.0 * k, {"range_m": np.array([1000.0 + k]), "bearing_rad": np.array([0.3])}) for k in range(4)]
    if case == "duplicate":
        frames.append((0, 2, 10.0, {"range_m": np.array([1000.0]), "bearing_rad": np.array([0.3])}))
        fragment = "1 duplicated frame(s), the first at run 0 scan 2"
    else:
        frames[1] = (0, 1, 5.0, {"range_m": np.array([1001.0, 7.0]), "bearing_rad": np.array([0.3])})
        fragment = "range_m and bearing_rad list different numbers of items at run 0 scan 1 (2 vs 1)"
    path = write_frames(tmp_path / f"{case}.mcap", {"/radar/plots": frames})
    before = sha(path)
    res = invoke(path, "--out", tmp_path / "o" / "tracks.mcap", "--no-rrd")
    assert_one_line_error(res, path, fragment)
    assert sha(path) == before and not (tmp_path / "o").exists()


@pytest.mark.parametrize("block", [1, 3, 7, 1 << 19])
def test_the_value_check_counts_the_same_in_any_block(monkeypatch, block):
    """The value table's check runs in blocks of values (its temporaries stay small); the counts it
    reports, NaN, above and below, and complex magnitudes, do not depend on the block."""
    import trackreplay.contract.checking as checking
    from trackreplay.vocabulary import ValueSpec

    monkeypatch.setattr(checking, "VALUES_CHECK_BLOCK", block)
    a = np.arange(20.0).reshape(4, 5)
    a[1, 2] = a[3, 4] = np.nan
    assert checking._values_problem(a, ValueSpec()) == "holds 2 NaN/Inf value(s)"
    a = np.nan_to_num(a) - 3.0
    assert checking._values_problem(a, ValueSpec(low=0.0)) == "holds 5 negative value(s)"  # -3, -2, -1 and the two NaN
    assert checking._values_problem(a, ValueSpec(high=10.0)) == "holds 5 value(s) above 10"  # 14 … 18, less 3
    z = np.full((3, 4), 1e29 + 1e29j)
    z[2, 1] = 1e30 + 0j          # on the bound: accepted
    z[0, 3] = 8e29 + 8e29j       # |z| > 1e30 although neither part is
    assert checking._values_problem(z, ValueSpec(kinds="fc", low=-1e30, high=1e30)) == "holds 1 value(s) above 1e+30"
