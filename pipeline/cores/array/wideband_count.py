"""Number of wideband sources seen by a uniform linear array, counted over a band of frequencies.

The array trackers take one narrowband STFT bin (``recorders/wav_array.py``). For a source whose
spectrum is flat across that bin, the bin's covariance is not rank one: the bin passes the
frequencies of the window's spectral main lobe, and over them the phase across the array changes.
With the window's power spectrum |W(ν)|² normalised to unit area, a source at θ contributes

    E[x xᴴ] = P · (a aᴴ) ⊙ T,    T_mn = ρ_w((m − n) τ),    τ = d sin θ / c,

ρ_w being the window's normalised autocorrelation (the characteristic function of |W|²). For small
delays ρ_w(t) ≈ 1 − ½ β² t² with β² = 4π² ∫ν²|W(ν)|² dν, which is 4π² / (3 T_w²) for a Hann window
of duration T_w; T then has, besides its main eigenvalue ≈ M, a second one, and the ratio of the two
is ≈ β² τ² (M² − 1) / 12 (:func:`bin_leakage_ratio`). For 8 sensors 0.1 m apart and a 32 ms window
this is −26 dB at 40°: at a per-sensor SNR in the bin of 20 dB or more the second eigenvalue stands
well above the noise and MDL counts it as a source. Averaging covariances over neighbouring bins
does not help (the steering vector changes with frequency, so the average spreads each source
further), nor does a sum of per-bin criteria at the same resolution (every bin has the same
spread, so more bins only make the false eigenvalue more certain).

What helps is resolution: the ratio falls as 1/T_w², at the price of fewer snapshots. The count
therefore uses its own STFT, with a Hann window just long enough that the predicted spread at
endfire, scaled by how far the strongest source stands above the noise, stays a tenth of the noise
(:func:`count_sources_in_band`, :func:`count_window_length`): weak sources keep the tracked
window and its many snapshots, strong ones get a longer window. It gathers the evidence of every
bin of a band around the tracked frequency incoherently, bin by bin, as the wideband eigenstructure methods of Wax, Shan &
Kailath (1984) treat the bins of a wideband array: each bin j is an independent zero-mean Gaussian
model with its own covariance, so the description length of the whole band for k sources is the
sum over the bins of the per-bin MDL of Wax & Kailath (1985),

    MDL_band(k) = Σ_j [ −N (M − k) log(g_jk / a_jk) + ½ k (2M − k) log N ],

and the count is the minimising k (:func:`band_source_count`). Each term is invariant to the scale
of its bin's covariance, so the noise level may differ from bin to bin (no whitening needed).
N is the effective number of independent snapshots of overlapping Hann frames (Welch 1967:
frames / (1 + 2 Σ_l (1 − l/K) ρ_l²), ρ_l the window's overlap correlation at l hops;
:func:`effective_snapshots`), 0.95 of the frames for Hann at 50 % overlap.

The count assumes the sources stay put over the frames it uses (a moving source spreads over
angle the way a wideband one spreads over a bin); the caller keeps that span short (a few seconds
at the start of the recording, where the tracker's start-up is). See ``docs/papers/array-bearing.md``
and the WAV section of ``docs/importers.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.cores.array.music import information_criterion

# the spread eigenvalue the count window is sized for, relative to the noise: a tenth of it is
# far below what MDL can tell from the noise eigenvalues (their sampling spread is larger)
DEFAULT_MARGIN = 0.1


def hann_window(nfft: int) -> np.ndarray:
    """Hann window of ``nfft`` samples without its zero end points (the converter's STFT window)."""
    return np.hanning(nfft + 2)[1:-1]


def frame_count(n_samples: int, nfft: int, hop: int) -> int:
    """Whole frames of ``nfft`` samples, ``hop`` apart, in ``n_samples``."""
    return 1 + (n_samples - nfft) // hop if n_samples >= nfft else 0


def stft_at_bins(samples: np.ndarray, nfft: int, hop: int, bins, n_frames: int | None = None) -> np.ndarray:
    """Hann-windowed DFT of every channel at the given bins, frame by frame.

    Parameters
    ----------
    samples : ndarray, shape (n_samples, C)
    nfft, hop : int
        Window length and hop (samples).
    bins : array_like of int, shape (J,)
        DFT bin indices k (frequency k · fs / nfft).
    n_frames : int, optional
        Frames from the start (default all whole frames).

    Returns
    -------
    ndarray, complex, shape (frames, C, J)
        ``Σ_n w(n) x(n + f·hop) exp(−2πj k n / nfft)`` (one windowed DFT row per bin, not a
        full FFT).
    """
    bins = np.atleast_1d(np.asarray(bins, dtype=float))
    frames = frame_count(samples.shape[0], nfft, hop)
    frames = frames if n_frames is None else min(frames, int(n_frames))
    kernel = hann_window(nfft)[:, None] * np.exp(-2j * np.pi * np.outer(np.arange(nfft), bins) / nfft)
    view = np.lib.stride_tricks.sliding_window_view(samples, nfft, axis=0)[::hop][:frames]  # (frames, C, nfft)
    out = np.empty((frames, samples.shape[1], bins.size), dtype=complex)
    step = max(1, 2 ** 21 // max(1, samples.shape[1] * nfft))  # ≈ 32 MB of complex frames at a time
    for start in range(0, frames, step):
        out[start:start + step] = view[start:start + step] @ kernel
    return out


def band_covariances(samples: np.ndarray, nfft: int, hop: int, bins, n_frames: int | None = None):
    """Per-bin sample covariance of the STFT snapshots, ``R_j = X_j X_jᴴ / K``.

    Returns
    -------
    covariances : ndarray, complex, shape (J, C, C)
    frames : int
        K, the frames behind every covariance.
    """
    X = stft_at_bins(samples, nfft, hop, bins, n_frames)  # (K, C, J)
    K = X.shape[0]
    return np.einsum("kmj,knj->jmn", X, np.conj(X)) / max(K, 1), K


def effective_snapshots(n_frames: int, nfft: int, hop: int) -> float:
    """Independent snapshots equivalent to ``n_frames`` overlapping Hann frames (Welch 1967).

    ``K / (1 + 2 Σ_{l≥1} (1 − l/K) ρ_l²)`` with ``ρ_l = Σ_n w(n) w(n + l·hop) / Σ_n w(n)²``, the
    correlation of two frames' DFT values of white noise l hops apart (1/6 for Hann at 50 %
    overlap: 0.95 K).
    """
    w = hann_window(nfft)
    energy = float(w @ w)
    K = int(n_frames)
    inflation = 1.0
    for lag in range(1, min(K, -(-nfft // hop))):
        shift = lag * hop
        rho = float(w[shift:] @ w[: nfft - shift]) / energy
        inflation += 2.0 * (1.0 - lag / K) * rho * rho
    return K / inflation


def bin_leakage_ratio(n_sensors: int, sensor_delay_s: float, window_s: float) -> float:
    """Ratio of a flat-spectrum source's second to first eigenvalue in one Hann-windowed bin.

    ``β² τ² (M² − 1) / 12`` with ``β² = 4π² / (3 T_w²)`` (Hann) and τ the delay between adjacent
    sensors (``d sin θ / c``; ``d / c`` gives the endfire worst case). The small-delay expansion
    of the module's docstring; accurate while the ratio is small.
    """
    beta2 = 4.0 * np.pi ** 2 / (3.0 * window_s ** 2)
    return float(beta2 * sensor_delay_s ** 2 * (n_sensors ** 2 - 1) / 12.0)


def count_window_length(n_sensors: int, sensor_delay_s: float, sample_rate_hz: float, n_samples: int,
                        min_nfft: int, min_frames: int, leakage: float) -> int:
    """Window length (samples, a power of two ≥ ``min_nfft``) of the count's STFT.

    The shortest with :func:`bin_leakage_ratio` at endfire ≤ ``leakage``, shortened (not below
    ``min_nfft``) until the recording holds ``min_frames`` frames at 50 % overlap: the per-bin
    covariances need more snapshots than sensors.
    """
    # ratio ∝ 1 / T_w²: the duration that meets the target, then the next power of two
    needed_s = window_s_for(n_sensors, sensor_delay_s, leakage)
    nfft = max(int(min_nfft), 1 << int(np.ceil(np.log2(max(needed_s * sample_rate_hz, 1.0)))))
    while nfft > min_nfft and frame_count(n_samples, nfft, nfft // 2) < min_frames:
        nfft = max(int(min_nfft), nfft // 2)
    return nfft


def window_s_for(n_sensors: int, sensor_delay_s: float, leakage: float) -> float:
    """Hann duration whose :func:`bin_leakage_ratio` equals ``leakage`` (inverse of it)."""
    return float(np.sqrt(bin_leakage_ratio(n_sensors, sensor_delay_s, 1.0) / leakage))


def band_source_count(covariances: np.ndarray, n_snapshots: float, criterion: str = "mdl",
                      max_sources: int | None = None):
    """Source count of a band: the k minimising the sum over its bins of the per-bin criterion.

    Parameters
    ----------
    covariances : ndarray, complex, shape (J, M, M)
        Sample covariance of each bin of the band.
    n_snapshots : float
        Effective snapshots behind each (:func:`effective_snapshots`).
    criterion : {"mdl", "aic"}
        :func:`pipeline.cores.array.music.information_criterion`.
    max_sources : int, optional
        Largest count considered (default M − 1).

    Returns
    -------
    count : int
    scores : ndarray, shape (kmax + 1,)
        The band's criterion per k, divided by the number of bins (the per-bin mean; the same
        minimiser as the sum).
    """
    values = np.linalg.eigvalsh(np.asarray(covariances))  # ascending, per bin
    scores = information_criterion(values, n_snapshots, criterion, max_sources).mean(axis=0)
    return int(np.argmin(scores)), scores


@dataclass(frozen=True)
class BandCount:
    """What :func:`count_sources_in_band` found and how."""

    count: int
    band_hz: tuple  # centres of the first and last bin used
    nfft: int  # the count window (samples)
    n_bins: int
    n_frames: int
    effective_snapshots: float
    dynamic_range: float  # median over the band of λ_max / λ_min at the tracked resolution
    leakage_endfire: float  # predicted in-bin eigenvalue ratio at endfire for the count window
    scores: np.ndarray  # per-bin mean criterion per k


def _bins(band_hz, sample_rate_hz: float, nfft: int) -> np.ndarray:
    """Bins of an ``nfft`` STFT inside the band (the nearest to its centre if none is); never DC
    or Nyquist, whose values are real."""
    low, high = (float(b) for b in band_hz)
    width = sample_rate_hz / nfft
    top = max(1, nfft // 2 - 1)
    bins = np.arange(max(1, int(np.ceil(low / width))), min(top, int(np.floor(high / width))) + 1)
    if bins.size == 0:
        bins = np.array([int(np.clip(round(0.5 * (low + high) / width), 1, top))])
    return bins


def count_sources_in_band(samples: np.ndarray, sample_rate_hz: float, sensor_delay_s: float, band_hz,
                          min_nfft: int, span_samples: int, min_frames: int, criterion: str = "mdl",
                          max_sources: int | None = None, margin: float = DEFAULT_MARGIN) -> BandCount:
    """Count the sources of a multichannel recording over a band (the module's method, end to end).

    1. A pilot at the tracked resolution (``min_nfft``) measures how far the strongest source
       stands above the noise: r = median over the band's bins of λ_max / λ_min.
    2. The count window is the shortest power of two ≥ ``min_nfft`` whose predicted spread
       (:func:`bin_leakage_ratio` at endfire) puts the spread eigenvalue at most ``margin`` times
       the noise: ratio · r ≤ margin (:func:`count_window_length`). Weak sources keep the short
       window and its many snapshots; strong ones get the resolution they need.
    3. The band's MDL (:func:`band_source_count`) over the frames of the first ``span_samples``
       (extended to ``min_frames`` frames if the window needs it and the recording has them).

    Parameters
    ----------
    samples : ndarray, shape (n_samples, M)
        The sensors in order along the line.
    sample_rate_hz : float
    sensor_delay_s : float
        d / c, the largest delay between adjacent sensors (endfire).
    band_hz : (float, float)
        The band; every bin of the STFT inside it is used (the nearest one to its centre if
        none is).
    min_nfft : int
        The tracked STFT's window: the pilot's and the shortest count window.
    span_samples : int
        Samples from the start over which the sources are taken to stay put.
    min_frames : int
        Frames the count window should leave (more than M).
    criterion : {"mdl", "aic"}
    max_sources : int, optional
        Largest count considered (default M − 1).
    margin : float
        Largest predicted spread eigenvalue, relative to the noise.

    Returns
    -------
    BandCount
    """
    n, M = samples.shape
    head = samples[: max(int(span_samples), min_nfft)]
    pilot_bins = _bins(band_hz, sample_rate_hz, min_nfft)
    pilot, _ = band_covariances(head, min_nfft, min_nfft // 2, pilot_bins)
    lam = np.linalg.eigvalsh(pilot)
    dynamic = float(np.median(lam[:, -1] / np.maximum(lam[:, 0], np.finfo(float).tiny)))
    nfft = count_window_length(M, sensor_delay_s, sample_rate_hz, n, min_nfft, min_frames, margin / max(dynamic, 1.0))
    hop = nfft // 2
    frames = max(frame_count(head.shape[0], nfft, hop), min(int(min_frames), frame_count(n, nfft, hop)))
    bins = _bins(band_hz, sample_rate_hz, nfft)
    cov, frames = band_covariances(samples, nfft, hop, bins, frames)
    n_eff = effective_snapshots(frames, nfft, hop)
    kmax = M - 1 if max_sources is None else int(max_sources)
    count, scores = band_source_count(cov, n_eff, criterion, min(kmax, frames - 1))
    width = sample_rate_hz / nfft
    return BandCount(count=count, band_hz=(float(bins[0] * width), float(bins[-1] * width)), nfft=nfft,
                     n_bins=int(bins.size), n_frames=int(frames), effective_snapshots=float(n_eff),
                     dynamic_range=dynamic, leakage_endfire=bin_leakage_ratio(M, sensor_delay_s, nfft / sample_rate_hz),
                     scores=scores)
