"""A plugged tracker cannot decide for the tool (issue 30, item 5).

A plugged tracker runs in a child process (:mod:`trackreplay.isolation`): one that ends its
process (``os._exit``) in its constructor, in ``track()`` or in ``track_run()``, or that never
returns, is that tracker's failure: one line naming it, the other trackers' outputs written,
exit 2. A plugged file whose import ends the process or hangs is one line naming the file.
Ctrl-C still stops the whole replay with its one line and leaves no process behind.

Every replay here runs as a subprocess with a timeout, so a hang fails the test instead of
blocking the suite.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from trackreplay import design_values
from trackreplay.contract import read_dataset
from trackreplay.isolation import ChildEnded, ChildRaised, ChildTimedOut, run_in_child, run_plugged_tracker

REPO = Path(__file__).resolve().parents[1]

TRACKERS = '''
import os, sys, time
from pathlib import Path
import numpy as np
from trackreplay.trackers.interface import Tracker


def first_plot_states(plots):
    r, b = plots.range_m[..., 0], plots.bearing_rad[..., 0]
    z = np.stack([r * np.cos(b), r * np.sin(b)], axis=-1)
    state = np.concatenate([z, np.zeros_like(z)], axis=-1)
    return {"state": state, "flags": np.zeros(state.shape[:2], np.uint16)}


class Fine(Tracker):
    name, family = "fine", "radar"

    def track(self, plots):
        return first_plot_states(plots)


class OsExitInTrack(Tracker):
    name, family = "os_exit_in_track", "radar"

    def track(self, plots):
        os._exit(0)


class OsExitWhenBuilt(Tracker):
    name, family = "os_exit_when_built", "radar"

    def __init__(self, **design):
        super().__init__(**design)
        os._exit(0)

    def track(self, plots):
        raise AssertionError("never reached")


class OsExitInTrackRun(Tracker):
    name, family, form = "os_exit_in_track_run", "radar", "run"

    def track_run(self, plots):
        os._exit(5)


class SysExitInTrack(Tracker):
    name, family = "sys_exit_in_track", "radar"

    def track(self, plots):
        sys.exit(3)


class SleepsForever(Tracker):
    name, family = "sleeps_forever", "radar"

    def track(self, plots):
        Path(os.environ["TRACKER_STARTED"]).write_text(str(os.getpid()))
        while True:
            time.sleep(0.1)
'''


def replay(args, cwd, timeout=120, env=None):
    """``replay ARGS`` from the source tree as a subprocess: (exit status, stdout, stderr)."""
    cmd = [sys.executable, "-c", "import sys; sys.argv[0] = 'replay'; from trackreplay.face.cli import main; main()",
           *map(str, args)]
    env = {**os.environ, "PYTHONPATH": str(REPO), **(env or {})}
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    return done.returncode, done.stdout, done.stderr


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.strip()]


@pytest.fixture
def trackers_file(tmp_path) -> Path:
    path = tmp_path / "plugged.py"
    path.write_text(TRACKERS)
    return path


# one case per way of ending or hanging: (class, fragment of the one line)
TRACKER_CASES = [
    ("OsExitInTrack", "tracker 'os_exit_in_track': ended its process (exit status 0) instead of returning"),
    ("OsExitWhenBuilt", "tracker 'os_exit_when_built': ended its process (exit status 0) instead of returning"),
    ("OsExitInTrackRun", "tracker 'os_exit_in_track_run': ended its process (exit status 5) instead of returning"),
    ("SysExitInTrack", "tracker 'sys_exit_in_track': raised SystemExit: 3"),
    ("SleepsForever", "tracker 'sleeps_forever': did not finish within 2 s and was stopped"),
]


@pytest.mark.parametrize("cls, fragment", TRACKER_CASES)
def test_a_plugged_tracker_that_ends_or_hangs_fails_alone(radar_small, trackers_file, tmp_path, cls, fragment):
    """Beside a plugged tracker that works, so that 'the others' include a plugged one too."""
    t0 = time.monotonic()
    code, _, stderr = replay([radar_small, "--tracker", f"{trackers_file}:{cls}", "--tracker", f"{trackers_file}:Fine",
                              "--tracker-time-limit", "2", "--no-rrd", "--out", "o/tracks.mcap", "--figures", "none",
                              "-q"], tmp_path, env={"TRACKER_STARTED": str(tmp_path / "started")})
    took = time.monotonic() - t0
    assert code == 2, stderr
    lines = error_lines(stderr)
    assert len(lines) == 1 and lines[0].startswith("replay: error: ") and fragment in lines[0], stderr
    assert "plugged.py" in lines[0] and "Traceback" not in stderr
    written = read_dataset(tmp_path / "o" / "tracks.mcap").channels
    assert {"/tracks/radar/kalman", "/tracks/radar/fine"} <= set(written)
    assert not any(cls.lower() in topic.replace("_", "") for topic in written)
    if cls == "SleepsForever":  # stopped at its limit, not at the subprocess timeout
        assert took < 60
        pid = int((tmp_path / "started").read_text())
        assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE


@pytest.mark.parametrize("body, fragment", [
    ("import os\nos._exit(0)\n", "importing it ended the process (exit status 0)"),
    ("import os, signal\nos.kill(os.getpid(), signal.SIGKILL)\n", "importing it ended the process (killed by SIGKILL)"),
    ("import time\nwhile True:\n    time.sleep(0.1)\n", "importing it did not finish within 2 s and was stopped"),
])
def test_a_plugged_file_whose_import_ends_or_hangs_is_one_line_naming_it(radar_small, tmp_path, body, fragment):
    (tmp_path / "ends.py").write_text(body)
    code, stdout, stderr = replay([radar_small, "--tracker", "ends.py:Anything", "--tracker-time-limit", "2",
                                   "--no-rrd", "--out", "o/tracks.mcap", "--figures", "none", "-q"], tmp_path)
    assert code == 2, stderr
    lines = error_lines(stderr)
    assert lines == [f"replay: error: ends.py: {fragment} (--tracker-time-limit sets the limit; 0 lifts it)"
                     if "did not finish" in fragment else f"replay: error: ends.py: {fragment}"], stderr
    assert not (tmp_path / "o").exists()


def test_ctrl_c_stops_the_replay_and_the_plugged_trackers_process(radar_small, trackers_file, tmp_path):
    """SIGINT to the process group, as a terminal sends it, while a plugged tracker runs."""
    started = tmp_path / "started"
    cmd = [sys.executable, "-c", "import sys; sys.argv[0] = 'replay'; from trackreplay.face.cli import main; main()",
           str(radar_small), "--tracker", f"{trackers_file}:SleepsForever", "--no-rrd", "--out", "o/tracks.mcap",
           "--figures", "none", "-q"]
    env = {**os.environ, "PYTHONPATH": str(REPO), "TRACKER_STARTED": str(started)}
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not started.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert started.exists(), proc.communicate(timeout=5)
        child = int(started.read_text())
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert error_lines(stderr) == ["replay: interrupted"], stderr
    deadline = time.monotonic() + 10
    while psutil.pid_exists(child) and psutil.Process(child).status() != psutil.STATUS_ZOMBIE:
        assert time.monotonic() < deadline, "the tracker's process outlived the replay"
        time.sleep(0.05)
    assert not (tmp_path / "o" / "tracks.mcap").exists()


def test_a_plugged_trackers_child_dies_with_a_killed_replay(radar_small, trackers_file, tmp_path):
    """SIGKILL of the replay itself: no handler runs, the kernel ends the tracker's process."""
    started = tmp_path / "started"
    cmd = [sys.executable, "-c", "import sys; sys.argv[0] = 'replay'; from trackreplay.face.cli import main; main()",
           str(radar_small), "--tracker", f"{trackers_file}:SleepsForever", "--no-rrd", "--out", "o/tracks.mcap",
           "--figures", "none", "-q"]
    env = {**os.environ, "PYTHONPATH": str(REPO), "TRACKER_STARTED": str(started)}
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not started.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert started.exists()
        child = int(started.read_text())
    finally:
        proc.kill()
        proc.wait(timeout=30)
    deadline = time.monotonic() + 10
    while psutil.pid_exists(child) and psutil.Process(child).status() != psutil.STATUS_ZOMBIE:
        assert time.monotonic() < deadline, "the tracker's process outlived the killed replay"
        time.sleep(0.05)


