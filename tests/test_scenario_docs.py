"""Scenario parameters are documented: `replay scenarios NAME` gives every parameter a meaning
and a unit, read from the scenario file's comments and the parameter's name."""

from __future__ import annotations

import pytest

from trackreplay.face.cli import main
from trackreplay.face.cli_text import TABLE_WIDTH
from trackreplay.recorders.scenarios import available_scenarios, load_scenario, parameter_docs, parameter_unit


def scenario_table(runner, name: str) -> tuple[dict[str, dict], list[str]]:
    """The parameter table ``replay scenarios NAME`` prints: ``name → {default, unit, meaning}``
    (continuation lines of a wrapped meaning joined) and the table's lines as printed."""
    res = runner.invoke(main, ["scenarios", name])
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("NAME") and "MEANING" in line)
    header = lines[start]
    cols = [header.index(h) for h in ("DEFAULT", "UNIT", "MEANING")]
    rows: dict[str, dict] = {}
    table = [header]
    last = None
    for line in lines[start + 1:]:
        if not line.strip():
            break
        table.append(line)
        if line[:1].isspace():  # a wrapped meaning goes on under its row
            assert last is not None, line
            rows[last]["meaning"] += " " + line.strip()
            continue
        last = line[:cols[0]].strip()
        rows[last] = {"default": line[cols[0]:cols[1]].strip(), "unit": line[cols[1]:cols[2]].strip(),
                      "meaning": line[cols[2]:].strip()}
    return rows, table


@pytest.mark.parametrize("name", available_scenarios())
def test_every_scenario_parameter_has_a_meaning_and_a_unit(runner, name):
    rows, table = scenario_table(runner, name)
    assert list(rows) == list(load_scenario(name).params)
    for key, row in rows.items():
        assert row["meaning"] not in ("", "-"), f"{name}: {key} has no meaning"
        assert row["unit"] not in ("", "-"), f"{name}: {key} has no unit"
        assert row["default"] != "", f"{name}: {key} has no default"
    assert max(len(line) for line in table) <= TABLE_WIDTH


def test_units_of_dimensionless_parameters_say_what_they_count():
    assert parameter_unit("sigma_range_m") == "m" and parameter_unit("design_sigma_v_mps2") == "m/s²"
    assert parameter_unit("n_targets") == "count" and parameter_unit("snapshots_per_scan") == "count"
    assert parameter_unit("detection_probability") == "probability"
    assert parameter_unit("weak_clutter_per_gate") == "count/gate"
    assert parameter_unit("startup_gains") == "flag" and parameter_unit("track_start") == "choice"
    assert parameter_unit("approach_rate_deg_per_s") == "deg/s"
    assert parameter_unit("q_deg2") == "deg²/s³"
    # a name that says nothing: the value's type decides, else there is no unit
    assert parameter_unit("mystery") is None
    assert parameter_unit("mystery", True) == "flag" and parameter_unit("mystery", "a") == "choice"
    assert parameter_unit("mystery", 3.0) is None


def test_a_parameter_is_documented_by_its_comment_or_the_lines_above(tmp_path):
    toml = tmp_path / "mine.toml"
    toml.write_text(
        '# file header: not a parameter\n'
        'name = "mine"\n'
        '# above the recorder key, outside [params]\n'
        'recorder = "radar-tws"\n'
        '\n'
        '[params]\n'
        '# first line of a block\n'
        '# and its second line\n'
        'above_only = 1\n'
        '# ignored: the comment on the line wins\n'
        'both = 2              # on the line\n'
        'inline_only = "a#b"   # after a string holding "#"\n'
        '# cut off by the blank line below\n'
        '\n'
        'after_blank = 3\n'
        '# ---- a heading of the group ----\n'
        'after_heading = 4\n'
        '# ---- design ----\n'
        '# the block under a heading\n'
        'under_heading = 5\n'
        'no_comment = 6\n'
        '# belongs to the value below, not to the one above\n'
        'last = [\n'
        '    1,  # an element\n'
        ']\n'
        'after_array = 7\n'
    )
    docs = parameter_docs(toml)
    assert docs == {
        "above_only": "first line of a block and its second line",
        "both": "on the line",
        "inline_only": 'after a string holding "#"',
        "under_heading": "the block under a heading",
        "last": "belongs to the value below, not to the one above",
    }


def test_a_user_scenario_shows_the_lines_above_in_the_table(runner, tmp_path):
    toml = tmp_path / "mine.toml"
    toml.write_text('name = "mine"\nrecorder = "radar-tws"\n[params]\n'
                    '# how many scans\nn_scans = 10\n'
                    '# not about sigma_range_m\n\nsigma_range_m = 50.0\n')
    rows, _ = scenario_table(runner, str(toml))
    assert rows["n_scans"]["meaning"] == "how many scans" and rows["n_scans"]["default"] == "10"
    # the blank line cut the comment off; the bundled scenario's meaning is not inherited
    assert rows["sigma_range_m"]["meaning"] == "-" and rows["sigma_range_m"]["unit"] == "m"
