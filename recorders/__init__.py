"""Recorders: simulators and converters that write sensor streams plus truth to MCAP.

Each simulator module exposes ``validate(params)`` and ``simulate(params, runs, seed)``.
"""

from __future__ import annotations

from pipeline.errors import InputError


def recorder_module(recorder: str):
    """The simulator module registered under a scenario's ``recorder`` name."""
    from recorders import radar_tws

    table = {"radar-tws": radar_tws}
    if recorder not in table:
        raise InputError(f"no simulator named {recorder!r} (have: {', '.join(sorted(table))})")
    return table[recorder]


def simulator_for(recorder: str):
    """The ``simulate(params, runs, seed)`` function of a recorder name."""
    return recorder_module(recorder).simulate
