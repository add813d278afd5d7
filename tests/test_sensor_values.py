"""Sensor values come from the data set, never from a bundled scenario (issue 28, items 1–2).

A converted recording records what the user said about its sensor (``--set`` on ``replay
convert``, a mapping file's ``[sensor]`` table) and what the file holds (runs, scans, time span);
a tracker that needs a value the recording does not say stops with one line naming the ``--set``
it needs, the others run; the scan period is estimated from the scan times and said; bounds and
efficiencies appear only for simulations (``pipeline/sensor_values.py``, ``docs/importers.md``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay import sensor_values as sv
from trackreplay.contract import METADATA_PROVENANCE, read_dataset
from trackreplay.face.cli import main
from trackreplay.recorders.scenarios import load_scenario

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "data" / "samples"
RADAR = load_scenario("radar-tws").params


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def ok(res):
    assert res.exit_code == 0, res.output + (res.stderr or "")
    return res


def digest(folder: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def one_error_line(res, *fragments) -> str:
    """The command failed with exit 2 and exactly one ``replay: error:`` line holding ``fragments``."""
    lines = [line for line in (res.stderr or "").splitlines() if line.strip()]
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and lines[0].startswith("replay: error: "), res.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def plots_table(path: Path, times, runs: int = 1, seed: int = 0) -> Path:
    """A plots table of one target flying straight, ``runs`` runs at ``times``, with truth."""
    rng = np.random.default_rng(seed)
    rows = ["run,time_s,range_m,bearing_rad,truth_x_m,truth_y_m,truth_vx_mps,truth_vy_mps"]
    for r in range(runs):
        for t in map(float, times):
            x, y = 8000.0 + 20.0 * t, 6000.0 - 10.0 * t
            rng_m = float(np.hypot(x, y) + rng.normal(0, 30.0))
            brg = float(np.arctan2(y, x) + rng.normal(0, np.deg2rad(0.4)))
            rows.append(f"{r},{t!r},{rng_m!r},{brg!r},{x!r},{y!r},20.0,-10.0")
    path.write_text("\n".join(rows) + "\n")
    return path


def provenance_design(tracks: Path) -> dict:
    return json.loads(read_dataset(tracks).metadata[METADATA_PROVENANCE]["design"])["radar"]


# --------------------------------------------------------------------------- converted with and without


def test_an_unknown_sensor_value_is_refused_naming_its_set_never_filled_from_the_scenario(tmp_path):
    table = plots_table(tmp_path / "plots.csv", np.arange(12) * 4.0, runs=2)
    with_noise, without = tmp_path / "with.mcap", tmp_path / "without.mcap"
    ok(invoke("convert", "plots", table, "-o", with_noise, "--set", "sigma_range_m=30", "--set", "sigma_bearing_deg=0.4"))
    res = ok(invoke("convert", "plots", table, "-o", without, "--set", "sigma_bearing_deg=0.4"))
    assert "unknown: sigma_range_m" in res.output  # the converter says what it leaves unknown

    # without: every built-in radar tracker needs the range noise; one line, exit 2, nothing written
    before = digest(tmp_path)
    out = tmp_path / "o" / "tracks.mcap"
    line = one_error_line(invoke(without, "--no-rrd", "--out", out), "--set sigma_range_m=VALUE")
    assert "sigma_bearing_deg" not in line  # the recording says that one
    assert not out.parent.exists() and digest(tmp_path) == before

    # given at replay time, the value used is the one given (the scenario's is 100 m)
    ok(invoke(without, "--no-rrd", "--out", out, "--set", "sigma_range_m=30"))
    design = provenance_design(out)
    assert design["sigma_range_m"] == 30.0 and design["sigma_bearing_deg"] == 0.4
    assert RADAR["sigma_range_m"] != 30.0 and RADAR["sigma_bearing_deg"] != 0.4
    # the file that says it replays with the same values and the same outputs
    ok(invoke(with_noise, "--no-rrd", "--out", tmp_path / "w" / "tracks.mcap"))
    assert provenance_design(tmp_path / "w" / "tracks.mcap") == design
    a = read_dataset(out).channel("/tracks/radar/kalman").grid("state")
    b = read_dataset(tmp_path / "w" / "tracks.mcap").channel("/tracks/radar/kalman").grid("state")
    np.testing.assert_array_equal(a, b)


PLUGGED = '''
import numpy as np
from trackreplay.trackers.interface import Param, Tracker

class FirstPlot(Tracker):
    """Needs nothing of the sensor: the first plot of each scan, as x/y."""
    name, family = "first_plot", "radar"
    params = (Param("weight", 1.0),)

    def track(self, plots):
        r, b = plots.range_m[..., 0], plots.bearing_rad[..., 0]
        xy = np.stack([r * np.cos(b), r * np.sin(b)], axis=-1) * self.weight
        state = np.concatenate([xy, np.zeros_like(xy)], axis=-1)
        return {"state": state, "flags": np.zeros(state.shape[:2], np.uint16)}
'''


def test_the_trackers_that_can_still_run_when_others_lack_a_sensor_value(tmp_path):
    table = plots_table(tmp_path / "plots.csv", np.arange(8) * 4.0)
    data = tmp_path / "rec.mcap"
    ok(invoke("convert", "plots", table, "-o", data))
    (tmp_path / "plugged.py").write_text(PLUGGED)
    out = tmp_path / "o" / "tracks.mcap"
    res = invoke(data, "--no-rrd", "--out", out, "--tracker", f"{tmp_path / 'plugged.py'}:FirstPlot")
    assert res.exit_code == 2, res.output
    lines = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(lines) == 4 and all("--set sigma_range_m=VALUE --set sigma_bearing_deg=VALUE" in x for x in lines)
    assert sorted(line.split("'")[1] for line in lines) == ["approximate", "exact", "fixed", "kalman"]
    written = read_dataset(out)  # the one that could run is written, complete
    assert [t for t in written.channels if t.startswith("/tracks/")] == ["/tracks/radar/first_plot"]


def test_the_scan_period_is_estimated_from_the_scan_times_and_said(tmp_path):
    times = [0.0, 2.5, 5.0, 7.5, 12.5, 15.0, 17.5]  # one scan missing: the median interval is still 2.5 s
    data = tmp_path / "rec.mcap"
    ok(invoke("convert", "plots", plots_table(tmp_path / "p.csv", times), "-o", data,
              "--set", "sigma_range_m=30", "--set", "sigma_bearing_deg=0.4"))
    res = ok(invoke(data, "--no-rrd", "--out", tmp_path / "o" / "tracks.mcap"))
    assert "note: scan_period_s = 2.5 estimated from the median interval between scan times" in " ".join(
        res.output.split())
    assert provenance_design(tmp_path / "o" / "tracks.mcap")["scan_period_s"] == float(np.median(np.diff(times)))
    # given, it is the given one, and nothing is said
    res = ok(invoke(data, "--no-rrd", "--out", tmp_path / "g" / "tracks.mcap", "--set", "scan_period_s=3"))
    assert "estimated" not in res.output
    assert provenance_design(tmp_path / "g" / "tracks.mcap")["scan_period_s"] == 3.0


def test_the_metadata_of_a_converted_file_matches_what_it_holds(tmp_path):
    times = np.arange(150) * 4.0 + 1000.0  # 150 scans (the bundled scenario has 64)
    data = tmp_path / "rec.mcap"
    ok(invoke("convert", "plots", plots_table(tmp_path / "p.csv", times, runs=3), "-o", data,
              "--set", "detection_probability=0.9", "--set", "sigma_range_m=30"))
    ds = read_dataset(data)
    params, plots = ds.scenario["params"], ds.channel("/radar/plots")
    assert params["n_scans"] == plots.n_scans == 150 and params["n_runs"] == plots.n_runs == 3
    assert params["time_span_s"] == float(plots.times()[-1] - plots.times()[0]) == 596.0
    assert params["first_time_s"] == 1000.0 and params["detection_probability"] == 0.9
    sources = sv.recorded_sources(ds.scenario)
    assert sources["detection_probability"] == sources["sigma_range_m"] == sv.CONVERTER_FLAG
    assert sources["n_scans"] == sources["n_runs"] == sources["time_span_s"] == sv.DATA
    # nothing of the scenario's truth or sensor rides along
    for key in ("start_x_m", "truth_process_noise_mps2", "sigma_bearing_deg", "scan_period_s"):
        assert key not in params
    assert sv.is_recording(ds.scenario) and not sv.is_simulation(ds.scenario)


def test_a_mapping_files_sensor_table_is_recorded_and_a_flag_wins(tmp_path):
    mapping = (SAMPLES / "ros2_radar_map.toml").read_text()
    (tmp_path / "map.toml").write_text(mapping)
    out = tmp_path / "ours.mcap"
    ok(invoke("convert", "mcap", SAMPLES / "ros2_radar.mcap", "--map", tmp_path / "map.toml", "-o", out,
              "--set", "sigma_bearing_deg=0.7"))
    ds = read_dataset(out)
    sources = sv.recorded_sources(ds.scenario)
    assert ds.scenario["params"]["sigma_range_m"] == 100.0 and sources["sigma_range_m"] == sv.MAPPING_FILE
    assert ds.scenario["params"]["sigma_bearing_deg"] == 0.7 and sources["sigma_bearing_deg"] == sv.CONVERTER_FLAG
    plots = ds.channel("/radar/plots")  # the record says what the file holds
    assert (ds.scenario["params"]["n_runs"], ds.scenario["params"]["n_scans"]) == (plots.n_runs, plots.n_scans)
    assert ds.scenario["params"]["time_span_s"] == float(plots.times()[-1] - plots.times()[0])
    # without the table, the noise is unknown and the replay through the mapping asks for it
    bare = "\n".join(line for line in mapping.splitlines() if line.strip() and not line.startswith(
        ("[sensor]", "sigma_", "#")))
    (tmp_path / "bare.toml").write_text(bare + "\n")
    one_error_line(invoke(SAMPLES / "ros2_radar.mcap", "--map", tmp_path / "bare.toml", "--no-rrd",
                          "--out", tmp_path / "o" / "tracks.mcap"), "--set sigma_range_m=VALUE")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("sensor, fragment", [
    ('sigma_rang_m = 100.0', "unknown parameter 'sigma_rang_m'"),
    ('sigma_range_m = "wide"', "parameter 'sigma_range_m'"),
    ('sigma_range_m = [1, 2]', "one value per name"),
])
def test_a_bad_sensor_table_is_one_line_naming_the_mapping_and_nothing_is_written(tmp_path, sensor, fragment):
    bare = (SAMPLES / "ros2_radar_map.toml").read_text().split("[sensor]")[0]
    (tmp_path / "map.toml").write_text(bare + "[sensor]\n" + sensor + "\n")
    before = digest(tmp_path)
    res = invoke("convert", "mcap", SAMPLES / "ros2_radar.mcap", "--map", tmp_path / "map.toml",
                 "-o", tmp_path / "ours.mcap")
    one_error_line(res, str(tmp_path / "map.toml"), fragment)
    assert digest(tmp_path) == before


@pytest.mark.parametrize("sets, fragment", [
    (["--set", "sigma_rnage_m=5"], "unknown parameter 'sigma_rnage_m'"),
    (["--set", "sigma_range_m=abc"], "sigma_range_m"),
    (["--set", "sigma_range_m"], "expected NAME=VALUE"),
])
def test_a_bad_converter_flag_is_one_line_and_nothing_is_written(tmp_path, sets, fragment):
    table = plots_table(tmp_path / "p.csv", np.arange(5) * 4.0)
    before = digest(tmp_path)
    one_error_line(invoke("convert", "plots", table, "-o", tmp_path / "rec.mcap", *sets), fragment)
    assert digest(tmp_path) == before


# --------------------------------------------------------------------------- bounds only where the model is known


BOUNDS = ("pcrb_", "crlb_")


def bound_metrics(summary: list) -> set:
    return {r["metric"] for r in summary if r["metric"].startswith(BOUNDS) or r["metric"].endswith("_efficiency")}


def test_bounds_appear_for_a_simulation_and_not_for_the_same_data_converted(tmp_path):
    sim = tmp_path / "sim.mcap"
    ok(invoke("simulate", "radar-tws", "--runs", "6", "--seed", "4", "-o", sim, "--set", "n_scans=12",
              "--set", "truth_process_noise_mps2=0.5"))
    ok(invoke("export", "--table", sim, "-o", tmp_path / "t"))
    rec = tmp_path / "rec.mcap"
    given = [f"--set={k}={RADAR[k]}" for k in ("sigma_range_m", "sigma_bearing_deg", "scan_period_s")]
    ok(invoke("convert", "plots", tmp_path / "t" / "radar_plots.csv", "-o", rec, *given))
    simulated = json.loads(ok(invoke("eval", sim, "--json")).output)
    converted = json.loads(ok(invoke("eval", rec, "--json")).output)
    assert {"pcrb_position_m", "position_efficiency"} <= bound_metrics(simulated)
    assert bound_metrics(converted) == set()
    # everything else is the same data, tracked the same way: the same numbers
    key = lambda r: (r["tracker"], r["metric"], r["scope"])  # noqa: E731
    same = {key(r): r["value"] for r in simulated if r["metric"] not in bound_metrics(simulated)}
    got = {key(r): r["value"] for r in converted}
    assert set(same) == set(got)
    for k, v in same.items():
        assert (v is None and got[k] is None) or np.isclose(v, got[k], rtol=1e-9, equal_nan=True), k


def test_a_converted_emitter_recording_has_no_crlb(tmp_path):
    rec = tmp_path / "emitter.mcap"
    ok(invoke("convert", "tdoa-fdoa", SAMPLES / "tdoa_fdoa.csv", "--sensors", SAMPLES / "tdoa_fdoa_sensors.csv",
              "-o", rec))
    summary = json.loads(ok(invoke("eval", rec, "--json")).output)
    assert summary and bound_metrics(summary) == set()
    assert any(r["metric"].startswith("rmse_") for r in summary)  # the truth is still scored


def test_a_file_of_an_earlier_converter_keeps_its_values_and_has_no_bound(tmp_path):
    """Seed −1 without sources: the values it holds were possibly the scenario's; they are used
    (as before) and said to be of unknown origin, and the file is a recording: no bound."""
    from trackreplay.contract import scenario_metadata
    from trackreplay.recorders import simulator_for
    from trackreplay.recorders.simulated import write_simulated

    scenario = load_scenario("radar-tws").with_overrides({"n_scans": 10, "truth_process_noise_mps2": 0.5})
    data = simulator_for(scenario.recorder)(scenario.params, 4, 2)
    sim, old = tmp_path / "sim.mcap", tmp_path / "old.mcap"
    write_simulated(sim, data, scenario_metadata(scenario.name, scenario.params, 2))
    write_simulated(old, data, scenario_metadata("radar table", scenario.params, -1))
    record = read_dataset(old).scenario
    assert sv.is_recording(record) and not sv.is_simulation(record)
    assert set(sv.recorded_sources(record).values()) == {sv.EARLIER_CONVERTER}
    simulated = json.loads(ok(invoke("eval", sim, "--json")).output)
    earlier = json.loads(ok(invoke("eval", old, "--json")).output)
    assert "pcrb_position_m" in bound_metrics(simulated) and bound_metrics(earlier) == set()


def test_a_file_without_a_record_is_a_recording_whose_sensor_values_are_unknown(tmp_path):
    """No ``replay.scenario`` record (written by hand, or by an older tool): nothing is borrowed from
    the bundled scenario. A tracker needing the noise stops with one line naming the ``--set``s
    (exit 2, the file untouched), ``replay info`` says so, and with the values given the replay
    scores the simulation's numbers without its bounds (issue 28, item 1)."""
    from trackreplay.contract import scenario_metadata
    from trackreplay.recorders import simulator_for
    from trackreplay.recorders.simulated import write_simulated

    scenario = load_scenario("radar-tws").with_overrides({"n_scans": 10, "truth_process_noise_mps2": 0.5})
    data = simulator_for(scenario.recorder)(scenario.params, 4, 2)
    sim, bare = tmp_path / "sim.mcap", tmp_path / "bare.mcap"
    write_simulated(sim, data, scenario_metadata(scenario.name, scenario.params, 2))
    write_simulated(bare, data, {})
    assert read_dataset(bare).scenario == {}
    assert sv.says_nothing({}) and sv.is_recording({}) and not sv.is_simulation({})
    assert sv.says_nothing({"contract": "replay.v2"}) and not sv.says_nothing(read_dataset(sim).scenario)

    before = hashlib.sha256(bare.read_bytes()).hexdigest()
    res = invoke("eval", bare, "--json")
    errors = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.exit_code == 2 and len(errors) == 1 and "Traceback" not in res.output, res.output
    assert errors[0].startswith(f"replay: error: {bare}: ")
    assert "--set sigma_range_m=VALUE" in errors[0] and "--set sigma_bearing_deg=VALUE" in errors[0]
    assert hashlib.sha256(bare.read_bytes()).hexdigest() == before

    info = json.loads(ok(invoke("info", bare, "--json")).output)
    assert info["origin"] == "recording" and info["says_nothing_of_its_sensor"] is True
    values = info["sensor_values"]["radar"]
    assert values["sigma_range_m"] == {"value": None, "source": sv.UNKNOWN, "needs": "--set sigma_range_m=VALUE"}
    assert "without a replay.scenario record" in ok(invoke("info", bare)).output

    given = [f"--set={k}={scenario.params[k]}" for k in ("sigma_range_m", "sigma_bearing_deg")]
    simulated = json.loads(ok(invoke("eval", sim, "--json")).output)
    recording = json.loads(ok(invoke("eval", bare, "--json", *given)).output)
    assert "pcrb_position_m" in bound_metrics(simulated) and bound_metrics(recording) == set()
    key = lambda r: (r["tracker"], r["metric"], r["scope"])  # noqa: E731
    same = {key(r): r["value"] for r in simulated if r["metric"] not in bound_metrics(simulated)}
    got = {key(r): r["value"] for r in recording}
    assert set(same) == set(got)
    for k, v in same.items():
        assert (v is None and got[k] is None) or np.isclose(v, got[k], rtol=1e-9, equal_nan=True), k