# --------------------------------------------------------------------------- the child process itself


def test_arrays_come_back_equal_and_writable():
    rng = np.random.default_rng(4)
    sent = {"state": rng.normal(size=(7, 5, 4)), "flags": rng.integers(0, 9, (7, 5)).astype(np.uint32),
            "strided": rng.normal(size=(6, 6))[:, ::2], "empty": np.zeros((0, 3))}
    got = run_in_child(lambda: sent, 30)
    assert set(got) == set(sent)
    for key, value in sent.items():
        assert got[key].dtype == value.dtype and np.array_equal(got[key], value)
        got[key][...] = 0  # the evaluators may write into what a tracker returned


def test_a_plugged_trackers_outputs_through_the_child_equal_a_call_here(radar_small):
    """The child changes where the tracker runs, not what comes back: bit for bit."""
    from trackreplay.stages import applicable_stages
    from trackreplay.trackers.interface import call_tracker
    from trackreplay.trackers.radar_tws import TRACKERS as RADAR

    ds = read_dataset(radar_small)
    stage = next(s for s in applicable_stages(ds.channels) if s.family == "radar")
    design = design_values.resolve(stage, ds)
    measurements = stage.decode(ds, design)
    cls = next(c for c in RADAR if c.name == "kalman")
    values = {p.name: design[p.name] for p in cls.params}
    here = call_tracker(cls(**values), measurements)
    there = run_plugged_tracker("kalman", "test", lambda: call_tracker(cls(**values), measurements), 60)
    assert set(here) == set(there)
    for key in here:
        assert here[key].dtype == there[key].dtype and here[key].tobytes() == there[key].tobytes()


