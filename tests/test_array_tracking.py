"""Array snapshots → bearing tracks, end to end: scenario, replay, Table 1, WAV input, bad input."""

import hashlib
import json

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay.evaluators.array import associate, follow_events
from trackreplay.face.cli import main
from trackreplay.contract import read_dataset, scenario_metadata, write_dataset
from trackreplay.cores.array.linear_array import beamwidth_rad
from trackreplay.replay import replay
from trackreplay.recorders.array_snapshots import truth_angles
from trackreplay.recorders.scenarios import load_scenario

RUNS = 40  # per SNR; the 100-run study is in benchmarks/bench_array.py


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def crossing(tmp_path_factory):
    """The default scenario at 0, 5 and 10 dB, written through the CLI, and its replay."""
    path = tmp_path_factory.mktemp("array") / "array.mcap"
    res = CliRunner().invoke(main, ["simulate", "array-crossing", "--runs", str(RUNS), "--snr-db", "0,5,10",
                                    "--seed", "3", "-o", str(path)])
    assert res.exit_code == 0, res.output
    return path, replay(path)


def metric(summary, tracker, name, scope):
    rows = summary.filter((summary["tracker"] == tracker) & (summary["metric"] == name) & (summary["scope"] == scope))
    assert rows.height == 1, (tracker, name, scope)
    return rows["value"][0]


# --------------------------------------------------------------------------- scenario


def test_default_scenario_matches_the_paper_setup():
    p = load_scenario("array-crossing").params
    assert (p["n_sensors"], p["spacing_wavelengths"], p["noise_variance"], p["snapshots_per_scan"],
            p["scan_period_s"], p["n_targets"]) == (15, 0.5, 1.0, 30, 1.0, 5)
    _, theta = truth_angles(p)
    diff = theta[:, :, None] - theta[:, None, :]
    crossings = sum(np.count_nonzero(np.diff(np.sign(diff[:, i, j])) != 0)
                    for i in range(5) for j in range(i + 1, 5))
    assert crossings >= 2
    rate = np.diff(theta, axis=0)
    assert np.any(np.abs(np.diff(rate, axis=0)) > np.deg2rad(0.1))  # a manoeuvre: the rate changes
    assert np.min(np.abs(diff[:, ~np.eye(5, dtype=bool)])) < beamwidth_rad(15)  # closer than the beamwidth
    start = np.sort(theta[0])
    assert np.min(np.diff(start)) > beamwidth_rad(15)  # MUSIC can resolve them at start-up


def test_simulated_file_holds_runs_times_snrs(crossing):
    path, _ = crossing
    ds = read_dataset(path)
    snaps = ds.channel("/array/snapshots")
    assert snaps.n_runs == 3 * RUNS and snaps.n_scans == 62
    assert snaps.arrays["snapshots"][0].shape == (15, 30) and snaps.arrays["snapshots"][0].dtype == np.complex64
    snr = ds.channel("/array/truth").grid("snr_db")[:, 0]
    assert list(np.unique(snr)) == [0.0, 5.0, 10.0] and np.all(snr[:RUNS] == 0) and np.all(snr[-RUNS:] == 10)
    meta = ds.scenario
    assert meta["scenario"] == "array-crossing" and meta["seed"] == "3"
    assert meta["params"]["spacing_wavelengths"] == 0.5


def test_same_seed_same_bytes(tmp_path):
    runner = CliRunner()
    paths = [tmp_path / f"{i}.mcap" for i in range(3)]
    for p, seed in zip(paths, (1, 1, 2)):
        assert runner.invoke(main, ["simulate", "array-crossing", "--runs", "2", "--seed", str(seed),
                                    "--set", "n_scans=5", "-o", str(p)]).exit_code == 0
    assert sha(paths[0]) == sha(paths[1]) != sha(paths[2])


def test_signal_power_matches_the_snr(tmp_path):
    """Per-element SNR: E|x|² = σ² (1 + Σₙ 10^(SNRₙ/10)) with per-target offsets."""
    from trackreplay.recorders.array_snapshots import simulate

    p = dict(load_scenario("array-crossing").params, snr_db=[3.0], n_scans=4, snapshot_dtype="complex128",
             target_snr_offset_db=[0.0, -3.0, 2.0, 0.0, 0.0, 0.0])
    data = simulate(p, 200, 9)
    power = np.mean(np.abs(data.fixed["/array/snapshots"]["snapshots"]) ** 2)
    expected = 1.0 + sum(10 ** ((3.0 + o) / 10) for o in (0.0, -3.0, 2.0, 0.0, 0.0))
    assert abs(power / expected - 1) < 0.02


