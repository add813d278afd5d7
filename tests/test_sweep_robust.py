"""Sweeps under stress: honest resume, interruption (Ctrl-C, SIGTERM, SIGKILL), stale files.

* ``--resume`` reuses a point only when its record (every scenario parameter, runs, seed,
  trackers, plugged trackers' specs and file hashes, package version) is the task's; a folder
  holding another sweep is refused in one line naming what changed; damaged files are
  computed again, never a traceback.
* A sweep stopped by SIGINT, SIGTERM or SIGKILL keeps its finished points and leaves no process
  behind (process pool and Dask), no temporaries (or the next sweep removes them), and the
  resumed sweep's table equals an uninterrupted one.
* A point whose worker process dies is that point's failure; the other points finish. A full
  disk stops the sweep with one line naming the file (exit 2), and no point leaves data behind.
"""

from __future__ import annotations

import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
import uuid
from pathlib import Path

import polars as pl
import psutil
import pytest
from click.testing import CliRunner

from trackreplay import sweep as sw
from trackreplay.face.cli import main

SORT = ["point_index", "tracker", "metric"]
SMALL = {"sigma_bearing_deg": ["0.5", "1"]}


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def sweep_args(out, *extra, runs=3, seed=7, param="sigma_bearing_deg=0.5,1"):
    return ["sweep", "radar-tws", "--param", param, "--runs", runs, "--seed", seed, "--executor", "serial",
            "--no-keep-data", "-o", out, *extra]


def reference(specs, runs, seed, **kw):
    tasks = sw.build_grid("radar-tws", specs, runs, seed, None, None, keep_data=False, **kw)
    rep = sw.run_sweep(tasks, list(specs), None, "serial")
    assert not rep.failed, rep.failed
    return rep.table.sort(SORT)


def stored(out: Path) -> pl.DataFrame:
    return pl.read_parquet(out / "sweep.parquet").sort(SORT)


def one_error_line(res) -> str:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    lines = message_lines(res.stderr)
    assert len(lines) == 1 and lines[0].startswith("replay: error: "), res.stderr
    return lines[0]


def notes(res) -> list[str]:
    return [ln for ln in res.stderr.splitlines() if ln.startswith("resume: ")]


# --------------------------------------------------------------------------- honest resume


def _no_plot(wide, x, metrics, path, **kwargs):
    return path


@pytest.fixture(autouse=True)
def no_plots(monkeypatch):
    """The in-process sweeps skip the PNGs (a second each; what is tested here is the table)."""
    monkeypatch.setattr("trackreplay.evaluators.report_plots.plot_metrics_vs", _no_plot)


