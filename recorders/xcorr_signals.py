"""Cross-correlation peaks made the physical way: two-channel signals → correlation → maxima.

Park, Ryu & Lee (1994), measurement way (b) (see ``docs/papers/xcorr.md``). Two sensors ``d`` apart
receive each target's broadband signal directly and via one multipath echo, plus independent
sensor noise (spec eq. 1 with an echo added)::

    r₁(t) = Σ_t [s_t(t) + g·s_t(t − Δ)] + n₁(t)
    r₂(t) = Σ_t [s_t(t − D_t) + g·s_t(t − Δ − D'_t)] + n₂(t)

with ``D_t = d cos θ_t / C`` (direct path) and ``D'_t = d cos(θ_t + δ) / C`` (the echo arrives
from an apparent bearing offset by ``multipath_offset_deg``, ``Δ`` its extra travel time).
The echo's cross terms with the direct path sit at lags beyond ``d/C``; the echo with itself
makes a *ghost* peak of height ``g²·P_t`` at the bearing ``θ_t + δ``: false peaks that are
neither uniform nor independent of the true ones, as in the paper's sea data.

Per scan and run one window of ``window_samples`` samples is correlated:
``R₁₂(τ) = (1/N) Σ r₁(t) r₂(t + τ)`` (circular, by FFT; or GCC-PHAT, the cross-spectrum
whitened to unit magnitude), local maxima over lags ``|τ| ≤ d/C`` are refined by a parabola
through three samples, and each becomes a peak with bearing ``θ = arccos(C·τ/d)`` (spec eq. 2)
and amplitude ``amplitude_scale · R₁₂(τ)`` (raw correlator units: sensor noise has unit
variance). Peaks outside the field or below ``peak_threshold`` are not reported.

Labels (``origin``): the peak nearest to target t's true lag, if within
``label_tolerance_samples``, is labelled t (the judge only; trackers never see it).

The signals are generated in the frequency domain (complex Gaussian spectra in the source
band, delays as phase ramps, so fractional delays are exact for the circular window), turned
into time series by an inverse FFT and correlated from those time series. Random numbers are
drawn block by block in a fixed order, so a seed fixes every byte. Geometry (``n_targets``
targets in crossing pairs, default the paper's two), the strength roles (``roles`` cycled, else
``pair``) and the filter design keys are those of :mod:`trackreplay.recorders.xcorr_peaks`.
"""

from __future__ import annotations

import numpy as np

from trackreplay.errors import check_all
from trackreplay.recorders.simulated import SimulatedData
from trackreplay.recorders.xcorr_peaks import (ORIGIN_CLUTTER, PEAKS_TOPIC, TRUTH_TOPIC, pack_peaks, target_bearings,
                                   track_roles)
from trackreplay.recorders.xcorr_peaks import validate as validate_geometry

BLOCK_SAMPLES = 1 << 21  # snapshots × samples per FFT block (bounded memory)


def validate(p: dict) -> None:
    """Geometry checks of :mod:`trackreplay.recorders.xcorr_peaks` plus the signal chain's own."""
    validate_geometry(p)
    checks = [
        (p["sample_rate_hz"] > 0, "sample_rate_hz must be > 0"),
        (p["window_samples"] >= 64, "window_samples must be ≥ 64"),
        (p["sensor_spacing_m"] > 0, "sensor_spacing_m must be > 0"),
        (p["sound_speed_mps"] > 0, "sound_speed_mps must be > 0"),
        (0 <= p["band_low_hz"] < p["band_high_hz"] <= p["sample_rate_hz"] / 2,
         "the source band must satisfy 0 ≤ band_low_hz < band_high_hz ≤ sample_rate_hz / 2"),
        (0 <= p["multipath_gain"] < 1, "multipath_gain must be in [0, 1)"),
        (p["multipath_delay_s"] >= 0, "multipath_delay_s must be ≥ 0"),
        (p["amplitude_scale"] > 0, "amplitude_scale must be > 0"),
        (p["peak_threshold"] >= 0, "peak_threshold must be ≥ 0 (peak amplitudes are reported ≥ 0)"),
        (p["label_tolerance_samples"] > 0, "label_tolerance_samples must be > 0"),
    ]
    max_lag = p["sensor_spacing_m"] / p["sound_speed_mps"] * p["sample_rate_hz"]
    checks.append((2 * max_lag + 3 < p["window_samples"], "window_samples must exceed twice d/C in samples"))
    check_all(checks)


def _complex_gaussian(rng, shape) -> np.ndarray:
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2.0)


def correlate(r1: np.ndarray, r2: np.ndarray, phat: bool) -> np.ndarray:
    """Circular cross-correlation ``(1/N) Σ r₁(t) r₂(t + τ)`` over the last axis (lag 0 first).

    With ``phat`` the cross-spectrum is whitened to unit magnitude (GCC-PHAT): the peak of two
    identical signals is then 1 whatever their spectrum.
    """
    N = r1.shape[-1]
    G = np.conj(np.fft.rfft(r1, axis=-1)) * np.fft.rfft(r2, axis=-1)
    if phat:
        G = G / np.maximum(np.abs(G), 1e-12 * np.abs(G).max(initial=1.0))
        return np.fft.irfft(G, n=N, axis=-1)
    return np.fft.irfft(G, n=N, axis=-1) / N


