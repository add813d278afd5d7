"""Recorders: simulators and converters that write sensor streams plus truth to MCAP.

Each simulator module exposes ``validate(params)`` and ``simulate(params, runs, seed)``
returning :class:`trackreplay.recorders.simulated.SimulatedData`. A scenario file's ``recorder`` key names
its module here.
"""

from __future__ import annotations

import importlib

from trackreplay.errors import InputError

RECORDERS = {
    "radar-tws": "trackreplay.recorders.radar_tws",
    "xcorr-peaks": "trackreplay.recorders.xcorr_peaks",
    "xcorr-signals": "trackreplay.recorders.xcorr_signals",
    "array-snapshots": "trackreplay.recorders.array_snapshots",
    "colored-noise": "trackreplay.recorders.colored_noise",
    "tdoa-fdoa": "trackreplay.recorders.tdoa_fdoa",
    "radar-multi": "trackreplay.recorders.radar_multi",
    # one line per recorder: "name": "trackreplay.recorders.module",
}


def recorder_module(recorder: str):
    """The simulator module registered under a scenario's ``recorder`` name."""
    if recorder not in RECORDERS:
        raise InputError(f"no simulator named {recorder!r} (have: {', '.join(sorted(RECORDERS))})")
    return importlib.import_module(RECORDERS[recorder])


def simulator_for(recorder: str):
    """The ``simulate(params, runs, seed)`` function of a recorder name."""
    return recorder_module(recorder).simulate
