"""Every server the tool starts listens on the loopback interface only.

The local Dask cluster of ``replay sweep --executor dask`` (scheduler, nannies, workers and
their HTTP routes, on random ports: not the fixed 8787), and the Rerun viewer's gRPC server of
``replay view FILE``, ``replay FILE --spawn`` and ``replay view FILE --screenshot`` (the desktop
viewer is started headless here: same command line plus ``--headless``). Each is checked with
psutil over its whole process tree.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import psutil
import pytest
from click.testing import CliRunner

from trackreplay.face import viewer
from trackreplay.face.cli import main

LOOPBACK = {"127.0.0.1", "::1", "::ffff:127.0.0.1"}
# the scheduler's HTTP port when dashboard_address=None alone is given
FIXED_DASK_HTTP = 8787


def listening(pid: int) -> set[tuple[int, str, int]]:
    """(pid, address, port) of every listening TCP socket of ``pid`` and its descendants."""
    try:
        root = psutil.Process(pid)
        procs = [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return set()
    out = set()
    for p in procs:
        try:
            for c in p.net_connections(kind="inet"):
                if c.status == psutil.CONN_LISTEN:
                    out.add((p.pid, c.laddr.ip, c.laddr.port))
        except (psutil.NoSuchProcess, psutil.ZombieProcess):
            pass
    return out


def assert_loopback(sockets) -> None:
    exposed = [s for s in sockets if s[1] not in LOOPBACK]
    assert not exposed, f"listening beyond loopback: {exposed}"


def wait_listening(pid: int, timeout: float = 60.0, proc=None) -> set:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = listening(pid)
        if found:
            time.sleep(1.0)  # let every server of the tree come up
            return found | listening(pid)
        if proc is not None and proc.poll() is not None:
            break
        time.sleep(0.2)
    return set()


stop_group = viewer.stop_process_group


# --------------------------------------------------------------------------- Dask


def test_local_dask_cluster_listens_on_loopback_only():
    from dask.distributed import Client

    from trackreplay.sweep import local_cluster

    before = listening(os.getpid())
    cluster = local_cluster(2)
    try:
        with Client(cluster) as client:
            client.wait_for_workers(2, timeout=60)
            sockets = listening(os.getpid()) - before
            http_port = cluster.scheduler.http_server.port
    finally:
        cluster.close()
    assert http_port != FIXED_DASK_HTTP
    # scheduler, its HTTP routes, two nannies, two workers and their HTTP routes
    assert len(sockets) >= 6, sockets
    assert {p for p, _, _ in sockets} - {os.getpid()}, "no worker process was seen"
    assert_loopback(sockets)
    assert FIXED_DASK_HTTP not in {port for _, _, port in sockets}


def test_sweep_on_dask_listens_on_loopback_only(tmp_path):
    cmd = [sys.executable, "-m", "trackreplay.face.cli", "sweep", "radar-tws", "--param", "sigma_bearing_deg=0.5,1,2",
           "--runs", "40", "--executor", "dask", "--workers", "2", "--no-keep-data", "-o", str(tmp_path / "s")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    seen = set()
    try:
        while proc.poll() is None:
            seen |= listening(proc.pid)
            time.sleep(0.05)
        err = proc.stderr.read().decode()
    finally:
        if proc.poll() is None:
            stop_group(proc)
    assert proc.returncode == 0, err
    assert {p for p, _, _ in seen} - {proc.pid}, f"the cluster's workers were not seen listening: {seen}"
    assert_loopback(seen)
    assert FIXED_DASK_HTTP not in {port for _, _, port in seen}


# --------------------------------------------------------------------------- Rerun viewer


def test_viewer_command_binds_loopback():
    cmd = viewer.viewer_command("x.rrd")
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1"
    assert cmd[cmd.index("--port") + 1] == "0"  # a free port, not the fixed 9876
    assert "--web-viewer" not in cmd and "--serve-web" not in cmd


@pytest.fixture(scope="module")
def recording(tmp_path_factory, demo_mcap):
    out = tmp_path_factory.mktemp("rec")
    res = CliRunner().invoke(main, [str(demo_mcap), "--out", str(out / "t.mcap")])
    assert res.exit_code == 0, res.output
    return out / "t.rrd"


@pytest.fixture
def headless_viewers(monkeypatch):
    """Start the desktop viewer the CLI asks for, headless (no display here), and collect it."""
    started = []
    real = viewer._start

    def start(cmd, **kwargs):
        kwargs.setdefault("stdout", subprocess.DEVNULL)
        kwargs.setdefault("stderr", subprocess.DEVNULL)
        proc = real([*cmd, "--headless"] if "--headless" not in cmd else cmd, **kwargs)
        started.append(proc)
        return proc

    monkeypatch.setattr(viewer, "_start", start)
    monkeypatch.setenv("DISPLAY", ":0")  # the CLI's display check passes; the viewer itself runs headless
    yield started
    for proc in started:
        if proc.poll() is None:
            stop_group(proc)


def _check_viewer(proc):
    sockets = wait_listening(proc.pid, proc=proc)
    assert sockets, f"the viewer never listened (exit code {proc.poll()})"
    assert_loopback(sockets)
    assert 9876 not in {port for _, _, port in sockets}  # a random port, not the fixed default


def test_view_file_listens_on_loopback_only(recording, headless_viewers):
    res = CliRunner().invoke(main, ["view", str(recording)])
    assert res.exit_code == 0, res.output
    assert len(headless_viewers) == 1
    _check_viewer(headless_viewers[0])


def test_run_with_spawn_listens_on_loopback_only(tmp_path, demo_mcap, headless_viewers, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, [str(demo_mcap), "--out", str(tmp_path / "o" / "t.mcap"), "--spawn"])
    assert res.exit_code == 0, res.output
    assert len(headless_viewers) == 1
    _check_viewer(headless_viewers[0])


def test_screenshot_viewer_listens_on_loopback_only(tmp_path, recording, monkeypatch):
    seen = []
    real = viewer._connect

    def connect(rrx, port, proc, timeout_s, home):
        client = real(rrx, port, proc, timeout_s, home)
        seen.append(wait_listening(proc.pid, timeout=10))  # the viewer answers: it is listening
        return client

    monkeypatch.setattr(viewer, "_connect", connect)
    png = tmp_path / "shot.png"
    res = CliRunner().invoke(main, ["view", str(recording), "--screenshot", str(png), "--size", "640x400"])
    assert res.exit_code == 0, res.output
    assert png.stat().st_size > 0
    assert seen and seen[0], "the headless viewer was not seen listening"
    assert_loopback(seen[0])


def test_the_viewer_without_a_display_is_one_line_with_the_alternatives(recording, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    res = CliRunner().invoke(main, ["view", str(recording)])
    lines = [l for l in res.stderr.splitlines() if l.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("replay: error: ")
    assert "--screenshot" in lines[0] and "127.0.0.1" in lines[0]
