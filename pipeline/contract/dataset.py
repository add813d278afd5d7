"""What a read gives: :class:`Dataset` (channels and metadata records) and :class:`ChannelData`
(one channel's frames), with the bulk columns behind them (docs/contract.md, "Reading").

A v2 file's arrays stay as decoded, one column per array and channel (``np.frombuffer`` of the
messages' bytes, joined); the per-frame views of :meth:`ChannelData.array` are made only when
asked for, and :meth:`ChannelData.grid` / :meth:`ChannelData.ragged` are read-only views of the
values where the frames are in the writer's order.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping as MappingABC
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from trackreplay.contract.layout import (FIXED, IRREGULAR, MAX_PADDED_BYTES, MAX_SPARSITY, METADATA_SCENARIO,
                                         RAGGED)
from trackreplay.errors import InputError


@dataclass
class _Column:
    """One array of a channel in bulk: the entries of the frames that carry it, in frame order.

    ``FIXED``: ``values`` is ``(count, *shape)``. ``RAGGED``: entry i is
    ``values[offsets[i]:offsets[i + 1]]`` (rows of ``shape``). ``IRREGULAR``: ``items``.
    """

    kind: int
    dtype: np.dtype
    count: int
    shape: tuple = ()
    values: np.ndarray | None = None
    offsets: np.ndarray | None = None
    items: list | None = None
    frames: np.ndarray | None = None  # in a decoded message: the frames carrying it (None: all)

    def entries(self) -> list[np.ndarray]:
        if self.kind == IRREGULAR:
            return list(self.items)
        if self.kind == RAGGED:
            return np.split(self.values, self.offsets[1:-1]) if self.count else []
        if self.values.ndim == 1:  # 0-d entries: keep them arrays, as v1 frames decode
            return [self.values[i, ...] for i in range(self.count)]
        return list(self.values)

    def lengths(self) -> np.ndarray:
        return np.diff(self.offsets)

    @property
    def nbytes(self) -> int:
        if self.kind == IRREGULAR:
            return sum(a.nbytes for a in self.items)
        return self.values.nbytes


class ColumnArrays(MappingABC):
    """``ChannelData.arrays`` of a v2 file: array name → list of per-frame arrays, made on first
    access (membership and iteration need no decoding)."""

    def __init__(self, columns: dict[str, _Column]):
        self.columns = columns
        self._lists: dict[str, list] = {}

    def __getitem__(self, name: str) -> list[np.ndarray]:
        if name not in self._lists:
            self._lists[name] = self.columns[name].entries()
        return self._lists[name]

    def __contains__(self, name) -> bool:
        return name in self.columns

    def __iter__(self):
        return iter(self.columns)

    def __len__(self) -> int:
        return len(self.columns)

    def __repr__(self) -> str:
        return f"ColumnArrays({', '.join(self.columns)})"


def _merge_columns(parts: list[_Column]) -> _Column:
    """One channel-level column from the same array's columns of successive messages."""
    if len(parts) == 1:
        return parts[0]
    count = sum(p.count for p in parts)
    dtype = parts[0].dtype
    same_dtype = all(p.dtype == dtype for p in parts)
    if same_dtype and all(p.kind == FIXED and p.shape == parts[0].shape for p in parts):
        return _Column(FIXED, dtype, count, parts[0].shape, np.concatenate([p.values for p in parts]))
    tails = {p.shape if p.kind == RAGGED else p.shape[1:] for p in parts if p.kind != IRREGULAR}
    if same_dtype and len(tails) == 1 and all(p.kind == RAGGED or (p.kind == FIXED and p.shape) for p in parts):
        tail = tails.pop()
        lengths, flats = [], []
        for p in parts:
            if p.kind == RAGGED:
                lengths.append(np.diff(p.offsets))
                flats.append(p.values)
            else:
                lengths.append(np.full(p.count, p.shape[0], np.int64))
                flats.append(p.values.reshape(p.count * p.shape[0], *tail))
        offsets = np.zeros(count + 1, np.int64)
        np.cumsum(np.concatenate(lengths), out=offsets[1:])
        return _Column(RAGGED, dtype, count, tail, np.concatenate(flats), offsets)
    items: list = []
    for p in parts:
        items.extend(p.entries())
    return _Column(IRREGULAR, dtype, count, items=items)


