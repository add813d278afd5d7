"""``replay export --foxglove``: a replay's outputs as an MCAP file that Foxglove and PlotJuggler
plot without our code.

The replay's own ``tracks.mcap`` keeps every run of a scan in one protobuf message of columns
(:mod:`trackreplay.contract`): compact and exact, but a plotting tool sees one opaque message per
scan. The export writes, for the chosen Monte Carlo runs, one small JSON message per scan and
topic, with named numeric fields:

``/run_000/<tracker>``   the tracker's estimate in run 0: ``t``, ``scan``, the state components
                         by name (``x, y, vx, vy`` for the radar and the emitter; ``bearing_0,
                         bearing_rate_0, …`` per track slot for the bearing trackers; ``x, vx,
                         ax[, y, vy, ay]`` for the coloured-noise trackers), ``sd_<component>``
                         (square root of the covariance's diagonal), ``flags`` and the tracker's
                         other per-scan numbers (e.g. ``lambda_cross``, ``nis``,
                         ``model_probability_0``);
``/run_000/truth``       the data set's truth in run 0 (when the data set holds it);
``/metrics/<tracker>``   the per-scan metrics over all runs (``rmse_position_m``, ``npe``, …).

Messages are ``message_encoding = "json"`` with a JSON Schema (``schema encoding =
"jsonschema"``) per topic, as Foxglove documents for JSON data; PlotJuggler's MCAP loader picks
its JSON parser by the same message encoding. Non-finite numbers are ``null`` (JSON has no NaN).

Time: ``log_time`` = ``publish_time`` = the scan time in nanoseconds (PlotJuggler takes
publish time unless told otherwise, Foxglove orders and plots by log time). All runs share the
same time axis: each run has its own topics, so nothing overlaps and no per-run offset is
needed; runs are compared by plotting ``/run_000/kalman.x`` and ``/run_001/kalman.x`` together.
Only two cases shift the time: scan times that go below zero are moved so the first is 0
(``log_time`` is unsigned), and scans that do not advance in time (e.g. one data set of
several noise levels at the same instant) are spaced one second apart by scan index. The field
``t`` always holds the recorded scan time. See ``docs/export.md``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trackreplay.errors import InputError
from trackreplay.vocabulary import FAMILIES

DEFAULT_RUNS = 10
SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"
JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


@dataclass
class ExportReport:
    """What an export wrote."""

    path: Path
    runs: list[int]
    n_runs: int
    trackers: list[str]
    topics: list[str] = field(default_factory=list)
    messages: int = 0
    time_base: str = "scan time"
    metrics: bool = False
    truth: bool = False
    notes: list[str] = field(default_factory=list)
    example: str = ""  # a message path to plot, e.g. /run_000/kalman.x


# --------------------------------------------------------------------------- names


def state_names(family: str | None, n: int) -> list[tuple[str, str]]:
    """``(name, unit)`` of the ``n`` state components of a family's tracks (one track slot), as
    its declaration names them (:attr:`trackreplay.vocabulary.Family.state_components`)."""
    components = FAMILIES[family].state_components if family in FAMILIES else ()
    k = len(components)
    if k and all("{axis}" in name for name, _ in components) and n % k == 0 and n // k <= 3:
        return [(name.format(axis=a), unit) for a in "xyz"[: n // k] for name, unit in components]
    if k and n == k:
        return list(components)
    return [(f"s{i}", "") for i in range(n)]


def parse_runs(spec: str | None, n_runs: int) -> list[int]:
    """``"0,1,2"`` or ``"0-4,9"`` → run indices (default: the first DEFAULT_RUNS).

    Raises
    ------
    InputError
        Not a list of runs, or a run the file does not hold.
    """
    if spec is None or not spec.strip():
        return list(range(min(DEFAULT_RUNS, n_runs)))
    runs: list[int] = []
    for part in spec.split(","):
        part = part.strip()
        try:
            if "-" in part:
                a, b = (int(x) for x in part.split("-", 1))
                if b < a:
                    raise ValueError(part)
                runs += range(a, b + 1)
            elif part:
                runs.append(int(part))
        except ValueError:
            raise InputError(f"--runs {spec!r}: expected run indices like 0,1,2 or 0-4") from None
    bad = [r for r in runs if not 0 <= r < n_runs]
    if bad:
        raise InputError(f"--runs: run {bad[0]} is not in the file (it holds runs 0–{n_runs - 1})")
    if not runs:
        raise InputError(f"--runs {spec!r} names no run")
    return list(dict.fromkeys(runs))


# --------------------------------------------------------------------------- fields


@dataclass
class _Field:
    name: str
    values: np.ndarray  # (R, K) or (K,)
    unit: str = ""
    integer: bool = False
    description: str = ""


def _finite_list(a: np.ndarray) -> list:
    if a.dtype.kind == "f":
        return [None if not math.isfinite(v) else v for v in a.tolist()]
    return a.tolist()


def _unique(fields: list[_Field]) -> list[_Field]:
    seen, out = set(), []
    for f in fields:
        if f.name in ("t", "scan") or f.name in seen:
            continue
        seen.add(f.name)
        out.append(f)
    return out


def track_fields(family: str | None, out: dict, n_runs: int, n_scans: int) -> list[_Field]:
    """The named per-run fields of one tracker's outputs (``(R, K, ...)`` arrays)."""
    fields: list[_Field] = []
    state = np.asarray(out["state"], dtype=float)
    slots = state.ndim == 4  # (R, K, T, n)
    n = state.shape[-1]
    names = state_names(family, n)
    n_slots = state.shape[2] if slots else 1
    suffix = (lambda j: f"_{j}") if slots else (lambda j: "")
    cov = out.get("covariance")
    cov = np.asarray(cov, dtype=float) if cov is not None and np.shape(cov)[-2:] == (n, n) else None
    for j in range(n_slots):
        for i, (name, unit) in enumerate(names):
            fields.append(_Field(name + suffix(j), state[:, :, j, i] if slots else state[:, :, i], unit,
                                 description=f"estimated {name}" + (f" of track slot {j}" if slots else "")))
        if cov is not None:
            diag = cov[:, :, j] if slots else cov
            for i, (name, unit) in enumerate(names):
                with np.errstate(invalid="ignore"):
                    sd = np.sqrt(diag[..., i, i])
                fields.append(_Field(f"sd_{name}{suffix(j)}", sd, unit,
                                     description=f"standard deviation of {name} (√ covariance diagonal)"))
    flags = out.get("flags")
    if flags is not None:
        flags = np.asarray(flags)
        if flags.shape == (n_runs, n_scans):
            fields.append(_Field("flags", flags.astype(np.int64), integer=True, description="flag bits (docs/contract.md)"))
        elif slots and flags.shape == (n_runs, n_scans, n_slots):
            fields += [_Field(f"flags_{j}", flags[:, :, j].astype(np.int64), integer=True,
                              description=f"flag bits of track slot {j}") for j in range(n_slots)]
    mu = out.get("model_probabilities")
    if mu is not None and np.ndim(mu) == 3 and np.shape(mu)[:2] == (n_runs, n_scans):
        mu = np.asarray(mu, dtype=float)
        fields += [_Field(f"model_probability_{m}", mu[:, :, m], description=f"IMM probability of model {m}")
                   for m in range(mu.shape[2])]
    for key, value in out.items():
        if key in ("state", "covariance", "flags", "model_probabilities"):
            continue
        a = np.asarray(value)
        if a.dtype.kind not in "fiub":
            continue
        if a.shape == (n_runs, n_scans):
            fields.append(_Field(key, a.astype(float) if a.dtype.kind == "f" else a.astype(np.int64),
                                 integer=a.dtype.kind != "f"))
        elif a.shape == (n_runs, n_scans, 1) and not slots:
            fields.append(_Field(key, a[..., 0].astype(float)))
        elif slots and a.shape == (n_runs, n_scans, n_slots):
            fields += [_Field(f"{key}_{j}", a[:, :, j].astype(float)) for j in range(n_slots)]
    return _unique(fields)


