"""One message and its arrays, both ways: ``replay.v1.Frame`` (:func:`encode_frame`,
:func:`decode_frame`) and ``replay.v2.Scan`` (:func:`encode_scan`, :func:`decode_scan`), with the
``SYMMETRIC`` packing of real symmetric matrices (:func:`upper_triangles`).

Encoding keeps each array's exact bytes, shape and dtype (little-endian, a dtype of the
contract); decoding checks every count against the bytes a message holds before sizing anything
by it, and makes no per-frame objects (docs/contract.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from trackreplay.contract.layout import (_ALLOWED_DTYPES, FIXED, IRREGULAR, MAX_FRAMES_PER_MESSAGE, RAGGED,
                                         SYMMETRIC, Frame, Scan, _BadData)
from trackreplay.contract.dataset import _Column


def _normalise(name: str, value) -> np.ndarray:
    """C-contiguous little-endian array of a contract dtype (0-d stays 0-d)."""
    a = np.asarray(value)
    if not a.flags.c_contiguous:  # (np.ascontiguousarray would turn 0-d into 1-d)
        a = a.copy(order="C")
    return _little_endian_contract_dtype(name, a)


def _little_endian_contract_dtype(name: str, a: np.ndarray) -> np.ndarray:
    """``a`` little-endian (a copy only if it was not), refused unless its dtype is in the contract."""
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    if a.dtype.str not in _ALLOWED_DTYPES:
        raise ValueError(f"dtype {a.dtype.str} of array {name!r} is not in the contract")
    return a


def encode_frame(run: int, scan: int, time_s: float, arrays: Mapping[str, np.ndarray],
                 run_count: int = 1) -> bytes:
    """Serialise one ``replay.v1.Frame``; arrays keep their exact bytes, shape and dtype.

    With ``run_count`` > 1 the frame is batched: every array's first axis is the run axis.
    """
    msg = Frame(run=int(run), scan=int(scan), time_s=float(time_s),
                run_count=int(run_count) if run_count > 1 else 0)
    for name, value in arrays.items():
        a = _normalise(name, value)
        msg.arrays.add(name=name, shape=a.shape, dtype=a.dtype.str, data=a.tobytes())
    return msg.SerializeToString()


def decode_frame(data: bytes) -> tuple[int, int, float, dict[str, np.ndarray], int]:
    """Inverse of :func:`encode_frame`; returns ``(run, scan, time_s, arrays, run_count)``."""
    msg = Frame()
    msg.ParseFromString(data)
    arrays = {}
    for a in msg.arrays:
        arrays[a.name] = _decode_array(a)
    return msg.run, msg.scan, msg.time_s, arrays, max(msg.run_count, 1)


_DTYPES = {s: np.dtype(s) for s in _ALLOWED_DTYPES}


def _decode_array(a) -> np.ndarray:
    """One ``Array`` message as a read-only view of its bytes (ValueError if it is malformed)."""
    dtype = _DTYPES.get(a.dtype)
    if dtype is None:
        raise ValueError(f"array {a.name!r} has dtype {a.dtype!r}, not in the contract")
    # frombuffer refuses a byte count that is not a multiple of the item size and reshape one
    # that does not match the shape: a malformed array is a ValueError, never a wrong array
    return np.frombuffer(a.data, dtype=dtype).reshape(tuple(a.shape))


@dataclass
class _Part:
    """Frames of one channel and scan handed to the writer in one call.

    ``kind`` "frame": one run, arrays as they are; "batch": runs ``first_run …`` with a leading
    run axis; "ragged": runs ``first_run …``, arrays flattened over the entries of every run
    (``lengths`` per run).
    """

    kind: str
    first_run: int
    n: int
    time_s: float
    arrays: dict
    lengths: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays.values())

    def entry_layout(self, a: np.ndarray):
        """(lengths along the entries' first axis or None for 0-d, tail shape, set of full shapes)."""
        if self.kind == "frame":
            return (None if a.ndim == 0 else np.array([a.shape[0]])), a.shape[1:], {a.shape}
        if self.kind == "batch":
            inner = a.shape[1:]
            return (None if not inner else np.full(self.n, inner[0])), inner[1:], {inner}
        tail = a.shape[1:]
        lengths = self.lengths
        shapes = {(int(v), *tail) for v in np.unique(lengths)}
        return lengths, tail, shapes

    def entries(self, a: np.ndarray) -> list:
        if self.kind == "frame":
            return [a]
        if self.kind == "batch":
            return [a[i] for i in range(self.n)]
        return np.split(a, np.cumsum(self.lengths)[:-1])


def _encode_column(col, name: str, pieces: list[tuple[_Part, np.ndarray]], frames: np.ndarray | None) -> None:
    """Fill the ``Column`` message ``col`` with one array's entries (layout chosen from their shapes)."""
    col.name = name
    col.dtype = pieces[0][1].dtype.str
    if frames is not None:
        col.frames = frames.astype("<u4").tobytes()
    layouts = [p.entry_layout(a) for p, a in pieces]
    shapes = set().union(*(s for _, _, s in layouts))
    same_dtype = len({a.dtype.str for _, a in pieces}) == 1
    if same_dtype and len(shapes) == 1:
        col.layout = FIXED
        col.shape.extend(shapes.pop())
        col.values = b"".join(a.tobytes() for _, a in pieces)
    elif same_dtype and all(lengths is not None for lengths, _, _ in layouts) and len({t for _, t, _ in layouts}) == 1:
        col.layout = RAGGED
        col.shape.extend(layouts[0][1])
        offsets = np.zeros(1 + sum(len(lengths) for lengths, _, _ in layouts), "<i8")
        np.cumsum(np.concatenate([lengths for lengths, _, _ in layouts]), out=offsets[1:])
        col.offsets = offsets.tobytes()
        col.values = b"".join(a.tobytes() for _, a in pieces)
    else:
        col.layout = IRREGULAR
        for p, a in pieces:
            for e in p.entries(a):
                col.entries.add(shape=e.shape, dtype=e.dtype.str, data=e.tobytes())


def encode_scan(scan: int, parts: list[_Part], scan_times: np.ndarray | None = None) -> bytes:
    """Serialise the frames of one channel and scan as one ``replay.v2.Scan`` message.

    With ``scan_times`` (G > 1 times) the one part holds G scans from ``scan`` on, the same runs
    in each, frames scan-major: a message of a long recording (:func:`scans_per_message`)."""
    counts = [p.n for p in parts]
    total = sum(counts)
    msg = Scan(scan=int(scan), time_s=float(parts[0].time_s), frame_count=total)
    if scan_times is not None:
        (part,) = parts
        msg.first_run = part.first_run
        msg.scan_count = len(scan_times)
        msg.times_s = np.repeat(np.asarray(scan_times, "<f8"), total // len(scan_times)).tobytes()
        counts = [total]
    else:
        runs = np.concatenate([np.arange(p.first_run, p.first_run + p.n, dtype=np.int64) for p in parts])
        if np.array_equal(runs, np.arange(runs[0], runs[0] + total)):
            msg.first_run = int(runs[0])
        else:
            msg.runs = runs.astype("<u4").tobytes()
        times = [float(p.time_s) for p in parts]
        if any(t != times[0] or math.copysign(1, t) != math.copysign(1, times[0]) for t in times):
            msg.times_s = np.repeat(np.array(times, "<f8"), counts).tobytes()
    starts = np.cumsum([0, *counts])
    names = list(dict.fromkeys(n for p in parts for n in p.arrays))
    for name in names:
        carriers = [i for i, p in enumerate(parts) if name in p.arrays]
        frames = None
        if len(carriers) < len(parts):
            frames = np.concatenate([np.arange(starts[i], starts[i + 1]) for i in carriers])
        _encode_column(msg.columns.add(), name, [(parts[i], parts[i].arrays[name]) for i in carriers], frames)
    return msg.SerializeToString()


def _triangle_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices into an ``n × n`` matrix of its upper triangle row by row, and of the
    mirrored entries (the lower triangle in the same order)."""
    rows, cols = np.triu_indices(n)
    return rows * n + cols, cols * n + rows


def _square_real(dtype: np.dtype, inner: tuple) -> bool:
    """Whether entries of this dtype and shape can be stored as ``SYMMETRIC`` (real square matrices)."""
    return dtype.kind == "f" and len(inner) >= 2 and inner[-1] == inner[-2] >= 2


def upper_triangles(a: np.ndarray) -> np.ndarray | None:
    """``a``'s matrices (its last two axes) as their upper triangles, ``(..., n(n+1)/2)``, when
    every one of them is symmetric to the bit (NaN and −0 included); else None.

    Lossless by construction: the lower triangle read back is the upper one, which equals it
    bit for bit. A grid that is not exactly symmetric (a plugged tracker's rounding) is stored
    whole. What the writer's ``SYMMETRIC`` layout holds (``benchmarks/bench_output_size.py``
    measures it through this function too).
    """
    n = a.shape[-1]
    # the matrices gathered once into C order (a scan of a (runs, scans, n, n) grid is strided):
    # the comparisons and the take below then read memory in order, where on the strided grid
    # each of them read a cache line per matrix (1.7× slower on the outputs of 10,000 radar runs)
    flat = np.ascontiguousarray(a).reshape(a.shape[:-2] + (n * n,))
    upper, lower = _triangle_indices(n)
    # the same bits, mirrored pair by pair (an integer view of the same width compares NaN and
    # −0 by their bits)
    bits = flat.view(f"<u{a.dtype.itemsize}")
    for u, l in zip(upper.tolist(), lower.tolist()):
        if u != l and not np.array_equal(bits[..., u], bits[..., l]):
            return None
    return flat.take(upper, axis=-1)


def _u4(data: bytes, n: int, what: str) -> np.ndarray:
    if len(data) != 4 * n:
        raise _BadData(f"{what} holds {len(data)} bytes for {n} frame(s)")
    return np.frombuffer(data, "<u4")


def _decode_column(c, n: int) -> tuple[str, _Column]:
    if c.dtype not in _ALLOWED_DTYPES:
        raise _BadData(f"column {c.name!r} has dtype {c.dtype!r}, not in the contract")
    dtype = np.dtype(c.dtype)
    m = n
    frames = c.frames
    if frames:
        idx = _u4(frames, len(frames) // 4, f"column {c.name!r} frames") if len(frames) % 4 == 0 else None
        if idx is None or (idx.size and (idx[-1] >= n or (idx.size > 1 and np.any(np.diff(idx.astype(np.int64)) <= 0)))):
            raise _BadData(f"column {c.name!r} lists frames outside 0 … {n - 1} or out of order")
        m = idx.size
    shape = tuple(int(s) for s in c.shape)
    which = idx if frames else None
    if c.layout == IRREGULAR:
        if len(c.entries) != m:
            raise _BadData(f"column {c.name!r} holds {len(c.entries)} entries for {m} frame(s)")
        return c.name, _Column(IRREGULAR, dtype, m, items=[_decode_array(e) for e in c.entries], frames=which)
    values = c.values
    if c.layout == SYMMETRIC:
        return c.name, _symmetric_column(c.name, dtype, m, shape, values, which)
    row = math.prod(shape) * dtype.itemsize
    if c.layout == FIXED:
        if m * row != len(values):
            raise _BadData(f"column {c.name!r} claims {m} entries of shape {shape} ({dtype}) but holds "
                           f"{len(values)} bytes")
        return c.name, _Column(FIXED, dtype, m, shape, np.frombuffer(values, dtype).reshape(m, *shape), frames=which)
    if c.layout != RAGGED:
        raise _BadData(f"column {c.name!r} has unknown layout {c.layout}")
    if len(c.offsets) != 8 * (m + 1):
        raise _BadData(f"column {c.name!r} holds {len(c.offsets)} bytes of offsets for {m} entries")
    offsets = np.frombuffer(c.offsets, "<i8")
    if offsets[0] != 0 or np.any(np.diff(offsets) < 0) or int(offsets[-1]) * row != len(values):
        raise _BadData(f"column {c.name!r} has offsets that do not match its {len(values)} bytes of values")
    rows = int(offsets[-1])
    return c.name, _Column(RAGGED, dtype, m, shape, np.frombuffer(values, dtype).reshape(rows, *shape),
                           offsets.astype(np.int64), frames=which)


def _symmetric_column(name: str, dtype: np.dtype, m: int, shape: tuple, values: bytes, frames) -> _Column:
    """A ``SYMMETRIC`` column (entries of ``shape`` stored as their upper triangles) made whole:
    the ``FIXED`` column the writer was given."""
    if len(shape) < 2 or shape[-1] != shape[-2] or not shape[-1] or dtype.kind != "f":
        raise _BadData(f"column {name!r} is stored as symmetric matrices but has entries of shape {shape} ({dtype})")
    n = shape[-1]
    upper, lower = _triangle_indices(n)
    lead = (m, *shape[:-2])
    if math.prod(lead) * upper.size * dtype.itemsize != len(values):
        raise _BadData(f"column {name!r} claims {m} entries of symmetric {shape} ({dtype}) but holds "
                       f"{len(values)} bytes")
    packed = np.frombuffer(values, dtype).reshape(*lead, upper.size)
    full = np.empty((*lead, n * n), dtype)
    full[..., lower] = packed
    full[..., upper] = packed
    return _Column(FIXED, dtype, m, shape, full.reshape(m, *shape), frames=frames)


@dataclass
class _Block:
    """One decoded v2 message: frames of one scan."""

    scan: int
    runs: np.ndarray
    time_s: float
    times: np.ndarray | None
    columns: dict[str, _Column]
    first_run: int | None = None  # the runs are first_run … (None: the message lists them)
    scan_count: int = 1  # scans scan … scan + scan_count − 1, runs first_run … in each (scan-major)

    def scans(self) -> np.ndarray:
        """The scan of each frame."""
        if self.scan_count == 1:
            return np.full(self.n, self.scan, np.int64)
        return np.repeat(np.arange(self.scan, self.scan + self.scan_count, dtype=np.int64), self.n // self.scan_count)

    @property
    def n(self) -> int:
        return self.runs.size


def decode_scan(data: bytes) -> _Block:
    """Decode one ``replay.v2.Scan`` message (checking every count against the bytes it holds)."""
    msg = Scan()
    msg.ParseFromString(data)
    n = msg.frame_count
    if not 0 < n <= MAX_FRAMES_PER_MESSAGE:
        raise _BadData(f"message claims {n} frames (1 … {MAX_FRAMES_PER_MESSAGE} allowed)")
    first_run = None
    if msg.runs:
        runs = _u4(msg.runs, n, "runs").astype(np.int64)
    else:
        first_run = msg.first_run
        runs = np.arange(first_run, first_run + n, dtype=np.int64)
    times = np.frombuffer(msg.times_s, "<f8") if msg.times_s else None
    if times is not None and times.size != n:
        raise _BadData(f"times_s holds {len(msg.times_s)} bytes for {n} frame(s)")
    scan_count = max(1, msg.scan_count)
    if scan_count > 1:  # a group of scans (a long recording): runs first_run … in each
        if msg.runs or times is None or n % scan_count:
            raise _BadData(f"a message of {scan_count} scans must hold the same runs in each ({n} frame(s)), "
                           "from first_run, with times_s")
        runs = np.tile(np.arange(first_run, first_run + n // scan_count, dtype=np.int64), scan_count)
    columns = {}
    for c in msg.columns:
        name, col = _decode_column(c, n)
        if name in columns:
            raise _BadData(f"column {name!r} appears twice")
        columns[name] = col
    return _Block(msg.scan, runs, msg.time_s, times, columns, first_run, scan_count)
