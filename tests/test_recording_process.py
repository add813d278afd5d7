"""The Rerun recording written by a second process (trackreplay.face.recording_process).

A recording made by the child must hold the same data as the one a replay makes in-process:
``rerun rrd compare`` (the Rerun CLI's own comparison, independent of our code) decides. A child
that fails must give one line and leave nothing; one that is not waited for must be stopped.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from trackreplay.contract import read_dataset
from trackreplay.errors import InputError
from trackreplay.face import recording_process
from trackreplay.face.recording_process import RecordingProcess
from trackreplay.replay import replay

REPO = Path(__file__).resolve().parents[1]


def same_recording(a, b) -> bool:
    """Whether two .rrd files hold the same data (log times aside), by the Rerun CLI.

    ``--unordered``: the SDK's batcher cuts and flushes chunks on a timer, so under load the same
    rows arrive in other chunks and another order (Rerun's data model is unordered); the rows
    themselves, every entity's and every component's values, are still compared.
    """
    done = subprocess.run([sys.executable, "-m", "rerun", "rrd", "compare", "--unordered", str(a), str(b)],
                          capture_output=True)
    return done.returncode == 0


@pytest.mark.parametrize("demo", ["radar_tws_demo.mcap", "array_crossing_demo.mcap", "tdoa_fdoa_demo.mcap"])
def test_the_child_draws_the_same_recording_as_the_replay_itself(demo, tmp_path):
    data = REPO / "data" / demo
    here = replay(data, rrd_path=tmp_path / "here.rrd", rerun_run=1)
    with RecordingProcess(data) as recorder:
        there = replay(data, rrd_path=tmp_path / "there.rrd", rerun_run=1, recorder=recorder)
    assert there.summary.equals(here.summary)
    assert same_recording(tmp_path / "here.rrd", tmp_path / "there.rrd")
    other = replay(data, rrd_path=tmp_path / "other.rrd", rerun_run=0)  # the comparison does tell them apart
    assert not same_recording(tmp_path / "there.rrd", other.rrd_path)


def test_what_the_child_computed_ahead_draws_the_same_recording(tmp_path):
    """The TDOA/FDOA views compute run 0's CEP plane in the child before the results arrive
    (their ``prepare``): the recording of run 0 drawn from it is the one drawn without it."""
    data = REPO / "data" / "tdoa_fdoa_demo.mcap"
    here = replay(data, rrd_path=tmp_path / "here.rrd", rerun_run=0)
    with RecordingProcess(data) as recorder:
        replay(data, rrd_path=tmp_path / "there.rrd", rerun_run=0, recorder=recorder)
    assert same_recording(here.rrd_path, tmp_path / "there.rrd")


def test_the_child_draws_with_the_designs_the_replay_used(tmp_path):
    data = REPO / "data" / "radar_tws_demo.mcap"
    override = {"nominal_cross_range_m": "120"}
    replay(data, rrd_path=tmp_path / "here.rrd", design_overrides=override)
    with RecordingProcess(data) as recorder:
        replay(data, rrd_path=tmp_path / "there.rrd", design_overrides=override, recorder=recorder)
    assert same_recording(tmp_path / "here.rrd", tmp_path / "there.rrd")


def test_a_child_that_cannot_write_gives_one_line_and_leaves_nothing(tmp_path):
    data = REPO / "data" / "radar_tws_demo.mcap"
    (tmp_path / "a_file").write_text("not a folder")
    with RecordingProcess(data) as recorder:
        with pytest.raises(OSError) as caught:
            replay(data, rrd_path=tmp_path / "a_file" / "tracks.rrd", recorder=recorder)
    # the file system's answer raised as in-process, so the command line words it the same way
    assert (caught.value.filename, caught.value.strerror) == (str(tmp_path / "a_file"), "File exists")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_a_child_refuses_an_input_replaced_between_the_two_reads(tmp_path):
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    data, other = tmp_path / "radar.mcap", tmp_path / "other.mcap"
    record(data, load_scenario("radar-tws"), runs=3, seed=1)
    record(other, load_scenario("radar-tws"), runs=3, seed=2)
    with RecordingProcess(data) as recorder:
        recorder.stamp_input()
        dataset = read_dataset(data)  # the replay's own read, before the file is replaced
        os.replace(other, data)
        with pytest.raises(InputError) as caught:
            replay(data, rrd_path=tmp_path / "tracks.rrd", dataset=dataset, recorder=recorder)
    assert "changed while it was replayed" in str(caught.value) and "\n" not in str(caught.value)
    assert not (tmp_path / "tracks.rrd").exists()


def test_a_child_left_unused_is_stopped(tmp_path):
    with RecordingProcess(REPO / "data" / "radar_tws_demo.mcap") as recorder:
        child = recorder._child
    assert child.poll() is not None
    assert list(tmp_path.iterdir()) == []


def test_a_stopped_child_exits_in_order_so_its_clean_ups_run():
    """``close()`` (Ctrl-C, an error) stops the child with SIGTERM, which it turns into an exit
    that unwinds: the recording's ``finally`` removes its temporary file, as in-process."""
    import signal
    import time

    with RecordingProcess(REPO / "data" / "radar_tws_demo.mcap") as recorder:
        time.sleep(1.0)  # inside its imports or waiting for the payload
        recorder._child.send_signal(signal.SIGTERM)
        assert recorder._child.wait(timeout=10) == 128 + signal.SIGTERM  # not -SIGTERM: not killed outright


def test_outputs_that_do_not_pickle_are_drawn_in_this_process(tmp_path, monkeypatch):
    data = REPO / "data" / "radar_tws_demo.mcap"

    def refuse(*args, **kwargs):
        raise TypeError("cannot pickle a plugged tracker's object")

    monkeypatch.setattr(recording_process.pickle, "dumps", refuse)
    with RecordingProcess(data) as recorder:
        replay(data, rrd_path=tmp_path / "tracks.rrd", recorder=recorder)
        assert recorder._child.poll() is not None  # stopped: it had nothing to draw
    replay(data, rrd_path=tmp_path / "here.rrd")
    assert same_recording(tmp_path / "here.rrd", tmp_path / "tracks.rrd")


def test_a_second_process_is_used_only_where_it_can_overlap_an_import(tmp_path, monkeypatch):
    small, large = tmp_path / "small.mcap", tmp_path / "large.mcap"
    small.write_bytes(b"x" * 1000)
    with open(large, "wb") as f:
        f.truncate(recording_process.LARGEST_INPUT_BYTES + 1)
    monkeypatch.delitem(sys.modules, "rerun", raising=False)
    assert recording_process.worth_it(small, cores=2)
    assert not recording_process.worth_it(small, cores=1)  # nothing to overlap it on
    assert not recording_process.worth_it(large, cores=2)  # the import is a small part of that wait
    assert not recording_process.worth_it(tmp_path / "missing.mcap", cores=2)
    monkeypatch.setitem(sys.modules, "rerun", object())
    assert not recording_process.worth_it(small, cores=2)  # already loaded: nothing to overlap


def test_the_command_line_records_a_small_replay_in_a_second_process(tmp_path):
    """A fresh ``replay`` on a small file waits for its child before the outputs appear, and
    its recording matches an in-process one."""
    data = REPO / "data" / "radar_tws_demo.mcap"
    done = subprocess.run([sys.executable, "-m", "trackreplay.face.cli", "-v", str(data), "--out",
                           str(tmp_path / "out" / "tracks.mcap"), "--figures", "none"],
                          capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "timing: rerun, drawn by a second process" in done.stderr
    replay(data, rrd_path=tmp_path / "here.rrd")
    assert same_recording(tmp_path / "here.rrd", tmp_path / "out" / "tracks.rrd")
    assert not any(p.name.startswith(".partial-") for p in (tmp_path / "out").iterdir())


def test_the_child_imports_this_process_package_not_one_in_the_working_folder(tmp_path, monkeypatch):
    """A ``pipeline`` folder of another project in the working folder must not shadow ours."""
    impostor = tmp_path / "pipeline"
    impostor.mkdir()
    (impostor / "__init__.py").write_text("raise ImportError('the wrong pipeline package')\n")
    monkeypatch.chdir(tmp_path)
    data = REPO / "data" / "radar_tws_demo.mcap"
    with RecordingProcess(data) as recorder:
        replay(data, rrd_path=tmp_path / "tracks.rrd", recorder=recorder)
    assert (tmp_path / "tracks.rrd").stat().st_size > 0


def test_a_child_that_cannot_start_leaves_the_recording_to_this_process(tmp_path, monkeypatch):
    data = REPO / "data" / "radar_tws_demo.mcap"
    monkeypatch.setattr(recording_process, "worth_it", lambda path: True)
    started = []

    def no_processes(*args, **kwargs):
        started.append(args)
        raise OSError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(recording_process.subprocess, "Popen", no_processes)
    assert recording_process.start(data) is None and len(started) == 1
    monkeypatch.setattr(recording_process.sys, "executable", "")  # an embedded interpreter
    assert recording_process.start(data) is None and len(started) == 1
