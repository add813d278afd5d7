"""Recorders: simulators and converters that write sensor streams plus truth to MCAP.

Each simulator module exposes ``validate(params)`` and ``simulate(params, runs, seed)``
returning :class:`trackreplay.recorders.simulated.SimulatedData`. A scenario file's ``recorder`` key names
its module (:func:`recorder_names`): no list to keep.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from trackreplay.errors import InputError


def recorder_names() -> dict[str, str]:
    """Simulator name -> its module: a scenario file's ``recorder = "radar-tws"`` is the module
    ``recorders/radar_tws.py`` (the name with ``-`` written ``_``), one that defines ``simulate``."""
    return {path.stem.replace("_", "-"): f"trackreplay.recorders.{path.stem}"
            for path in sorted(Path(__file__).parent.glob("*.py"))
            if not path.stem.startswith("_") and "\ndef simulate(" in path.read_text()}


def recorder_module(recorder: str):
    """The simulator module registered under a scenario's ``recorder`` name."""
    names = recorder_names()
    if recorder not in names:
        raise InputError(f"no simulator named {recorder!r} (have: {', '.join(sorted(names))})")
    return importlib.import_module(names[recorder])


def simulator_for(recorder: str):
    """The ``simulate(params, runs, seed)`` function of a recorder name."""
    return recorder_module(recorder).simulate