@dataclass(frozen=True)
class _FrameBlocks:
    """The frames of a channel as its messages list them, one row per message: every message
    carries runs ``first_run … first_run + count − 1`` of one ``scan`` at one ``time_s``.

    This is what a v2 grid holds; the per-frame run, scan and time arrays it stands for are three
    times eight bytes a frame (31 MB for a 10,000-run radar data set's two channels), made only
    when asked for.
    """

    scan: np.ndarray
    first_run: np.ndarray
    count: np.ndarray
    time_s: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.count.sum())

    def run(self) -> np.ndarray:
        starts = np.cumsum(self.count) - self.count
        return np.arange(self.n_frames, dtype=np.int64) - np.repeat(starts - self.first_run, self.count)

    def scans(self) -> np.ndarray:
        return np.repeat(self.scan, self.count)

    def times(self) -> np.ndarray:
        return np.repeat(self.time_s, self.count)

    def scan_major(self, n_runs: int, n_scans: int) -> bool:
        """Whether the frames are every (run, scan) once, scan by scan and run by run within one."""
        if self.n_frames != n_runs * n_scans:
            return False
        starts = np.cumsum(self.count) - self.count  # frame number of each message's first frame
        return bool(np.array_equal(self.scan, starts // n_runs) and np.array_equal(self.first_run, starts % n_runs)
                    and np.all(self.first_run + self.count <= n_runs))


class ChannelData:
    """All frames of one channel, as decoded.

    Attributes
    ----------
    run, scan : ndarray of int
        Run and scan index per frame.
    time_s : ndarray of float
        Scan time per frame.
    arrays : mapping of str to list of ndarray
        One list per array name, one entry per frame (for a v2 file a :class:`ColumnArrays`
        that makes the per-frame views on first access).
    topic : str
        The channel's topic (named in error messages).
    path : str, optional
        The file it was read from (named in error messages).

    A channel read from messages that each carry consecutive runs of one scan (what the writer
    makes) keeps those messages' lists instead of ``run``, ``scan`` and ``time_s``, and makes
    the arrays on each access (:class:`_FrameBlocks`); ``n_frames``, ``n_runs``, ``n_scans`` and
    :meth:`times` need no per-frame array.
    """

    def __init__(self, run, scan, time_s, arrays: Mapping[str, list[np.ndarray]], topic: str = "channel",
                 path: str | None = None, *, blocks: _FrameBlocks | None = None):
        self._run, self._scan, self._time_s, self._blocks = run, scan, time_s, blocks
        self.arrays = arrays
        self.topic = topic
        self.path = path
        self._order: bool | None = None

    @classmethod
    def of_blocks(cls, blocks: _FrameBlocks, arrays, topic: str = "channel", path: str | None = None) -> "ChannelData":
        """A channel whose frames are the messages ``blocks`` lists (no per-frame arrays kept)."""
        return cls(None, None, None, arrays, topic, path, blocks=blocks)

    def __repr__(self) -> str:
        return f"ChannelData(topic={self.topic!r}, frames={self.n_frames}, arrays={self.arrays!r})"

    @property
    def run(self) -> np.ndarray:
        return self._run if self._blocks is None else self._blocks.run()

    @property
    def scan(self) -> np.ndarray:
        return self._scan if self._blocks is None else self._blocks.scans()

    @property
    def time_s(self) -> np.ndarray:
        return self._time_s if self._blocks is None else self._blocks.times()

    @property
    def n_frames(self) -> int:
        return self._run.size if self._blocks is None else self._blocks.n_frames

    @property
    def n_runs(self) -> int:
        if self._blocks is not None:
            b = self._blocks
            return int((b.first_run + b.count).max()) if b.count.size else 0
        return int(self._run.max()) + 1 if self._run.size else 0

    @property
    def n_scans(self) -> int:
        scan = self._scan if self._blocks is None else self._blocks.scan
        return int(scan.max()) + 1 if scan.size else 0

    def _column(self, name: str) -> _Column | None:
        """The bulk column behind ``name`` (after the checks :meth:`array` makes), or None for
        per-frame lists."""
        if not isinstance(self.arrays, ColumnArrays):
            return None
        self._check_count(name, self.arrays.columns.get(name))
        return self.arrays.columns[name]

    def _check_count(self, name: str, column: _Column | None) -> None:
        if name not in self.arrays:
            have = ", ".join(sorted(self.arrays)) or "none"
            raise InputError(f"{self.topic} lacks array {name!r} (have: {have})", self.path)
        count = column.count if column is not None else len(self.arrays[name])
        if count != self.n_frames:
            raise InputError(f"{self.topic} array {name!r} is in {count} of {self.n_frames} frames; "
                             "every frame must carry it", self.path)

    def array(self, name: str) -> list[np.ndarray]:
        """One array's entries, one per frame.

        Raises
        ------
        InputError
            The channel has no array ``name``, or only some of its frames carry it.
        """
        column = self.arrays.columns.get(name) if isinstance(self.arrays, ColumnArrays) else None
        self._check_count(name, column)
        return self.arrays[name]

    def require_every_frame(self, n_runs: int | None = None, n_scans: int | None = None) -> None:
        """Raise :class:`InputError` naming the first (run, scan) without a frame.

        :meth:`grid` fills a missing frame with NaN; a stage that cannot work with gaps calls
        this first so the user learns which frame is missing rather than that NaNs appeared.
        """
        n_runs = self.n_runs if n_runs is None else n_runs
        n_scans = self.n_scans if n_scans is None else n_scans
        seen = np.zeros((n_runs, n_scans), bool)
        inside = (self.run < n_runs) & (self.scan < n_scans)
        seen[self.run[inside], self.scan[inside]] = True
        if not seen.all():
            r, k = (int(v[0]) for v in np.nonzero(~seen))
            raise InputError(f"{self.topic} has no frame for run {r} scan {k} (it must cover all {n_runs} run(s) × "
                             f"{n_scans} scan(s))", self.path)

    def _where(self, i: int) -> str:
        return f"run {int(self.run[i])} scan {int(self.scan[i])}"

    def _guard_size(self, name: str, shape: tuple, dtype, data_bytes: int) -> None:
        """Refuse an output that would be huge and mostly padding (implausible indices or lengths)."""
        size = math.prod(int(s) for s in shape) * np.dtype(dtype).itemsize
        if size > MAX_PADDED_BYTES and size > MAX_SPARSITY * max(data_bytes, 1):
            raise InputError(f"{self.topic} array {name!r}: its [run, scan] array {tuple(int(s) for s in shape)} "
                             f"would need {size / 2**30:.1f} GiB for {data_bytes / 2**20:.1f} MiB of values; "
                             "the frames' run/scan indices or list lengths are implausible", self.path)

    def grid(self, name: str) -> np.ndarray:
        """Stack a fixed-shape array into ``[run, scan, ...]`` (NaN where a frame is missing).

        Raises
        ------
        InputError
            The array is missing or its shape differs between frames.
        """
        column = self._column(name)
        if column is None or column.kind == IRREGULAR:
            return self._grid_items(name, self.array(name))
        if column.count == 0:
            return np.zeros((0, 0))
        if column.kind == RAGGED:
            lengths = column.lengths()
            bad = np.flatnonzero(lengths != lengths[0])
            if bad.size:
                b = int(bad[0])
                first, other = (int(lengths[0]), *column.shape), (int(lengths[b]), *column.shape)
                raise InputError(f"{self.topic} array {name!r} has shape {first} in {self._where(0)} but "
                                 f"{other} in {self._where(b)}; it must keep one shape in every frame", self.path)
            values = column.values.reshape(column.count, int(lengths[0]), *column.shape)
        else:
            values = column.values
        inner = values.shape[1:]
        dtype = np.result_type(column.dtype, np.float64) if column.dtype.kind in "iub" else column.dtype
        shape = (self.n_runs, self.n_scans, *inner)
        if dtype == values.dtype and self._scan_major():
            # every frame present, scan by scan and run by run within a scan (as the writer puts
            # them): the values already are the grid, scan axis first; a read-only view of them
            # spares a copy of the largest arrays (array snapshots)
            view = values.reshape(self.n_scans, self.n_runs, *inner).swapaxes(0, 1)
            view.flags.writeable = False
            return view
        self._guard_size(name, shape, dtype, values.nbytes)
        out = np.full(shape, np.nan, dtype=dtype)
        out[self.run, self.scan] = values
        return out

    def _scan_major(self) -> bool:
        """Whether the frames are every (run, scan) once, in scan-major order."""
        if self._order is None:
            R, K = self.n_runs, self.n_scans
            if self._blocks is not None:
                self._order = self._blocks.scan_major(R, K)
            else:
                self._order = bool(self._run.size == R * K and np.array_equal(self._scan, np.repeat(np.arange(K), R))
                                   and np.array_equal(self._run, np.tile(np.arange(R), K)))
        return self._order

    def _grid_items(self, name: str, items: list) -> np.ndarray:
        if not items:
            return np.zeros((0, 0))
        inner = items[0].shape
        bad = next((i for i, a in enumerate(items) if a.shape != inner), None)
        if bad is not None:
            raise InputError(f"{self.topic} array {name!r} has shape {inner} in {self._where(0)} but "
                             f"{items[bad].shape} in {self._where(bad)}; it must keep one shape in every frame",
                             self.path)
        dtype = np.result_type(items[0].dtype, np.float64) if items[0].dtype.kind in "iub" else items[0].dtype
        shape = (self.n_runs, self.n_scans, *inner)
        self._guard_size(name, shape, dtype, sum(a.nbytes for a in items))
        out = np.full(shape, np.nan, dtype=dtype)
        out[self.run, self.scan] = np.stack(items)
        return out

    def ragged(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Pad a variable-length array into ``[run, scan, max_len, ...]`` with NaN.

        Returns
        -------
        values : ndarray
            Padded values; a read-only view of the decoded values when every frame holds the
            same number of float64 entries and the frames are in the writer's order.
        counts : ndarray of int, shape (run, scan)
            How many entries each frame held (0 where the frame is missing); read-only with
            such a view.

        Raises
        ------
        InputError
            The array is missing, 0-d in some frame (no entry axis), or its entries change
            shape between frames.
        """
        column = self._column(name)
        if column is None or column.kind == IRREGULAR:
            items = self.array(name)
            bad = next((i for i, a in enumerate(items) if a.ndim == 0), None)
            if bad is not None:
                raise InputError(f"{self.topic} array {name!r} is a scalar in {self._where(bad)}; "
                                 "it must hold a list of entries (at least 1-D) in every frame", self.path)
            tail = items[0].shape[1:] if items else ()
            bad = next((i for i, a in enumerate(items) if a.shape[1:] != tail), None)
            if bad is not None:
                raise InputError(f"{self.topic} array {name!r} has entries of shape {tail} in {self._where(0)} but "
                                 f"{items[bad].shape[1:]} in {self._where(bad)}; entries must keep one shape",
                                 self.path)
            lengths = np.array([a.shape[0] for a in items], dtype=np.int64)
            return self._pad(name, lengths, tail, lambda: np.concatenate(items))
        if column.kind == FIXED:
            if not column.shape:
                raise InputError(f"{self.topic} array {name!r} is a scalar in {self._where(0)}; "
                                 "it must hold a list of entries (at least 1-D) in every frame", self.path)
            length, tail = column.shape[0], column.shape[1:]
            if column.dtype == np.float64 and self._scan_major():
                # as in grid(): every frame holds ``length`` entries, in the writer's order, so
                # the padded array is the values themselves (read-only views, no padding to fill:
                # 15 MB and a scatter less for a 10,000-run radar data set's plots)
                R, K = self.n_runs, self.n_scans
                view = column.values.reshape(K, R, length, *tail).swapaxes(0, 1)
                view.flags.writeable = False
                return view, np.broadcast_to(np.int64(length), (R, K))
            lengths = np.full(column.count, length, np.int64)
            return self._pad(name, lengths, tail, lambda: column.values.reshape(column.count * length, *tail))
        return self._pad(name, column.lengths(), column.shape, lambda: column.values)

    def _pad(self, name: str, lengths: np.ndarray, tail: tuple, flat) -> tuple[np.ndarray, np.ndarray]:
        counts = np.zeros((self.n_runs, self.n_scans), dtype=np.int64)
        counts[self.run, self.scan] = lengths
        width = int(lengths.max()) if lengths.size else 0
        shape = (self.n_runs, self.n_scans, width, *tail)
        self._guard_size(name, shape, np.float64, int(lengths.sum()) * math.prod(tail) * 8)
        out = np.full(shape, np.nan)
        if width:
            # one scatter instead of a Python loop over frames
            slot = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
            out[np.repeat(self.run, lengths), np.repeat(self.scan, lengths), slot] = flat()
        return out, counts

    def times(self) -> np.ndarray:
        """Scan times ``[scan]`` (taken from run 0's frames, or the first seen per scan)."""
        t = np.full(self.n_scans, np.nan)
        if self._blocks is not None:  # per message, not per frame: the same first time per scan
            t[self._blocks.scan[::-1]] = self._blocks.time_s[::-1]
        else:
            t[self._scan[::-1]] = self._time_s[::-1]
        return t


@dataclass
class Dataset:
    """An MCAP file's content: channels by topic plus the metadata records."""

    path: str
    channels: dict[str, ChannelData]
    metadata: dict[str, dict[str, str]]
    recovered_messages: int | None = None
    cache: dict = field(default_factory=dict, repr=False)  # stages' decoded views, computed once
    contract: str | None = None  # "replay.v1" or "replay.v2" (None: no frames)

    def channel(self, topic: str) -> ChannelData:
        if topic not in self.channels:
            have = ", ".join(sorted(self.channels)) or "none"
            raise InputError(f"missing channel {topic!r} (channels present: {have})", self.path)
        return self.channels[topic]

    @property
    def scenario(self) -> dict:
        """Scenario record: name, params (dict), seed, package version."""
        rec = self.metadata.get(METADATA_SCENARIO, {})
        out = dict(rec)
        if "params" in out:
            try:
                out["params"] = json.loads(out["params"])
            except (ValueError, RecursionError):  # (RecursionError: nested deeper than json recurses)
                raise InputError(f"{METADATA_SCENARIO} metadata: params is not valid JSON", self.path) from None
            if not isinstance(out["params"], dict):
                raise InputError(f"{METADATA_SCENARIO} metadata: params must be a JSON object", self.path)
        return out
