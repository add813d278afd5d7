"""What a data set knows about its sensor, and where each value comes from.

A tracker's design values are of two kinds. Some describe the *sensor* that made the data: its
noise, scan period, geometry, detection probability. Only the data set can say them. A
simulation records them from its parameters; a converter records the ones the user gave
(``--set`` on ``replay convert``, or the ``[sensor]`` table of a mapping file). The others are
the *tracker's own* choices (a design acceleration, a gate, a forgetting factor), with
defaults documented with each tracker and its paper's scenario.

Whatever a recording does not say about its sensor is **unknown**. It is never taken from a
bundled scenario: a tracker that needs an unknown value stops with one line naming the
``--set NAME=VALUE`` it needs, unless its family documents an estimate from the data (the scan
period from the scan times), which is then used and said (``docs/importers.md``, "Sensor
values").

The record of a converted data set (``replay.scenario``) carries two fields a simulation's
lacks: ``origin = "recording"`` and ``sources``, a JSON object naming the source of each value
it records (:data:`SOURCES`). Files converted before these fields existed (seed ``-1``) and the
WAV converter's records (scenario ``array-wav``) are recordings too, and so is a file with no
record, or a record without parameters (one written by hand with
:func:`trackreplay.contract.write_dataset`, or by an older tool): it says nothing about its sensor,
so all its sensor values are unknown. Only a simulation records its generating model, so only a
simulation has Cramér–Rao bounds (``docs/evaluation.md``).
"""

from __future__ import annotations

import json

#: the sources a value can have, as ``replay info`` prints them
SIMULATION = "simulation parameters"
CONVERTER_FLAG = "converter flag"
MAPPING_FILE = "mapping file"
DATA = "the data"
ESTIMATED = "estimated"
UNKNOWN = "unknown"
EARLIER_CONVERTER = "an earlier converter (possibly the bundled scenario's value)"
SOURCES = (SIMULATION, CONVERTER_FLAG, MAPPING_FILE, DATA, ESTIMATED, UNKNOWN, EARLIER_CONVERTER)

# Which design values describe a family's sensor, which it estimates from the data, and which its
# measurements carry are declared with the family (trackreplay.vocabulary.Family: sensor_keys,
# estimable_keys, sensor_arrays).

#: how a sensor value a family may estimate is estimated from the data (:func:`estimate`)
ESTIMATES = {"scan_period_s": "the median interval between scan times"}

#: what a record may say about the data themselves, recorded by every converter from the file
DATA_KEYS = ("n_runs", "n_scans", "time_span_s")

#: what the WAV converter (``replay convert array-wav``) reads from the file rather than its flags
WAV_MEASURED = ("source_wav", "sample_rate_hz", "n_sensors", "n_sources")

#: the recording field values
ORIGIN_RECORDING = "recording"


def _record(scenario: dict) -> dict:
    return scenario if isinstance(scenario, dict) else {}


def says_nothing(scenario: dict) -> bool:
    """Whether a ``replay.scenario`` record is missing or holds no parameters: the file says
    nothing about its sensor, so every sensor value of it is unknown (issue 28, item 1)."""
    return not isinstance(_record(scenario).get("params"), dict)


def is_recording(scenario: dict) -> bool:
    """Whether a ``replay.scenario`` record (as :attr:`trackreplay.contract.Dataset.scenario`
    gives it) is a converted recording's rather than a simulation's.

    A record written by a converter says ``origin = "recording"``; earlier converters wrote seed
    ``-1`` (tables, foreign MCAP) or scenario ``array-wav``. A file without a record, or whose
    record holds no parameters (written by hand with :func:`trackreplay.contract.write_dataset`,
    or by an older tool), says nothing about its sensor: it is a recording too, every sensor
    value of it unknown (:func:`says_nothing`), never the bundled scenario's."""
    rec = _record(scenario)
    if says_nothing(rec):
        return True
    if rec.get("origin") == ORIGIN_RECORDING:
        return True
    return str(rec.get("seed", "")).strip() == "-1" or rec.get("scenario") == "array-wav"


def is_simulation(scenario: dict) -> bool:
    """Whether the record is a simulation's: its generating model is recorded, so bounds such as
    the PCRB and the CRLB at the truth can be computed from it."""
    rec = _record(scenario)
    return bool(rec) and "params" in rec and not is_recording(rec)


def recorded_sources(scenario: dict) -> dict:
    """``{parameter: source}`` of every value the record holds (:data:`SOURCES`)."""
    rec = _record(scenario)
    params = rec.get("params", {})
    if not isinstance(params, dict):
        return {}
    if not is_recording(rec):
        return {k: SIMULATION for k in params}
    raw = rec.get("sources")
    sources = {}
    if isinstance(raw, str):
        try:
            sources = json.loads(raw)
        except (ValueError, RecursionError):  # (RecursionError: nested deeper than json recurses)
            sources = {}
    if not isinstance(sources, dict):
        sources = {}
    if raw is None and rec.get("scenario") == "array-wav":
        # the WAV converter records its flags and what it measured in the file, nothing borrowed
        return {k: DATA if k in WAV_MEASURED or k.startswith("source_count") else CONVERTER_FLAG for k in params}
    return {k: str(sources.get(k, EARLIER_CONVERTER if raw is None else DATA)) for k in params}


def estimate(key: str, times_s) -> float | None:
    """The estimate of sensor value ``key`` from the data (see :data:`ESTIMATES`), or None.

    The scan period is the median interval between successive scan times: robust to a missing
    scan, which doubles one interval, and exact on evenly spaced scans."""
    if key != "scan_period_s":
        return None
    import numpy as np

    t = np.asarray(times_s, dtype=float)
    steps = np.diff(t[np.isfinite(t)])
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else None


def unknown_message(tracker: str, keys) -> str:
    """The one line a tracker that needs unknown sensor values stops with."""
    keys = list(keys)
    sets = " ".join(f"--set {k}=VALUE" for k in keys)
    what = "value" if len(keys) == 1 else "values"
    return (f"tracker {tracker!r} needs the sensor {what} {', '.join(keys)}, which this recording does not say: "
            f"give {'it' if len(keys) == 1 else 'them'} with {sets}")
