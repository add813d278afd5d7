"""No command removes or rewrites an input, whatever the names (issue 30, item 2).

Every combination of command (replay, eval, compare, simulate, convert, check --update), output
flags (an output named like an input, pointing at an input, into a folder holding inputs, a
recording slot holding an MCAP called ``tracks.rrd``) and ``--force`` runs in a fresh copy of
one folder of inputs; afterwards every input of that command has its bytes and is still a
regular file (not replaced by a link, not moved). Refusals are fine; a traceback is not.
"""

from __future__ import annotations

import hashlib
import itertools
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from trackreplay.face.cli import main

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def template(tmp_path_factory, monkeypatch_module):
    """The inputs, with names chosen to collide with outputs, and two earlier replays."""
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    root = tmp_path_factory.mktemp("walk_template")
    record(root / "data.mcap", load_scenario("radar-tws").with_overrides({"n_scans": 12}), runs=2, seed=3)
    (root / "o").mkdir()
    shutil.copy(root / "data.mcap", root / "o" / "tracks.rrd")  # an MCAP named like a recording
    shutil.copy(REPO / "data" / "samples" / "radar_plots.csv", root / "o" / "metrics.csv")  # a table named like one
    shutil.copy(REPO / "data" / "scenarios" / "radar-tws.toml", root / "o" / "scen.toml")
    shutil.copy(REPO / "data" / "samples" / "ros2_radar.mcap", root / "foreign.mcap")
    shutil.copy(REPO / "data" / "samples" / "ros2_radar_map.toml", root / "map.toml")
    (root / "chk" / "baselines").mkdir(parents=True)
    shutil.copy(root / "data.mcap", root / "chk" / "small.mcap")
    monkeypatch_module.chdir(root)
    for folder, value in (("r", "150"), ("r2", "120")):  # earlier replays: eval and compare read them
        res = CliRunner().invoke(main, ["data.mcap", "--out", f"{folder}/tracks.mcap", "--figures", "none",
                                        "--set", f"nominal_cross_range_m={value}"])
        assert res.exit_code == 0, res.output
    return root


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def _run_cases():
    """The input an MCAP named ``o/tracks.rrd`` (beside the outputs' folder) with every --out,
    recording slot and --force; the plain ``data.mcap`` with every --out and --force."""
    outs = [None, "o/tracks.mcap", "o/tracks.rrd", "data.mcap", "r/tracks.mcap", "o/metrics.csv"]
    rrds = [None, "--no-rrd", "o/tracks.rrd", "data.mcap"]
    combos = [*itertools.product(["o/tracks.rrd"], outs, rrds, [False, True]),
              *itertools.product(["data.mcap"], outs, [None], [False, True])]
    for data, out, rrd, force in combos:
        args = [data, "--figures", "none"]
        args += ["--out", out] if out else []
        args += ["--no-rrd"] if rrd == "--no-rrd" else ["--rrd", rrd] if rrd else []
        yield args + (["--force"] if force else []), [data]


def _eval_cases():
    for data, outputs, export in itertools.product(["o/tracks.rrd"], [None, "r/tracks.mcap"], [None, "o", "r", "."]):
        args = ["eval", data] + ([outputs] if outputs else []) + (["--export", export] if export else [])
        yield args, [data] + ([outputs] if outputs else [])


def _compare_cases():
    for data, out in itertools.product([None, "data.mcap"], [None, "r", "r2", "o"]):
        args = ["compare", "r/tracks.mcap", "r2/tracks.mcap"] + (["--data", data] if data else [])
        yield args + (["-o", out] if out else []), ["r/tracks.mcap", "r2/tracks.mcap"] + ([data] if data else [])


def _simulate_cases():
    for scenario, out, force in itertools.product(["radar-tws", "o/scen.toml"],
                                                  ["o/tracks.rrd", "o/scen.toml", "new.mcap", "o/metrics.csv"],
                                                  [False, True]):
        args = ["simulate", scenario, "--runs", "2", "-o", out] + (["--force"] if force else [])
        yield args, [scenario] if scenario.endswith(".toml") else []


def _convert_cases():
    for out, force in itertools.product(["o/metrics.csv", "o/tracks.rrd", "x.mcap", "data.mcap"], [False, True]):
        yield ["convert", "plots", "o/metrics.csv", "-o", out] + (["--force"] if force else []), ["o/metrics.csv"]
    for out, force in itertools.product(["foreign.mcap", "map.toml", "y.mcap"], [False, True]):
        yield (["convert", "mcap", "foreign.mcap", "--map", "map.toml", "-o", out] + (["--force"] if force else []),
               ["foreign.mcap", "map.toml"])


def _check_cases():
    yield ["check", "chk", "--update"], ["chk/small.mcap"]
    # a baseline slot that is a link to the data set itself: the baseline replaces the link, never the data
    yield ["check", "chk", "--update", "@link"], ["chk/small.mcap"]


CASES = [*_run_cases(), *_eval_cases(), *_compare_cases(), *_simulate_cases(), *_convert_cases(), *_check_cases()]


def _state(path: Path):
    """An input as it must stay: a regular file (not a link) with these bytes."""
    return (path.is_file() and not path.is_symlink(), hashlib.sha256(path.read_bytes()).hexdigest())


def test_no_combination_of_command_output_and_force_touches_an_input(template, tmp_path, monkeypatch):
    walked, modified, statuses = 0, [], {}
    runner = CliRunner()
    for i, (args, inputs) in enumerate(CASES):
        here = tmp_path / f"c{i}"
        shutil.copytree(template, here, symlinks=True)
        monkeypatch.chdir(here)
        if "@link" in args:
            args = [a for a in args if a != "@link"]
            (here / "chk" / "baselines" / "small.json").symlink_to(here / "chk" / "small.mcap")
        # the inputs of a replay's set (r/tracks.mcap) are links into its version folder: their bytes count
        before = {p: (hashlib.sha256((here / p).read_bytes()).hexdigest(), (here / p).is_symlink()) for p in inputs}
        res = runner.invoke(main, args)
        walked += 1
        statuses[res.exit_code] = statuses.get(res.exit_code, 0) + 1
        assert res.exit_code in (0, 1, 2), (args, res.output)
        assert "Traceback" not in res.output, (args, res.output)
        after = {p: (hashlib.sha256((here / p).read_bytes()).hexdigest(), (here / p).is_symlink())
                 if (here / p).is_file() else None for p in inputs}
        if after != before:
            modified.append((args, [p for p in inputs if after[p] != before[p]]))
        shutil.rmtree(here)
    print(f"\ncombinations walked {walked} / inputs modified {len(modified)}; exit statuses {statuses}")
    assert modified == []
    assert walked == len(CASES) >= 100
    assert statuses.get(0, 0) >= 20 and statuses.get(2, 0) >= 20  # both written and refused combinations