def local_maxima(values: np.ndarray, lags: np.ndarray):
    """Interior local maxima of ``values (n, L)`` over lags, refined by a three-point parabola.

    Returns
    -------
    row, lag, height : ndarray
        Snapshot index, interpolated lag (samples) and interpolated height of every maximum.
    """
    y0 = values[:, 1:-1]
    ym, yp = values[:, :-2], values[:, 2:]
    is_max = (y0 > ym) & (y0 >= yp)
    row, col = np.nonzero(is_max)
    a, b, c = ym[row, col], y0[row, col], yp[row, col]
    den = a - 2 * b + c
    delta = np.where(den < 0, 0.5 * (a - c) / np.where(den < 0, den, -1.0), 0.0)
    return row, lags[col + 1] + delta, b - 0.25 * (a - c) * delta


def simulate(p: dict, runs: int, seed: int) -> SimulatedData:
    """Simulate ``runs`` Monte Carlo runs: signals → correlation → peaks, plus truth.

    Returns
    -------
    SimulatedData
        Same channels as :func:`trackreplay.recorders.xcorr_peaks.simulate`: ``/xcorr/peaks``
        (``bearing_rad``, ``amplitude``, ``origin``) and ``/xcorr/truth``.
    """
    validate(p)
    rng = np.random.default_rng(seed)
    times, bearing, rate = target_bearings(p)
    K, T = bearing.shape
    roles = track_roles(p, T)  # the roles pattern cycled over the n_targets targets
    fs, N = float(p["sample_rate_hz"]), int(p["window_samples"])
    d, C = float(p["sensor_spacing_m"]), float(p["sound_speed_mps"])
    lo, hi = np.deg2rad(p["field_min_deg"]), np.deg2rad(p["field_max_deg"])
    power = np.array([10 ** (p[f"{r}_snr_db"] / 10) for r in roles])
    g, echo_delay = float(p["multipath_gain"]), float(p["multipath_delay_s"])
    offset = np.deg2rad(p["multipath_offset_deg"])

    f = np.fft.rfftfreq(N, 1 / fs)
    band = (f >= p["band_low_hz"]) & (f <= p["band_high_hz"])
    # Parseval (numpy's unnormalised DFT): unit-variance white noise has E|X_k|² = N; a source
    # of variance P confined to the band's bins has E|X_k|² = N·P·(N/2)/(band bins) there.
    bin_scale = np.sqrt(N)
    src_scale = bin_scale * np.sqrt((N / 2) / band.sum())
    max_lag = d / C * fs
    lag_idx = np.arange(-int(np.floor(max_lag)), int(np.floor(max_lag)) + 1)
    direct = d * np.cos(bearing) / C  # (K, T) seconds
    echo = d * np.cos(bearing + offset) / C

    snapshots = runs * K
    block = max(1, BLOCK_SAMPLES // N)
    peaks = {"run": [], "scan": [], "bearing_rad": [], "amplitude": [], "origin": []}
    for start in range(0, snapshots, block):
        idx = np.arange(start, min(start + block, snapshots))
        n = idx.size
        run, scan = np.divmod(idx, K)
        S = _complex_gaussian(rng, (n, T, f.size)) * (np.sqrt(power)[:, None] * band * src_scale)
        N1 = _complex_gaussian(rng, (n, f.size)) * bin_scale
        N2 = _complex_gaussian(rng, (n, f.size)) * bin_scale
        w = -2j * np.pi * f
        X1 = np.sum(S * (1 + g * np.exp(w * echo_delay)), axis=1) + N1
        X2 = np.sum(S * (np.exp(w * direct[scan][..., None]) + g * np.exp(w * (echo_delay + echo[scan][..., None]))),
                    axis=1) + N2
        r1 = np.fft.irfft(X1, n=N, axis=-1)
        r2 = np.fft.irfft(X2, n=N, axis=-1)
        R = correlate(r1, r2, bool(p["gcc_phat"]))[:, lag_idx % N]  # lags −L … L
        row, lag, height = local_maxima(R, lag_idx.astype(float))
        b = np.arccos(np.clip(C * lag / fs / d, -1.0, 1.0))
        amp = p["amplitude_scale"] * height
        keep = (b >= lo) & (b <= hi) & (amp >= p["peak_threshold"])
        row, lag, b, amp = row[keep], lag[keep], b[keep], amp[keep]
        origin = np.full(row.size, ORIGIN_CLUTTER, np.int32)
        true_lag = direct[scan] * fs  # (n, T)
        dist = np.abs(lag[:, None] - true_lag[row])  # (peaks, T)
        for t in range(T):
            # nearest peak to target t's lag within tolerance, unless it is nearer another target
            cand = np.where((dist[:, t] <= p["label_tolerance_samples"]) & (np.argmin(dist, axis=1) == t),
                            dist[:, t], np.inf)
            best = np.full(n, np.inf)
            np.minimum.at(best, row, cand)
            origin[np.isfinite(cand) & (cand == best[row])] = t
        peaks["run"].append(run[row])
        peaks["scan"].append(scan[row])
        peaks["bearing_rad"].append(b)
        peaks["amplitude"].append(amp)
        peaks["origin"].append(origin)
    flat = {k: np.concatenate(v) for k, v in peaks.items()}
    padded, counts = pack_peaks(flat.pop("run"), flat.pop("scan"), flat, runs, K)
    truth = {
        "bearing_rad": np.broadcast_to(bearing, (runs, K, T)).copy(),
        "bearing_rate_radps": np.broadcast_to(rate, (runs, K, T)).copy(),
        "snr_db": np.broadcast_to(10 * np.log10(power), (runs, K, T)).copy(),
    }
    return SimulatedData(times=times, fixed={TRUTH_TOPIC: truth}, ragged={PEAKS_TOPIC: (padded, counts)})
