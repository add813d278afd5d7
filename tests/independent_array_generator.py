"""An array recording generator that shares nothing with the project's simulator (``recorders/``).

It makes the multichannel WAV files of ``tests/test_array_foreign_recordings.py``: what a user
would record with a uniform linear array of microphones in a free field, written by other means
than the ones the trackers were built and tested with.

Physics (far field, no reverberation):

* **sources** are speech-like: white noise shaped by a two-pole resonance and a −3 dB/octave
  tilt, band-limited to ``SOURCE_BAND_HZ``, with a slow syllabic amplitude envelope (a few Hz,
  ±40 %); each source has its own resonance and rhythm;
* **propagation** is a time-varying fractional delay per sensor, applied sample by sample with a
  Kaiser-windowed sinc interpolator (Laakso, Välimäki, Karjalainen & Laine 1996, "Splitting the
  unit delay", section on windowed-sinc fractional-delay filters), so a source may move during the
  recording; the delays are relative to the array's centre, and a source at a positive bearing
  (from broadside) reaches the last channel first;
* **noise** is a spherically isotropic (diffuse) field: white noise mixed, frequency by
  frequency, with a square root of the coherence matrix ``sinc(2 f d |m − n| / c)`` (Cook,
  Waterhouse, Edwards & Thompson 1955; the mixing of Habets & Gannot 2007), plus independent
  sensor self-noise 20 dB below it.

The SNR is each source's power over the diffuse noise's power, per sensor, within the source
band. Everything comes from one ``numpy.random.Generator`` seed (same seed, same bytes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SOURCE_BAND_HZ = (200.0, 6000.0)
SELF_NOISE_DB = -20.0  # sensor self-noise relative to the diffuse field
FD_HALF_TAPS = 24  # the interpolator uses 2·24 taps
FD_KAISER_BETA = 8.0
FD_FRACTIONS = 1024  # fractional delays tabulated per sample


@dataclass(frozen=True)
class Source:
    """A source whose bearing (rad, from broadside) moves at a constant rate from ``start_rad``."""

    start_rad: float
    rate_rad_s: float = 0.0

    def bearing_rad(self, t_s):
        return self.start_rad + self.rate_rad_s * np.asarray(t_s, float)


def speech_like(n: int, fs: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-power speech-like noise: tilted, resonant, band-limited, slowly amplitude modulated."""
    f = np.fft.rfftfreq(n, 1.0 / fs)
    spectrum = np.fft.rfft(rng.standard_normal(n))
    resonance_hz = rng.uniform(500.0, 3000.0)
    width_hz = rng.uniform(300.0, 900.0)
    shape = 1.0 / np.sqrt(np.maximum(f, 50.0) / 1000.0)  # −3 dB per octave
    shape *= 1.0 + 2.0 / (1.0 + ((f - resonance_hz) / width_hz) ** 2)  # a broad formant
    shape *= (f >= SOURCE_BAND_HZ[0]) & (f <= SOURCE_BAND_HZ[1])
    signal = np.fft.irfft(spectrum * shape, n)
    t = np.arange(n) / fs
    rhythm = rng.uniform(2.5, 5.0)
    envelope = 1.0 + 0.4 * np.sin(2 * np.pi * rhythm * t + rng.uniform(0, 2 * np.pi))
    signal *= envelope
    return signal / np.sqrt(np.mean(signal ** 2))


def _interpolator_table() -> np.ndarray:
    """Kaiser-windowed sinc taps for ``FD_FRACTIONS`` evenly spaced fractional delays in [0, 1]
    (rows), ``2 · FD_HALF_TAPS`` taps each: a delay is rounded to 1/(2·FD_FRACTIONS) of a sample
    (a phase error below 1e-3 rad at 6 kHz)."""
    taps = np.arange(-FD_HALF_TAPS + 1, FD_HALF_TAPS + 1)
    frac = np.linspace(0.0, 1.0, FD_FRACTIONS + 1)
    offset = taps[None, :] - frac[:, None]  # distance of each tap from the wanted instant
    window = np.i0(FD_KAISER_BETA * np.sqrt(np.clip(1.0 - (offset / FD_HALF_TAPS) ** 2, 0.0, None)))
    return np.sinc(offset) * window / np.i0(FD_KAISER_BETA)


