"""A multichannel WAV of wideband sources: the converter counts them over a band (wideband MDL,
``pipeline/cores/array/wideband_count.py``), records the count as the trackers' ``n_sources``,
and the replayed bearings land on the true ones with the documented sign.

The recordings are simulated here from known sources, in plain numpy: band-limited white noise
per source, delayed for a uniform linear array by a phase ramp in the frequency domain
(fractional delays), plus white sensor noise; see ``docs/importers.md`` (WAV section) and
``docs/papers/array.md``.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay.contract import read_dataset
from trackreplay.cores.array import wideband_count as wc
from trackreplay.face.cli import main
from trackreplay.replay import replay

FS, M, SPACING_M, C = 16000, 8, 0.1, 343.0   # 0.7 m aperture; d = λ/2 at 1715 Hz
FREQUENCY_HZ = 1700.0                         # its bin: 1687.5 Hz at the default nfft = 512
SOURCE_BAND_HZ = (300.0, 3700.0)


def simulate_wav(path, angles_deg, snr_db, seconds=3.0, seed=0):
    """Write a float32 WAV of wideband sources at ``angles_deg`` (from broadside).

    The documented convention: a positive angle's wave reaches the last channel first, so
    channel m leads channel 0 by m d sin θ / c. Every source has unit power spread evenly over
    ``SOURCE_BAND_HZ``; the white sensor noise makes each source's per-sensor SNR within that
    band ``snr_db``.
    """
    from scipy.io import wavfile

    rng = np.random.default_rng(seed)
    n = int(FS * seconds)
    f = np.fft.rfftfreq(n, 1.0 / FS)
    inband = (f >= SOURCE_BAND_HZ[0]) & (f <= SOURCE_BAND_HZ[1])
    lead_s = np.arange(M)[:, None] * SPACING_M / C  # per unit sin θ
    x = np.zeros((M, n))
    for theta in np.deg2rad(angles_deg):
        spectrum = np.fft.rfft(rng.standard_normal(n)) * inband
        spectrum *= np.sqrt(n / (2 * inband.sum()))  # unit power
        x += np.fft.irfft(spectrum[None, :] * np.exp(2j * np.pi * f[None, :] * lead_s * np.sin(theta)), n)
    in_band_share = (SOURCE_BAND_HZ[1] - SOURCE_BAND_HZ[0]) / (FS / 2)
    noise_std = np.sqrt(10 ** (-snr_db / 10) / in_band_share)  # white: only that share lies in the band
    x += noise_std * rng.standard_normal((M, n))
    wavfile.write(path, FS, (x.T / np.abs(x).max() * 0.9).astype(np.float32))


def convert(tmp_path, name, angles_deg, snr_db, *extra):
    wav, mcap = tmp_path / f"{name}.wav", tmp_path / f"{name}.mcap"
    simulate_wav(wav, angles_deg, snr_db)
    r = CliRunner().invoke(main, ["convert", "array-wav", str(wav), "-o", str(mcap), "--spacing-m", str(SPACING_M),
                                  "--frequency-hz", str(FREQUENCY_HZ), *extra])
    assert r.exit_code == 0, r.output
    return mcap, r.output


def bearings_deg(result, tracker):
    return np.rad2deg(result.results["array"]["tracks"][tracker]["state"][0, :, :, 0])


GEOMETRIES = [([-30.0, 5.0, 40.0], 25.0), ([-45.0, -10.0, 20.0], 25.0), ([-20.0, 25.0], 25.0)]


def test_default_count_is_right_where_one_bin_is_not_and_bearings_land_on_the_truth(tmp_path):
    one_bin_wrong = 0
    for i, (angles, snr_db) in enumerate(GEOMETRIES):
        mcap, printed = convert(tmp_path, f"g{i}", angles, snr_db)
        params = read_dataset(mcap).scenario["params"]
        assert params["n_sources"] == len(angles), (angles, printed)
        assert f"{len(angles)} source(s) by wideband MDL" in printed
        low, high = params["source_count_band_hz"]
        assert low < 1687.5 < high  # the default band is around the tracked bin
        res = replay(mcap)
        for tracker in ("proposed", "ryu"):
            est = bearings_deg(res, tracker)
            assert est.shape[-1] == len(angles)  # one track per source, no spare slot
            # every scan, start-up included, within 0.5° of the truth, with its sign: a
            # positive bearing is on the side of the last channel
            assert np.all(np.abs(est - np.array(angles)) < 0.5), (angles, tracker, est)
        # today's count without the converter's: MDL on the tracked bin at start-up
        old = replay(mcap, design_overrides={"n_sources": 0}).results["array"]["tracks"]["proposed"]
        one_bin_wrong += int(old["source_count"][0, 0] != len(angles))
    assert one_bin_wrong >= 1  # the change matters: one bin over-counts these wideband sources


def test_set_still_overrides_the_recorded_count(tmp_path):
    mcap, _ = convert(tmp_path, "g", [-30.0, 5.0, 40.0], 25.0)
    est = bearings_deg(replay(mcap, design_overrides={"n_sources": 2}), "proposed")
    assert est.shape[-1] == 2


def test_one_bin_spread_matches_its_prediction_and_shrinks_with_the_window():
    """The mechanism the count is built on: one noise-free wideband source at 40° has, in each
    bin, a second eigenvalue at the ratio :func:`bin_leakage_ratio` predicts (within 2 dB), and a
    window eight times longer lowers it by about 18 dB."""
    rng = np.random.default_rng(1)
    n = FS * 3
    f = np.fft.rfftfreq(n, 1.0 / FS)
    spectrum = np.fft.rfft(rng.standard_normal(n)) * ((f > 300) & (f < 3700))
    delay = SPACING_M * np.sin(np.deg2rad(40.0)) / C
    x = np.fft.irfft(spectrum[None, :] * np.exp(2j * np.pi * f[None, :] * np.arange(M)[:, None] * delay), n).T
    measured = []
    for nfft in (512, 4096):
        bins = np.arange(int(1500 * nfft / FS), int(1900 * nfft / FS))
        cov, _ = wc.band_covariances(x, nfft, nfft // 2, bins)
        lam = np.linalg.eigvalsh(cov)
        ratio = np.median(lam[:, -2] / lam[:, -1])
        predicted = wc.bin_leakage_ratio(M, delay, nfft / FS)
        assert abs(10 * np.log10(ratio / predicted)) < 2.0, (nfft, ratio, predicted)
        measured.append(ratio)
    assert 10 * np.log10(measured[0] / measured[1]) == pytest.approx(20 * np.log10(8), abs=2.0)


def test_a_spread_source_fills_two_dimensions_but_is_one_direction():
    """What the count is built on: a strong wideband source's band covariances have a second,
    spread dimension well above the noise (MDL counts 2 or more), yet the band's signal subspace
    holds one direction, within 1° of the source (a flat-bottomed dip: the count is what matters,
    the trackers measure the bearings); two sources give two."""
    rng = np.random.default_rng(2)
    n = FS * 2
    f = np.fft.rfftfreq(n, 1.0 / FS)
    inband = (f > 300) & (f < 3700)
    lead_s = np.arange(M)[:, None] * SPACING_M / C
    for angles in ([40.0], [-25.0, 40.0]):
        x = np.zeros((M, n))
        for theta in np.deg2rad(angles):
            spectrum = np.fft.rfft(rng.standard_normal(n)) * inband
            x += np.fft.irfft(spectrum[None, :] * np.exp(2j * np.pi * f[None, :] * lead_s * np.sin(theta)), n)
        x += 10 ** (-40 / 20) * np.std(x) * rng.standard_normal(x.shape)  # 40 dB above the noise
        bins = np.arange(int(1500 * 512 / FS), int(1900 * 512 / FS))
        # the last channel first (the reference, as the converter orders them), conjugated to exp(+jωτ)
        cov, frames = wc.band_covariances(x[::-1].T, 512, 256, bins)
        cov = np.conj(cov)
        dimension, directions = wc.segment_count(cov, wc.effective_snapshots(frames, 512, 256),
                                                 SPACING_M / C * bins * FS / 512)
        assert dimension >= 2 * len(angles)  # every source spreads into a second dimension
        assert directions.size == len(angles)
        assert np.all(np.abs(np.rad2deg(directions) - angles) < 1.0), directions
    # Welch: 50 % overlapped Hann frames correlate by 1/6, worth 1 / (1 + 2/36) independent ones
    assert wc.effective_snapshots(1000, 4096, 2048) == pytest.approx(1000 / (1 + 2 / 36), rel=1e-3)


def test_bad_band(tmp_path):
    wav = tmp_path / "rec.wav"
    simulate_wav(wav, [10.0], 20.0, seconds=2.0)
    for band, message in (("1900,1500", "0 < LOW < HIGH"), ("abc", "LOW,HIGH"), ("1500,9000", "Nyquist")):
        out = tmp_path / "out.mcap"
        r = CliRunner().invoke(main, ["convert", "array-wav", str(wav), "-o", str(out), "--spacing-m", str(SPACING_M),
                                      "--frequency-hz", str(FREQUENCY_HZ), "--band-hz", band])
        assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output, (band, r.output)
        assert r.output.count("\n") == 1 and not out.exists()
