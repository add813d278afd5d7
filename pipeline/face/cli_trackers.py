"""``replay trackers``: every tracker a replay can run, built-in and plugged.
"""

from __future__ import annotations

import json

import click

from trackreplay.face.cli_common import resolve_tracker_specs, tracker_option
from trackreplay.face.cli_text import _format_default, _table

from trackreplay.errors import InputError


def tracker_listing(specs=()) -> list[dict]:
    """Every tracker found (built-in, entry points, ``specs``) with its design parameters.

    A parameter whose default is None takes its value from the bundled scenario of the stage
    that consumes the tracker's family (:func:`trackreplay.design_values.parameter_defaults`);
    ``from`` says which (``"tracker"`` or ``"scenario <name>"``), and ``default`` stays None when
    neither has one (the value must then come from the data set or ``--set``).
    """
    from trackreplay import design_values
    from trackreplay.registry import available_trackers
    from trackreplay.stages import STAGES

    stages = {}
    for s in STAGES:
        stages.setdefault(s.family, s)
    rows = []
    for e in available_trackers(specs).values():
        stage = stages.get(e.family)
        try:
            resolved = design_values.parameter_defaults(stage, [e]) if stage is not None else {}
        except InputError:  # a parameter neither the tracker nor the scenario sets: resolve one by one
            from trackreplay.recorders.scenarios import load_scenario

            scenario = load_scenario(stage.scenario).params
            resolved = {p.name: scenario.get(p.name) for p in e.cls.params if p.default is None}
        params = []
        for p in e.cls.params:
            if p.default is not None:
                default, origin = p.default, "tracker"
            else:
                default = resolved.get(p.name)
                origin = f"scenario {stage.scenario}" if stage is not None and default is not None else "data set / --set"
            params.append({"name": p.name, "default": default, "unit": p.unit, "from": origin, "doc": p.doc})
        if not e.builtin:
            runs = "always"  # a plugged tracker runs beside the built-ins
        elif not getattr(e.cls, "runs_by_default", True):
            runs = "when-named"
        else:
            runs = "many-targets" if getattr(e.cls, "targets", "one") == "many" else "paper-scenes"
        rows.append({"name": e.name, "family": e.family, "form": e.cls.form, "source": e.source, "runs": runs,
                     "spec": e.spec, "stage": stage.name if stage is not None else None, "params": params})
    return rows


@click.command("trackers")
@tracker_option
@click.option("--json", "as_json", is_flag=True, help="Print the listing as JSON.")
def trackers_cmd(tracker_specs, as_json):
    """List the trackers: built-in, installed (entry points) and plugged with --tracker.

    For each: its measurement family, form (batch: all runs at once; run: one run at a time),
    which data sets a replay runs it on without --trackers (paper-scenes: a built-in made for
    the papers' scenes; many-targets: for truth sets of many targets among clutter; when-named: a
    variant run only when named; always: a plugged one), where it comes from, and
    its design parameters with default and unit (a default taken from
    the stage's bundled scenario says so). Any of them can be changed with --set NAME=VALUE.

    \b
    Example:
      replay trackers
      replay trackers --tracker my_trackers.py:ConstantVelocity --json
    """
    rows = tracker_listing(resolve_tracker_specs(tracker_specs))
    if as_json:
        click.echo(json.dumps(rows, indent=1, default=str))
        return
    for line in _table(("TRACKER", "FAMILY", "FORM", "BY-DEFAULT-ON", "SOURCE"),
                       [(r["name"], r["family"], r["form"], r["runs"], r["source"]) for r in rows]):
        click.echo(line)
    # trackers with the same parameter table share one listing
    groups: dict[str, list] = {}
    for r in rows:
        if r["params"]:
            groups.setdefault(json.dumps(r["params"], default=str), []).append(r)
    for members in groups.values():
        click.echo(f"\ndesign parameters of {', '.join(r['name'] for r in members)}:")
        params = members[0]["params"]
        for line in _table(("NAME", "DEFAULT", "UNIT", "FROM", "MEANING"),
                           [(p["name"], _format_default(p["default"]), p["unit"] or "-", p["from"], p["doc"])
                            for p in params], indent="  "):
            click.echo(line)


COMMANDS = [trackers_cmd]