def truth_fields(family: str | None, channel, n_runs: int, n_scans: int) -> list[_Field]:
    """The named per-run fields of a truth channel (arrays ``(R, K)`` or ``(R, K, n ≤ 16)``)."""
    fields: list[_Field] = []
    for key in channel.arrays:
        try:
            a = np.asarray(channel.grid(key))
        except InputError:
            continue
        if a.dtype.kind not in "fiub" or a.shape[:2] != (n_runs, n_scans):
            continue
        a = a.astype(float)
        if a.ndim == 2:
            fields.append(_Field(key, a))
        elif a.ndim == 3 and a.shape[2] <= 16:
            names = state_names(family, a.shape[2]) if key == "state" else [(f"{key}_{i}", "") for i in range(a.shape[2])]
            fields += [_Field(name, a[:, :, i], unit, description=f"true {name}") for i, (name, unit) in enumerate(names)]
    return _unique(fields)


def json_schema(title: str, fields: list[_Field], per_run: bool) -> dict:
    """The JSON Schema of one topic's messages."""
    props = {"t": {"type": "number", "description": "scan time (s)"},
             "scan": {"type": "integer", "description": "scan index"}}
    if per_run:
        props["run"] = {"type": "integer", "description": "Monte Carlo run"}
    for f in fields:
        spec = {"type": ["integer", "null"] if f.integer else ["number", "null"]}
        text = f.description or f.name
        if f.unit:
            text += f" ({f.unit})"
        spec["description"] = text
        props[f.name] = spec
    return {"$schema": JSON_SCHEMA_DIALECT, "title": title, "type": "object", "properties": props,
            "required": list(props)}


