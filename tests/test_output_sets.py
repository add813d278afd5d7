"""A replay's outputs appear as a set: a replay killed at any moment leaves the complete previous
set or the complete new one, never a mix, and leaves nothing half-written behind."""

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

REPO = Path(__file__).resolve().parents[1]
SETTINGS = {"a": "nominal_cross_range_m=150", "b": "nominal_cross_range_m=120"}


def _command(data: Path, out: Path, setting: str) -> list[str]:
    return [sys.executable, "-m", "pipeline.face.cli", str(data), "--out", str(out / "tracks.mcap"), "--no-rrd",
            "--force", "--set", setting]


def _digest(folder: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture(scope="module")
def reference_sets(tmp_path_factory, radar_small):
    sets, durations = {}, []
    for key, setting in SETTINGS.items():
        out = tmp_path_factory.mktemp(f"ref_{key}")
        t0 = time.perf_counter()
        subprocess.run(_command(radar_small, out, setting), check=True, capture_output=True, cwd=REPO)
        durations.append(time.perf_counter() - t0)
        sets[key] = _digest(out)
    assert sets["a"] != sets["b"]
    return sets, min(durations)


def test_a_killed_replay_leaves_the_old_set_or_the_new_one(tmp_path, radar_small, reference_sets):
    reference_sets, duration = reference_sets
    out = tmp_path / "out"
    rng = random.Random(11)
    current, mixed, kills = None, 0, 0
    for i in range(8):
        key = "ab"[i % 2]
        proc = subprocess.Popen(_command(radar_small, out, SETTINGS[key]), cwd=REPO,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # kill times spread over a whole replay, whatever this machine's speed (start-up,
        # computing, writing the set): some land before the end
        time.sleep(rng.uniform(0.05, 1.3) * duration)
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            kills += 1
        proc.wait()
        files = _digest(out) if out.exists() else {}
        if files:
            match = [k for k, ref in reference_sets.items() if files == ref]
            mixed += not match
            current = match[0] if match else current
        assert not list(out.glob("*.tmp")) if out.exists() else True
    assert mixed == 0
    assert kills >= 2  # the schedule really interrupted replays
    # the next complete run clears what killed runs left in staging
    subprocess.run(_command(radar_small, out, SETTINGS["a"]), check=True, capture_output=True, cwd=REPO)
    assert _digest(out) == reference_sets["a"]
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == []
