"""A full or read-only disk: one line naming the file, exit 2, nothing partial left, the inputs
unchanged, and never a hang (issue 30, item 3), for replay (with and without its recording
process), simulate, convert and check --update.

Disks: every file limited by ``RLIMIT_FSIZE`` (writes beyond it fail with EFBIG, as on a disk
that fills up; any user can set it); as root, also a real full file system (a tiny tmpfs filled
to its last blocks: ENOSPC, where Rerun's writer used to stall) and a read-only one (a tmpfs
remounted read-only: EROFS); as another user, a folder without write permission instead.
Each command runs with a time limit, so a hang fails the test.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TIMEOUT_S = 90  # a hang fails; a refused write takes a few seconds


def _can_mount() -> bool:
    if os.geteuid() != 0 or not shutil.which("mount"):
        return False
    probe = Path(f"/tmp/trackreplay-mount-probe-{os.getpid()}")
    probe.mkdir(exist_ok=True)
    ok = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(probe)], capture_output=True).returncode == 0
    if ok:
        subprocess.run(["umount", str(probe)], check=True)
    probe.rmdir()
    return ok


DISKS = ["file-size-limit", "read-only"] + (["full-tmpfs"] if _can_mount() else [])


@pytest.fixture
def disk(request, tmp_path):
    """(folder on the disk, preexec_fn for the command, how to make the folder refuse writes
    once its inputs are in)."""
    kind = request.param
    if kind == "file-size-limit":
        folder = tmp_path / "disk"
        folder.mkdir()
        yield kind, folder, _limited(8_000), lambda: None
        return
    if kind == "read-only" and os.geteuid() != 0:  # a folder a user cannot write to
        folder = tmp_path / "disk"
        folder.mkdir()
        yield kind, folder, None, lambda: folder.chmod(0o555)
        for p in [folder, *folder.rglob("*")]:
            if p.is_dir():
                p.chmod(0o755)
        return
    folder = tmp_path / "disk"  # root: a small file system of its own (root writes through chmod)
    folder.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(folder)], check=True)
    try:
        if kind == "read-only":
            yield kind, folder, None, lambda: subprocess.run(["mount", "-o", "remount,ro", str(folder)], check=True)
        else:
            yield kind, folder, None, lambda: _fill(folder, free_bytes=12_000)
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=True)


def _limited(limit: int):
    import resource

    def apply():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def _fill(folder: Path, free_bytes: int) -> None:
    """Fill ``folder``'s file system until about ``free_bytes`` stay free."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    with open(folder / "filler", "wb") as f:
        f.write(b"\0" * max(0, free - free_bytes))


def _one_core():
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def _chain(*fns):
    fns = [f for f in fns if f is not None]
    return (lambda: [f() for f in fns]) if fns else None


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    path = tmp_path_factory.mktemp("full_disk_data") / "small.mcap"
    record(path, load_scenario("radar-tws").with_overrides({"n_scans": 12}), runs=2, seed=4)
    return path


# command → (arguments with {disk}, {data}, {elsewhere}; inputs to place on the disk first;
# whether the replay records in one process, i.e. pinned to one core)
CASES = {
    "replay": (["{data}", "--out", "{disk}/o/tracks.mcap", "--figures", "now"], [], False),
    "replay-in-process": (["{data}", "--out", "{disk}/o/tracks.mcap", "--figures", "now"], [], True),
    "replay-recording-only": (["{data}", "--out", "{elsewhere}/o/tracks.mcap", "--rrd", "{disk}/x.rrd",
                               "--figures", "none"], [], False),
    "replay-recording-only-in-process": (["{data}", "--out", "{elsewhere}/o/tracks.mcap", "--rrd", "{disk}/x.rrd",
                                          "--figures", "none"], [], True),
    "simulate": (["simulate", "radar-tws", "--runs", "20", "-o", "{disk}/sim.mcap"], [], False),
    "convert": (["convert", "plots", str(REPO / "data" / "samples" / "radar_plots.csv"), "-o", "{disk}/plots.mcap"],
                [], False),
    "check-update": (["check", "{disk}/chk", "--update"], ["chk/small.mcap"], False),
}


def _snapshot(root: Path) -> dict:
    return {p.relative_to(root): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != "filler"}