@pytest.fixture(scope="module")
def done_once(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("done") / "s"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("trackreplay.evaluators.report_plots.plot_metrics_vs", _no_plot)
        res = cli(*sweep_args(out))
    assert res.exit_code == 0, res.output
    return out


@pytest.fixture
def done(done_once, tmp_path) -> Path:
    """A finished two-point sweep (runs 3, seed 7) in ``tmp_path/s`` (a copy: tests change it)."""
    out = tmp_path / "s"
    shutil.copytree(done_once, out)
    return out


@pytest.mark.parametrize("change, fragment", [
    (dict(runs=4), "runs 3 → 4"),
    (dict(seed=8), "seed 7 → 8"),
    (dict(param="sigma_bearing_deg=0.5,2"), "--param sigma_bearing_deg 0.5,1 → 0.5,2"),
    (dict(param="nominal_cross_range_m=120,150"), "--param nominal_cross_range_m - → 120,150"),
])
def test_resume_into_a_folder_of_another_sweep_is_refused(done, change, fragment, sha):
    before = sha(done / "sweep.parquet")
    line = one_error_line(cli(*sweep_args(done, "--resume", **change)))
    assert fragment in line and "--resume" in line
    assert sha(done / "sweep.parquet") == before  # the other sweep's table is left alone


def test_resume_with_a_fixed_value_changed_is_refused(done):
    line = one_error_line(cli(*sweep_args(done, "--resume", "--set", "n_scans=20")))
    assert "--set n_scans - → 20" in line


def test_resume_of_the_same_sweep_reuses_every_point(done):
    table = stored(done)
    res = cli(*sweep_args(done, "--resume"))
    assert res.exit_code == 0, res.output
    assert "0 done, 2 resumed" in res.output and not notes(res)
    assert stored(done).equals(table)


@pytest.mark.parametrize("change, fragment, runs, seed", [
    (dict(runs=4), "runs 3 → 4", 4, 7),
    (dict(seed=8), "seed 7 → 8", 3, 8),
])
def test_interrupted_sweep_resumed_with_other_settings_computes_every_point(done, change, fragment, runs, seed):
    (done / "sweep.json").unlink()  # a first sweep that was stopped has no sweep.json yet
    res = cli(*sweep_args(done, "--resume", **change))
    assert res.exit_code == 0, res.output
    assert "2 done, 0 resumed" in res.output
    assert notes(res) == [f"resume: computing 2 points again: {fragment}"]
    assert stored(done).equals(reference(SMALL, runs, seed))
    assert json.loads((done / "sweep.json").read_text())["runs"] == runs


def test_other_package_version_computes_points_again(done, monkeypatch):
    table = stored(done)
    from trackreplay.sweep import grid, outputs

    for module in (grid, outputs):  # the point records and sweep.json
        monkeypatch.setattr(module, "__version__", "9.9.9")
    res = cli(*sweep_args(done, "--resume"))
    assert res.exit_code == 0, res.output
    assert "2 done, 0 resumed" in res.output
    from trackreplay import __version__

    assert notes(res) == [f"resume: computing 2 points again: package version {__version__} → 9.9.9"]
    assert stored(done).equals(table)
    assert json.loads((done / "points" / "sigma_bearing_deg=1" / "point.json").read_text())["version"] == "9.9.9"


def test_grid_extended_after_an_interruption_reuses_the_points_it_has(done):
    (done / "sweep.json").unlink()
    res = cli(*sweep_args(done, "--resume", param="sigma_bearing_deg=0.25,0.5,1"))
    assert res.exit_code == 0, res.output
    assert "1 done, 2 resumed" in res.output
    # the reused points take their place (point_index) in the new grid
    assert stored(done).equals(reference({"sigma_bearing_deg": ["0.25", "0.5", "1"]}, 3, 7))


@pytest.mark.parametrize("damage, fragment", [
    (lambda p: p.write_bytes(b"PAR1 this is not parquet"), "metrics.parquet unreadable"),
    (lambda p: p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2]), "metrics.parquet unreadable"),
    (lambda p: p.with_name("point.json").write_text("{not json"), "point.json unreadable"),
    (lambda p: p.with_name("point.json").unlink(), "no point.json"),
])
def test_damaged_point_files_are_computed_again(done, damage, fragment):
    table = stored(done)
    damage(done / "points" / "sigma_bearing_deg=1" / "metrics.parquet")
    res = cli(*sweep_args(done, "--resume"))
    assert res.exit_code == 0, res.output
    assert "Traceback" not in res.output
    assert "1 done, 1 resumed" in res.output
    assert len(notes(res)) == 1 and "point sigma_bearing_deg=1" in notes(res)[0] and fragment in notes(res)[0]
    assert stored(done).equals(table)


def test_damaged_sweep_json_gives_one_line(done):
    (done / "sweep.json").write_text("[")
    line = one_error_line(cli(*sweep_args(done, "--resume")))
    assert "sweep.json" in line


def test_record_names_what_changed():
    tasks = sw.build_grid("radar-tws", SMALL, 3, 7, None, None, keep_data=False)
    other = sw.build_grid("radar-tws", SMALL, 3, 7, None, None, keep_data=False, fixed={"n_scans": "20"})
    assert sw.record_changes(tasks[0].record(), other[0].record()) == ["n_scans 64 → 20"]
    assert sw.record_changes(tasks[0].record(), tasks[0].record()) == []


TRACKER = textwrap.dedent('''
    import numpy as np
    from trackreplay import vocabulary as vocab
    from trackreplay.trackers.interface import Tracker


    class FirstPlot(Tracker):
        name = "first_plot"
        family = "radar"
        form = "run"

        def track_run(self, plots):
            r, b = plots.range_m[:, 0], plots.bearing_rad[:, 0]
            have = plots.counts > 0
            x, y = r * np.cos(b), r * np.sin(b)
            state = np.stack([x, y, np.zeros_like(x), np.zeros_like(x)], axis=-1)
            state[~have] = np.nan
            return {"state": state, "flags": np.where(have, 0, vocab.NO_TRACK).astype(np.uint16)}


    class Other(FirstPlot):
        name = "other_plot"
''')


