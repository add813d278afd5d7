"""A replay's outputs appear as a set: a replay killed at any moment leaves the complete previous
set or the complete new one, never a mix, and leaves nothing the next run does not clean
(``pipeline/paths.py``, ``OutputSet``: the set is published with one rename of a link)."""

from __future__ import annotations

import hashlib
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from trackreplay.paths import OutputSet

REPO = Path(__file__).resolve().parents[1]
# two sets that differ in their bytes and in their names (b has a recording, a does not)
SETTINGS = {"a": ["--set", "nominal_cross_range_m=150", "--no-rrd"], "b": ["--set", "nominal_cross_range_m=120"]}
STEPS = ("links", "swap", "swapped", "done")  # the publish steps with a hook (trackreplay.paths._pause)


def _command(data: Path, out: Path, key: str) -> list[str]:
    return [sys.executable, "-m", "trackreplay.face.cli", str(data), "--out", str(out / "tracks.mcap"), "--force",
            "--figures", "none", *SETTINGS[key]]


def _digest(folder: Path) -> dict:
    """What a reader sees: every name that opens as a file (links followed), with its bytes' hash
    (a Rerun recording differs from run to run in its ids and times: only its presence counts,
    and only set b has one)."""
    out = {}
    for p in sorted(folder.iterdir()):
        if p.name.startswith(".") or not p.is_file():
            continue
        try:
            out[p.name] = "present" if p.suffix == ".rrd" else hashlib.sha256(p.read_bytes()).hexdigest()
        except FileNotFoundError:  # the name went between listing and reading
            out[p.name] = None
    return out


def _which(files: dict, references: dict) -> str | None:
    """The set a reader sees ("none" before the first one is published), or None for a mix."""
    match = [k for k, ref in {"none": {}, **references}.items() if files == ref]
    return match[0] if match else None


