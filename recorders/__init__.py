"""Recorders: simulators and converters that write sensor streams plus truth to MCAP.

Each simulator module exposes ``validate(params)`` and ``simulate(params, runs, seed)``
returning :class:`recorders.simulated.SimulatedData`. A scenario file's ``recorder`` key names
its module here.
"""

from __future__ import annotations

import importlib

from pipeline.errors import InputError

RECORDERS = {
    "radar-tws": "recorders.radar_tws",
    "xcorr-peaks": "recorders.xcorr_peaks",
    "xcorr-signals": "recorders.xcorr_signals",
    "array-snapshots": "recorders.array_snapshots",
    "colored-noise": "recorders.colored_noise",
    "tdoa-fdoa": "recorders.tdoa_fdoa",
    "radar-multi": "recorders.radar_multi",
    # one line per recorder: "name": "recorders.module",
}


def recorder_module(recorder: str):
    """The simulator module registered under a scenario's ``recorder`` name."""
    if recorder not in RECORDERS:
        raise InputError(f"no simulator named {recorder!r} (have: {', '.join(sorted(RECORDERS))})")
    return importlib.import_module(RECORDERS[recorder])


def simulator_for(recorder: str):
    """The ``simulate(params, runs, seed)`` function of a recorder name."""
    return recorder_module(recorder).simulate
