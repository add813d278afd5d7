"""``replay convert mcap``: a recording made by another tool (an MCAP of ROS 2, JSON or protobuf
messages), mapped onto a measurement family by a small TOML file.

Registered under the existing ``replay convert`` group (this module is listed in
``trackreplay.face.cli.EXTENSION_MODULES``; its CONVERT_COMMANDS join the group). ``replay FOREIGN.mcap
--map MAP.toml`` converts through :func:`convert_for_replay` and replays the result.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import click

COMMANDS: list = []  # no top-level command


@click.command("mcap")
@click.argument("src", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--map", "map_path", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="The TOML mapping file (topic, time, items, columns with their fields and units).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="The data set to write (never SRC or the mapping: an input is never written over).")
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
              help="A sensor or design value recorded with the data, e.g. sigma_range_m=50 (wins over the "
                   "mapping's [sensor] table); a sensor value given nowhere is unknown.")
@click.option("--force", is_flag=True, help="Replace the output file if it exists.")
def convert_mcap_cmd(src, map_path, output, sets, force):
    """An MCAP recorded by another tool (ROS 2, JSON or protobuf) → a data set.

    The mapping file (TOML) names the family and, in [measurements] (and [sensors] for
    tdoa-fdoa), where each column of the family's table comes from:

    \b
      family = "radar"
      [measurements]
      topic = "/radar/scan"          # the topic to read
      time = "header.stamp"          # "log_time", a stamp (sec + nanosec), or
                                     # { field = "t", unit = "ms" }
      items = "returns"              # optional list field: one row per element
      range_m = { field = "range", unit = "km" }
      bearing_rad = { field = "azimuth", unit = "deg" }
      run = "/run_id"                # optional; a leading / reads from the message
      amplitude = { value = 1.0 }    # a constant
      [sensor]                       # optional: what the sensor was like
      sigma_range_m = 50.0           # (a value given nowhere is unknown)

    \b
    Columns are those of the family's table (replay convert plots|peaks|tdoa-fdoa|positions
    --help). Field paths are dotted with list indices (returns[0].range) and read from each
    item of `items` (or from the message when there is none). Units: m km cm mm ft nmi mi,
    rad mrad deg, s ms us ns, Hz kHz MHz GHz, m/s km/h kn ft/s, m/s2 ft/s2 g, rad/s deg/s, 1;
    values are converted to the column's unit (its name's suffix). Each message is one scan
    of its run, so times must increase from message to message. A radar recording of many
    targets adds a [truth] table (its own topic, time and items; truth_id and the four truth_*
    columns), matched to the scans by time. Decoders: cdr with a ros2msg schema (mcap_ros2),
    protobuf (mcap_protobuf), json. See docs/importers.md.

    \b
    Example:
      replay convert mcap radar.mcap --map radar.toml -o ours.mcap --set sigma_range_m=50
      replay radar.mcap --map radar.toml           # convert and replay at once
    """
    from trackreplay.paths import refuse_input_overwrite, refuse_replacing_file
    from trackreplay.recorders.foreign_mcap import convert_foreign_mcap
    from trackreplay.recorders.scenarios import parse_assignments

    refuse_input_overwrite([src, map_path], [output])
    refuse_replacing_file(output, force)
    rep = convert_foreign_mcap(src, map_path, output, parse_assignments(sets))
    click.echo(f"wrote {output}: {rep['messages_out']} messages ({rep['family']})")
    for table, topic in rep["topics"].items():
        click.echo(f"  {table}: {rep['messages_in'][table]} messages on {topic} → {rep['rows'][table]} rows")
    for note in rep["notes"]:
        click.echo(f"  {note}")
    click.echo(f"  {_sensor_line(output, rep['family'])}")


def _sensor_line(data: Path, family: str) -> str:
    """Which sensor values the converted data set records (from the mapping file's [sensor] or
    --set) and which it leaves unknown, read back from what was written."""
    from trackreplay.contract import read_dataset
    from trackreplay.sensor_values import recorded_sources
    from trackreplay.recorders.tables import sensor_summary

    record = read_dataset(data).scenario
    return sensor_summary(family, record.get("params", {}), recorded_sources(record))


def convert_for_replay(src: Path, map_path: Path) -> Path:
    """Convert ``src`` through ``map_path`` into a temporary data set named after ``src``, for
    ``replay FOREIGN.mcap --map MAP.toml``; the folder goes when the command ends."""
    from trackreplay.recorders.foreign_mcap import convert_foreign_mcap

    scratch = Path(click.get_current_context().with_resource(tempfile.TemporaryDirectory(prefix="replay-map-")))
    out = scratch / f"{src.stem}.mcap"
    rep = convert_foreign_mcap(src, map_path, out)
    click.echo(f"converted {src} through {map_path.name}: " + ", ".join(
        f"{rep['messages_in'][t]} messages on {topic} → {rep['rows'][t]} rows" for t, topic in rep["topics"].items()))
    click.echo(_sensor_line(out, rep["family"]))
    return out


CONVERT_COMMANDS = [convert_mcap_cmd]  # added under `replay convert` by trackreplay.face.cli
