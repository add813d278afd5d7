"""A small replay's Rerun recording, written by a second process that loads Rerun meanwhile.

On a small data set most of a replay's wait is imports, and the Rerun SDK is the largest of
them (0.3–0.4 s of a radar replay of 10 runs that takes about 0.9 s; ``docs/benchmarks.md``).
The command line therefore starts this module as a child process before it loads anything
heavy. The child imports Rerun and reads the same input while the replay runs on the other core;
when the replay has scored everything it sends the child what the views draw (tracker outputs,
the per-scan table, the designs used), and the child draws them with the very function a replay
uses in-process (:func:`trackreplay.face.rerun_views.write_recording`) into the staged ``.rrd``.
The replay waits for it, so the outputs still appear all together or not at all, and a
failure is the one line the replay would have given in-process. Before drawing, the child
checks that it read the same input file as the replay (not one put in its place meanwhile).
Stopped early, it exits through its clean-ups, which remove its temporary file.

It only pays when there is an import to overlap and little data to hand over:
:func:`worth_it` says when.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

from trackreplay.errors import InputError

#: Inputs above this size replay long enough that the import is a small part of the wait, while
#: the child would decode the input a second time and receive the outputs it draws: in-process.
LARGEST_INPUT_BYTES = 8 * 2**20


def worth_it(data_path, cores: int | None = None) -> bool:
    """Whether a replay of ``data_path`` should record in a :class:`RecordingProcess`.

    Yes when Rerun is not loaded in this process yet (otherwise there is no import to
    overlap), there is a second core to overlap it on, and the input is at most
    :data:`LARGEST_INPUT_BYTES`.
    """
    if "rerun" in sys.modules:
        return False
    if cores is None:
        from trackreplay.machine import usable_cores

        cores = usable_cores()
    try:
        size = Path(data_path).stat().st_size
    except OSError:
        return False  # the replay itself reports it
    return cores >= 2 and size <= LARGEST_INPUT_BYTES


def start(data_path, recover: bool = False) -> "RecordingProcess | None":
    """A :class:`RecordingProcess` for ``data_path`` if :func:`worth_it` and it starts; else None
    (the replay then records in its own process)."""
    if not worth_it(data_path) or not sys.executable or getattr(sys, "frozen", False):
        return None
    try:
        return RecordingProcess(data_path, recover)
    except OSError:  # no interpreter to start, no processes left: record here
        return None


def file_stamp(path) -> tuple:
    """What tells one version of a file from another: device, inode, size, modification time."""
    st = os.stat(path)
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


class RecordingProcess:
    """The child process that writes one replay's recording; a ``recorder`` for
    :func:`trackreplay.replay.replay`.

    Start it (``with RecordingProcess(data) as recorder:``, or :func:`start`) before the
    replay's imports, call :meth:`stamp_input` as the replay reads its input, and pass it to
    ``replay(..., recorder=recorder)``: the call returns when the recording is written, or
    raises :class:`InputError`. Leaving the block otherwise (an error, Ctrl-C) stops the child,
    which removes what it had begun to write.
    """

    def __init__(self, data_path, recover: bool = False):
        self._data_path = Path(data_path)
        self._input_stamp = None
        # the child's messages go to a file, not a pipe: a pipe it filled (warnings, a profiler's
        # output) while this process waits to hand it the payload would block both
        self._errors = tempfile.TemporaryFile()
        # this interpreter with this process's module path: ``python -m`` would put the working
        # folder first, where another project's ``pipeline`` package may be
        start = f"import sys; sys.path[:] = {sys.path!r}; from trackreplay.face.recording_process import main; main()"
        try:
            self._child = subprocess.Popen(
                [sys.executable, "-c", start, os.fspath(data_path), "1" if recover else "0"],
                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._errors)
        except BaseException:
            self._errors.close()
            raise

    def __enter__(self) -> "RecordingProcess":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.close()
        return False

    def stamp_input(self) -> None:
        """Note the input file as this process reads it: the child refuses to draw a file that
        is not the same (replaced or rewritten between the two reads)."""
        try:
            self._input_stamp = file_stamp(self._data_path)
        except OSError:
            self._input_stamp = None  # the replay's own read reports it

    def __call__(self, rrd_path, ds, stages, results, per_scan, rerun_run: int = 0) -> None:
        """Hand the child what the views draw (it has read ``ds``'s file itself) and wait until
        the recording is written; raise :class:`InputError` if it was not.

        Outputs that do not pickle (a plugged tracker's own types) are drawn here instead, as a
        replay without a child would.
        """
        payload = {"rrd_path": os.fspath(rrd_path), "stages": [s.name for s in stages], "results": results,
                   "per_scan": per_scan, "rerun_run": rerun_run, "input_stamp": self._input_stamp,
                   "designs": {s.name: ds.cache[("design", s.name)] for s in stages if ("design", s.name) in ds.cache}}
        try:
            data = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # noqa: BLE001 (whatever pickling raises, the recording is made here)
            from trackreplay.face.rerun_views import write_recording

            self.close()
            write_recording(rrd_path, ds, stages, results, per_scan, rerun_run)
            return
        try:
            self._child.stdin.write(data)
            self._child.stdin.close()
        except OSError:  # the child has gone: its status and message say why
            pass
        try:  # a watchdog: a child that stalls (a writer waiting on a full disk) is not waited for forever
            status = self._child.wait(timeout=RECORDING_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            from trackreplay.paths import stalled_writer_error

            self.close()
            raise stalled_writer_error(rrd_path, f"the recording process did not finish within "
                                                 f"{RECORDING_TIMEOUT_S:g} s") from None
        if status != 0:
            self._errors.seek(0)
            lines = self._errors.read().decode(errors="replace").splitlines()
            failed = [line[len(_DISK):].split("\t", 2) for line in lines if line.startswith(_DISK)]
            if failed:  # the file system's answer, raised as such: it names the file
                number, filename, problem = failed[-1]
                raise OSError(int(number) if number.lstrip("-").isdigit() else None, problem, filename)
            said = [line[len(_MESSAGE):] for line in lines if line.startswith(_MESSAGE)]
            if said:
                raise InputError(said[-1])
            raise InputError(f"the Rerun recording was not written (its process ended with status "
                             f"{self._child.returncode})", self._data_path)

    def close(self) -> None:
        """Stop the child if it is still running, and let it remove what it had begun to write."""
        if self._child.poll() is None:
            self._child.terminate()  # the child turns SIGTERM into an exit that runs its clean-ups
            try:
                self._child.wait(timeout=STOP_SECONDS)
            except subprocess.TimeoutExpired:
                self._child.kill()
                self._child.wait()
        if self._child.stdin is not None and not self._child.stdin.closed:
            try:
                self._child.stdin.close()
            except OSError:
                pass
        self._errors.close()


#: How long :meth:`RecordingProcess.close` gives the child to clean up before it is killed.
STOP_SECONDS = 5.0
#: The longest the replay waits for the child once it has its payload (it draws a small
#: replay's recording in about a second; its own writer calls are bounded tighter, see
#: ``pipeline/face/timeline.py``): beyond it the child is stopped and the replay fails naming
#: the recording, instead of waiting forever.
RECORDING_TIMEOUT_S = float(os.environ.get("TRACKREPLAY_RECORDING_TIMEOUT_S", "300"))
#: What starts the line a child writes for the user (anything else on its stderr is not for them).
_MESSAGE = "replay-recording: "
#: What starts the line a child writes for a file-system failure: errno, file, problem (tab-separated).
_DISK = "replay-recording-oserror: "


def _record(data_path: str, recover: bool) -> None:
    """The child: import Rerun and read the input, then draw what the replay sends."""
    from trackreplay.face import lazy_imports

    lazy_imports.defer()  # as the command line does
    import rerun  # noqa: F401  (what this process is for: loaded while the replay runs)
    import rerun.blueprint  # noqa: F401

    from trackreplay.contract import read_dataset
    from trackreplay.face.rerun_views import prepare_views, write_recording
    from trackreplay.stages import applicable_stages

    stamp = file_stamp(data_path)
    ds = read_dataset(data_path, recover=recover)
    stages = {s.name: s for s in applicable_stages(ds.channels)}
    for stage in stages.values():  # their views' imports and data-only work, still while the replay runs
        try:
            prepare_views(stage, ds)
        except Exception:  # noqa: BLE001 (work ahead only: the drawing does it again and reports its error)
            pass
    try:
        payload = pickle.load(sys.stdin.buffer)
    except EOFError:  # the replay ended without a recording to write (it failed, or was stopped)
        return
    if payload["input_stamp"] is not None and tuple(payload["input_stamp"]) != stamp:
        raise InputError("changed while it was replayed, so the recording would not match the outputs; "
                         "replay it again", data_path)
    for name, design in payload["designs"].items():  # what this replay used, --set included
        ds.cache[("design", name)] = design
    write_recording(payload["rrd_path"], ds, [stages[n] for n in payload["stages"]], payload["results"],
                    payload["per_scan"], payload["rerun_run"])


def _end_with_parent(period_s: float = 0.5) -> None:
    """End this child when the replay that started it is gone (killed without stopping it):
    a child stalled in a writer would otherwise wait forever, orphaned. What it had begun
    lies in the replay's staging folder, which the next run cleans."""
    import threading
    import time

    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(period_s)
        os._exit(1)

    threading.Thread(target=watch, name="end with the replay", daemon=True).start()


def _stop(signum, frame):
    raise SystemExit(128 + signum)  # unwinds: the recording's temporary file is removed


def main() -> None:
    """The child's entry point: ``DATA RECOVER`` (``1`` or ``0``) in ``sys.argv``, the payload on
    stdin. A failure ends with one line for the user on stderr, in the words the command line
    would use, and exit status 1."""
    import signal
    import warnings

    signal.signal(signal.SIGTERM, _stop)
    _end_with_parent()
    warnings.filterwarnings("ignore", category=RuntimeWarning)  # as the command line does
    try:
        _record(sys.argv[1], sys.argv[2] == "1")
        # the recording is written and published, its writer disconnected: the interpreter's
        # own teardown (Rerun's, polars', 0.1 s) would only keep the replay waiting for the exit
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    except InputError as exc:
        print(f"{_MESSAGE}{exc}", file=sys.stderr)
        sys.exit(1)
    except OSError as exc:  # the file system's answer: the replay raises it as its own
        if exc.filename is None:
            print(f"{_MESSAGE}{exc.strerror or exc}", file=sys.stderr)
        else:
            print(f"{_DISK}{exc.errno}\t{exc.filename}\t{exc.strerror or exc}", file=sys.stderr)
        _exit(1)
    except Exception as exc:  # a bug of ours: one line, naming what failed
        print(f"{_MESSAGE}the Rerun recording was not written: {type(exc).__name__}: {exc}", file=sys.stderr)
        _exit(1)


def _exit(status: int) -> None:
    """End the child; at once when a Rerun writer thread stalled (a normal exit would wait for it)."""
    from trackreplay import paths

    if paths.STALLED_WRITERS:
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)
