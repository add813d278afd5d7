"""``replay simulate``, ``replay scenarios`` and the ``replay convert`` group: making data sets.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from trackreplay.face import progress
from trackreplay.face.cli_common import _parameter_options, force_option
from trackreplay.face.cli_text import TABLE_WIDTH, _format_value, _wrap_cells
from trackreplay.paths import refuse_input_overwrite, refuse_replacing_file


@click.command("simulate", context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
@click.argument("scenario")
@click.option("--runs", default=100, show_default=True, type=click.IntRange(min=1), help="Monte Carlo runs.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Random seed (same seed, same bytes).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help="Override a scenario parameter.")
@force_option
@click.pass_context
def simulate_cmd(ctx, scenario, runs, seed, output, sets, force):
    """Simulate a scenario (a name from data/scenarios/ or a TOML path) into an MCAP file.

    Any scenario parameter also works as an option: --name value means --set name=value.

    \b
    Example:
      replay simulate radar-tws --runs 500 --seed 7 -o radar.mcap --set sigma_bearing_deg=0.5
      replay simulate tdoa-fdoa --geometry line --emitter 1 --runs 1000 -o emitter.mcap
    """
    from trackreplay.recorders import recorder_module
    from trackreplay.recorders.scenarios import load_scenario, parse_assignments
    from trackreplay.recorders.simulated import write_simulated
    from trackreplay.contract import scenario_metadata

    sc = load_scenario(scenario).with_overrides({**_parameter_options(ctx.args), **parse_assignments(sets)})
    rec = recorder_module(sc.recorder)
    t0 = time.perf_counter()
    refuse_input_overwrite([Path(scenario)], [output])
    refuse_replacing_file(output, force)
    with progress.bar(1, f"simulating {sc.name} ({runs} runs)") as bar, progress.timed("simulate"):
        data = rec.simulate(sc.params, runs, seed)
        bar.update(1)
    with progress.bar(len(data.times), f"writing {output.name}") as bar, progress.timed("write"):
        n = write_simulated(output, data, scenario_metadata(sc.name, sc.params, seed), bar.update)
    click.echo(f"wrote {output}: {n} messages, {data.n_runs} runs × {len(data.times)} scans, seed {seed} "
               f"({time.perf_counter() - t0:.2f} s)")


@click.command("scenarios")
@click.argument("name", required=False)
def scenarios_cmd(name):
    """List the bundled scenarios, or show one scenario's parameters.

    With NAME (a bundled scenario or a TOML path): every parameter with its default, its unit
    (from the suffix of its name: _m, _s, _deg, _mps, _mps2, _hz, _db, _rad, ...; count,
    probability, flag, ... for the dimensionless ones) and its meaning (the comment after it in
    the scenario file, or the comment lines directly above it). Any of them can be changed with
    `replay simulate NAME --set name=value` (or --name value).

    \b
    Example:
      replay scenarios
      replay scenarios radar-tws
      replay simulate radar-tws --set sigma_bearing_deg=0.5 -o radar.mcap
    """
    from trackreplay.recorders.scenarios import available_scenarios, load_scenario, parameter_docs, parameter_unit

    if name is None:
        rows = []
        for n in available_scenarios():
            sc = load_scenario(n)
            rows.append((n, f"{len(sc.params)}", sc.description or "-"))
        for line in _wrap_cells(("SCENARIO", "PARAMETERS", "DESCRIPTION"), rows):
            click.echo(line)
        click.echo("\nparameters, units and defaults of one: replay scenarios NAME")
        return
    import textwrap

    sc = load_scenario(name)
    docs = parameter_docs(sc.source)
    click.echo(textwrap.fill(f"{sc.name}: {sc.description or '(no description)'}", TABLE_WIDTH,
                             subsequent_indent="  "))
    click.echo(f"recorder {sc.recorder}; file {sc.source}")
    click.echo("")
    rows = [(k, _format_value(v), parameter_unit(k, v) or "-", docs.get(k, "-")) for k, v in sc.params.items()]
    for line in _wrap_cells(("NAME", "DEFAULT", "UNIT", "MEANING"), rows):
        click.echo(line)
    click.echo(f"\nchange any: replay simulate {sc.name} --set NAME=VALUE -o data.mcap (a list: comma-separated)")


@click.group("convert")
def convert_group():
    """Convert recorded data into the MCAP data contract.

    Tables of measurements (CSV or Parquet) come in with plots, peaks, tdoa-fdoa and positions;
    `replay export --table` writes a data set's measurements out in the same format.

    \b
    Example:
      replay convert plots plots.csv -o plots.mcap --set sigma_bearing_deg=0.8
      replay convert tdoa-fdoa pairs.parquet --sensors sensors.parquet -o emitter.mcap
      replay convert array-wav array.wav -o rec.mcap --spacing-m 0.04 --frequency-hz 2000
    """


COMMANDS = [simulate_cmd, scenarios_cmd, convert_group]
