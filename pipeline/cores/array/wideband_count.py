"""Number of wideband sources seen by a uniform linear array, counted over a band of frequencies.

The array trackers take one narrowband STFT bin (``recorders/array_wav.py``). For a source whose
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
further), nor does a sum of per-bin criteria (every bin has the same spread, so more bins only
make the false eigenvalue more certain).

So the dimension of the signal subspace is not the number of sources. A source that moves
does the same over time: over the frames of a covariance it sweeps a small arc, and to first
order its snapshots span a(θ) and its derivative ∂a/∂θ. At 25 dB a source moving 3°/s fills a
second dimension within half a second (8 sensors at half a wavelength), and over a few seconds
it sweeps far enough that its dip splits in two. A longer window, which would shrink the
wideband spread, needs more time per frame and so more motion per covariance: beyond some SNR no
window removes both.

The count therefore asks how many *directions* the signal subspace holds, not how many
dimensions:

1. the band's MDL over the first seconds gives the signal subspace's dimension k, spread
   included: each bin j is an independent zero-mean Gaussian model with its own covariance (the
   bins treated incoherently, as the wideband eigenstructure methods of Wax, Shan & Kailath
   (1984) do), so the description length of the whole band is the sum over the bins of the
   per-bin MDL of Wax & Kailath (1985),

       MDL_band(k) = Σ_j [ −N (M − k) log(g_jk / a_jk) + ½ k (2M − k) log N ]

   (:func:`band_source_count`; each term is invariant to its bin's scale, so the noise level may
   change across the band). N is the effective number of independent snapshots of overlapping
   Hann frames (Welch 1967: frames / (1 + 2 Σ_l (1 − l/K) ρ_l²), ρ_l the window's overlap
   correlation at l hops; :func:`effective_snapshots`), 0.95 of the frames at 50 % overlap.
   The noise is taken as white or as diffuse over white (spherically isotropic noise is
   correlated between neighbours below d = λ/2), whichever model describes the band better
   (:func:`noise_model_and_dimension`); the next step works on the data whitened by it;
2. per segment of one scan of the tracked STFT (the trackers too take the sources to stay put
   within a scan), the share of each direction's steering vector outside the k-dimensional
   signal subspaces, averaged over the bins with each bin's own d/λ (:func:`band_null_spectrum`,
   the incoherent wideband MUSIC null spectrum), dips where a source is. The spread dimensions lie along the
   derivatives of the steering vector at the source, so they deepen and widen the source's dip
   instead of adding one; a noise dimension taken for a signal points elsewhere in each bin and
   averages out. Each separate dip below half the level of an unrelated direction is a source
   (:func:`distinct_directions`).

The count recorded is the one most segments of the first few seconds give
(:func:`count_sources_in_band`). See ``docs/papers/array.md`` (Recordings: wideband
sources) and the WAV section of ``docs/importers.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay.cores.array.music import information_criterion

DIRECTION_GRID_POINTS = 1801  # 0.1° steps over the half-plane for the directions of the count
# diffuse-to-white noise power ratios the count tries (dB; none first): from white sensor noise
# alone to a diffuse field 40 dB above the sensors' own noise
DIFFUSE_TO_WHITE_DB = (None, -10.0, -5.0, 0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)


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
        :func:`trackreplay.cores.array.music.information_criterion`.
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


def band_null_spectrum(covariances: np.ndarray, dimension: int, spacing_wavelengths, grid: np.ndarray,
                       whiteners: np.ndarray | None = None) -> np.ndarray:
    """Share of each direction's steering vector outside the band's signal subspaces.

    ``Q(θ) = (1/J) Σ_j ‖(I − E_j E_jᴴ) a_j(θ)‖² / M``, E_j the ``dimension`` leading
    eigenvectors of bin j's covariance and a_j the steering vector at bin j's own electrical
    spacing (the incoherent wideband MUSIC of Wax, Shan & Kailath 1984, normalised to [0, 1]):
    0 where a direction lies in every bin's signal subspace, 1 where it is orthogonal to all.

    Parameters
    ----------
    covariances : ndarray, complex, shape (J, M, M)
        Per-bin covariances in the trackers' convention (a(θ) = exp(j κ m sin θ)).
    dimension : int
        Signal-subspace dimension k (≥ 1).
    spacing_wavelengths : array_like, shape (J,)
        d/λ at each bin's frequency.
    grid : ndarray, shape (G,)
        Directions (rad from broadside).
    whiteners : ndarray, complex, shape (J, M, M), optional
        W_j with W_j N_j W_jᴴ = I for the noise covariance N_j of each bin
        (:func:`noise_whiteners`): the subspaces and steering vectors are then those of the
        whitened data, W_j R_j W_jᴴ and W_j a_j(θ), and each share is taken of ‖W_j a_j(θ)‖².

    Returns
    -------
    ndarray, shape (G,)
    """
    from trackreplay.cores.array.linear_array import steering_vectors

    J, M, _ = covariances.shape
    if whiteners is not None:
        covariances = whiteners @ covariances @ np.conj(np.swapaxes(whiteners, -1, -2))
    vectors = np.linalg.eigh(covariances)[1][..., ::-1][..., :dimension]  # (J, M, k), leading first
    spacing = np.broadcast_to(np.asarray(spacing_wavelengths, float), (J,))
    outside = np.zeros(np.shape(grid))
    for j in range(J):
        a = steering_vectors(grid[None, :], M, spacing[j])[0]  # (M, G)
        if whiteners is not None:
            a = whiteners[j] @ a
        norm = np.sum(np.abs(a) ** 2, axis=0)
        outside += 1.0 - np.sum(np.abs(np.conj(vectors[j]).T @ a) ** 2, axis=0) / norm
    return outside / J


def diffuse_coherence(n_sensors: int, spacing_wavelengths) -> np.ndarray:
    """Coherence of spherically isotropic (diffuse) noise between the sensors of a uniform linear
    array: ``sin(k r) / (k r)`` at distance r = |m − n| d (Cook, Waterhouse, Edwards & Thompson
    1955), ``np.sinc(2 (d/λ) |m − n|)``; shape ``(..., M, M)`` for d/λ of shape ``(...)``.
    It vanishes between neighbours at d = λ/2 and tends to 1 as d/λ falls."""
    gaps = np.abs(np.subtract.outer(np.arange(n_sensors), np.arange(n_sensors)))
    return np.sinc(2.0 * np.asarray(spacing_wavelengths, float)[..., None, None] * gaps)


def noise_whiteners(n_sensors: int, spacing_wavelengths, diffuse_to_white_db: float) -> np.ndarray:
    """W with ``W N Wᴴ = I`` for the noise covariance ``N = I + ρ Γ`` of each bin: diffuse noise
    (:func:`diffuse_coherence`) ρ = 10^(dB/10) times the power of the spatially white sensor
    noise under it (the scale of N does not matter). ``N^(−1/2)`` from its eigen-decomposition;
    shape ``(J, M, M)``."""
    ratio = 10.0 ** (float(diffuse_to_white_db) / 10.0)
    N = np.eye(n_sensors) + ratio * diffuse_coherence(n_sensors, spacing_wavelengths)
    values, vectors = np.linalg.eigh(N)
    return (vectors / np.sqrt(values)[..., None, :]) @ np.conj(np.swapaxes(vectors, -1, -2))


def noise_model_and_dimension(covariances: np.ndarray, n_snapshots: float, spacing_wavelengths,
                              criterion: str = "mdl", ratios_db=DIFFUSE_TO_WHITE_DB):
    """The noise model (diffuse over white) and the signal subspace's dimension that describe a
    band best.

    MDL takes the noise as spatially white. Diffuse noise is not, below d = λ/2: neighbours are
    correlated, and its eigenvalues spread (by 37 dB for 8 sensors at d = 0.29 λ), so MDL counts
    noise as signals. For every diffuse-to-white ratio of :data:`DIFFUSE_TO_WHITE_DB` the band's
    covariances are whitened by :func:`noise_whiteners`; the per-bin MDL of the whitened
    covariances is the likelihood ratio of the model against the unconstrained covariance (an
    invertible whitening leaves that ratio as it is), which makes the ratios comparable, and a
    diffuse part pays one parameter more (½ log N). The pair (ratio, k) of least description
    length wins (:func:`band_source_count`).

    Returns
    -------
    ratio_db : float or None
        None: white noise alone.
    dimension : int
    whiteners : ndarray, shape (J, M, M), or None for white noise
    """
    M = covariances.shape[-1]
    best = None
    for ratio_db in ratios_db:
        W = None if ratio_db is None else noise_whiteners(M, spacing_wavelengths, ratio_db)
        cov = covariances if W is None else W @ covariances @ np.conj(np.swapaxes(W, -1, -2))
        k, scores = band_source_count(cov, n_snapshots, criterion, M - 1)
        length = scores[k] * covariances.shape[0] + (0.0 if W is None else 0.5 * np.log(n_snapshots))
        if best is None or length < best[0]:
            best = (length, ratio_db, int(k), W)
    return best[1], best[2], best[3]


def distinct_directions(null_spectrum: np.ndarray, grid: np.ndarray, dimension: int, n_sensors: int) -> np.ndarray:
    """Directions of the sources a band's signal subspace holds: one per separate dip of
    :func:`band_null_spectrum` below half the value a direction unrelated to the signals has.

    A direction picked at random leaves ``(M − k)/M`` of its steering vector's energy outside a
    k-dimensional subspace of C^M; a source's direction leaves almost none. The grid points
    below half of ``(M − k)/M`` form runs, and each run is one source, at its deepest point.
    What this is for: the signal subspace of wideband or moving sources has more dimensions than
    there are sources (each spreads into the derivatives of its steering vector,
    ``docs/papers/array.md``), but those dimensions lie along the steering vectors near
    the source, so they widen and flatten its dip instead of adding one (a flat bottom may ripple
    into several local minima: they are one run); a dimension of noise taken for a signal points
    elsewhere in every bin and averages out over the band. Two sources whose dips merge (closer
    than about a beamwidth) count as one.

    Returns
    -------
    ndarray, shape (n,)
        The directions (rad, ascending).
    """
    q = np.asarray(null_spectrum, float)
    below = np.concatenate([[False], q < 0.5 * (n_sensors - dimension) / n_sensors, [False]])
    edges = np.flatnonzero(np.diff(below.astype(np.int8)))  # starts and ends of the runs, alternately
    runs = edges.reshape(-1, 2)
    return np.asarray([grid[a + int(np.argmin(q[a:b]))] for a, b in runs], dtype=float)


@dataclass(frozen=True)
class BandCount:
    """What :func:`count_sources_in_band` found and how."""

    count: int  # the most common count over the segments
    band_hz: tuple  # centres of the first and last bin used
    nfft: int  # the window (samples)
    n_bins: int
    n_frames: int  # frames per segment
    effective_snapshots: float  # per segment
    segment_counts: np.ndarray  # (S,) distinct directions per segment
    dimension: int  # the signal subspace's dimension by the band's MDL over the span (≥ count: spread included)
    diffuse_to_white_db: float | None  # the noise model that describes the band best (None: white)
    directions_rad: np.ndarray  # the first segment's directions (ascending)
    leakage_endfire: float  # predicted in-bin eigenvalue ratio at endfire for the window


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


def segment_count(covariances: np.ndarray, n_snapshots: float, bin_spacing_wavelengths, criterion: str = "mdl",
                  dimension: int | None = None, whiteners: np.ndarray | None = None):
    """Sources seen by one segment: the band's MDL dimension k (unless given, with the noise model
    of :func:`noise_model_and_dimension`), then the distinct directions of its k-dimensional
    signal subspaces (:func:`band_null_spectrum`, :func:`distinct_directions`).

    ``covariances`` (J, M, M) in the trackers' convention; ``whiteners`` (J, M, M) the noise
    model's whitening (None: white noise, or the model chosen here when ``dimension`` is None);
    returns ``(k, directions_rad)``.
    """
    M = covariances.shape[-1]
    if dimension is None:
        _, dimension, whiteners = noise_model_and_dimension(covariances, n_snapshots, bin_spacing_wavelengths, criterion)
    if dimension == 0:
        return 0, np.empty(0)
    grid = np.linspace(-np.pi / 2, np.pi / 2, DIRECTION_GRID_POINTS)
    null = band_null_spectrum(covariances, dimension, bin_spacing_wavelengths, grid, whiteners)
    return int(dimension), distinct_directions(null, grid, dimension, M)


def count_sources_in_band(samples: np.ndarray, sample_rate_hz: float, sensor_delay_s: float, band_hz,
                          nfft: int, hop: int, segment_frames: int, span_samples: int,
                          criterion: str = "mdl", max_sources: int | None = None) -> BandCount:
    """Count the sources of a multichannel recording over a band (the module's method, end to end).

    The recording's first ``span_samples`` are cut into segments of ``segment_frames`` frames of
    the tracked STFT (window ``nfft``, hop ``hop``): over one segment the sources are taken to
    stay put, as the trackers take them within a scan. The signal subspace's dimension k is the
    band's MDL over the whole span (each bin's covariance over all the frames: the most
    snapshots behind one estimate, which weak sources need; motion over the span only adds
    spread dimensions, which do not add directions). In every segment, the distinct directions
    of its k-dimensional signal subspaces over the band (:func:`segment_count`); the count is
    the one most segments give (the smaller on a tie).

    Parameters
    ----------
    samples : ndarray, shape (n_samples, M)
        The sensors in order along the line, the reference (the one a positive bearing's wave
        reaches last) first.
    sample_rate_hz : float
    sensor_delay_s : float
        d / c, the delay between adjacent sensors at endfire (d/λ at f is f · d / c).
    band_hz : (float, float)
        The band; every bin of the STFT inside it is used (the nearest one to its centre if
        none is).
    nfft, hop : int
        The tracked STFT's window and hop.
    segment_frames : int
        Frames per segment (more than M).
    span_samples : int
        Samples from the start that are cut into segments (one segment at least, when the
        recording holds it).
    criterion : {"mdl", "aic"}
    max_sources : int, optional
        Largest count reported (default M − 1).

    Returns
    -------
    BandCount
    """
    n, M = samples.shape
    bins = _bins(band_hz, sample_rate_hz, nfft)
    width = sample_rate_hz / nfft
    spacing = sensor_delay_s * bins * width
    frames = min(frame_count(n, nfft, hop), max(frame_count(min(n, int(span_samples)), nfft, hop), segment_frames))
    X = np.conj(stft_at_bins(samples, nfft, hop, bins, frames))  # the trackers' exp(+jωτ)
    per_segment = max(1, min(int(segment_frames), frames))
    n_eff = effective_snapshots(per_segment, nfft, hop)
    covariances = np.stack([np.einsum("kmj,knj->jmn", X[a:a + per_segment], np.conj(X[a:a + per_segment])) / per_segment
                            for a in range(0, max(frames - per_segment, 0) + 1, per_segment)])  # (S, J, M, M)
    # one noise model and dimension for the whole span, from each bin's covariance over all its
    # frames (the most snapshots behind one estimate: weak sources need them; motion over the
    # span only adds spread dimensions, which add no direction)
    share, dimension, whiteners = noise_model_and_dimension(
        covariances.mean(axis=0), effective_snapshots(per_segment * len(covariances), nfft, hop), spacing, criterion)
    counts, first = [], None
    for cov in covariances:
        _, directions = segment_count(cov, n_eff, spacing, criterion, dimension, whiteners)
        counts.append(directions.size)
        first = directions if first is None else first
    counts = np.asarray(counts)
    kmax = M - 1 if max_sources is None else int(max_sources)
    values, votes = np.unique(counts, return_counts=True)
    count = min(int(values[np.argmax(votes)]), kmax)  # argmax: the first, smallest, of the ties
    return BandCount(count=count, band_hz=(float(bins[0] * width), float(bins[-1] * width)), nfft=int(nfft),
                     n_bins=int(bins.size), n_frames=int(per_segment), effective_snapshots=float(n_eff),
                     segment_counts=counts, dimension=int(dimension), diffuse_to_white_db=share, directions_rad=first,
                     leakage_endfire=bin_leakage_ratio(M, sensor_delay_s, nfft / sample_rate_hz))
