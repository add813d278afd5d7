"""Nothing lost, nothing decided by accident (issue 30). An input is never removed, whatever
its name. A plugged tracker cannot decide the tool's exit: ``sys.exit()`` in ``track()``, in its
constructor or at import is that tracker's failure like any exception, one line and exit 2, and
the built-ins' outputs are still written. Scan times that stall or go back, plots with two
numbers each and a --pair naming no tracker are one line and exit 2, never an internal error."""

from __future__ import annotations

from pathlib import Path

import pytest

from trackreplay.contract import read_dataset
from trackreplay.face.cli import main

EXITING = '''
import sys
from trackreplay.trackers.interface import Tracker

class ExitsInTrack(Tracker):
    name, family = "exits_in_track", "radar"

    def track(self, plots):
        sys.exit({code})

class ExitsWhenBuilt(Tracker):
    name, family = "exits_when_built", "radar"

    def __init__(self, **design):
        super().__init__(**design)
        sys.exit({code})

    def track(self, plots):
        raise AssertionError("never reached")
'''


@pytest.mark.parametrize("code", [0, 3, "'bye'"])
@pytest.mark.parametrize("cls", ["ExitsInTrack", "ExitsWhenBuilt"])
def test_sys_exit_in_a_tracker_is_its_failure_and_the_others_are_written(runner, radar_small, tmp_path, cls, code):
    (tmp_path / "exiting.py").write_text(EXITING.format(code=code))
    res = runner.invoke(main, [str(radar_small), "--tracker", f"exiting.py:{cls}", "--no-rrd", "--out", "o/t.mcap",
                               "--figures", "none"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and "SystemExit" in errors[0] and "Traceback" not in res.output, res.output
    assert "/tracks/radar/kalman" in read_dataset(Path("o/t.mcap")).channels


@pytest.mark.parametrize("code", [0, 3])
def test_sys_exit_at_import_is_one_line_naming_the_file(runner, radar_small, tmp_path, code):
    (tmp_path / "exits_at_import.py").write_text(f"import sys\nsys.exit({code})\n")
    res = runner.invoke(main, [str(radar_small), "--tracker", "exits_at_import.py:Nothing", "--no-rrd", "--out",
                               "o/t.mcap", "--figures", "none"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and "exits_at_import.py" in errors[0] and "SystemExit" in errors[0], res.output


@pytest.mark.parametrize("step", [0.0, -2.5])
def test_scan_times_that_do_not_increase_are_refused_with_one_line(runner, tmp_path, step):
    """A recording whose scan times stall or go back is refused as the importers refuse it: a
    filter's time step would be zero or negative (issue 30: it was accepted silently)."""
    import dataclasses

    from trackreplay.contract import scenario_metadata
    from trackreplay.recorders.radar_tws import simulate
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import write_simulated

    params = load_scenario("radar-tws").params
    data = simulate(params, 2, 1)
    times = data.times.copy()
    times[5] = times[4] + step
    path = tmp_path / "back.mcap"
    write_simulated(path, dataclasses.replace(data, times=times), scenario_metadata("radar-tws", params, 1))
    before = path.read_bytes()
    res = runner.invoke(main, [str(path), "--no-rrd", "--out", "o/t.mcap", "--figures", "none"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and "back.mcap" in errors[0] and "scan times must increase" in errors[0], res.output
    assert path.read_bytes() == before and not Path("o").exists()


def test_a_pair_naming_a_tracker_neither_output_holds_is_one_line(runner, radar_small):
    """``compare --pair nosuch:kalman`` was an internal error (exit 3); it is the user's slip."""
    assert runner.invoke(main, [str(radar_small), "--no-rrd", "--out", "a/t.mcap", "--figures", "none"]).exit_code == 0
    res = runner.invoke(main, ["compare", "a/t.mcap", "a/t.mcap", "--data", str(radar_small), "--pair", "nosuch:kalman"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and "A has no tracker 'nosuch'" in errors[0] and "kalman" in errors[0], res.output


def test_plots_with_two_numbers_each_are_refused_as_input_not_blamed_on_a_tracker(runner, tmp_path):
    import numpy as np

    from trackreplay.contract import scenario_metadata, write_dataset
    from trackreplay.recorders.radar_tws import simulate
    from trackreplay.recorders.scenarios import load_scenario

    params = load_scenario("radar-tws").params
    data = simulate(params, 1, 2)
    values, counts = data.ragged["/radar/plots"]
    path = tmp_path / "wide.mcap"
    with write_dataset(path, scenario_metadata("radar-tws", params, 2)) as w:
        for k, t in enumerate(data.times):
            n = counts[0, k]
            w.write("/radar/plots", 0, k, float(t), {"range_m": np.stack([values["range_m"][0, k, :n]] * 2, -1),
                                                     "bearing_rad": values["bearing_rad"][0, k, :n]})
    res = runner.invoke(main, [str(path), "--no-rrd", "--out", "o/t.mcap", "--figures", "none"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and "wide.mcap" in errors[0] and "range_m has shape (2,) per plot" in errors[0], res.output


@pytest.mark.parametrize("rrd", [None, "elsewhere.rrd"])
def test_an_input_named_like_a_stale_output_is_never_removed(runner, radar_small, rrd):
    """``replay o/tracks.rrd --no-rrd --out o/tracks.mcap --force`` with an MCAP input named
    ``tracks.rrd`` deleted it: the clean-up of a stale recording must spare what the command reads."""
    import shutil

    Path("o").mkdir()
    shutil.copy(radar_small, "o/tracks.rrd")
    before = Path("o/tracks.rrd").read_bytes()
    extra = ["--no-rrd"] if rrd is None else ["--rrd", rrd]
    res = runner.invoke(main, ["o/tracks.rrd", *extra, "--out", "o/tracks.mcap", "--force", "--figures", "none"])
    assert res.exit_code == 0, res.output
    assert Path("o/tracks.rrd").read_bytes() == before
    assert "/tracks/radar/kalman" in read_dataset(Path("o/tracks.mcap")).channels


@pytest.mark.parametrize("setting", ["gate_deg=1e-300", "gate_deg=1e-9", "strong_clutter_per_gate=2e6"])
def test_a_clutter_density_beyond_any_correlator_is_refused_before_any_work(runner, tmp_path, setting):
    # a tiny gate or a huge count per gate asked for 10¹¹ peaks a scan or more: an internal error,
    # a MemoryError or the system's out-of-memory kill
    res = runner.invoke(main, ["simulate", "xcorr-crossing", "--runs", "2", "--set", setting, "-o", "x.mcap"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert len(errors) == 1 and "clutter peaks a scan" in errors[0], res.output
    assert not Path("x.mcap").exists()


def test_a_design_value_a_tracker_refuses_is_that_trackers_failure(runner, tmp_path):
    # the scenario accepts a zero process noise; the multi-target trackers' Param refuses it: one line
    # naming the file (was: an internal error), the trackers that can run still write
    assert runner.invoke(main, ["simulate", "radar-multi", "--runs", "2", "--set", "n_scans=20",
                                "--set", "design_process_noise_m2ps3=0", "-o", "m.mcap"]).exit_code == 0
    res = runner.invoke(main, ["m.mcap", "--no-rrd", "--out", "o/t.mcap", "--figures", "none"])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert errors and all("m.mcap" in e and "design_process_noise_m2ps3" in e for e in errors), res.output
    assert "Traceback" not in res.output and "internal error" not in res.output


def test_an_array_grid_finer_than_memory_allows_is_refused(runner, tmp_path):
    assert runner.invoke(main, ["simulate", "array-crossing", "--runs", "1", "--set", "n_scans=5",
                                "-o", "a.mcap"]).exit_code == 0
    res = runner.invoke(main, ["a.mcap", "--no-rrd", "--out", "o/t.mcap", "--set", "music_grid_step_deg=1e-6"])
    assert res.exit_code == 2, res.output
    assert "music_grid_step_deg" in res.stderr and not Path("o/t.mcap").exists()


def test_a_killed_writers_temporary_goes_at_the_next_write(tmp_path):
    # simulate and convert write through atomic_output: a writer killed mid-write left
    # NAME.<random>.tmp that nothing removed; its process id in the name now marks it as stale
    import subprocess
    import sys
    import time

    from trackreplay.contract import atomic_output

    out = tmp_path / "data.mcap"
    code = (f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})\n"
            "from trackreplay.contract import atomic_output\n"
            f"with atomic_output({str(out)!r}) as f:\n    f.write(b'half'); f.flush(); import time; time.sleep(60)\n")
    child = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.monotonic() + 30
    while not list(tmp_path.glob("data.mcap.*.tmp")) and time.monotonic() < deadline:
        time.sleep(0.05)
    child.kill()
    child.wait()
    assert len(list(tmp_path.glob("data.mcap.*.tmp"))) == 1 and not out.exists()
    (tmp_path / "data.mcap.notapid.x.tmp").write_bytes(b"mine")  # not a writer's: left alone
    with atomic_output(out) as f:
        f.write(b"whole")
    assert out.read_bytes() == b"whole"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.mcap", "data.mcap.notapid.x.tmp"]


def test_eval_export_and_compare_replace_an_earlier_runs_outputs_only_when_asked(runner):
    # as replay does: a second run into the same folder is refused with one line naming it, and
    # --force replaces the set; compare's default folder moves on to compare-2
    assert runner.invoke(main, ["simulate", "radar-tws", "--runs", "5", "--set", "n_scans=20", "-o",
                                "small.mcap"]).exit_code == 0
    radar_small = Path("small.mcap").resolve()
    assert runner.invoke(main, [str(radar_small), "--no-rrd", "--out", "a/t.mcap", "--figures", "none"]).exit_code == 0
    assert runner.invoke(main, [str(radar_small), "--no-rrd", "--out", "b/t.mcap", "--figures", "none",
                                "--set", "sigma_bearing_deg=1.5"]).exit_code == 0
    for args in (["eval", str(radar_small), "a/t.mcap", "--export", "x"],
                 ["compare", "a/t.mcap", "b/t.mcap", "--data", str(radar_small), "-o", "c"]):
        first = runner.invoke(main, args)
        assert first.exit_code == 0, first.output
        before = {p.name: p.resolve().read_bytes() for p in Path(args[-1]).iterdir() if not p.name.startswith(".")}
        res = runner.invoke(main, args)
        assert res.exit_code == 2 and "add --force" in res.stderr and args[-1] in res.stderr, res.output
        assert {p.name: p.resolve().read_bytes() for p in Path(args[-1]).iterdir() if not p.name.startswith(".")} == before
        assert runner.invoke(main, [*args, "--force"]).exit_code == 0
    Path("replay-out/compare").mkdir(parents=True)
    Path("replay-out/compare/compare.csv").write_text("an earlier comparison")
    assert runner.invoke(main, ["compare", "a/t.mcap", "b/t.mcap", "--data", str(radar_small)]).exit_code == 0
    assert Path("replay-out/compare/compare.csv").read_text() == "an earlier comparison"
    assert (Path("replay-out") / "compare-2" / "compare.csv").exists()


@pytest.mark.parametrize("setting", ["nominal_cross_range_m=0", "subspace_tracker=nope"])
def test_a_design_value_refused_by_a_tracker_names_the_file(runner, radar_small, setting):
    # the check lives in the tracker; its one line still names the data set it was replaying
    data = radar_small if setting.startswith("nominal") else None
    if data is None:
        assert runner.invoke(main, ["simulate", "array-crossing", "--runs", "1", "--set", "n_scans=5",
                                    "-o", "a.mcap"]).exit_code == 0
        data = Path("a.mcap")
    res = runner.invoke(main, [str(data), "--no-rrd", "--out", "o/t.mcap", "--figures", "none", "--set", setting])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("replay: error: ")]
    assert errors and all(f"{data.name}:" in e and setting.split("=")[0] in e for e in errors), res.output


def test_a_reader_that_goes_away_is_no_error():
    """`replay trackers | head -1`: the pipe's reader closed before the output ends, so replay
    stops as a Unix tool does (exit 141, 128 + SIGPIPE) and prints nothing on stderr."""
    import os
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    os.close(read_end)  # a reader that has already gone: the first write finds no one
    try:
        done = subprocess.run([sys.executable, "-m", "trackreplay.face.cli", "trackers"], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert done.returncode == 141 and done.stderr == ""