# --------------------------------------------------------------------------- tracking properties


def test_mse_falls_as_snr_rises(crossing):
    _, res = crossing
    for tracker in ("proposed", "ryu"):
        for name in ("angle_mse_deg2", "angle_mse_deg2_clean"):
            mse = [metric(res.summary, tracker, name, f"snr_db={v}") for v in (0, 5, 10)]
            assert mse[0] > mse[1] > mse[2], (tracker, name, mse)
        losses = [metric(res.summary, tracker, "target_losses_per_run", f"snr_db={v}") for v in (0, 5, 10)]
        assert losses[0] > losses[2]


def test_both_algorithms_give_the_same_tracks_and_mse(crossing):
    _, res = crossing
    tracks = res.results["array"]["tracks"]
    a, b = tracks["proposed"]["state"][..., 0], tracks["ryu"]["state"][..., 0]
    assert np.nanmax(np.abs(a - b)) < 1e-9  # identical innovations → identical filters
    for v in (0, 5, 10):
        sel = res.dataset.channel("/array/truth").grid("snr_db")[:, 0] == v
        truth = res.dataset.channel("/array/truth").grid("angle_rad")[sel][:, 2:]
        per_run = {t: np.mean(np.rad2deg(tracks[t]["state"][sel][:, 2:, :, 0] - truth) ** 2, axis=(1, 2)) for t in tracks}
        diff = per_run["proposed"] - per_run["ryu"]
        mc_error = 2 * np.std(per_run["proposed"]) / np.sqrt(sel.sum())
        assert abs(metric(res.summary, "proposed", "angle_mse_deg2", f"snr_db={v}")
                   - metric(res.summary, "ryu", "angle_mse_deg2", f"snr_db={v}")) <= mc_error
        assert abs(diff.mean()) <= mc_error


def test_no_track_swaps_at_10_db_and_right_source_count(crossing):
    _, res = crossing
    for tracker in ("proposed", "ryu"):
        assert metric(res.summary, tracker, "runs_without_swap", "snr_db=10") >= 0.95
        assert metric(res.summary, tracker, "source_count_correct", "overall") == 1.0


def test_swap_and_loss_accounting_on_constructed_tracks():
    truth = np.zeros((3, 6, 2))
    truth[..., 0], truth[..., 1] = np.deg2rad(-10.0), np.deg2rad(10.0)
    est = truth.copy()
    est[1, 3:] = truth[1, 3:, ::-1]  # run 1: the tracks exchange their targets
    est[2, 3:, 1] = truth[2, 3:, 0]  # run 2: track 1 merges onto target 0
    assoc = associate(est[:, 1], truth[:, 1])
    swapped, lost = follow_events(est, truth, assoc, np.deg2rad(3.0))
    assert swapped.any(axis=(1, 2)).tolist() == [False, True, False]
    assert lost.any(axis=(1, 2)).tolist() == [False, False, True]


# --------------------------------------------------------------------------- CLI, outputs, Rerun


def test_replay_cli_writes_outputs_and_eval_prints_table1(crossing, tmp_path):
    path, res = crossing
    before = sha(path)
    runner = CliRunner()
    out = tmp_path / "o" / "tracks.mcap"
    r = runner.invoke(main, [str(path), "--out", str(out), "--no-rrd"])
    assert r.exit_code == 0, r.output
    assert sha(path) == before
    assert "FLOP ratio" in r.output and "Table 1" not in r.output  # the table repeats the scopes printed above
    layout = (out.parent / "report.txt").read_text()
    assert "Table 1" in layout and "MSE 10 dB" in layout
    # the layout's FLOP counts are the summary's, formatted
    flops = res.summary.filter((res.summary["metric"] == "innovation_flops_model")
                               & (res.summary["scope"] == "n_targets=5"))
    assert flops.height == 2 and all(f"{int(v):,}" in layout for v in flops["value"])
    r = runner.invoke(main, ["eval", str(path), str(out), "--json"])
    assert r.exit_code == 0, r.output
    from_file = {(d["tracker"], d["metric"], d["scope"]): d["value"] for d in json.loads(r.output)}
    in_memory = {(d["tracker"], d["metric"], d["scope"]): d["value"] for d in res.summary.to_dicts()}
    assert from_file.keys() == in_memory.keys()
    assert all(from_file[k] == pytest.approx(in_memory[k], rel=1e-12, abs=1e-15) for k in in_memory)


