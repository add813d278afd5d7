"""One point of a sweep: simulate, replay and evaluate (:func:`run_point`, a pure function of its
:class:`~trackreplay.sweep.grid.PointTask` that never raises), and its rows of the sweep's table."""

from __future__ import annotations

import shutil
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import polars as pl

from trackreplay.errors import InputError
# errors of writing a point's files that no other point would escape (a full or read-only disk, a
# file size limit): the sweep stops at the first, with one line naming the file
from trackreplay.paths import DISK_ERRNOS, disk_error
from trackreplay.sweep.evaluation import evaluation_used
from trackreplay.sweep.folder import _point_files, discard_point_files

if TYPE_CHECKING:
    from trackreplay.sweep.grid import PointTask


@dataclass
class PointResult:
    index: int
    label: str
    records: list = field(default_factory=list)
    error: str | None = None
    work_s: float = 0.0
    # (where, message) of every tracker that failed on this point; the others' records are kept
    tracker_errors: list = field(default_factory=list)
    # stage name → {evaluation design value: value} the point was scored with
    evaluation: dict = field(default_factory=dict)
    # (errno, problem, file) when the point failed because its files could not be written (a full
    # or read-only disk, a file size limit): every point would, so the sweep stops (DISK_ERRNOS)
    disk_error: tuple | None = None


# every metric of a point with its Monte Carlo standard error and 95 % interval (docs/evaluation.md)
RECORD_COLUMNS = ("tracker", "metric", "value", "se", "ci_low", "ci_high")
RECORD_SCHEMA = {"tracker": pl.Utf8, "metric": pl.Utf8, "value": pl.Float64, "se": pl.Float64,
                 "ci_low": pl.Float64, "ci_high": pl.Float64}


def run_point(task: PointTask) -> PointResult:
    """Simulate, replay and evaluate one grid point; errors come back in the result."""
    from trackreplay.trackers.interface import TrackerError

    t0 = time.perf_counter()
    try:
        records, failures, evaluation = _run_point(task)
        return PointResult(task.index, task.label, records, None, time.perf_counter() - t0,
                           [(f.path or "", str(f)) for f in failures], evaluation)
    except TrackerError as exc:  # no tracker of the point ran (e.g. the plugged one alone failed)
        return PointResult(task.index, task.label, [], None, time.perf_counter() - t0, [(exc.path or "", str(exc))])
    except OSError as exc:
        msg = f"{exc.filename}: {exc.strerror or exc}" if exc.filename else str(exc)
        disk = (exc.errno, exc.strerror or str(exc), str(exc.filename or "")) if exc.errno in DISK_ERRNOS else None
        return PointResult(task.index, task.label, [], msg, time.perf_counter() - t0, disk_error=disk)
    except Exception as exc:  # isolate the point: the sweep reports it and goes on
        msg = str(exc) if isinstance(exc, InputError) else "".join(
            traceback.format_exception_only(type(exc), exc)).strip()
        return PointResult(task.index, task.label, [], msg, time.perf_counter() - t0)


def _run_point(task: PointTask) -> tuple[list[dict], list, dict]:
    from trackreplay.replay import replay
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    sc = load_scenario(task.scenario).with_overrides(dict(task.overrides))
    keep = task.point_dir is not None
    work = Path(task.point_dir) if keep else Path(tempfile.mkdtemp(prefix="sweep-point-"))
    before = _point_files(work) if keep else None
    writing = [work]  # the file being written, named in an error that names none

    def recording(*args):  # the Rerun recording is written last, after tracks.mcap
        from trackreplay.face.rerun_views import write_recording

        writing[0] = work / "tracks.rrd"
        return write_recording(*args)

    done = False
    try:
        work.mkdir(parents=True, exist_ok=True)
        data = writing[0] = work / "data.mcap"
        record(data, sc, task.runs, task.seed)
        writing[0] = work / "tracks.mcap"
        res = replay(data, list(task.trackers) if task.trackers else None,
                     out_path=work / "tracks.mcap" if keep else None,
                     rrd_path=work / "tracks.rrd" if keep else None,
                     design_overrides=dict(task.design) or None, tracker_specs=task.tracker_specs,
                     recorder=recording, tracker_time_limit_s=task.tracker_time_limit_s)
        done = True
    except (OSError, RuntimeError) as exc:  # a writer's failure that names no file (Rerun's: RuntimeError)
        named = disk_error(exc, writing[0])
        if named is not None:
            raise named from None
        raise
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
        elif not done:  # a point is complete or leaves nothing: what this point wrote goes
            discard_point_files(work, before)
    overall = res.summary.filter(pl.col("scope") == "overall")
    records = [{k: r.get(k) for k in RECORD_COLUMNS} for r in overall.iter_rows(named=True)]
    return records, res.failures, evaluation_used(res)


def _point_frame(task: PointTask, records: list[dict], swept: list[str]) -> pl.DataFrame:
    values = {**dict(task.overrides), **dict(task.design)}  # the swept values come last, so they win
    df = pl.DataFrame(records, schema=RECORD_SCHEMA)
    return df.with_columns(
        pl.lit(task.label).alias("point"), pl.lit(task.index).alias("point_index"),
        pl.lit(task.seed, dtype=pl.UInt64).alias("seed"),
        *[pl.lit(values[n]).alias(n) for n in swept],
    ).select("point_index", "point", *swept, "seed", *RECORD_COLUMNS)
