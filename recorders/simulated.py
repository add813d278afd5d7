"""Simulated streams in memory and their one way into an MCAP file."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.contract import scenario_metadata, write_dataset


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


def write_simulated(path: str | Path, data: SimulatedData, metadata: dict, progress=None) -> int:
    """Write ``data`` scan-major (all channels, all runs of scan k, then k + 1), atomically.

    Returns the number of messages written. ``progress(n)`` is called once per scan.
    """
    n = 0
    with write_dataset(path, metadata) as w:
        for k, t in enumerate(data.times):
            for topic, (arrays, counts) in data.ragged.items():
                for r in range(counts.shape[0]):
                    c = counts[r, k]
                    w.write(topic, r, k, t, {name: a[r, k, :c] for name, a in arrays.items()})
                    n += 1
            for topic, arrays in data.fixed.items():
                for r in range(next(iter(arrays.values())).shape[0]):
                    w.write(topic, r, k, t, {name: a[r, k] for name, a in arrays.items()})
                    n += 1
            w.flush()  # one chunk per scan: a crash or a cut file loses at most one scan
            if progress:
                progress(1)
    return n


def record(path, scenario, runs: int, seed: int, progress=None) -> int:
    """Simulate ``scenario`` and write it with its scenario/seed/version metadata."""
    from recorders import simulator_for

    data = simulator_for(scenario.recorder)(scenario.params, runs, seed)
    return write_simulated(path, data, scenario_metadata(scenario.name, scenario.params, seed), progress)