@pytest.mark.parametrize("disk", DISKS, indirect=True)
@pytest.mark.parametrize("case", list(CASES))
def test_a_full_or_read_only_disk_gives_one_line_naming_the_file(tmp_path, small, disk, case):
    kind, folder, preexec, refuse_writes = disk
    args, placed, one_core = CASES[case]
    for rel in placed:
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(small, folder / rel)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    data_before = hashlib.sha256(small.read_bytes()).hexdigest()
    refuse_writes()
    before_disk, before_elsewhere = _snapshot(folder), _snapshot(elsewhere)
    argv = [a.format(disk=folder, data=small, elsewhere=elsewhere) for a in args]
    # the command line of this tree (not an installed copy), with every command registered
    cmd = [sys.executable, "-c", "import sys; sys.argv[0] = 'replay'; from trackreplay.face.cli import main; main()", *argv]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S, cwd=tmp_path, env=env,
                          preexec_fn=_chain(preexec, _one_core if one_core else None))
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2, (kind, case, done.stderr)
    assert len(lines) == 1 and lines[0].startswith("replay: error: "), (kind, case, done.stderr)
    named = lines[0][len("replay: error: "):].split(": ", 1)[0]
    # the file (or the folder) it could not write, on that disk (under the size limit, any output)
    assert named.startswith(str(folder)) or (kind == "file-size-limit" and named.startswith(str(elsewhere))), lines[0]
    assert "Traceback" not in done.stderr
    # nothing partial: the disk and the other output folder hold what they held
    assert _snapshot(folder) == before_disk, (kind, case, sorted(map(str, folder.rglob("*"))))
    assert sorted(p.name for p in folder.iterdir() if p.name != "filler") == sorted(
        {Path(rel).parts[0] for rel in placed}), (kind, case)
    assert _snapshot(elsewhere) == before_elsewhere and not any(elsewhere.iterdir()), (kind, case)
    assert hashlib.sha256(small.read_bytes()).hexdigest() == data_before


def test_writer_failures_without_a_file_name_name_the_output(tmp_path):
    """What writers say on a full disk (no file name, a temporary's name, Rerun's own words)
    becomes an OSError naming the output; other failures are left alone."""
    import errno

    from trackreplay.paths import disk_error

    out = tmp_path / "tracks.rrd"
    cases = [OSError(errno.ENOSPC, "No space left on device"),
             OSError(errno.EFBIG, "File too large", str(tmp_path / "tracks.rrd.k2j4h1.tmp")),
             RuntimeError("Failed to encode LogMsg: Failed to write: No space left on device (os error 28)")]
    for exc in cases:
        named = disk_error(exc, out)
        assert isinstance(named, OSError) and named.filename == str(out) and named.errno == getattr(exc, "errno", 28)
    stopped = disk_error(RuntimeError("File-writer thread shut down prematurely"), out)
    assert stopped.filename == str(out) and "Rerun writer stopped" in stopped.strerror
    assert disk_error(OSError(errno.EACCES, "Permission denied", str(tmp_path / "other")), out) is None
    assert disk_error(ValueError("a bug"), out) is None


def test_a_writer_call_that_never_returns_is_abandoned_in_bounded_time(tmp_path):
    import threading
    import time

    from trackreplay import paths

    never = threading.Event()
    t0 = time.monotonic()
    with pytest.raises(OSError) as caught:
        paths.bounded_call(never.wait, 0.5, tmp_path / "x.rrd", "a stalled save")
    assert time.monotonic() - t0 < 5 and caught.value.filename == str(tmp_path / "x.rrd")
    assert "did not return" in caught.value.strerror
    assert paths.bounded_call(lambda: 42, 5, tmp_path / "x.rrd", "a quick call") == 42
    never.set()


def test_the_recording_process_is_not_waited_for_forever(tmp_path, monkeypatch):
    """A child that stalls after its payload (as Rerun's writer did on a full disk) is stopped
    at the watchdog's limit, and the replay fails naming the recording."""
    import time

    from trackreplay.face import recording_process

    monkeypatch.setattr(recording_process, "RECORDING_TIMEOUT_S", 1.0)
    recorder = recording_process.RecordingProcess.__new__(recording_process.RecordingProcess)
    recorder._data_path, recorder._input_stamp = tmp_path / "data.mcap", None
    recorder._errors = __import__("tempfile").TemporaryFile()
    recorder._child = subprocess.Popen([sys.executable, "-c", "import sys, time; sys.stdin.buffer.read(); time.sleep(60)"],
                                       stdin=subprocess.PIPE)

    class Data:
        cache = {}

    t0 = time.monotonic()
    with pytest.raises(OSError) as caught:
        recorder(tmp_path / "tracks.rrd", Data(), [], {}, None)
    assert time.monotonic() - t0 < 15 and caught.value.filename == str(tmp_path / "tracks.rrd")
    assert recorder._child.poll() is not None  # stopped, not left behind