@pytest.fixture(scope="module")
def reference_sets(tmp_path_factory, radar_small):
    sets, durations = {}, []
    for key in SETTINGS:
        out = tmp_path_factory.mktemp(f"ref_{key}")
        t0 = time.perf_counter()
        subprocess.run(_command(radar_small, out, key), check=True, capture_output=True, cwd=REPO)
        durations.append(time.perf_counter() - t0)
        sets[key] = _digest(out)
    assert sets["a"] != sets["b"] and set(sets["a"]) != set(sets["b"])
    return sets, min(durations)


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_a_killed_replay_leaves_the_old_set_or_the_new_one(tmp_path, radar_small, reference_sets):
    references, duration = reference_sets
    out = tmp_path / "out"
    rng = random.Random(11)
    mixed, kills = 0, 0
    for i in range(6):
        proc = subprocess.Popen(_command(radar_small, out, "ab"[i % 2]), cwd=REPO,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # kill times spread over a whole replay, whatever this machine's speed (start-up,
        # computing, writing the set): some land before the end
        time.sleep(rng.uniform(0.05, 1.3) * duration)
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            kills += 1
        proc.wait()
        files = _digest(out) if out.exists() else {}
        mixed += _which(files, references) is None
    assert mixed == 0
    assert kills >= 2  # the schedule really interrupted replays
    _a_complete_run_cleans_up(radar_small, out, references)


def _a_complete_run_cleans_up(data, out, references) -> str:
    done = subprocess.run(_command(data, out, "a"), capture_output=True, text=True, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert _digest(out) == references["a"]
    # only the published version and its link stay hidden
    hidden = _hidden(out)
    assert len(hidden) == 2 and hidden[0] == ".replay-current" and hidden[1] == os.readlink(out / hidden[0])
    return done.stderr


def test_kills_timed_to_the_publish_step_never_leave_a_mix(tmp_path, radar_small, reference_sets):
    """Each replay pauses at one step of publishing (a test hook); the folder is read there,
    then the process is killed at that step or a moment after it (``TIMED_KILLS`` kills; the
    default keeps the suite fast, the report's figure came from a larger value)."""
    references, _ = reference_sets
    out = tmp_path / "out"
    rng = random.Random(7)
    n_kills = int(os.environ.get("TRACKREPLAY_TIMED_KILLS", "8"))
    kills, mixed, seen_mixed, at_step, seen = 0, 0, 0, {s: 0 for s in STEPS}, []
    for i in range(n_kills):
        step = STEPS[i % len(STEPS)]
        trace = tmp_path / f"trace{i}"
        env = {**os.environ, "TRACKREPLAY_PUBLISH_TRACE": str(trace), "TRACKREPLAY_PUBLISH_PAUSE_S": "0.3"}
        now = _which(_digest(out), references) if out.exists() else "none"
        key = "a" if now != "a" else "b"  # always the other set, so that a mix would show
        proc = subprocess.Popen(_command(radar_small, out, key), cwd=REPO, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            if trace.exists() and step in trace.read_text().split():
                break
            time.sleep(0.005)
        assert proc.poll() is None, "the replay ended before its publish step"
        # an instant inside the publish: what a reader sees now
        seen_mixed += _which(_digest(out), references) is None
        time.sleep(rng.uniform(0.0, 0.35))  # in the pause, or just after it (the next operation)
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            kills += 1
            at_step[step] += 1
        proc.wait()
        if _which(_digest(out), references) is None:
            mixed += 1
            seen.append((key, step, sorted(_digest(out).items()), sorted(os.listdir(out))))
    print(f"\ntimed kills {kills} / mixed sets {mixed} (mixed seen in the pauses: {seen_mixed}); by step {at_step}")
    assert mixed == 0 and seen_mixed == 0, seen
    assert kills >= n_kills * 3 // 4 and all(at_step.values())
    hidden = _hidden(out)
    dangling = [p for p in out.iterdir() if p.is_symlink() and not p.exists()]
    left = len(hidden) > 2 or bool(dangling) or (hidden and os.readlink(out / ".replay-current") not in hidden)
    said = _a_complete_run_cleans_up(radar_small, out, references)
    notes = [line for line in said.splitlines() if "removed what an interrupted run left" in line]
    assert len(notes) == (1 if left else 0), (hidden, dangling, said)


def test_an_output_set_never_removes_a_file_it_did_not_write(tmp_path):
    """Regular files, inputs and other sets' links in the folder stay, whatever their names; the
    previous set's links go with it; a failing run leaves the previous set."""
    folder = tmp_path / "o"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    (folder / "b.csv").write_text("an input named like an output")
    notes = []
    with OutputSet(folder, replaces=["b.csv", "c.csv"], inputs=[folder / "b.csv"], say=notes.append) as s:
        s.path("a.csv").write_text("1")
        s.path("c.csv").write_text("1")
    assert (folder / "a.csv").read_text() == "1" and (folder / "c.csv").is_symlink()
    with OutputSet(folder, replaces=["b.csv", "c.csv"], inputs=[folder / "b.csv"], say=notes.append) as s:
        s.path("a.csv").write_text("2")
    assert (folder / "a.csv").read_text() == "2"
    assert not (folder / "c.csv").exists() and not (folder / "c.csv").is_symlink()  # the old set's name went
    assert (folder / "notes.txt").read_text() == "mine" and (folder / "b.csv").read_text().startswith("an input")
    with pytest.raises(RuntimeError), OutputSet(folder, say=notes.append) as s:
        s.path("a.csv").write_text("3")
        raise RuntimeError("the run failed")
    assert (folder / "a.csv").read_text() == "2" and len(_hidden(folder)) == 2
    assert notes == []  # nothing was left to clean or kept


def test_a_regular_file_at_an_output_name_is_replaced_without_a_moment_of_absence(tmp_path):
    """An earlier run's regular file (a set made before links) keeps its bytes visible until the
    new set is published, and a regular file the new set does not produce is kept and named."""
    folder = tmp_path / "o"
    folder.mkdir()
    (folder / "a.csv").write_text("old")
    (folder / "errors.png").write_text("old figure")
    notes, seen = [], []
    os.environ["TRACKREPLAY_PUBLISH_TRACE"] = str(tmp_path / "trace")
    try:
        import trackreplay.paths as paths

        real_pause = paths._pause
        paths._pause = lambda step: seen.append((step, (folder / "a.csv").read_text()))
        with OutputSet(folder, replaces=["errors.png"], say=notes.append) as s:
            s.path("a.csv").write_text("new")
    finally:
        paths._pause = real_pause
        del os.environ["TRACKREPLAY_PUBLISH_TRACE"]
    assert seen == [("links", "old"), ("swap", "old"), ("swapped", "new"), ("done", "new")]
    assert (folder / "errors.png").read_text() == "old figure" and len(notes) == 1 and "errors.png" in notes[0]


def test_figures_drawn_later_join_the_set_and_leave_with_it(tmp_path, radar_small, monkeypatch):
    """``replay plot`` adds its figures to the published set (links into its version folder), so
    the next replay's set replaces them like the rest instead of leaving old figures beside it."""
    from click.testing import CliRunner

    from trackreplay.face.cli import main

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "o"
    run = ["--out", str(out / "tracks.mcap"), "--no-rrd", "--figures", "none"]
    assert CliRunner().invoke(main, [str(radar_small), *run]).exit_code == 0
    assert not (out / "report.png").exists()
    res = CliRunner().invoke(main, ["plot", str(radar_small), str(out / "tracks.mcap")])
    assert res.exit_code == 0, res.output
    version = out / os.readlink(out / ".replay-current")
    assert (out / "report.png").is_symlink() and (version / "report.png").is_file()
    assert CliRunner().invoke(main, [str(radar_small), *run, "--force"]).exit_code == 0
    assert not (out / "report.png").exists() and not (out / "report.png").is_symlink()
    assert len(_hidden(out)) == 2
