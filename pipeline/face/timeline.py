"""Rerun output: one recording per replay, logged in columns, saved atomically to ``.rrd``.

Every series goes through :func:`log_series` / :func:`log_points` with ``send_columns`` (two
timelines: ``scan`` and ``sim_time``), which is two orders of magnitude faster than per-step
``rr.log``; nothing here is per-scan Python logging.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import importlib

import numpy as np

from trackreplay.contract import publish


class LazyModule:
    """A module imported on first attribute access.

    Stage modules are imported by every replay and every sweep worker, but only a replay that
    writes a recording needs rerun (~0.6 s to import): deferring it keeps worker start-up, and
    so a sweep's per-point overhead, small.
    """

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attr):
        return getattr(importlib.import_module(self._name), attr)


rr = LazyModule("rerun")
rrb = LazyModule("rerun.blueprint")

PALETTE = {
    "truth": (230, 230, 230),
    "plots": (150, 150, 150),
    "fixed": (31, 119, 180),
    "approximate": (255, 127, 14),
    "exact": (44, 160, 44),
    "kalman": (214, 39, 40),
}
_EXTRA = [(148, 103, 189), (140, 86, 75), (227, 119, 194), (188, 189, 34), (23, 190, 207)]


def color(name: str) -> tuple[int, int, int]:
    """A stable colour per tracker / entity name."""
    if name in PALETTE:
        return PALETTE[name]
    return _EXTRA[sum(map(ord, name)) % len(_EXTRA)]


def _indexes(scans, times):
    return [rr.TimeColumn("scan", sequence=np.asarray(scans, np.int64)),
            rr.TimeColumn("sim_time", duration=np.asarray(times, float))]


def log_series(rec, entity: str, scans, times, values, name: str, rgb=None) -> None:
    """A scalar time series (NaN samples are left out, not drawn as zero)."""
    values = np.asarray(values, float)
    keep = np.isfinite(values)
    if not keep.any():
        return
    rec.log(entity, rr.SeriesLines(names=[name], colors=[rgb or color(name)]), static=True)
    rr.send_columns(entity, indexes=_indexes(np.asarray(scans)[keep], np.asarray(times)[keep]),
                    columns=rr.Scalars.columns(scalars=values[keep]), recording=rec)


def log_metric_series(rec, per_scan, tracker: str, metrics, entity, rgb=None) -> None:
    """Per-scan metric columns of one tracker as series ``entity(metric)/tracker``.

    ``per_scan`` is a stage's per-scan polars table (columns ``tracker``, ``scan``, ``time_s``
    and the metrics); ``entity`` maps a metric name to its entity path prefix. Metrics the
    table lacks are skipped.
    """
    part = per_scan.filter(per_scan["tracker"] == tracker)
    for metric in metrics:
        if metric in part.columns:
            log_series(rec, f"{entity(metric)}/{tracker}", part["scan"].to_numpy(), part["time_s"].to_numpy(),
                       part[metric].to_numpy(), tracker, rgb)


def log_points(rec, entity: str, scans, times, points_per_scan: list[np.ndarray], rgb, radius=None) -> None:
    """A set of 2-D points per scan (any count, including none)."""
    lengths = np.array([len(p) for p in points_per_scan], np.int64)
    if lengths.sum() == 0:
        return
    flat = np.concatenate([np.asarray(p, float).reshape(-1, 2) for p in points_per_scan])
    cols = rr.Points2D.columns(positions=flat, colors=np.tile(np.array(rgb, np.uint8), (len(flat), 1)),
                               radii=np.full(len(flat), radius if radius is not None else -2.0, np.float32))
    rr.send_columns(entity, indexes=_indexes(scans, times), columns=cols.partition(lengths), recording=rec)


def log_path(rec, entity: str, xy: np.ndarray, rgb, width: float = -1.5) -> None:
    """A static polyline (a whole track or truth trajectory), NaN points dropped."""
    xy = np.asarray(xy, float)
    xy = xy[np.all(np.isfinite(xy), axis=-1)]
    if len(xy) > 1:
        rec.log(entity, rr.LineStrips2D([xy], colors=[rgb], radii=[width]), static=True)


def identity_color(identity) -> np.ndarray:
    """A stable colour per track or target identity, ``(..., 3)`` uint8: golden-ratio hues, so
    identities born one after the other differ clearly, and one identity keeps its colour in
    every view and every replay."""
    hue = (np.asarray(identity, np.float64) * 0.618033988749895) % 1.0
    # HSV → RGB at saturation 0.65, value 0.95 (bright on the viewer's dark background)
    h6 = hue * 6.0
    c = 0.95 * 0.65
    x = c * (1.0 - np.abs(h6 % 2.0 - 1.0))
    sector = np.floor(h6).astype(int) % 6
    zero = np.zeros_like(hue)
    table = [(c, x, zero), (x, c, zero), (zero, c, x), (zero, x, c), (x, zero, c), (c, zero, x)]
    rgb = np.zeros(hue.shape + (3,))
    for i, (r, g, b) in enumerate(table):
        pick = sector == i
        rgb[pick] = np.stack([np.broadcast_to(r, hue.shape), np.broadcast_to(g, hue.shape),
                              np.broadcast_to(b, hue.shape)], axis=-1)[pick]
    return np.round(255 * (rgb + (0.95 - c))).astype(np.uint8)


def log_identified(rec, entity: str, scans, times, xy, ids, prefix: str, radius: float = -4.0,
                   paths: bool = True, show_labels: bool = True) -> None:
    """Objects with identities in slots, one run: ``xy`` (K, S, 2) NaN where a slot is empty,
    ``ids`` (K, S) (−1 empty). Per scan, the points coloured and labelled by identity
    (``prefix`` + id; drawn, or shown on hover only without ``show_labels``); with ``paths``,
    each identity's whole trajectory as a static line in its colour."""
    xy, ids = np.asarray(xy, float), np.asarray(ids, np.int64)
    present = (ids >= 0) & np.all(np.isfinite(xy), axis=-1)
    lengths = present.sum(axis=1).astype(np.int64)
    if lengths.sum() == 0:
        return
    k_of, s_of = np.nonzero(present)
    who = ids[k_of, s_of]
    cols = rr.Points2D.columns(positions=xy[k_of, s_of], colors=identity_color(who),
                               radii=np.full(who.size, radius, np.float32),
                               labels=[f"{prefix}{i}" for i in who.tolist()])
    if not show_labels:
        rec.log(entity + "/now", rr.Points2D.from_fields(show_labels=False), static=True)
    rr.send_columns(entity + "/now", indexes=_indexes(scans, times), columns=cols.partition(lengths), recording=rec)
    if not paths:
        return
    order = np.lexsort((k_of, who))
    who, points = who[order], xy[k_of[order], s_of[order]]
    starts = np.flatnonzero(np.r_[True, who[1:] != who[:-1]])
    strips = [p for p in np.split(points, starts[1:]) if len(p) > 1]
    if strips:
        owners = who[starts][[len(p) > 1 for p in np.split(points, starts[1:])]]
        rec.log(entity + "/paths", rr.LineStrips2D(strips, colors=identity_color(owners), radii=[-1.0]), static=True)


