"""``replay convert array-wav``: a multichannel WAV array recording → snapshot channels, the input
of the array-snapshot bearing trackers (Ryu, Lee & Lee 2001; ``docs/papers/array.md``).

Registered under the existing ``replay convert`` group (this module is listed in
``trackreplay.face.cli.EXTENSION_MODULES``; its CONVERT_COMMANDS join the group).
"""

from __future__ import annotations

from pathlib import Path

import click

COMMANDS: list = []  # no top-level command


@click.command("array-wav")
@click.argument("wav_path", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--spacing-m", required=True, type=float, help="Sensor spacing d (m); the channels are the sensors "
              "in order along the line.")
@click.option("--frequency-hz", required=True, type=float, help="Narrowband frequency; the nearest STFT bin is used.")
@click.option("--sound-speed-mps", default=343.0, show_default=True, type=float, help="Propagation speed c.")
@click.option("--nfft", default=512, show_default=True, type=int, help="STFT window length (samples, Hann).")
@click.option("--hop", type=int, help="STFT hop (samples; default nfft/2).")
@click.option("--snapshots-per-scan", default=30, show_default=True, type=int, help="STFT frames grouped into one scan (Ns).")
@click.option("--complex128", "wide", is_flag=True, help="Store complex128 snapshots (default complex64).")
@click.option("--positive-toward", type=click.Choice(["last", "first"]), default="last", show_default=True,
              help="The end of the array a positive bearing points to: 'last' = a source whose wave reaches the "
                   "last channel first has θ > 0 (θ from broadside); 'first' mirrors it.")
@click.option("--band-hz", metavar="LOW,HIGH", help="Band over which the sources are counted (wideband MDL; "
              "default ±10 % of the tracked bin's frequency).")
@click.option("--force", is_flag=True, help="Replace the output file if it exists.")
def array_wav_cmd(wav_path, output, spacing_m, frequency_hz, sound_speed_mps, nfft, hop, snapshots_per_scan, wide,
                  positive_toward, band_hz, force):
    """Multichannel WAV (uniform linear array) → /array/snapshots, ready for `replay`.

    Bearings are angles from broadside; by default a positive one points to the last channel's
    end of the array (its wave reaches the last channel first), as in most array texts;
    --positive-toward first mirrors them. The convention is recorded in the data set.

    The number of sources is counted over a band around the frequency (wideband MDL, printed)
    and recorded as the trackers' n_sources; `replay --set n_sources=…` overrides it.

    \b
    Example:
      replay convert array-wav array.wav -o rec.mcap --spacing-m 0.04 --frequency-hz 2000
      replay rec.mcap                       # follows the counted sources
      replay rec.mcap --set n_sources=2     # or a number of your own
    """
    from trackreplay.recorders.array_wav import convert_array_wav

    from trackreplay.paths import refuse_input_overwrite, refuse_replacing_file

    refuse_input_overwrite([wav_path], [output])
    refuse_replacing_file(output, force)
    info = convert_array_wav(wav_path, output, spacing_m, frequency_hz, sound_speed_mps, nfft, hop,
                             snapshots_per_scan, "complex128" if wide else "complex64", positive_toward,
                             _band(band_hz))
    click.echo(f"wrote {output}: {info['scans']} scans × {info['sensors']} sensors × {snapshots_per_scan} snapshots "
               f"at {info['bin_hz']:.1f} Hz (d = {info['spacing_wavelengths']:.3f} λ, T = {info['scan_period_s']:.3f} s)")
    click.echo(f"bearings from broadside, positive toward the {positive_toward} channel"
               + (f"; free of grating lobes within ±{info['unambiguous_field_deg']:.1f}°"
                  if info["unambiguous_field_deg"] < 90 else ""))
    low, high = info["count_band_hz"]
    counted = (f"{info['n_sources']} source(s)" if info["n_sources"] else
               "no source (the trackers will count at start-up from the tracked bin)")
    click.echo(f"{counted} by wideband MDL over {low:.0f}–{high:.0f} Hz ({info['count_bins']} bins; the most common "
               f"count of {info['count_segments']} scan(s) of {info['count_frames']} frames, signal subspace of "
               f"{info['count_dimension']} dimension(s)); recorded as n_sources "
               "(replay --set n_sources=… overrides it)")



def _band(text):
    """``LOW,HIGH`` → two floats (None when the option is absent)."""
    from trackreplay.errors import InputError

    if text is None:
        return None
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        return float(parts[0]), float(parts[1])
    except ValueError:
        raise InputError(f"--band-hz must be LOW,HIGH in Hz (e.g. 1500,1900), got {text!r}") from None


CONVERT_COMMANDS = [array_wav_cmd]  # added under `replay convert` by trackreplay.face.cli
