"""Converter: a multichannel WAV recording of a uniform linear array → the snapshot channels.

One narrowband frequency bin of a short-time Fourier transform gives one complex snapshot per
channel and frame; consecutive frames are grouped into scans of ``snapshots_per_scan`` frames
(the interval [(k−1)T, kT] of Ryu, Lee & Lee 2001, T = Ns · hop / fs). The result is written to
``/array/snapshots`` exactly as the simulator writes it (one run, no truth), so a recording goes
through the same trackers (``replay out.mcap``; see ``docs/papers/array.md``).

Conventions:

* the channels of the file are the sensors in order along the line, equally spaced by
  ``spacing_m``; the electrical spacing d/λ = spacing_m · f_bin / c is recorded as the data set's
  ``spacing_wavelengths``. Above 1/2 the array has grating lobes; a bin up to half a bin width
  above the half-wavelength frequency is accepted (the field free of ambiguity then ends short
  of endfire, at ``unambiguous_field_deg``, recorded), anything higher is refused with the
  highest bin that would pass;
* bearings θ are measured from broadside. By default (``positive_toward="last"``) a source on
  the side of the last channel, whose wave reaches the last channel first, has θ > 0, as in
  most array texts and toolboxes; ``positive_toward="first"`` mirrors it. Either way the
  sensor the wave reaches last is the paper's reference, so its channel m lags by
  τ = (m−1) d sin θ / c; the STFT then carries exp(−jωτ), and the snapshots are conjugated to
  the paper's exp(+jωτ) model (conjugation keeps every subspace property). The choice is
  recorded as ``bearing_positive_toward``;
* the STFT uses a Hann window of ``nfft`` samples and hop ``hop``; only the chosen bin is
  computed (one windowed DFT row per frame, not a full FFT);
* a scan's time stamp is the centre of its frames (the mean of the frame centres), the instant
  its snapshots describe as a whole; the first is ((Ns − 1) · hop + nfft) / (2 fs);
* the number of sources is counted over a band around the bin (default ±10 % of its frequency,
  or ``band_hz``) by :mod:`trackreplay.cores.array.wideband_count`: per scan of the first
  ``COUNT_SPAN_S`` seconds (of 2M frames if a scan has fewer), the band's null spectrum gives the
  distinct directions in the signal subspace, whose dimension the band's MDL over the whole span
  gives, with the noise taken as white or as diffuse over white, whichever describes the band
  better (a wideband or moving source fills more than one dimension but is one direction); the
  count most scans give
  is recorded as the trackers' ``n_sources``, so a replay starts that many tracks (``--set
  n_sources=…`` overrides it; 0 makes the trackers count at start-up from the tracked bin, as
  before), with how it was obtained (``source_count_*``);
* the record also sets the trackers' ``align_subspace_instant``: the frames are a continuous
  timeline, and PAST's memory reaches back before each time stamp, so the trackers measure each
  bearing at the instant the scan's subspace describes
  (:func:`trackreplay.cores.array.past_subspace.subspace_instant_offset`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.contract import scenario_metadata
from trackreplay.cores.array import wideband_count
from trackreplay.errors import InputError, check_all, require_finite
from trackreplay.recorders.simulated import SimulatedData, write_simulated

SNAPSHOTS_TOPIC = vocab.CHANNELS["array_snapshots"]
POSITIVE_TOWARD = ("last", "first")
# the default counting band, relative to the tracked bin's frequency: wide enough for dozens of
# the count's fine bins (the criterion averages over them), narrow enough that the sources
# counted are the ones the tracked bin sees
BAND_RELATIVE = 0.10
COUNT_SPAN_S = 4.0       # the count looks at the scans of the start of the recording, where the
                         # trackers start, and takes the count most of them give
COUNT_MIN_FRAMES = 2     # frames per sensor of each counted segment (the covariances need > M)


def read_wav(path: str | Path) -> tuple[int, np.ndarray]:
    """Sample rate and samples ``(n_samples, channels)`` as float (integers scaled to ±1)."""
    from scipy.io import wavfile

    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError("is a directory, expected a WAV file", path)
    try:
        fs, data = wavfile.read(path)
    except (ValueError, EOFError, OSError) as exc:
        raise InputError(f"not a readable WAV file ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})", path) from None
    if data.ndim != 2 or data.shape[1] < 2:
        raise InputError(f"{1 if data.ndim == 1 else data.shape[1]} channel(s); an array recording needs at least 2", path)
    if data.dtype.kind in "iu":
        info = np.iinfo(data.dtype)
        data = (data.astype(float) - (info.max + info.min + 1) / 2) / (info.max + 1)
    else:
        data = data.astype(float)
    require_finite("samples", data, path)
    return int(fs), data


def narrowband_snapshots(samples: np.ndarray, fs: int, frequency_hz: float, nfft: int, hop: int):
    """STFT value of every channel at the bin nearest ``frequency_hz``, frame by frame.

    Returns
    -------
    snapshots : ndarray, complex, shape (channels, frames)
        Conjugated (paper's exp(+jωτ) convention).
    bin_hz : float
        The bin's centre frequency.
    """
    n, C = samples.shape
    k = int(round(frequency_hz * nfft / fs))
    frames = 1 + (n - nfft) // hop if n >= nfft else 0
    # the count's STFT (trackreplay.cores.array.wideband_count) uses the same window; this one DFT
    # row per frame is kept as it was so that a recording converts to the same bytes
    window = wideband_count.hann_window(nfft)  # Hann without the zero end points
    kernel = window * np.exp(-2j * np.pi * k * np.arange(nfft) / nfft)
    view = np.lib.stride_tricks.sliding_window_view(samples, nfft, axis=0)[::hop][:frames]  # (frames, C, nfft)
    stft = view @ kernel  # (frames, C)
    return np.conj(stft).T, k * fs / nfft


def convert_array_wav(src, dst, spacing_m: float, frequency_hz: float, sound_speed_mps: float = 343.0,
                      nfft: int = 512, hop: int | None = None, snapshots_per_scan: int = 30,
                      snapshot_dtype: str = "complex64", positive_toward: str = "last",
                      band_hz: tuple[float, float] | None = None) -> dict:
    """Convert ``src`` (WAV) to ``dst`` (MCAP); returns a summary of what was written.

    Parameters
    ----------
    spacing_m : float
        Sensor spacing d (m).
    frequency_hz : float
        Narrowband frequency (the nearest STFT bin is used).
    sound_speed_mps : float
        c.
    nfft, hop : int
        STFT window length and hop (default nfft / 2).
    snapshots_per_scan : int
        Frames per scan (Ns).
    positive_toward : {"last", "first"}
        The end of the array a positive bearing points to (see the module's conventions).
    band_hz : (float, float), optional
        Band over which the sources are counted (default ±10 % of the bin's frequency).
    """
    hop = nfft // 2 if hop is None else hop
    checks = [
        (spacing_m > 0, "spacing_m must be > 0"), (sound_speed_mps > 0, "sound_speed_mps must be > 0"),
        (nfft >= 8, "nfft must be ≥ 8"), (0 < hop <= nfft, "hop must be in (0, nfft]"),
        (snapshots_per_scan >= 1, "snapshots_per_scan must be ≥ 1"), (frequency_hz > 0, "frequency_hz must be > 0"),
        (snapshot_dtype in ("complex64", "complex128"), "snapshot_dtype must be complex64 or complex128"),
        (positive_toward in POSITIVE_TOWARD, f"positive_toward must be one of {', '.join(POSITIVE_TOWARD)}"),
    ]
    if band_hz is not None:
        band_hz = tuple(float(b) for b in band_hz)
        checks.append((len(band_hz) == 2 and 0 < band_hz[0] < band_hz[1],
                       "band_hz must be two frequencies LOW,HIGH with 0 < LOW < HIGH"))
    check_all(checks)
    fs, samples = read_wav(src)
    if band_hz is not None and band_hz[1] > fs / 2:
        raise InputError(f"band_hz upper edge {band_hz[1]:g} Hz is above the Nyquist frequency {fs / 2:g} Hz", src)
    if frequency_hz >= fs / 2:
        raise InputError(f"frequency_hz = {frequency_hz:g} is not below the Nyquist frequency {fs / 2:g} Hz", src)
    if nfft > samples.shape[0]:
        raise InputError(f"nfft = {nfft} is longer than the recording ({samples.shape[0]} samples per channel)", src)
    if positive_toward == "last":
        # the paper's reference sensor is the one a positive bearing's wave reaches last
        samples = samples[:, ::-1]
    snaps, bin_hz = narrowband_snapshots(samples, fs, frequency_hz, nfft, hop)
    if bin_hz <= 0:
        raise InputError(f"frequency_hz = {frequency_hz:g} falls in the DC bin (nfft = {nfft} at {fs} Hz)", src)
    spacing_wavelengths = spacing_m * bin_hz / sound_speed_mps
    half_wave_hz = sound_speed_mps / (2 * spacing_m)        # d = λ/2 at this frequency
    bin_width_hz = fs / nfft
    if bin_hz > half_wave_hz + bin_width_hz / 2:
        highest = np.floor((half_wave_hz + bin_width_hz / 2) / bin_width_hz) * bin_width_hz
        hint = (f"a frequency up to {highest:g} Hz (its bin) passes" if highest > 0 else
                "no bin passes: a longer --nfft or a smaller spacing")
        raise InputError(f"spacing {spacing_m:g} m is {spacing_wavelengths:.3f} wavelengths at the {bin_hz:g} Hz bin; "
                         f"above 1/2 (at {half_wave_hz:g} Hz) the array has grating lobes: {hint}", src)
    # |sin θ| < λ/d − 1 is free of grating lobes: the whole field up to d = λ/2
    unambiguous_deg = float(np.rad2deg(np.arcsin(min(1.0, 1.0 / spacing_wavelengths - 1.0))))
    M, frames = snaps.shape
    K = frames // snapshots_per_scan
    if K < 3:
        raise InputError(f"{frames} STFT frames make {K} scan(s) of {snapshots_per_scan}; the tracker needs ≥ 3 "
                         "(a longer recording, a smaller hop or fewer snapshots per scan)", src)
    blocks = snaps[:, : K * snapshots_per_scan].reshape(M, K, snapshots_per_scan).transpose(1, 0, 2)
    if band_hz is None:
        band_hz = (bin_hz * (1.0 - BAND_RELATIVE), min(bin_hz * (1.0 + BAND_RELATIVE), fs / 2))
    # the tracker needs N ≤ M − 1 and N ≤ Ns (the stage refuses more); a segment of the count is
    # one scan (the trackers' sources stay put within a scan), or 2M frames if a scan is shorter
    counted = wideband_count.count_sources_in_band(
        samples, fs, spacing_m / sound_speed_mps, band_hz, nfft, hop, max(snapshots_per_scan, COUNT_MIN_FRAMES * M),
        int(COUNT_SPAN_S * fs), max_sources=min(M - 1, snapshots_per_scan))
    scan_period_s = snapshots_per_scan * hop / fs
    # a scan's time stamp is the centre of its frames (the mean of the frame centres): the instant
    # its snapshots describe as a whole, and the one the trackers' filters refer to
    first_centre_s = ((snapshots_per_scan - 1) * hop + nfft) / (2.0 * fs)
    data = SimulatedData(times=np.arange(K) * scan_period_s + first_centre_s,
                         fixed={SNAPSHOTS_TOPIC: {"snapshots": blocks[None].astype(snapshot_dtype)}})
    params = {"source_wav": Path(src).name, "sample_rate_hz": fs, "frequency_hz": float(bin_hz),
              "spacing_m": float(spacing_m), "sound_speed_mps": float(sound_speed_mps), "nfft": int(nfft),
              "hop": int(hop), "snapshots_per_scan": int(snapshots_per_scan), "n_sensors": int(M),
              "spacing_wavelengths": float(spacing_wavelengths), "scan_period_s": float(scan_period_s),
              "bearing_positive_toward": f"{positive_toward} channel", "unambiguous_field_deg": unambiguous_deg,
              # the trackers' own parameter: a replay follows this many sources unless --set overrides it
              "n_sources": int(counted.count),
              # the frames are a continuous timeline stamped at each scan's centre, and PAST's memory
              # reaches back before it: the trackers measure each bearing at the instant it describes
              "align_subspace_instant": True,
              "source_count_method": "distinct directions of the band's MDL signal subspace, per scan, the most common",
              "source_count_band_hz": [counted.band_hz[0], counted.band_hz[1]], "source_count_bins": counted.n_bins,
              "source_count_frames": counted.n_frames, "source_count_effective_snapshots": counted.effective_snapshots,
              "source_count_per_segment": [int(c) for c in counted.segment_counts],
              "source_count_dimension": counted.dimension,
              "source_count_noise_model": ("white" if counted.diffuse_to_white_db is None else
                                           f"diffuse {counted.diffuse_to_white_db:g} dB over white"),
              "source_count_leakage_db": float(10 * np.log10(counted.leakage_endfire))}
    n = write_simulated(dst, data, scenario_metadata("array-wav", params, 0))
    return {"messages": n, "scans": K, "sensors": M, "bin_hz": bin_hz,
            "spacing_wavelengths": spacing_wavelengths, "scan_period_s": scan_period_s,
            "unambiguous_field_deg": unambiguous_deg, "n_sources": int(counted.count),
            "count_band_hz": counted.band_hz, "count_bins": counted.n_bins, "count_frames": counted.n_frames,
            "count_segments": int(counted.segment_counts.size), "count_dimension": counted.dimension,
            "count_leakage_db": float(10 * np.log10(counted.leakage_endfire))}