def test_plugged_tracker_spec_and_file_are_part_of_a_point(tmp_path):
    plugged = tmp_path / "mine.py"
    plugged.write_text(TRACKER)
    out = tmp_path / "s"
    res = cli(*sweep_args(out, "--tracker", f"{plugged}:FirstPlot"))
    assert res.exit_code == 0, res.output
    assert "first_plot" in set(stored(out)["tracker"])
    # another plugged tracker: another sweep
    line = one_error_line(cli(*sweep_args(out, "--resume", "--tracker", f"{plugged}:Other")))
    assert "tracker_specs" in line
    # the same spec, its file edited: every point again, saying why
    plugged.write_text(TRACKER + "\n# edited\n")
    res = cli(*sweep_args(out, "--resume", "--tracker", f"{plugged}:FirstPlot"))
    assert res.exit_code == 0, res.output
    assert "2 done, 0 resumed" in res.output
    assert notes(res) == [f"resume: computing 2 points again: tracker file {plugged} edited"]


def test_stale_temporaries_are_removed_by_the_next_sweep(done):
    stale = [done / "sweep.parquet.k3j_x9q2.tmp", done / "plots" / "mota.png.abcdefgh.tmp",
             done / "points" / "sigma_bearing_deg=1" / "metrics.parquet.0a1b2c3d.tmp"]
    keep = done / "notes.tmp"  # not one of ours
    for f in stale + [keep]:
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_bytes(b"half")
    res = cli(*sweep_args(done, "--resume"))
    assert res.exit_code == 0, res.output
    assert not any(f.exists() for f in stale) and keep.exists()


def test_a_second_sweep_into_a_busy_folder_is_refused(done):
    import fcntl

    fd = os.open(done, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a running sweep holds it
        line = one_error_line(cli(*sweep_args(done, "--resume")))
        assert "another sweep is writing to this folder" in line
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- interruption


RANDOM_KILL_SPECS = {"sigma_bearing_deg": ["0.5", "1", "2", "3"]}
RANDOM_KILL_RUNS = 5


def start_sweep(out: Path, marker: str, executor: str, *extra, runs=RANDOM_KILL_RUNS, specs=RANDOM_KILL_SPECS):
    cmd = [sys.executable, "-m", "trackreplay.face.cli", "sweep", "radar-tws",
           *[a for n, v in specs.items() for a in ("--param", f"{n}={','.join(v)}")],
           "--runs", str(runs), "--seed", "11", "--executor", executor, "--workers", "2", "-o", str(out), *extra]
    env = dict(os.environ, SWEEP_ROBUST_MARKER=marker)
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, start_new_session=True)


def marked(marker: str) -> list[psutil.Process]:
    """Every live process that inherited the marker (the sweep's whole tree, orphans included)."""
    found = []
    for p in psutil.process_iter():
        try:
            if p.environ().get("SWEEP_ROBUST_MARKER") == marker and p.status() != psutil.STATUS_ZOMBIE:
                found.append(p)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            pass
    return found


def kill_and_check(proc, sig, marker: str, group: bool = False) -> tuple[int, str]:
    """Send ``sig`` to the sweep (its pid, or its process group as a terminal's Ctrl-C does),
    wait for it, and check that none of its processes is left after a few seconds."""
    try:
        tree = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        tree = []
    (os.killpg if group else os.kill)(proc.pid, sig)
    out, err = proc.communicate(timeout=60)
    _, alive = psutil.wait_procs(tree, timeout=15)
    deadline = time.monotonic() + 15
    left = marked(marker)
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = marked(marker)
    for p in {*alive, *left}:  # do not leave them to the next test
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass
    assert not alive, f"children of the killed sweep still alive: {[p.pid for p in alive]}"
    assert not left, f"processes of the killed sweep still alive: {[p.pid for p in left]}"
    return proc.returncode, err.decode()


def message_lines(stderr: str) -> list[str]:
    """stderr without the progress label and blank lines."""
    return [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("sweep radar-tws (")]


def temporaries(out: Path) -> list[Path]:
    return sorted(out.rglob("*.tmp")) if out.exists() else []


def finished(out: Path) -> set[str]:
    return {p.parent.name for p in out.glob("points/*/point.json")}


