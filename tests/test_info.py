"""``replay info DATA.mcap``: what a data set holds and where each sensor value comes from."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay import sensor_values as sv
from trackreplay.contract import read_dataset
from trackreplay.face.cli import main

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "data" / "samples"


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def info_json(path) -> dict:
    res = invoke("info", path, "--json")
    assert res.exit_code == 0, res.output + (res.stderr or "")
    return json.loads(res.output)


def test_a_simulation_says_its_channels_and_that_every_value_is_a_simulation_parameter(tmp_path):
    sim = tmp_path / "sim.mcap"
    assert invoke("simulate", "radar-tws", "--runs", "3", "--seed", "5", "-o", sim, "--set", "n_scans=9",
                  "--set", "sigma_range_m=42").exit_code == 0
    info, ds = info_json(sim), read_dataset(sim)
    assert info["origin"] == "simulation" and info["scenario"] == "radar-tws" and info["seed"] == "5"
    assert info["runs"] == 3 and info["scans"] == 9 and info["truth"] is True
    assert set(info["channels"]) == set(ds.channels)
    for topic, ch in ds.channels.items():
        got = info["channels"][topic]
        assert (got["runs"], got["scans"], got["frames"]) == (ch.n_runs, ch.n_scans, ch.n_frames)
        assert got["arrays"] == sorted(ch.arrays)
    times = ds.channel("/radar/plots").times()
    assert info["time_span_s"] == [float(times.min()), float(times.max())]
    radar = info["sensor_values"]["radar"]
    assert radar["sigma_range_m"] == {"value": 42.0, "source": sv.SIMULATION}
    assert radar["scan_period_s"]["source"] == sv.SIMULATION
    text = invoke("info", sim)
    assert text.exit_code == 0 and "a simulation of radar-tws (seed 5)" in text.output
    assert "/radar/plots" in text.output and "3 run(s) × 9 scan(s)" in text.output


def test_a_recording_says_each_value_given_estimated_or_unknown(tmp_path):
    rec = tmp_path / "rec.mcap"
    res = invoke("convert", "plots", SAMPLES / "radar_plots.csv", "-o", rec, "--set", "sigma_range_m=80")
    assert res.exit_code == 0, res.output
    info = info_json(rec)
    radar = info["sensor_values"]["radar"]
    assert info["origin"] == "recording" and info["truth"] is True
    assert radar["sigma_range_m"] == {"value": 80.0, "source": sv.CONVERTER_FLAG}
    assert radar["sigma_bearing_deg"] == {"value": None, "source": sv.UNKNOWN, "needs": "--set sigma_bearing_deg=VALUE"}
    times = read_dataset(rec).channel("/radar/plots").times()
    assert radar["scan_period_s"]["value"] == float(np.median(np.diff(times)))
    assert radar["scan_period_s"]["source"].startswith(sv.ESTIMATED)
    # what the file holds, from the data
    assert info["recorded"]["n_scans"] == {"value": info["scans"], "source": sv.DATA}
    assert info["recorded"]["n_runs"] == {"value": info["runs"], "source": sv.DATA}
    text = invoke("info", rec).output
    assert "unknown: a tracker that needs it asks for --set sigma_bearing_deg=VALUE" in text


def test_a_mapping_files_values_say_so(tmp_path):
    rec = tmp_path / "many.mcap"
    res = invoke("convert", "mcap", SAMPLES / "json_radar_many.mcap", "--map", SAMPLES / "json_radar_many_map.toml",
                 "-o", rec)
    assert res.exit_code == 0, res.output
    radar = info_json(rec)["sensor_values"]["radar"]
    assert radar["clutter_per_scan"] == {"value": 1.5, "source": sv.MAPPING_FILE}
    assert radar["detection_probability"] == {"value": 0.85, "source": sv.MAPPING_FILE}


def test_the_emitter_family_reads_its_sensor_from_the_measurements(tmp_path):
    rec = tmp_path / "emitter.mcap"
    assert invoke("convert", "tdoa-fdoa", SAMPLES / "tdoa_fdoa.csv", "--sensors", SAMPLES / "tdoa_fdoa_sensors.csv",
                  "-o", rec).exit_code == 0
    values = info_json(rec)["sensor_values"]["tdoa-fdoa"]
    carrier = np.concatenate([np.ravel(a) for a in read_dataset(rec).channel("/emitter/measurements").array("carrier_hz")])
    assert values["carrier_hz"]["value"] == float(carrier[0]) and np.all(carrier == carrier[0])
    assert values["carrier_hz"]["source"].startswith(sv.DATA)


@pytest.mark.parametrize("content, fragment", [(None, "no such file"), (b"not an mcap file", "")])
def test_a_bad_file_is_one_line_and_is_not_touched(tmp_path, content, fragment):
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    before = hashlib.sha256(content).hexdigest() if content is not None else None
    res = invoke("info", path)
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"replay: error: {path}: "), res.stderr
    assert fragment in lines[0]
    if content is not None:
        assert hashlib.sha256(path.read_bytes()).hexdigest() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ([] if content is None else ["bad.mcap"])


def test_a_wav_recording_says_its_geometry_comes_from_the_converters_flags(tmp_path):
    from scipy.io import wavfile

    fs, M, spacing, c = 16000, 4, 0.05, 343.0
    rng = np.random.default_rng(3)
    t = np.arange(int(1.5 * fs)) / fs
    delay = spacing * np.sin(np.deg2rad(20.0)) / c  # one source at 20°, a tone in white noise
    x = np.stack([np.sin(2 * np.pi * 2000.0 * (t - m * delay)) for m in range(M)], axis=1)
    x += 0.05 * rng.standard_normal(x.shape)
    wavfile.write(tmp_path / "rec.wav", fs, (x / np.abs(x).max() * 0.9).astype(np.float32))
    rec = tmp_path / "rec.mcap"
    res = invoke("convert", "array-wav", tmp_path / "rec.wav", "-o", rec, "--spacing-m", spacing,
                 "--frequency-hz", 2000, "--nfft", 256, "--snapshots-per-scan", 10)
    assert res.exit_code == 0, res.output + (res.stderr or "")
    info = info_json(rec)
    values = info["sensor_values"]["array"]
    assert info["origin"] == "recording" and info["truth"] is False
    assert values["spacing_wavelengths"]["source"] == sv.CONVERTER_FLAG
    recorded = read_dataset(rec).scenario["params"]
    assert values["spacing_wavelengths"]["value"] == recorded["spacing_wavelengths"] == spacing * recorded[
        "frequency_hz"] / c
    assert values["scan_period_s"]["value"] == 10 * 128 / fs
    assert info["recorded"]["n_sensors"] == {"value": M, "source": sv.DATA}
