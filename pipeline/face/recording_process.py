"""A small replay's Rerun recording, written by a second process that loads Rerun meanwhile.

On a small data set most of a replay's wait is imports, and the Rerun SDK is the largest of
them (0.3–0.4 s of a radar replay of 10 runs that takes about 0.9 s; ``docs/benchmarks.md``).
The command line therefore starts this module as a child process before it loads anything
heavy. The child imports Rerun and reads the same input while the replay runs on the other core;
when the replay has scored everything it sends the child what the views draw (tracker outputs,
the per-scan table, the designs used), and the child draws them with the very function a replay
uses in-process (:func:`pipeline.face.rerun_views.write_recording`) into the staged ``.rrd``.
The command line waits for it before any output is moved into place, so the outputs still
appear all together or not at all.

It only pays when there is an import to overlap and little data to hand over:
:func:`worth_it` says when.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
from pathlib import Path

from pipeline.errors import InputError

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
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
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


class RecordingProcess:
    """The child process that writes one replay's recording; a ``recorder`` for
    :func:`pipeline.replay.replay`.

    Start it (``with RecordingProcess(data) as recorder:``) before the replay's imports, pass it
    to ``replay(..., recorder=recorder)``, and call :meth:`finish` before the outputs are moved
    into place. Leaving the block without :meth:`finish` (an error, Ctrl-C) stops the child.
    """

    def __init__(self, data_path, recover: bool = False):
        self._data_path = Path(data_path)
        self._drawn_here = False
        self._sending = None
        # this interpreter with this process's module path: ``python -m`` would put the working
        # folder first, where another project's ``pipeline`` package may be
        start = f"import sys; sys.path[:] = {sys.path!r}; from pipeline.face.recording_process import main; main()"
        self._child = subprocess.Popen(
            [sys.executable, "-c", start, os.fspath(data_path), "1" if recover else "0"],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    def __enter__(self) -> "RecordingProcess":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.close()
        return False

    def __call__(self, rrd_path, ds, stages, results, per_scan, rerun_run: int = 0) -> None:
        """Hand the child what the views draw (it has read ``ds``'s file itself) and return.

        Outputs that do not pickle (a plugged tracker's own types) are drawn here instead, as a
        replay without a child would.
        """
        payload = {"rrd_path": os.fspath(rrd_path), "stages": [s.name for s in stages], "results": results,
                   "per_scan": per_scan, "rerun_run": rerun_run,
                   "designs": {s.name: ds.cache[("design", s.name)] for s in stages if ("design", s.name) in ds.cache}}
        try:
            data = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # noqa: BLE001 (whatever pickling raises, the recording is made here)
            from pipeline.face.rerun_views import write_recording

            self.close()
            write_recording(rrd_path, ds, stages, results, per_scan, rerun_run)
            self._drawn_here = True
            return
        # on a thread: the child may still be importing, and the pipe takes 64 KiB at a time;
        # meanwhile this process prints and writes its tables
        self._sending = threading.Thread(target=self._send, args=(data,), daemon=True)
        self._sending.start()

    def _send(self, data: bytes) -> None:
        try:
            self._child.stdin.write(data)
            self._child.stdin.close()
        except (OSError, ValueError):  # the child has gone (finish() says why), or was stopped
            pass

    def finish(self) -> None:
        """Wait until the recording is written; raise :class:`InputError` if it could not be."""
        if self._drawn_here:
            return
        if self._sending is not None:
            self._sending.join()
        if self._child.stdin and not self._child.stdin.closed:
            self._child.stdin.close()
        problem = self._child.stderr.read().decode(errors="replace").strip()
        if self._child.wait() != 0:
            last = problem.splitlines()[-1] if problem else f"exit status {self._child.returncode}"
            raise InputError(f"the Rerun recording was not written: {last}", self._data_path)

    def close(self) -> None:
        """Stop the child if it is still running (nothing of it stays: it writes atomically)."""
        if self._child.poll() is None:
            self._child.kill()
        self._child.wait()
        if self._sending is not None:  # its write fails at once on the closed pipe
            self._sending.join()
        for stream in (self._child.stdin, self._child.stderr):
            if stream is not None and not stream.closed:
                stream.close()


def _record(data_path: str, recover: bool) -> None:
    """The child: import Rerun and read the input, then draw what the replay sends."""
    from pipeline.face import lazy_imports

    lazy_imports.defer()  # as the command line does
    import rerun  # noqa: F401  (what this process is for: loaded while the replay runs)
    import rerun.blueprint  # noqa: F401

    from pipeline.contract import read_dataset
    from pipeline.face.rerun_views import views_for, write_recording
    from pipeline.stages import applicable_stages

    ds = read_dataset(data_path, recover=recover)
    stages = {s.name: s for s in applicable_stages(ds.channels)}
    for stage in stages.values():  # their views' imports (scipy for some), still while the replay runs
        views_for(stage)
    try:
        payload = pickle.load(sys.stdin.buffer)
    except EOFError:  # the replay ended without a recording to write (it failed, or was stopped)
        return
    for name, design in payload["designs"].items():  # what this replay used, --set included
        ds.cache[("design", name)] = design
    write_recording(payload["rrd_path"], ds, [stages[n] for n in payload["stages"]], payload["results"],
                    payload["per_scan"], payload["rerun_run"])


def main() -> None:
    """The child's entry point: ``DATA RECOVER`` (``1`` or ``0``) in ``sys.argv``, the payload on stdin;
    a failure is one line on stderr and exit status 1."""
    import warnings

    warnings.filterwarnings("ignore", category=RuntimeWarning)  # as the command line does
    try:
        _record(sys.argv[1], sys.argv[2] == "1")
    except Exception as exc:  # one line for the parent, which reports it
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        sys.exit(1)
