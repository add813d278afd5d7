"""Shared fixtures: small simulated data sets and an isolated home for the rerun CLI."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests draw the same examples on every run: a CI result is reproducible, and a
# counterexample found once stays found (run with HYPOTHESIS_PROFILE=explore to search anew).
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", max_examples=500)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

REPO = Path(__file__).resolve().parents[1]

# The files that take longest (10-80 s each on a 2-core machine), longest first. The two workers
# take whole files in collection order (`--dist loadfile --no-loadscope-reorder` in pyproject.toml),
# so these start first and the many short files fill in after them; one left to the end would keep
# one worker busy while the other has nothing left. Only the order changes: every test still runs.
LONGEST_FIRST = ("test_sweep_robust.py", "test_readme_commands.py", "test_plugged_trackers.py",
                 "test_output_paths_walk.py", "test_many_targets.py", "test_recording_process.py",
                 "test_loopback.py", "test_ux.py", "test_figures.py", "test_jpda_success.py", "test_fuzz.py",
                 "test_output_sets.py", "test_inputs_and_exits.py", "test_replay_streaming.py", "test_full_disk.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order


@pytest.fixture(autouse=True, scope="session")
def _isolated_rerun_home(tmp_path_factory):
    # The rerun CLI writes analytics state under the home directory.
    home = tmp_path_factory.mktemp("xdg")
    for var in ("XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_CACHE_HOME"):
        os.environ[var] = str(home)
    yield


@pytest.fixture
def runner(tmp_path, monkeypatch):
    """A click runner whose working directory is a fresh temporary folder."""
    from click.testing import CliRunner

    monkeypatch.chdir(tmp_path)
    return CliRunner()


@pytest.fixture
def sha():
    """SHA-256 of a file's bytes (to show an input was not modified)."""
    return lambda path: hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="session")
def radar_small(tmp_path_factory) -> Path:
    """A 30-run radar-tws data set written through the real recorder."""
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    path = tmp_path_factory.mktemp("data") / "radar_small.mcap"
    record(path, load_scenario("radar-tws"), runs=30, seed=5)
    return path


@pytest.fixture(scope="session")
def demo_mcap() -> Path:
    return REPO / "data" / "radar_tws_demo.mcap"


def _strip_truth(src: Path, dst: Path) -> None:
    """``src`` with its truth channels left out (a recording as a sensor would give it)."""
    from trackreplay.contract import McapFrameWriter, iter_frames

    meta: dict = {}
    with open(dst, "wb") as f:
        writer, previous = None, None
        for topic, run, scan, t, arrays, n in iter_frames(src, False, meta):
            if "truth" in topic:
                continue
            if writer is None:
                writer = McapFrameWriter(f, meta["metadata"])
            if previous is not None and scan != previous:
                writer.flush()
            previous = scan
            writer.write(topic, run, scan, t, arrays, run_count=n)
        writer.finish()


@pytest.fixture
def without_truth():
    """``without_truth(src, dst)`` writes ``src`` without its truth channels."""
    return _strip_truth


def _replay_without_truth(folder: Path, scenario: str, seed: int, options=()):
    """Simulate ``scenario`` (4 runs), strip its truth and replay it through the command line as a
    recording would be; returns the command's result and the outputs path (it must succeed)."""
    from click.testing import CliRunner

    from trackreplay.contract import read_dataset
    from trackreplay.face.cli import main

    runner = CliRunner()
    full, bare = folder / "full.mcap", folder / "bare.mcap"
    res = runner.invoke(main, ["simulate", scenario, "--runs", "4", "--seed", str(seed), "-o", str(full), *options])
    assert res.exit_code == 0, res.output
    _strip_truth(full, bare)
    assert not any("truth" in t for t in read_dataset(bare).channels)
    out = folder / "o" / "tracks.mcap"
    res = runner.invoke(main, [str(bare), "--out", str(out), "--no-rrd", "-q"])
    assert res.exit_code == 0, res.output
    assert "Traceback" not in res.output
    return res, out


@pytest.fixture
def replay_without_truth(tmp_path):
    """``replay_without_truth(scenario, seed, options)`` → ``(result, tracks.mcap)`` of replaying a
    simulated data set with its truth left out."""
    return lambda scenario, seed, options=(): _replay_without_truth(tmp_path, scenario, seed, options)


def assert_mapped_recording_refused(folder, how: str, case: str, named: str, fragments) -> None:
    """``in.mcap`` with ``map.toml`` in ``folder`` (the working folder), converted (``how`` =
    "convert") or replayed ("replay"), is refused with one line ``replay: error: <named>: …``
    holding every fragment, exit 2, no traceback, the inputs unchanged and no output written."""
    from click.testing import CliRunner

    from trackreplay.face.cli import main

    before = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    args = (["convert", "mcap", "in.mcap", "--map", "map.toml", "-o", "out.mcap"] if how == "convert"
            else ["in.mcap", "--map", "map.toml", "--no-rrd"])
    res = CliRunner().invoke(main, args)
    errors = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.exit_code == 2, (case, res.output)
    assert len(errors) == 1 and errors[0].startswith(f"replay: error: {named}: "), (case, res.stderr)
    for fragment in fragments:
        assert fragment in errors[0], (case, errors[0])
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit)
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == before  # inputs kept, no output
    assert not (folder / "replay-out").exists() or not any((folder / "replay-out").rglob("tracks.mcap"))
