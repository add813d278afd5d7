"""``replay info DATA.mcap``: what a data set holds and what it says about its sensor.

Channels (runs, scans, frames, arrays), the time span, whether it carries truth, where it came
from (a simulation or a converted recording), and for every stage that applies the sensor values
a replay would use with their source: the simulation's parameters, a converter flag, a mapping
file, the data themselves, an estimate from the data, or *unknown* (a tracker that needs it then
asks for ``--set NAME=VALUE``). The rules are in :mod:`trackreplay.sensor_values`; this module only
gathers and prints them (``docs/importers.md``, "Sensor values").
"""

from __future__ import annotations

import json
from pathlib import Path

import click

COMMANDS: list = []


def _plain(value):
    """A value as JSON holds it (numpy scalars and tuples made plain)."""
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        return value.item()
    return value


def _channel_info(ch) -> dict:
    times = ch.times()
    span = [float(times.min()), float(times.max())] if len(times) else []
    return {"runs": int(ch.n_runs), "scans": int(ch.n_scans), "frames": int(ch.n_frames),
            "arrays": sorted(ch.arrays), "time_span_s": span}


def _sensor_values(dataset, stage) -> dict:
    """``{name: {"value", "source", "note"?}}``: the sensor values ``stage`` would use on ``dataset``."""
    import numpy as np

    from trackreplay import design_values, sensor_values as sv
    from trackreplay import vocabulary as vocab
    from trackreplay.design_values import design_notes

    out = {}
    family = stage.family
    declared = vocab.FAMILIES[family]
    for name in declared.sensor_arrays:  # carried by the measurements, one per pair and epoch
        topic = stage.input_topics[0]
        ch = dataset.channels[topic]
        if name in ch.arrays:
            values = np.concatenate([np.ravel(a) for a in ch.array(name)]).astype(float)
            low, high = float(values.min()), float(values.max())
            out[name] = {"value": low if low == high else [low, high], "source": f"{sv.DATA} ({topic})"}
    keys = declared.sensor_keys
    if not keys:
        return out
    design = design_values.resolve(stage, dataset)
    notes = design_notes(dataset, stage.name)
    recorded = sv.recorded_sources(dataset.scenario)
    from_scenario = design_values.scenario_sourced_keys(stage)
    recording = sv.is_recording(dataset.scenario)
    for key in keys:
        if key in stage.when_unsaid and key not in recorded:  # what the stage reads instead
            value, why = stage.when_unsaid[key]
            out[key] = {"value": value, "source": f"{sv.UNKNOWN}: {why}"}
            continue
        if key not in design and key not in recorded:
            continue
        value = design.get(key)
        note = next((n for n in notes if n.startswith(f"{key} = ")), None)
        if key in recorded:
            source = recorded[key]
        elif value is None:
            source = sv.UNKNOWN
        elif note is not None:
            source = f"{sv.ESTIMATED} from {sv.ESTIMATES[key]}"
        elif key not in from_scenario:
            source = "the trackers' own default (the file does not say it)"
        elif recording:
            source = sv.UNKNOWN
        else:
            source = f"the bundled {stage.scenario} scenario (the file records no value)"
        entry = {"value": _plain(value), "source": source}
        if value is None:
            entry["needs"] = f"--set {key}=VALUE"
        out[key] = entry
    return out


