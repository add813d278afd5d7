"""Array recordings the project has never seen, at the defaults (issue 28, item 4).

The recordings come from ``tests/independent_array_generator.py``, which shares nothing with the
project's simulator: speech-like sources, time-varying fractional delays by a windowed-sinc
interpolator (sources that move during the recording), spherically isotropic (diffuse) noise.
Each is converted as a user would (``replay convert array-wav REC.wav --spacing-m 0.05
--frequency-hz 3430``) and replayed with no ``--set``: the source count must be right and every
source tracked within 0.5° of the truth at the scans' time stamps, start-up included, by both
trackers, static and moving, at 15, 20 and 25 dB, at d = λ/2 and at d = 0.29 λ (where the diffuse
noise is far from white). See ``docs/papers/array.md`` (Recordings: wideband sources).
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

import independent_array_generator as gen
from trackreplay.contract import read_dataset
from trackreplay.cores.array import wideband_count as wc
from trackreplay.cores.array.past_subspace import subspace_instant_offset
from trackreplay.face.cli import main
from trackreplay.replay import replay

SPACING_M, FREQUENCY_HZ, SECONDS = 0.05, 3430.0, 10.0
D = np.deg2rad
RECORDINGS = {  # name: (sources, SNR per sensor and source in the source band (dB), seed[, frequency])
    "static-25dB": ([gen.Source(D(-35.0)), gen.Source(D(5.0)), gen.Source(D(40.0))], 25.0, 11),
    "static-15dB": ([gen.Source(D(-50.0)), gen.Source(D(-10.0)), gen.Source(D(30.0))], 15.0, 12),
    "moving-25dB": ([gen.Source(D(-40.0), D(3.2)), gen.Source(D(45.0), D(-2.5))], 25.0, 13),
    "moving-15dB": ([gen.Source(D(-45.0), D(2.0)), gen.Source(D(0.0)), gen.Source(D(50.0), D(-3.0))], 15.0, 14),
    # d = 0.29 λ: the diffuse noise is far from white there (neighbours correlate by 0.47)
    "moving-20dB-2kHz": ([gen.Source(D(-40.0), D(3.0)), gen.Source(D(35.0), D(-2.0))], 20.0, 5, 2000.0),
}
TOLERANCE_DEG = 0.5


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    """Every recording written, converted at the defaults and replayed at the defaults."""
    folder = tmp_path_factory.mktemp("foreign")
    out = {}
    for name, (sources, snr_db, seed, *frequency) in RECORDINGS.items():
        wav, mcap = folder / f"{name}.wav", folder / f"{name}.mcap"
        gen.write_wav(wav, gen.record(sources, snr_db, SECONDS, seed))
        r = CliRunner().invoke(main, ["convert", "array-wav", str(wav), "-o", str(mcap), "--spacing-m", str(SPACING_M),
                                      "--frequency-hz", str(frequency[0] if frequency else FREQUENCY_HZ)])
        assert r.exit_code == 0, r.output
        out[name] = (mcap, sources, r.output, replay(mcap))
    return out


def errors_deg(result, tracker, sources):
    """``(scans, sources)``: each source's distance to the nearest track at the scans' time stamps."""
    stage = result.results["array"]
    times = np.asarray(stage["times"], float)
    est = stage["tracks"][tracker]["state"][0, :, :, 0]  # (K, slots)
    truth = np.stack([s.bearing_rad(times) for s in sources], -1)  # (K, N)
    gap = np.abs(est[:, :, None] - truth[:, None, :])
    return np.rad2deg(np.nanmin(np.where(np.isnan(gap), np.inf, gap), axis=1))


@pytest.mark.parametrize("name", list(RECORDINGS))
def test_count_right_and_every_source_within_half_a_degree_at_the_defaults(converted, name):
    mcap, sources, printed, result = converted[name]
    params = read_dataset(mcap).scenario["params"]
    assert params["n_sources"] == len(sources), printed
    assert f"{len(sources)} source(s) by wideband MDL" in printed
    for tracker in ("proposed", "ryu"):
        state = result.results["array"]["tracks"][tracker]["state"]
        assert state.shape[2] == len(sources)  # one track per source, no false one
        assert np.all(np.isfinite(state[0, 1:, :, 0]))  # none deleted
        worst = errors_deg(result, tracker, sources).max(axis=0)
        assert np.all(worst < TOLERANCE_DEG), (name, tracker, worst)


def test_scans_are_stamped_at_their_centre_and_moving_tracks_do_not_trail(converted):
    """A scan's time stamp is the centre of its frames; on moving sources the tracks' mean
    signed error at those stamps is small, while the paper's filter as printed
    (``align_subspace_instant=false``) trails each source by its rate times PAST's offset from
    :func:`subspace_instant_offset` (agreement within a third, an independent prediction)."""
    mcap, sources, _, aligned = converted["moving-25dB"]
    ds = read_dataset(mcap)
    p = ds.scenario["params"]
    times = np.asarray(aligned.results["array"]["times"], float)
    centre = ((p["snapshots_per_scan"] - 1) * p["hop"] + p["nfft"]) / (2 * p["sample_rate_hz"])
    assert times[0] == pytest.approx(centre) and np.diff(times) == pytest.approx(p["scan_period_s"])
    printed = replay(mcap, design_overrides={"align_subspace_instant": False})
    offset = subspace_instant_offset("past", 0.97, p["scan_period_s"], p["snapshots_per_scan"], times.size)[-1]
    settled = slice(6, None)  # PAST's start forgotten (offset within 1 % of its limit)
    for result, expected in ((aligned, 0.0), (printed, offset)):
        stage = result.results["array"]
        est = stage["tracks"]["proposed"]["state"][0, settled, :, 0]
        for j, source in enumerate(sorted(sources, key=lambda s: s.start_rad)):
            signed = np.rad2deg(np.mean(est[:, j] - source.bearing_rad(times[settled])))
            lag = np.rad2deg(source.rate_rad_s) * expected
            if expected == 0.0:
                assert abs(signed) < 0.1, signed
            else:
                assert abs(signed - lag) < abs(lag) / 3, (signed, lag)


def test_diffuse_noise_alone_is_no_source_once_modelled():
    """Diffuse noise at d = 0.29 λ has eigenvalues spread by tens of dB: MDL taking it as white
    counts sources in noise alone, the count with the noise model chosen by description length
    (:func:`noise_model_and_dimension`) counts none, and the model it picks is a diffuse one."""
    fs, M, frequency = 16000, 8, 2000.0
    noise = gen.diffuse_noise(fs * 3, fs, M, SPACING_M, 343.0, np.random.default_rng(3)).T
    noise += 0.01 * np.random.default_rng(4).standard_normal(noise.shape)  # sensor noise, 20 dB below
    bins = wc._bins((0.9 * frequency, 1.1 * frequency), fs, 512)
    X = np.conj(wc.stft_at_bins(noise[:, ::-1], 512, 256, bins))
    cov = np.einsum("kmj,knj->jmn", X, np.conj(X)) / X.shape[0]
    n_eff = wc.effective_snapshots(X.shape[0], 512, 256)
    spacing = SPACING_M / 343.0 * bins * fs / 512
    assert wc.band_source_count(cov, n_eff)[0] >= M // 2  # white-noise MDL: noise taken for sources
    ratio_db, dimension, _ = wc.noise_model_and_dimension(cov, n_eff, spacing)
    assert dimension == 0 and ratio_db is not None and ratio_db >= 10.0
    assert wc.segment_count(cov, n_eff, spacing)[1].size == 0


def test_past_instant_offset_is_the_mean_age_of_its_weights():
    """The closed form against the weights summed term by term: (1 − β) βⁱ for the snapshots,
    β^n for the start (scan 0's EVD, at scan 0's centre)."""
    beta, Ns, T, K = 0.95, 12, 0.3, 7
    got = subspace_instant_offset("past", beta, T, Ns, K)
    assert got[0] == got[1] == 0.0
    for k in range(2, K):
        n = k * Ns
        ages = np.arange(n, dtype=float)
        weights = (1 - beta) * beta ** ages
        mean_age = weights @ ages + beta ** n * (n + (Ns - 1) / 2)
        assert got[k] == pytest.approx(-T / Ns * (mean_age - (Ns - 1) / 2), rel=1e-12)
    assert np.all(subspace_instant_offset("batch", beta, T, Ns, K) == 0.0)
    assert np.all(subspace_instant_offset("past", 1.0, T, Ns, K) == 0.0)
    # the limit: β/(1 − β) snapshots of mean age
    far = subspace_instant_offset("past", beta, T, Ns, 400)[-1]
    assert far == pytest.approx(-T / Ns * (beta / (1 - beta) - (Ns - 1) / 2), rel=1e-9)