def north_up(rec, entity: str) -> None:
    """Make ``entity``'s subtree draw with +y up in a 2-D view whose origin is its parent.

    Rerun's 2-D views draw +y downwards (image convention); a y-flip transform on the world
    entity puts north up while hover still shows the true coordinates.
    """
    rec.log(entity, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)


def north_up_bounds(lo, hi, pad: float):
    """Visual bounds of a :func:`north_up` world box ``lo``..``hi`` (x, y) in view coordinates."""
    return rrb.VisualBounds2D(x_range=[lo[0] - pad, hi[0] + pad], y_range=[-hi[1] - pad, -lo[1] + pad])


@contextmanager
def recording(path: str | Path, app_id: str, recording_id: str, blueprint=None):
    """A recording stream saved to ``path`` atomically when the block ends without error."""
    from trackreplay.paths import bounded_call, disk_error

    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
        os.close(fd)
        rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False)
        # Rerun's file sink writes in a thread of its own and, on a full disk, can stall in
        # save() or flush() instead of failing: both are bounded, and the failure names the file
        bounded_call(lambda: rec.save(tmp, default_blueprint=blueprint), WRITER_TIMEOUT_S, path, "Rerun's save")
        yield rec
        bounded_call(lambda: rec.flush(timeout_sec=WRITER_TIMEOUT_S), WRITER_TIMEOUT_S, path, "Rerun's flush")
        bounded_call(rec.disconnect, WRITER_TIMEOUT_S, path, "Rerun's disconnect")
        publish(tmp, path)
    except BaseException as exc:
        if isinstance(exc, OSError) and "did not return within" in str(exc):
            rr.unregister_shutdown()  # its flush at exit would wait on the stalled sink forever
        named = disk_error(exc, path)
        if named is not None:
            raise named from None
        raise
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)


#: The longest a Rerun file-sink call may take before the recording counts as failed (a
#: recording of a large replay flushes in seconds; a stalled one never returns).
WRITER_TIMEOUT_S = float(os.environ.get("TRACKREPLAY_RERUN_WRITER_TIMEOUT_S", "60"))
