"""Resuming a sweep: a point's metrics are reused only when its record (``point.json``) is the
task's; what changed is said in one line; a folder that holds another sweep is refused."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import polars as pl

from trackreplay.errors import InputError
from trackreplay.sweep.folder import _metrics_file, _record_file
from trackreplay.sweep.point import RECORD_COLUMNS, RECORD_SCHEMA, _point_frame

if TYPE_CHECKING:
    from trackreplay.sweep.grid import PointTask


def _short(value, limit: int = 60) -> str:
    """A value for a one-line message: ``-`` for none, lists comma-separated, long text cut."""
    if value is None:
        text = "-"
    elif isinstance(value, list) and all(isinstance(v, (str, int, float)) for v in value):
        text = ",".join(map(str, value)) or "-"
    elif isinstance(value, str):
        text = value
    else:
        text = json.dumps(value, default=str)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def record_changes(old: dict, new: dict) -> list[str]:
    """What differs between two point records, as short phrases ("runs 100 → 5")."""
    out = []
    for key in dict.fromkeys([*new, *old]):
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if key == "seed" and old.get("base_seed") != new.get("base_seed"):
            continue  # follows from the base seed
        if key == "overrides" and old.get("params") != new.get("params"):
            continue  # the parameters say it better
        if key == "params" and isinstance(a, dict) and isinstance(b, dict):
            out += [f"{k} {_short(a.get(k))} → {_short(b.get(k))}"
                    for k in dict.fromkeys([*b, *a]) if a.get(k) != b.get(k)]
        elif key == "tracker_files" and isinstance(a, dict) and isinstance(b, dict) and set(a) == set(b):
            out += [f"tracker file {k.rpartition(':')[0]} edited" for k in b if a[k] != b[k]]
        else:
            label = {"version": "package version", "base_seed": "seed"}.get(key, key)
            out.append(f"{label} {_short(a)} → {_short(b)}")
    return out


def _reuse(task: PointTask, out_dir: Path, swept: list[str]) -> tuple[pl.DataFrame | None, str | None, dict]:
    """The point's table from a previous sweep, or ``None`` and why it is computed again
    (``None`` as the reason: it never finished); and the evaluation values it was scored with."""
    metrics = _metrics_file(out_dir, task.label)
    if not metrics.exists():
        return None, None, {}
    rec = _record_file(out_dir, task.label)
    if not rec.exists():
        return None, "no point.json records what it computed", {}
    try:
        old = json.loads(rec.read_text())
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return None, f"point.json unreadable ({type(exc).__name__})", {}
    # what the point was scored with: a result, not part of what it computes (its record)
    evaluation = old.pop("evaluation", None)
    evaluation = evaluation if isinstance(evaluation, dict) else {}
    new = task.record()
    if old != new:
        return None, "; ".join(record_changes(old, new)) or "point.json differs", {}
    try:
        stored = pl.read_parquet(metrics)
        stored = stored.with_columns(*(pl.lit(None, pl.Float64).alias(c) for c in RECORD_COLUMNS
                                       if c not in stored.columns))
        records = stored.select(RECORD_COLUMNS).cast(RECORD_SCHEMA).to_dicts()
    except Exception as exc:  # any damage: compute the point again rather than trust it
        return None, f"metrics.parquet unreadable ({type(exc).__name__})", {}
    # the stored values under this grid's index, label and columns, as a fresh run builds them
    return _point_frame(task, records, swept), None, evaluation


def _resume_notes(reasons: dict[str, str]) -> list[str]:
    """One line per distinct reason why points of a resumed sweep were computed again."""
    by_reason: dict[str, list[str]] = {}
    for label, why in reasons.items():
        by_reason.setdefault(why, []).append(label)
    lines = []
    for why, labels in by_reason.items():
        which = f"point {labels[0]}" if len(labels) == 1 else f"{len(labels)} points"
        lines.append(f"resume: computing {which} again: {why}")
    return lines


def _spec_key(spec: dict) -> dict:
    """The parts of a sweep spec (``sweep.json``) that define its table."""
    keys = ("scenario", "params", "fixed", "runs", "seed", "trackers", "tracker_specs")
    return json.loads(json.dumps({k: spec.get(k) for k in keys}, default=str))


def check_resume(out_dir: Path, spec: dict) -> None:
    """Refuse to resume into a folder whose ``sweep.json`` describes another sweep.

    Raises
    ------
    InputError
        One line naming what changed (grid, fixed values, runs, seed, trackers).
    """
    path = Path(out_dir) / "sweep.json"
    if not path.exists():
        return  # a first sweep that was interrupted: every point's record decides
    try:
        old = json.loads(path.read_text())
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"--resume: cannot read sweep.json ({type(exc).__name__}); "
                         "drop --resume to compute the sweep again", out_dir) from None
    a, b = _spec_key(old), _spec_key(spec)
    changes = []
    for key in b:
        if a[key] == b[key]:
            continue
        if key in ("params", "fixed") and isinstance(a[key], dict) and isinstance(b[key], dict):
            for name in dict.fromkeys([*b[key], *a[key]]):
                va, vb = a[key].get(name), b[key].get(name)
                if va != vb:
                    changes.append(f"{'--param' if key == 'params' else '--set'} {name} {_short(va)} → {_short(vb)}")
        else:
            changes.append(f"{key} {_short(a[key])} → {_short(b[key])}")
    if changes:
        raise InputError(f"--resume: this folder holds another sweep ({'; '.join(changes)}); "
                         "drop --resume to compute it again, or choose another -o", out_dir)