def test_what_the_child_raises_comes_back_with_its_file():
    from trackreplay.trackers.interface import TrackerError

    def fails():
        raise TrackerError("tracker 'x': run 3 scan 4: NaN state", "my_file.py")

    with pytest.raises(TrackerError) as caught:
        run_in_child(fails, 30)
    assert caught.value.path == "my_file.py" and caught.value.problem.endswith("NaN state")
    with pytest.raises(ChildRaised, match="ZeroDivisionError"):
        run_in_child(lambda: 1 / 0, 30)


@pytest.mark.parametrize("job, how", [
    (lambda: os._exit(7), "exit status 7"),
    (lambda: os.kill(os.getpid(), signal.SIGKILL), "killed by SIGKILL"),
])
def test_a_child_that_ends_says_how(job, how):
    with pytest.raises(ChildEnded) as caught:
        run_in_child(job, 30)
    assert caught.value.how == how


def test_a_child_that_ends_while_its_own_child_holds_the_pipe_is_seen_to_end():
    """No end of file comes while a grandchild holds the pipe open; the child's status says it ended."""
    def leaves_a_grandchild():
        if os.fork() == 0:  # the grandchild: lives on a little, then goes
            time.sleep(20)
            os._exit(0)
        os._exit(4)

    t0 = time.monotonic()
    with pytest.raises(ChildEnded, match="exit status 4"):
        run_in_child(leaves_a_grandchild, 15)
    assert time.monotonic() - t0 < 10


def test_a_child_over_its_limit_is_stopped_at_the_limit():
    t0 = time.monotonic()
    with pytest.raises(ChildTimedOut):
        run_in_child(lambda: time.sleep(60), 1.0)
    assert 0.9 < time.monotonic() - t0 < 10