def dataset_info(path: Path, recover: bool = False) -> dict:
    """Everything ``replay info`` prints, as one JSON-ready dict."""
    from trackreplay import sensor_values as sv
    from trackreplay import vocabulary as vocab
    from trackreplay.contract import read_dataset
    from trackreplay.stages import applicable_stages

    dataset = read_dataset(path, recover=recover)
    record = dataset.scenario
    # a file without a record (or without parameters in it) is a recording that says nothing
    origin = "recording" if sv.is_recording(record) else "simulation" if sv.is_simulation(record) else "unknown"
    channels = {topic: _channel_info(ch) for topic, ch in sorted(dataset.channels.items())}
    spans = [c["time_span_s"] for c in channels.values() if c["time_span_s"]]
    stages = applicable_stages(dataset.channels)
    truth = sorted({vocab.FAMILIES[s.family].truth for s in stages} & set(dataset.channels))
    recorded = sv.recorded_sources(record)
    params = record.get("params", {})
    sensor = {}
    for stage in stages:
        sensor[stage.name] = _sensor_values(dataset, stage)
    shown = {k for values in sensor.values() for k in values}
    return {
        "file": str(path), "contract": dataset.contract, "origin": origin,
        "says_nothing_of_its_sensor": sv.says_nothing(record),
        "scenario": record.get("scenario"), "seed": record.get("seed"),
        "package_version": record.get("package_version"),
        "runs": max((c["runs"] for c in channels.values()), default=0),
        "scans": max((c["scans"] for c in channels.values()), default=0),
        "time_span_s": [min(s[0] for s in spans), max(s[1] for s in spans)] if spans else [],
        "truth": bool(truth), "truth_channels": truth,
        "channels": channels,
        "stages": [s.name for s in stages],
        "sensor_values": sensor,
        "recorded": {k: {"value": _plain(v), "source": recorded.get(k, "")} for k, v in sorted(params.items())
                     if k not in shown},
        "recovered_messages": dataset.recovered_messages,
    }


def _show(value) -> str:
    if value is None:
        return "unknown"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return "…".join(_show(v) for v in value) if len(value) == 2 and all(isinstance(v, float) for v in value) \
            else json.dumps(value)
    return str(value)


def print_info(info: dict) -> None:
    origin = info["origin"]
    if origin == "simulation":
        origin = f"a simulation of {info['scenario']} (seed {info['seed']})"
    elif origin == "recording" and info["says_nothing_of_its_sensor"]:
        origin = ("a recording without a replay.scenario record of its sensor (written by hand or by an older "
                  "tool): its sensor values are unknown")
    elif origin == "recording":
        origin = f"a recording ({info['scenario']})"
    click.echo(f"{info['file']}: {origin}; contract {info['contract']}")
    span = info["time_span_s"]
    click.echo(f"  runs {info['runs']}, scans {info['scans']}, time span "
               + (f"{span[0]:g}–{span[1]:g} s" if span else "none"))
    click.echo(f"  truth: {'yes (' + ', '.join(info['truth_channels']) + ')' if info['truth'] else 'no'}")
    click.echo("channels:")
    width = max((len(t) for t in info["channels"]), default=0)
    for topic, ch in info["channels"].items():
        click.echo(f"  {topic:<{width}}  {ch['runs']} run(s) × {ch['scans']} scan(s), {ch['frames']} frames; "
                   f"{', '.join(ch['arrays'])}")
    for stage, values in info["sensor_values"].items():
        click.echo(f"sensor values ({stage}):" if values else f"sensor values ({stage}): none the trackers read")
        width = max((len(k) for k in values), default=0)
        for key, v in values.items():
            tail = f": a tracker that needs it asks for {v['needs']}" if "needs" in v else ""
            click.echo(f"  {key:<{width}}  {_show(v['value']):>12}  {v['source']}{tail}")
    if info["recorded"]:
        click.echo("also recorded:")
        width = max(len(k) for k in info["recorded"])
        for key, v in info["recorded"].items():
            source = f"  {v['source']}" if v["source"] else ""
            click.echo(f"  {key:<{width}}  {_show(v['value']):>12}{source}")


@click.command("info")
@click.argument("data", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of text.")
@click.option("--recover", is_flag=True, help="Accept a truncated MCAP: describe its complete chunks.")
def info_cmd(data, as_json, recover):
    """What a data set holds: channels, runs, scans, time span, truth, and the sensor values a
    replay would use with their source (simulation parameters, converter flag, mapping file,
    the data, estimated, or unknown).

    \b
    Example:
      replay info data/radar_tws_demo.mcap
      replay info rec.mcap --json
    """
    from trackreplay.errors import InputError

    if not data.exists():
        raise InputError("no such file", data)
    info = dataset_info(data, recover)
    if as_json:
        click.echo(json.dumps(info, indent=2, sort_keys=True, default=str))
    else:
        print_info(info)


COMMANDS.append(info_cmd)
