"""Simulated streams in memory and their one way into an MCAP file."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackreplay.contract import CONTRACT_V2, CONTRACT_VERSION, scans_per_message, scenario_metadata, write_dataset


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
    per run and scan as version 1 did. A long recording of few runs (``scans_per_message`` > 1)
    goes in messages, and chunks, of several scans (``write_scan_group``): per scan, reading and
    writing 100,000 scans of one run cost tens of seconds. Returns the number of MCAP messages
    written.
    ``progress(n)`` is called once per scan.
    """
    n_scans = len(data.times)
    group = scans_per_message(data.n_runs, n_scans) if contract == CONTRACT_V2 else 1
    if group > 1:  # a long recording of few runs: messages (and chunks) of several scans
        with write_dataset(path, metadata, contract, group_scans=True) as w:
            for first in range(0, n_scans, group):
                scans = slice(first, first + group)
                for topic, (arrays, counts) in data.ragged.items():
                    w.write_scan_group(topic, first, data.times[scans], {name: a[:, scans] for name, a in arrays.items()},
                                       counts[:, scans])
                for topic, arrays in data.fixed.items():
                    w.write_scan_group(topic, first, data.times[scans], {name: a[:, scans] for name, a in arrays.items()})
                w.flush()  # one chunk per group of scans
                if progress:
                    progress(len(data.times[scans]))
        return w.messages
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
    from trackreplay.recorders import simulator_for

    data = simulator_for(scenario.recorder)(scenario.params, runs, seed)
    return write_simulated(path, data, scenario_metadata(scenario.name, scenario.params, seed), progress, contract)