def test_kill_at_random_moments_then_resume_equals_an_uninterrupted_sweep(tmp_path):
    """SIGKILL, SIGTERM and SIGINT of the sweep's own pid at seeded random moments: no process
    left, finished points kept, and the resumed table equals an uninterrupted sweep's."""
    rng = random.Random(20240611)
    out = tmp_path / "study"
    marker = uuid.uuid4().hex
    signals = [signal.SIGKILL, signal.SIGTERM, signal.SIGINT, signal.SIGKILL, signal.SIGTERM]
    rng.shuffle(signals)
    expected_rc = {signal.SIGKILL: -signal.SIGKILL, signal.SIGTERM: 128 + signal.SIGTERM, signal.SIGINT: 130}
    t_start = time.monotonic()
    for i, sig in enumerate(signals):
        kept = finished(out)
        proc = start_sweep(out, marker, "process", *(["--resume"] if i else []))
        # a random moment: from start-up (pool and imports) through the points to the plots
        time.sleep(rng.uniform(0.8, 5.0))
        if proc.poll() is not None:  # finished before the moment came: nothing to stop
            assert proc.wait() == 0, proc.stderr.read().decode()
            continue
        rc, err = kill_and_check(proc, sig, marker)
        if rc == 0:  # finished between the poll and the signal
            continue
        if sig == signal.SIGTERM and rc == -signal.SIGTERM and not err:
            # it came while the interpreter was still importing, before the sweep set its
            # handlers: the default action, with nothing begun (no line, nothing written)
            assert kept <= finished(out) and not temporaries(out), temporaries(out)
            continue
        assert rc == expected_rc[sig], (sig, rc, err)
        assert kept <= finished(out), "a finished point was lost"
        if sig != signal.SIGKILL:  # stopped cleanly: one line, nothing half-written
            assert "Traceback" not in err, err
            lines = message_lines(err)
            assert lines == (["replay: interrupted"] if sig == signal.SIGINT
                             else ["sweep: stopped by SIGTERM; finished points are kept"]), err
            assert not temporaries(out), temporaries(out)
    kept = finished(out)
    proc = start_sweep(out, marker, "process", "--resume")
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr.decode()
    assert f"{len(kept)} resumed" in stdout.decode(), stdout.decode()
    assert not temporaries(out), temporaries(out)  # including what a SIGKILL left
    assert not marked(marker)
    want = reference(RANDOM_KILL_SPECS, RANDOM_KILL_RUNS, 11)
    assert stored(out).equals(want)
    assert time.monotonic() - t_start < 90


@pytest.mark.parametrize("executor", ["process", "dask"])
def test_ctrl_c_keeps_finished_points_leaves_nothing_and_says_one_line(tmp_path, executor):
    """SIGINT to the whole process group, as a terminal sends it, once a point has finished."""
    out = tmp_path / "s"
    marker = uuid.uuid4().hex
    specs = {"sigma_bearing_deg": ["0.5", "1", "2", "3", "4", "5"]}
    proc = start_sweep(out, marker, executor, runs=60, specs=specs)
    deadline = time.monotonic() + 60
    while not finished(out) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert proc.poll() is None, "the sweep ended before it could be interrupted"
    kept = finished(out)
    rc, err = kill_and_check(proc, signal.SIGINT, marker, group=True)
    assert rc == 130, err
    assert message_lines(err) == ["replay: interrupted"], err
    assert not temporaries(out), temporaries(out)
    assert kept and kept <= finished(out) and len(finished(out)) < len(specs["sigma_bearing_deg"])
    for label in finished(out):  # every kept point is whole
        assert pl.read_parquet(out / "points" / label / "metrics.parquet").height > 0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_killed_dask_sweep_leaves_no_workers(tmp_path, sig):
    out = tmp_path / "s"
    marker = uuid.uuid4().hex
    specs = {"sigma_bearing_deg": ["0.5", "1", "2", "3", "4", "5"]}
    proc = start_sweep(out, marker, "dask", runs=60, specs=specs)
    deadline = time.monotonic() + 60
    while not finished(out) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert proc.poll() is None, "the sweep ended before it could be killed"
    rc, err = kill_and_check(proc, sig, marker)
    assert rc == (128 + sig if sig == signal.SIGTERM else -sig), err
    if sig == signal.SIGTERM:
        assert message_lines(err) == ["sweep: stopped by SIGTERM; finished points are kept"], err
        assert not temporaries(out), temporaries(out)


# --------------------------------------------------------------------------- lost workers, full disks


DOOMED = '''
import os, signal
import numpy as np
from trackreplay.trackers.interface import Param, Tracker


class Doomed(Tracker):
    """Kills the process that runs it (its parent: the sweep's worker) where doom > 0."""

    name, family = "doomed", "radar"
    params = (Param("doom", 0.0),)

    def track(self, plots):
        if self.doom > 0:
            os.kill(os.getppid(), signal.SIGKILL)
        r, b = plots.range_m[..., 0], plots.bearing_rad[..., 0]
        z = np.stack([r * np.cos(b), r * np.sin(b)], axis=-1)
        state = np.concatenate([z, np.zeros_like(z)], axis=-1)
        return {"state": state, "flags": np.zeros(state.shape[:2], np.uint16)}
'''


