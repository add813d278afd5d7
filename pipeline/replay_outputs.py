"""The outputs file of a replay: its provenance (what it was made from and how) and the writer
that writes it one scoring unit at a time, a large unit on a thread of its own beside the scoring
(:func:`trackreplay.replay.replay`; the file layout is :mod:`trackreplay.contract`'s)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from trackreplay import __version__, stage_running
from trackreplay.contract import METADATA_PROVENANCE, OUTPUT_ZSTD_LEVEL, write_dataset


def _canonical(specs):
    from trackreplay.registry import canonical_spec

    return [canonical_spec(s) for s in specs]


def output_provenance(ds, n_runs, stages, designs, tracker_specs) -> dict:
    """The outputs' metadata: what they were made from and how."""
    meta = {METADATA_PROVENANCE: {"input": Path(ds.path).name, "input_sha256": dataset_identity(ds),
                                  "runs": str(n_runs), "package_version": __version__,
                                  "stages": ",".join(s.name for s in stages),
                                  "tracker_specs": json.dumps(list(_canonical(tracker_specs))),
                                  "design": json.dumps(designs, sort_keys=True, default=str)}}
    if "replay.scenario" in ds.metadata:
        meta["replay.scenario"] = ds.metadata["replay.scenario"]
    return meta


class OutputWriter:
    """The outputs MCAP, written one scoring unit at a time, a large one on a thread of its own.

    zstd compresses without holding the GIL, so the chunks of one tracker's outputs are
    compressed while the main thread scores them; :meth:`wait` joins before the outputs are
    released. The file is opened on the first write (its provenance records the run count)
    and appears complete or not at all (:func:`trackreplay.contract.write_dataset`). Without a
    path nothing is written.
    """

    def __init__(self, path, metadata_for_runs):
        self.path, self._metadata_for_runs = path, metadata_for_runs
        self._context = self._writer = self._pool = self._pending = None
        self.seconds = 0.0  # writing, in all
        self.seconds_beside = 0.0  # of which on the thread, beside the scoring

    def __enter__(self):
        return self

    def write(self, stage, unit: dict) -> None:
        """Write ``unit`` (``{"times", "tracks"}``): on the thread when its outputs are large,
        where compression is most of the work; small ones (many short messages, whose Python
        work would hold the GIL the scoring needs) at once."""
        if self.path is None:
            return
        self.wait()
        if self._writer is None:
            self._context = write_dataset(self.path, self._metadata_for_runs(runs_in({stage.name: unit})),
                                          zstd_level=OUTPUT_ZSTD_LEVEL, pack_symmetric=True)
            self._writer = self._context.__enter__()

        beside = stage_running.outputs_nbytes(unit["tracks"]) >= stage_running.SCORING_UNIT_BYTES

        def job():
            t = time.perf_counter()
            stage_running.write_outputs(stage, self._writer, unit)
            if beside:  # its bytes start for the disk now, beside the scoring, not in the final fsync
                self._writer.start_writeback()
            self.seconds += time.perf_counter() - t
            if beside:
                self.seconds_beside += time.perf_counter() - t

        if not beside:
            job()
            return
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="replay-write")
        self._pending = self._pool.submit(job)

    def wait(self) -> None:
        """Until the last write is done (its error, if any, raised here)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def __exit__(self, kind, exc, tb):
        try:
            if exc is None:
                self.wait()
            elif self._pending is not None:  # let the thread stop before the file is discarded
                self._pending.exception()
        finally:
            if self._pool is not None:
                self._pool.shutdown()
            if self._context is not None:
                if exc is None:
                    self._context.__exit__(None, None, None)
                else:
                    self._context.__exit__(kind, exc, tb)
        return False


def dataset_identity(ds) -> str:
    """SHA-256 of the data set's file (its identity in the outputs' provenance); empty for an
    in-memory data set."""
    import hashlib

    path = Path(ds.path) if ds.path else None
    if path is None or not path.is_file():
        return ""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def runs_in(results) -> int:
    for result in results.values():
        for out in result["tracks"].values():
            if "state" in out:
                return int(out["state"].shape[0])
    return 0