# --------------------------------------------------------------------------- time


def log_times(times: np.ndarray) -> tuple[np.ndarray, str]:
    """``log_time`` (ns) of each scan and a description of the time base used."""
    t = np.asarray(times, dtype=float)
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        return np.arange(len(t), dtype=np.int64) * 1_000_000_000, "scan index (1 s per scan: the scan times do not advance)"
    shift = -float(t.min()) if len(t) and t.min() < 0 else 0.0
    ns = np.round((t + shift) * 1e9).astype(np.int64)
    return ns, ("scan time" if shift == 0 else f"scan time + {shift:g} s (the first scan time is negative)")


# --------------------------------------------------------------------------- export


def _family_of(stage) -> str | None:
    from trackreplay.vocabulary import FAMILIES

    if getattr(stage, "family", None):
        return stage.family
    return next((f.name for f in FAMILIES.values() if f.output_prefix == stage.output_prefix), None)


def _metrics_fields(per_scan, tracker: str, n_scans: int) -> list[_Field]:
    import polars as pl

    part = per_scan.filter(pl.col("tracker") == tracker).sort("scan")
    if part.height == 0:
        return []
    scans = part["scan"].to_numpy().astype(int)
    fields = []
    for col in part.columns:
        if col in ("tracker", "scan", "time_s", "stage") or not part[col].dtype.is_numeric():
            continue
        if part[col].null_count() == part.height:
            continue
        full = np.full(n_scans, np.nan)
        ok = (scans >= 0) & (scans < n_scans)
        full[scans[ok]] = part[col].cast(pl.Float64).fill_null(np.nan).to_numpy()[ok]
        fields.append(_Field(col, full))
    return fields