def point_data(out: Path) -> list[Path]:
    """Every file a point writes (data set, outputs, recording), half-written ones included."""
    return sorted(p for p in out.rglob("*") if p.is_file() and p.name.split(".")[0] in ("data", "tracks"))


def test_a_point_whose_worker_dies_is_that_points_failure_and_the_others_finish(tmp_path):
    """A worker killed under a point (here by the point's own tracker) broke the whole pool
    (BrokenProcessPool, exit 3, data left behind): now that point fails by name, every other
    point finishes, and the failed points leave nothing."""
    (tmp_path / "doomed.py").write_text(DOOMED)
    out = tmp_path / "s"
    marker = uuid.uuid4().hex
    specs = {"doom": ["0", "1"], "sigma_bearing_deg": ["0.5", "1"]}
    proc = start_sweep(out, marker, "process", "--tracker", str(tmp_path / "doomed.py") + ":Doomed", runs=3,
                       specs=specs)
    try:
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    err = stderr.decode()
    assert proc.returncode == 1, err
    assert "Traceback" not in err and "BrokenProcessPool" not in err
    failed = sorted(ln for ln in message_lines(err))
    assert failed == [f"FAILED doom=1,sigma_bearing_deg={s}: its worker process ended (killed by SIGKILL) while "
                      "computing it" for s in ("0.5", "1")], err
    assert finished(out) == {"doom=0,sigma_bearing_deg=0.5", "doom=0,sigma_bearing_deg=1"}
    assert "2 done, 0 resumed, 2 failed" in stdout.decode()
    assert {p.parent.name for p in point_data(out)} == finished(out)  # nothing of the failed points
    assert pl.read_parquet(out / "sweep.parquet")["point"].unique().sort().to_list() == sorted(finished(out))
    assert not marked(marker)


def run_with_file_size_limit(limit: int, args, timeout=240):
    """The command line under RLIMIT_FSIZE (every file it writes stops at ``limit`` bytes, as on a
    disk that fills up), with SIGXFSZ ignored so that a write beyond it fails with EFBIG."""
    import resource

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    cmd = [sys.executable, "-m", "trackreplay.face.cli", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, preexec_fn=limited)


@pytest.mark.parametrize("limit, file", [(10_000, "data.mcap"), (100_000, "tracks.mcap")])
@pytest.mark.parametrize("executor", ["serial", "process"])
def test_a_sweep_on_a_full_disk_stops_with_one_line_and_leaves_no_point_data(tmp_path, executor, limit, file):
    """Four FAILED lines, exit 1 and the points' data left behind before; now one line naming
    the file, exit 2, and nothing of the points (their data sets are 27 kB, outputs 165 kB)."""
    out = tmp_path / "s"
    done = run_with_file_size_limit(limit, ["sweep", "radar-tws", "--param", "sigma_bearing_deg=0.5,1,2,3", "--runs",
                                            "3", "--executor", executor, "--workers", "2", "-o", out])
    assert done.returncode == 2, done.stderr
    lines = message_lines(done.stderr)
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert re.fullmatch(rf"replay: error: {re.escape(str(out))}/points/sigma_bearing_deg=[0-9.]+/{re.escape(file)}: "
                        r"File too large; the sweep stopped \(finished points kept: 0; the unfinished ones leave "
                        r"nothing\)", lines[0]), lines[0]
    assert point_data(out) == [] and not temporaries(out)
    assert not (out / "points").exists()


def test_a_stop_landing_in_a_finalizer_prints_no_traceback(monkeypatch):
    # a worker's SIGTERM (or Rerun's recording stream flushing in __del__ after its save) inside a
    # finalizer: Python would print "Exception ignored … Traceback" on the sweep's stderr
    from types import SimpleNamespace

    from trackreplay.sweep import executors as sw

    reported = []
    monkeypatch.setattr(sys, "__unraisablehook__", reported.append)

    class RecordingStream:
        def __del__(self):
            pass

    sw._quiet_when_stopped(SimpleNamespace(exc_value=sw._WorkerStop(143), object=None))
    sw._quiet_when_stopped(SimpleNamespace(exc_value=RuntimeError("flush"), object=RecordingStream.__del__))
    assert reported == []
    other = SimpleNamespace(exc_value=ValueError("a bug of ours"), object=None)
    sw._quiet_when_stopped(other)
    assert reported == [other]
