"""Monte Carlo studies of the bearing-peak trackers through the path a user's replay takes: the
simulated peaks written to an MCAP file, read back and run by the family's stage (no second run
path for tests)."""

from __future__ import annotations

import itertools
import tempfile
from pathlib import Path

import numpy as np

from trackreplay import design_values, stage_running
from trackreplay.contract import read_dataset, scenario_metadata
from trackreplay.stages import stage_named
from trackreplay.recorders.simulated import write_simulated

_FILES = itertools.count()


def track_recorded(data, params: dict, trackers=("jpda", "jpda_a"), overrides: dict | None = None,
                   seed: int = 0, scenario: str = "xcorr-crossing") -> dict:
    """Write ``data`` (a :class:`trackreplay.recorders.simulated.SimulatedData` of the xcorr
    ``scenario`` with ``params``) and run its trackers through the family's stage.

    Returns
    -------
    dict
        ``{"tracks": {tracker: outputs}, "truth": (R, K, T) bearings, "gate_rad": V}``.
    """
    stage = stage_named("xcorr")
    with tempfile.TemporaryDirectory(prefix="peaks-") as folder:
        path = Path(folder) / f"peaks-{next(_FILES)}.mcap"
        write_simulated(path, data, scenario_metadata(scenario, params, seed=seed))
        dataset = read_dataset(path)
        design = design_values.resolve(stage, dataset, overrides)
        entries = [e for e in stage.entries() if e.name in trackers]
        out = stage_running.run(stage, dataset, entries, design)
        truth = stage.decode(dataset, design).truth_bearing_rad
    assert not out["errors"], out["errors"]
    return {"tracks": out["tracks"], "truth": truth, "gate_rad": float(np.deg2rad(design["gate_deg"]))}