def export_foxglove(tracks_path, out_path, runs: str | None = None, data_path=None, recover: bool = False,
                    progress=None) -> ExportReport:
    """Write the JSON MCAP described in the module docstring.

    Parameters
    ----------
    tracks_path : path
        A replay output (``tracks.mcap``).
    out_path : path
        The file to write (never one of the inputs).
    runs : str, optional
        Run indices (``"0,1,2"``, ``"0-4"``); default the first DEFAULT_RUNS.
    data_path : path, optional
        The data set the replay read, for the truth and the per-scan metrics; default the one
        the outputs' provenance names (looked up as ``replay compare`` does). Without it the
        export holds the tracks only (and says so in the report's notes).
    progress : callable, optional
        Called with the number of scans written, as they are written.

    Raises
    ------
    InputError
        Not a replay output, a bad run list, an output path equal to an input.
    """
    from trackreplay import stage_running
    from mcap.writer import CompressionType, Writer

    from trackreplay import __version__
    from trackreplay.contract import atomic_output, read_dataset
    from trackreplay.paths import refuse_input_overwrite
    from trackreplay.stages import stage_for_outputs

    tracks_path, out_path = Path(tracks_path), Path(out_path)
    refuse_input_overwrite([tracks_path, data_path], [out_path])
    out_ds = read_dataset(tracks_path, recover=recover)
    stage = stage_for_outputs(out_ds.channels)
    if stage is None:
        raise InputError("holds no tracker outputs (expected /tracks/... channels): give a replay's tracks.mcap",
                         tracks_path)
    result = stage_running.read_outputs(stage, out_ds)
    tracks = {name: out for name, out in result["tracks"].items() if "state" in out}
    if not tracks:
        raise InputError("holds no tracker states to export", tracks_path)
    first = next(iter(tracks.values()))["state"]
    n_runs, n_scans = first.shape[:2]
    chosen = parse_runs(runs, n_runs)
    family = _family_of(stage)
    times = np.asarray(result["times"], dtype=float)
    if times.shape != (n_scans,):
        times = np.arange(n_scans, dtype=float)
    stamps, time_base = log_times(times)
    report = ExportReport(out_path, chosen, n_runs, list(tracks), time_base=time_base)

    # truth and per-scan metrics need the data set
    from trackreplay.replay import _find_input, evaluate_files

    data_ds, per_scan = None, None
    given = data_path is not None
    try:
        data_path = Path(data_path) if given else _find_input(tracks_path, recover)
        per_scan = evaluate_files(data_path, tracks_path, recover=recover).per_scan
        data_ds = read_dataset(data_path, recover=recover)
    except InputError as exc:
        if given:  # the data set the user named must fit
            raise
        report.notes.append(f"no truth or per-scan metrics: {exc}")

    topics: list[tuple[str, str, list[_Field], int | None]] = []  # (topic, schema title, fields, run)
    per_tracker = {name: track_fields(family, out, n_runs, n_scans) for name, out in tracks.items()}
    truth = None
    if data_ds is not None:
        from trackreplay.vocabulary import FAMILIES

        fam = FAMILIES.get(family) if family else None
        if fam is not None and fam.truth in data_ds.channels:
            ch = data_ds.channel(fam.truth)
            truth = truth_fields(family, ch, n_runs, n_scans) or None
    for r in chosen:
        for name, fields in per_tracker.items():
            topics.append((f"/run_{r:03d}/{name}", f"trackreplay.track.{name}", fields, r))
        if truth:
            topics.append((f"/run_{r:03d}/truth", f"trackreplay.truth.{family}", truth, r))
    if per_scan is not None:  # every tracker with metrics (an estimator without states too)
        for name in per_scan["tracker"].unique(maintain_order=True).to_list():
            fields = _metrics_fields(per_scan, name, n_scans)
            if fields:
                topics.append((f"/metrics/{name}", f"trackreplay.metrics.{name}", fields, None))
    report.truth = truth is not None
    report.metrics = any(t[3] is None for t in topics)

    with atomic_output(out_path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"trackreplay {__version__}")
        schema_ids: dict[str, int] = {}
        channels = []
        for topic, title, fields, run in topics:
            schema = json.dumps(json_schema(title, fields, run is not None), ensure_ascii=False)
            key = title + "\0" + schema
            if key not in schema_ids:
                schema_ids[key] = writer.register_schema(name=title, encoding=SCHEMA_ENCODING, data=schema.encode())
            cid = writer.register_channel(topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_ids[key],
                                          metadata={"source": str(tracks_path.name)})
            # values as Python lists once per topic (fast), NaN → None
            columns = [(fl.name, _finite_list(fl.values[run] if run is not None else fl.values)) for fl in fields]
            channels.append((cid, run, columns))
        t_list = times.tolist()
        for k in range(n_scans):
            for cid, run, columns in channels:
                msg = {"t": t_list[k], "scan": k}
                if run is not None:
                    msg["run"] = run
                for name, values in columns:
                    msg[name] = values[k]
                writer.add_message(channel_id=cid, log_time=int(stamps[k]), publish_time=int(stamps[k]),
                                   data=json.dumps(msg, separators=(",", ":"), allow_nan=False).encode(), sequence=k)
                report.messages += 1
            if progress is not None:
                progress(1)
        writer.add_metadata("trackreplay.export", {
            "source": tracks_path.name, "runs": ",".join(map(str, chosen)), "runs_in_source": str(n_runs),
            "time_base": time_base, "stage": stage.name, "package_version": __version__})
        writer.finish()
    report.topics = [t[0] for t in topics]
    first_topic, _, first_fields, _ = topics[0]
    report.example = f"{first_topic}.{first_fields[0].name}" if first_fields else first_topic
    return report
