"""Simulated streams in memory and their one way into an MCAP file."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.contract import CONTRACT_VERSION, scenario_metadata, write_dataset


@dataclass
class SimulatedData:
    """What a recorder produces before it is written.

    Attributes
    ----------
    times : ndarray, shape (scans,)
    fixed : dict
        ``topic -> {array name -> ndarray (runs, scans, ...)}``, one frame per (run, scan).
    ragged : dict
        ``topic -> ({array name -> ndarray (runs, scans, width, ...)}, counts (runs, scans))``:
        frame (r, k) holds the first ``counts[r, k]`` entries (possibly none).
    """

    times: np.ndarray
    fixed: dict = field(default_factory=dict)
    ragged: dict = field(default_factory=dict)

    @property
    def n_runs(self) -> int:
        for arrays in self.fixed.values():
            return next(iter(arrays.values())).shape[0]
        for _, counts in self.ragged.values():
            return counts.shape[0]
        return 0


def write_simulated(path: str | Path, data: SimulatedData, metadata: dict, progress=None,
                    contract: str = CONTRACT_VERSION) -> int:
    """Write ``data`` scan-major (all channels, all runs of scan k, then k + 1), atomically.

    Each channel's scan goes to the writer in one call (``write_ragged`` / ``write_batch``): in
    contract v2 that is one message of every run; ``contract="replay.v1"`` writes one message
    per run and scan as version 1 did. Returns the number of MCAP messages written.
    ``progress(n)`` is called once per scan.
    """
    with write_dataset(path, metadata, contract) as w:
        for k, t in enumerate(data.times):
            for topic, (arrays, counts) in data.ragged.items():
                w.write_ragged(topic, k, t, {name: a[:, k] for name, a in arrays.items()}, counts[:, k])
            for topic, arrays in data.fixed.items():
                w.write_batch(topic, k, t, {name: a[:, k] for name, a in arrays.items()})
            w.flush()  # one chunk per scan: a crash or a cut file loses at most one scan
            if progress:
                progress(1)
    return w.messages


def record(path, scenario, runs: int, seed: int, progress=None, contract: str = CONTRACT_VERSION) -> int:
    """Simulate ``scenario`` and write it with its scenario/seed/version metadata."""
    from recorders import simulator_for

    data = simulator_for(scenario.recorder)(scenario.params, runs, seed)
    return write_simulated(path, data, scenario_metadata(scenario.name, scenario.params, seed), progress, contract)
