"""Open a recording in the Rerun viewer, or render it headless to a PNG.

Every viewer this module starts listens on the loopback interface only. The ``rerun`` viewer
always runs a gRPC server (the SDK's and ``ViewerClient``'s way in), by default on
``0.0.0.0:9876``; :func:`viewer_command` passes ``--bind 127.0.0.1`` and a random port
(``--port 0`` for the desktop viewer, a free loopback port for the headless one, which we
connect to). ``rr.spawn`` is not used: it has no bind address and takes the fixed port 9876.

Headless rendering uses the real viewer (software Vulkan from Debian's
``mesa-vulkan-drivers``): ``rerun --headless`` serves on 127.0.0.1, and
``rerun.experimental.ViewerClient`` opens the file, waits for it to load, moves the time
cursor to the end and saves a screenshot. The viewer runs in its own process group, which is
ended afterwards whatever happens.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from trackreplay.errors import InputError


LOOPBACK = "127.0.0.1"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def _rerun_cli() -> list[str]:
    exe = shutil.which("rerun")
    return [exe] if exe else [sys.executable, "-m", "rerun"]


def viewer_command(rrd: str | Path | None = None, *, port: int = 0, headless: bool = False,
                   size: str | None = None) -> list[str]:
    """The ``rerun`` command line of a viewer whose server listens on 127.0.0.1 only.

    ``port=0`` lets the system choose a free port (nothing else is served: no web viewer).
    """
    cmd = [*_rerun_cli(), "--bind", LOOPBACK, "--port", str(int(port))]
    if headless:
        cmd.append("--headless")
    if size:
        cmd += ["--window-size", size]
    if rrd is not None:
        cmd.append(str(rrd))
    return cmd


def stop_process_group(proc: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """Stop a viewer started in its own session: SIGTERM to its process group, SIGKILL if it
    has not gone within ``timeout_s``."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=timeout_s)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=timeout_s)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass


def _start(cmd: list[str], **kwargs) -> subprocess.Popen:
    return subprocess.Popen(cmd, **kwargs)


RRD_MAGIC = b"RRF"  # every Rerun recording file starts with it (then the format version)


def check_recording(rrd: str | Path) -> Path:
    """``rrd`` as a Path after checking that it exists and is a Rerun recording (``.mcap``
    inputs, which the viewer also opens, are passed through).

    Raises
    ------
    InputError
        A missing file, a folder, or a ``.rrd`` whose header is not a Rerun recording's.
    """
    rrd = Path(rrd).resolve()
    if not rrd.is_file():
        raise InputError("no such recording" if not rrd.exists() else "is a folder, not a recording", rrd)
    if rrd.suffix != ".mcap":
        with open(rrd, "rb") as f:
            if f.read(len(RRD_MAGIC)) != RRD_MAGIC:
                raise InputError("not a Rerun recording (its header is not RRF)", rrd)
    return rrd


def require_display() -> None:
    """Refuse, in one line with the alternatives, to open a desktop window where there is no
    display (a server, CI, an SSH session): the viewer would otherwise fail silently."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError("no display to open the viewer on (DISPLAY and WAYLAND_DISPLAY are unset); render a PNG "
                         "with `replay view FILE --screenshot out.png`, or serve it to a browser with "
                         "`rerun FILE --web-viewer --bind 127.0.0.1` and open the printed http://127.0.0.1 address")


def open_viewer(rrd: str | Path) -> subprocess.Popen:
    """Start the desktop viewer on a recording (returns at once), listening on loopback only.

    Raises
    ------
    InputError
        No such recording, not a recording, or no display (:func:`require_display`).
    """
    rrd = check_recording(rrd)
    require_display()
    return _start(viewer_command(rrd), start_new_session=True)


STARTUP_TOAST_S = 10.0  # the headless viewer's start-up notification has gone by then


def screenshot(rrd: str | Path, png: str | Path, size: str = "1600x900", timeline: str = "scan",
               settle_s: float = 3.0, timeout_s: float = 90.0) -> Path:
    """Render ``rrd`` in the headless viewer and save a PNG of the whole window.

    Raises
    ------
    InputError
        When the viewer cannot start (e.g. no Vulkan driver) or does not answer in time.
    """
    import rerun.experimental as rrx

    rrd, png = check_recording(rrd), Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    port = _free_port()
    home = tempfile.mkdtemp(prefix="rerun-home-")
    env = dict(os.environ, XDG_CONFIG_HOME=home, XDG_DATA_HOME=home, XDG_CACHE_HOME=home)
    log = open(Path(home) / "viewer.log", "wb")
    proc = _start(viewer_command(port=port, headless=True, size=size),
                  start_new_session=True, env=env, stdout=log, stderr=subprocess.STDOUT)
    started = time.monotonic()
    tmp = png.with_name(png.name + ".tmp.png")
    try:
        client = _connect(rrx, port, proc, timeout_s, home)
        try:
            client.open(str(rrd))
        except ConnectionError:
            raise InputError("the viewer could not open it (not a Rerun recording?)", rrd) from None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if not client.get_state().loading:  # empty once every source has arrived
                break
            time.sleep(0.2)
        try:
            # "following" puts the time cursor on the newest data: the end of the replay
            client.set_time(timeline, play_state="following")
        except Exception:  # a recording without that timeline still gets a picture
            pass
        # the viewer greets a headless start with a toast over the top right corner for several
        # seconds: the picture is taken once it has gone (and the views have settled)
        time.sleep(max(settle_s, STARTUP_TOAST_S - (time.monotonic() - started)))
        client.save_screenshot(str(tmp))
        if not tmp.exists() or tmp.stat().st_size == 0:
            raise InputError("the viewer produced no screenshot", rrd)
        os.replace(tmp, png)
        return png
    finally:
        stop_process_group(proc)
        log.close()
        if tmp.exists():
            tmp.unlink()
        shutil.rmtree(home, ignore_errors=True)


def _connect(rrx, port, proc, timeout_s, home):
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            tail = (Path(home) / "viewer.log").read_text(errors="replace").strip().splitlines()[-1:]
            raise InputError(f"headless viewer exited ({' '.join(tail) or 'no output'}); "
                             "is a Vulkan driver installed (Debian: mesa-vulkan-drivers)?")
        try:
            client = rrx.ViewerClient.connect(f"rerun+http://{LOOPBACK}:{port}/proxy")
            client.get_state()
            return client
        except Exception as exc:  # not listening yet
            last = exc
            time.sleep(0.3)
    raise InputError(f"headless viewer did not answer within {timeout_s:.0f} s ({last})")