def test_rerun_recording_of_a_small_file(tmp_path):
    data = tmp_path / "small.mcap"
    runner = CliRunner()
    assert runner.invoke(main, ["simulate", "array-crossing", "--runs", "1", "--set", "n_scans=8", "-o", str(data)]).exit_code == 0
    r = runner.invoke(main, [str(data), "--out", str(tmp_path / "o" / "t.mcap")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "o" / "t.rrd").stat().st_size > 10_000


# --------------------------------------------------------------------------- WAV recordings


def write_array_wav(path, angles_deg, fs=16000, M=8, d=0.04, seconds=5.0, noise=0.3, seed=3):
    """Wideband noise sources at ``angles_deg`` from broadside in the documented convention: a
    positive angle's wave reaches the last channel first (channel m leads channel 0 by
    m d sin θ / c)."""
    from scipy.io import wavfile

    rng = np.random.default_rng(seed)
    n = int(fs * seconds)
    freqs = np.fft.rfftfreq(n, 1 / fs)
    out = noise * rng.standard_normal((n, M))
    for th in np.deg2rad(angles_deg):
        spectrum = np.fft.rfft(rng.standard_normal(n))
        for m in range(M):  # channel m leads channel 0 by m d sin θ / c
            out[:, m] += np.fft.irfft(spectrum * np.exp(2j * np.pi * freqs * m * d * np.sin(th) / 343.0), n)
    wavfile.write(path, fs, (out / np.abs(out).max() * 0.9 * 32767).astype(np.int16))


def test_wav_recording_goes_through_the_same_trackers(tmp_path):
    wav, mcap = tmp_path / "rec.wav", tmp_path / "rec.mcap"
    write_array_wav(wav, [-20.0, 25.0])
    runner = CliRunner()
    r = runner.invoke(main, ["convert", "array-wav", str(wav), "-o", str(mcap), "--spacing-m", "0.04",
                             "--frequency-hz", "2000", "--nfft", "256"])
    assert r.exit_code == 0, r.output
    ds = read_dataset(mcap)
    assert ds.channel("/array/snapshots").arrays["snapshots"][0].shape == (8, 30)
    assert ds.scenario["params"]["spacing_wavelengths"] == pytest.approx(0.04 * 2000 / 343.0)
    res = replay(mcap)
    est = np.rad2deg(res.results["array"]["tracks"]["proposed"]["state"][0, 2:, :, 0])
    assert est.shape[-1] == 2
    assert np.all(np.abs(est - [-20.0, 25.0]) < 1.0)
    assert ds.scenario["params"]["bearing_positive_toward"] == "last channel"
    # the other convention mirrors every bearing
    mirrored = tmp_path / "mirrored.mcap"
    r = runner.invoke(main, ["convert", "array-wav", str(wav), "-o", str(mirrored), "--spacing-m", "0.04",
                             "--frequency-hz", "2000", "--nfft", "256", "--positive-toward", "first"])
    assert r.exit_code == 0, r.output
    other = np.rad2deg(replay(mirrored).results["array"]["tracks"]["proposed"]["state"][0, 2:, :, 0])
    assert np.all(np.abs(other - [-25.0, 20.0]) < 1.0)


def test_wav_frequency_within_half_a_bin_of_half_wavelength_passes_and_a_higher_one_names_one_that_would(tmp_path):
    """3430 Hz at 0.05 m is exactly d = λ/2; its nearest bin (3437.5 Hz at 16 kHz / 512) is
    0.501 λ, within half a bin, and passes with its field of no ambiguity recorded; 3500 Hz is
    refused with the highest frequency that passes."""
    wav = tmp_path / "rec.wav"
    write_array_wav(wav, [10.0], d=0.05, seconds=2.0)
    runner = CliRunner()
    r = runner.invoke(main, ["convert", "array-wav", str(wav), "-o", str(tmp_path / "a.mcap"), "--spacing-m", "0.05",
                             "--frequency-hz", "3430"])
    assert r.exit_code == 0, r.output
    params = read_dataset(tmp_path / "a.mcap").scenario["params"]
    assert 0.5 < params["spacing_wavelengths"] < 0.502
    field = np.rad2deg(np.arcsin(1 / params["spacing_wavelengths"] - 1))
    assert params["unambiguous_field_deg"] == pytest.approx(field) and 80 < field < 90
    r = runner.invoke(main, ["convert", "array-wav", str(wav), "-o", str(tmp_path / "b.mcap"), "--spacing-m", "0.05",
                             "--frequency-hz", "3500"])
    assert r.exit_code == 2 and "grating lobes" in r.output and "up to 3437.5 Hz" in r.output, r.output
    assert not (tmp_path / "b.mcap").exists()


def test_bad_wav_files(tmp_path):
    from scipy.io import wavfile

    runner = CliRunner()
    mono, junk = tmp_path / "mono.wav", tmp_path / "junk.wav"
    wavfile.write(mono, 16000, np.zeros(16000, np.int16))
    junk.write_bytes(b"not a wav file at all")
    good = tmp_path / "good.wav"
    write_array_wav(good, [10.0], seconds=2.0)
    cases = [(mono, ["--spacing-m", "0.04"], "at least 2"), (junk, ["--spacing-m", "0.04"], "not a readable WAV"),
             (good, ["--spacing-m", "0.2"], "grating lobes"), (good, ["--spacing-m", "0.04", "--snapshots-per-scan", "500"], "needs ≥ 3")]
    for src, extra, message in cases:
        out = tmp_path / "out.mcap"
        r = runner.invoke(main, ["convert", "array-wav", str(src), "-o", str(out), "--frequency-hz", "2000", *extra])
        assert r.exit_code == 2, r.output
        assert message in r.output and str(src) in r.output and "Traceback" not in r.output
        assert not out.exists()


# --------------------------------------------------------------------------- bad input


def write_snapshots(path, frames, truth=None, params=None):
    with write_dataset(path, scenario_metadata("array-crossing", params or {}, 0)) as w:
        for k, x in enumerate(frames):
            w.write("/array/snapshots", 0, k, float(k), {"snapshots": x})
            if truth is not None:
                w.write("/array/truth", 0, k, float(k), {"angle_rad": truth, "snr_db": np.array(10.0)})


def test_bad_snapshot_files_fail_with_one_line_and_nothing_lost(tmp_path):
    rng = np.random.default_rng(0)
    good = (rng.standard_normal((15, 30)) + 1j * rng.standard_normal((15, 30))).astype(np.complex64)
    nan = good.copy()
    nan[3, 4] = np.nan
    cases = {
        "real.mcap": ([good.real.copy()] * 4, None, "must be complex"),
        "shape.mcap": ([good[0].copy()] * 4, None, "must be 2-D"),
        "ragged.mcap": ([good, good, good[:, :20].copy(), good], None, "change shape"),
        "nan.mcap": ([good, nan, good, good], None, "NaN"),
        "few.mcap": ([good[:, :3].copy()] * 4, np.deg2rad([-30.0, -12.0, 5.0, 25.0, 45.0]), "fewer than the 5 targets"),
        "short.mcap": ([good] * 2, None, "scan(s)"),
    }
    runner = CliRunner()
    for name, (frames, truth, message) in cases.items():
        path = tmp_path / name
        write_snapshots(path, frames, truth)
        before = sha(path)
        out = tmp_path / f"out_{name}"
        r = runner.invoke(main, [str(path), "--out", str(out / "t.mcap")])
        assert r.exit_code == 2, (name, r.output)
        assert r.output.count("\n") <= 2 and message in r.output and name in r.output, (name, r.output)
        assert "Traceback" not in r.output
        assert sha(path) == before and not (out / "t.mcap").exists()


def test_more_targets_than_the_array_can_hold(tmp_path, crossing):
    path, _ = crossing
    runner = CliRunner()
    r = runner.invoke(main, [str(path), "--no-rrd", "--out", str(tmp_path / "t.mcap"), "--set", "n_sources=15"])
    assert r.exit_code == 2 and "M − 1 = 14" in r.output
    r = runner.invoke(main, ["simulate", "array-crossing", "--runs", "1", "--set", "n_targets=15", "-o", str(tmp_path / "x.mcap")])
    assert r.exit_code == 2 and "n_targets = 15 must be ≤ n_sensors − 1 = 14" in r.output
    assert not (tmp_path / "x.mcap").exists()
    r = runner.invoke(main, ["simulate", "array-crossing", "--runs", "1", "--set", "snapshots_per_scan=4", "-o", str(tmp_path / "y.mcap")])
    assert r.exit_code == 2 and "fewer than the 5 targets" in r.output
    r = runner.invoke(main, ["simulate", "array-crossing", "--runs", "1", "--snr-db", "0,x", "-o", str(tmp_path / "z.mcap")])
    assert r.exit_code == 2 and "snr_db" in r.output
