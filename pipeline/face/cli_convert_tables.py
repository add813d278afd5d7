"""``replay convert <command>`` of every table format: tables of measurements (CSV or Parquet) →
data sets, and ``replay export --table``'s writing of them the other way.

Registered under the existing ``replay convert`` group (this module is listed in
``trackreplay.face.cli.EXTENSION_MODULES``; its CONVERT_COMMANDS join the group). The commands,
their help texts and words are written from the formats the families declare
(:data:`trackreplay.recorders.table_formats.TABLE_FORMATS`: each format's command, its aliases,
earlier names that stay, its title, item word, samples and columns); this module names no
family. The checks and the numbers are in :mod:`trackreplay.recorders.tables`.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import click

# the formats alone: neither numpy nor polars (starting `replay` lists these commands)
from trackreplay.recorders.table_formats import scenario_of, table_formats

COMMANDS: list = []  # no top-level command

HELP_WIDTH = 100


def _column_lines(columns, indent: str = "  ") -> list[str]:
    """A columns table that fits HELP_WIDTH: name, unit, required, meaning (wrapped)."""
    name_w = min(max(len(c.name) for c in columns), 34)
    unit_w = max(len(c.unit) for c in columns)
    lead = len(indent) + name_w + 2 + unit_w + 2 + 9
    out = []
    for c in columns:
        meaning = textwrap.wrap(c.meaning, HELP_WIDTH - lead) or [""]
        name = c.name if len(c.name) <= name_w else None
        if name is None:  # a long name takes its own line
            out.append(f"{indent}{c.name}")
            name = ""
        out.append(f"{indent}{name:<{name_w}}  {c.unit:<{unit_w}}  {'required' if c.required else 'optional':<9}"
                   f"{meaning[0]}".rstrip())
        out += [" " * lead + m for m in meaning[1:]]
    return out


def format_help(family: str, command: str) -> str:
    """The --help text of a table converter, from the family's
    :data:`trackreplay.recorders.table_formats.TABLE_FORMATS` entry."""
    from trackreplay.vocabulary import FAMILIES

    fmt = table_formats()[family]
    sample, sensors = fmt.samples["measurements"], fmt.samples.get("sensors")
    lines = [f"{fmt.title} table (.csv or .parquet) → data set (MCAP), ready for `replay`.", "",
             f"{fmt.summary[0].upper()}{fmt.summary[1:]}. Say what you know about the sensor with --set "
             f"(its noise, scan period, …: {', '.join(FAMILIES[family].sensor_keys) or 'none; they are columns'}); "
             f"what you do not say stays unknown, never taken from the bundled {scenario_of(family)} scenario, "
             "and a tracker that needs it asks for it. `replay info DATA` shows every value and its source.", ""]
    for key, columns in fmt.tables.items():
        title = "Columns" if key == "measurements" else "Columns of the sensors table (--sensors)"
        lines += ["\b", f"{title} (unit; rad | ° means _rad or _deg):", *_column_lines(columns), ""]
    lines += ["\b", *[wrapped for note in fmt.notes
                      for wrapped in textwrap.wrap(note, HELP_WIDTH - 4, initial_indent="* ", subsequent_indent="  ")],
              ""]
    lines += ["Every table: runs numbered from 0 without gaps, each run's rows in time order, numbers only (no "
              "text, NaN or Inf); an error names the file and the first bad row (rows counted from 1 after the "
              "header). See docs/importers.md.", ""]
    extra = f" --sensors data/samples/{sensors}" if sensors else ""
    given = "".join(f" --set {k}={v}" for k, v in fmt.sample_sensor_values.items())
    lines += ["\b", "Example:", f"  replay convert {command} data/samples/{sample}{extra} -o rec.mcap{given}",
              "  replay info rec.mcap", "  replay rec.mcap --no-rrd"]
    return "\n".join(lines)


#: the sensor values the bundled samples were made with (docs/importers.md, "Sample tables"), per
#: family (its format's sample_sensor_values)
SAMPLE_SENSOR_VALUES = {f: fmt.sample_sensor_values for f, fmt in table_formats().items() if fmt.sample_sensor_values}


class _TableCommand(click.Command):
    """A converter whose long help is written from the table format only when asked for, so
    that starting `replay` does not import polars and the stages."""

    def __init__(self, *args, family: str, help_name: str, **kwargs):
        super().__init__(*args, **kwargs)
        self.family, self.help_name = family, help_name

    def format_help_text(self, ctx, formatter) -> None:
        if self.help is None:
            self.help = format_help(self.family, self.help_name)
        super().format_help_text(ctx, formatter)


def _convert_command(name: str, family: str, alias_of: str | None = None) -> click.Command:
    params = [
        click.Argument(["table_path"], type=click.Path(dir_okay=False, path_type=Path)),
        click.Option(["-o", "--output"], required=True, type=click.Path(dir_okay=False, path_type=Path),
                     help="The data set to write (never the input itself)."),
    ]
    fmt = table_formats()[family]
    if "sensors" in fmt.tables:  # a format with a second table: the sensors
        params.append(click.Option(["--sensors", "sensors_path"], required=True,
                                   type=click.Path(dir_okay=False, path_type=Path),
                                   help=fmt.table_help["sensors"]))
    params += [
        click.Option(["--set", "sets"], multiple=True, metavar="NAME=VALUE",
                     help="A sensor value (sigma_range_m=50) or design value recorded with the data; "
                          "a sensor value not given is unknown."),
        click.Option(["--force"], is_flag=True, help="Replace the output file if it exists."),
    ]

    def callback(table_path, output, sets, force, sensors_path=None):
        from trackreplay.paths import refuse_input_overwrite, refuse_replacing_file
        from trackreplay.recorders.scenarios import parse_assignments
        from trackreplay.recorders.tables import convert_table, sensor_summary

        refuse_input_overwrite([table_path, sensors_path], [output])
        refuse_replacing_file(output, force)
        rep = convert_table(family, table_path, output, parse_assignments(sets), sensors_path)
        click.echo(f"wrote {output}: {rep.messages} messages, {rep.runs} run(s) × {rep.scans} scan(s), "
                   f"{rep.items} {fmt.item_word}; {'with truth' if rep.truth else 'no truth'}")
        for note in rep.notes:
            click.echo(f"note: {note}")
        click.echo(sensor_summary(family, rep.params, rep.sources))

    short = (f"Alias of `{alias_of}` (its earlier name)." if alias_of
             else f"{fmt.title} table (CSV or Parquet) → MCAP.")
    return _TableCommand(name, callback=callback, params=params, short_help=short, family=family,
                         help_name=alias_of or name)


def export_tables(data: Path, out_dir: Path, fmt: str, recover: bool, force: bool) -> None:
    """``replay export --table``: every family's input channels of ``data`` as tables in ``out_dir``,
    written as a set (all files or none)."""
    from trackreplay.contract import read_dataset
    from trackreplay.errors import InputError
    from trackreplay.paths import OutputSet, refuse_input_overwrite, refuse_replacing_file
    from trackreplay.recorders.tables import exportable_families, table_file_names, tables_from_dataset, write_table

    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("is a file; --table writes its tables into a folder", out_dir)
    if not data.exists():
        raise InputError("no such file", data)
    dataset = read_dataset(data, recover=recover)
    families, skipped = exportable_families(dataset)
    if not families:
        raise InputError(f"no channels of a family with a table format ({', '.join(table_formats())}); channels "
                         f"present: {', '.join(sorted(dataset.channels)) or 'none'}", data)
    plan = []
    for family in families:
        names = table_file_names(family, fmt)
        plan += [(out_dir / names[key], df) for key, df in tables_from_dataset(dataset, family).items()]
    refuse_input_overwrite([data], [p for p, _ in plan])
    for p, _ in plan:
        refuse_replacing_file(p, force)
    # a set per group of files (one family's tables in one format): exporting another family or
    # format into the same folder adds its own set beside, and only the same files are replaced
    set_name = "tables-" + "+".join(sorted(p.name for p, _ in plan))
    with OutputSet(out_dir, inputs=[data], name=set_name) as outputs:
        for p, df in plan:
            write_table(df, outputs.path(p.name), fmt)
    for p, df in plan:
        click.echo(f"wrote {p}: {df.height} rows, columns {', '.join(df.columns)}")
    for family in skipped:
        click.echo(f"note: {family} has no table format (its recordings come in as WAV: replay convert array-wav)")
    for family in families:
        names = table_file_names(family, fmt)
        sensors = f" --sensors {out_dir / names['sensors']}" if "sensors" in names else ""
        click.echo(f"back: replay convert {table_formats()[family].command} {out_dir / names['measurements']}{sensors} "
                   "-o DATA.mcap")


#: command → (family, the command it is an alias of): each format's command, then its aliases
TABLE_COMMANDS = {name: (family, alias_of)
                  for family, fmt in table_formats().items()
                  for name, alias_of in ((fmt.command, None), *((a, fmt.command) for a in fmt.aliases))}
# added under `replay convert` by trackreplay.face.cli
CONVERT_COMMANDS = [_convert_command(name, family, alias_of) for name, (family, alias_of) in TABLE_COMMANDS.items()]