def fractional_delay(signal: np.ndarray, delay_samples: np.ndarray) -> np.ndarray:
    """``y[n] = s(n − D[n])`` by a Kaiser-windowed sinc interpolator (time-varying delay D)."""
    n = signal.size
    taps = np.arange(-FD_HALF_TAPS + 1, FD_HALF_TAPS + 1)
    table = _interpolator_table()
    pad = FD_HALF_TAPS + 2 + int(np.ceil(np.max(np.abs(delay_samples))))  # leads need samples ahead
    padded = np.concatenate([np.zeros(pad), signal, np.zeros(pad)])
    out = np.empty(n)
    step = 1 << 14
    for first in range(0, n, step):
        idx = np.arange(first, min(n, first + step))
        position = idx - delay_samples[idx]
        whole = np.floor(position).astype(np.int64)
        row = np.rint((position - whole) * FD_FRACTIONS).astype(np.int64)
        out[idx] = np.einsum("nk,nk->n", padded[whole[:, None] + taps[None, :] + pad], table[row])
    return out


def diffuse_noise(n: int, fs: float, n_sensors: int, spacing_m: float, sound_speed_mps: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Spherically isotropic noise ``(n_sensors, n)`` of unit power per sensor (white spectrum)."""
    f = np.fft.rfftfreq(n, 1.0 / fs)
    white = np.fft.rfft(rng.standard_normal((n_sensors, n)), axis=1)  # (M, F)
    gaps = np.abs(np.subtract.outer(np.arange(n_sensors), np.arange(n_sensors))) * spacing_m
    out = np.empty_like(white)
    step = 4096
    for first in range(0, f.size, step):
        part = slice(first, first + step)
        coherence = np.sinc(2.0 * f[part, None, None] * gaps[None] / sound_speed_mps)  # (F, M, M)
        values, vectors = np.linalg.eigh(coherence)
        mix = vectors * np.sqrt(np.clip(values, 0.0, None))[:, None, :]
        out[:, part] = np.einsum("fmk,kf->mf", mix, white[:, part])
    return np.fft.irfft(out, n, axis=1)


def in_band_share(fs: float) -> float:
    """The share of a white spectrum's power inside the source band."""
    return (SOURCE_BAND_HZ[1] - SOURCE_BAND_HZ[0]) / (fs / 2)


def record(sources, snr_db: float, seconds: float, seed: int, fs: int = 16000, n_sensors: int = 8,
           spacing_m: float = 0.05, sound_speed_mps: float = 343.0) -> np.ndarray:
    """Samples ``(n, n_sensors)`` of the sources over diffuse noise (float, peak 0.9)."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * fs))
    t = np.arange(n) / fs
    centred = np.arange(n_sensors) - (n_sensors - 1) / 2
    x = np.zeros((n_sensors, n))
    for source in sources:
        s = speech_like(n, fs, rng)
        lead_s = spacing_m * np.sin(source.bearing_rad(t)) / sound_speed_mps  # per sensor, toward the last
        for m in range(n_sensors):
            x[m] += fractional_delay(s, -centred[m] * lead_s * fs)
    noise = diffuse_noise(n, fs, n_sensors, spacing_m, sound_speed_mps, rng)
    noise += 10 ** (SELF_NOISE_DB / 20) * rng.standard_normal(noise.shape)
    # a white noise has only in_band_share of its power in the source band
    x += np.sqrt(10 ** (-snr_db / 10) / in_band_share(fs)) * noise
    return (x / np.abs(x).max() * 0.9).T


def write_wav(path, samples: np.ndarray, fs: int = 16000) -> None:
    """Multichannel float32 WAV (scipy.io.wavfile)."""
    from scipy.io import wavfile

    wavfile.write(path, fs, np.asarray(samples, np.float32))
