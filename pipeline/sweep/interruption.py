"""Stopping a sweep: SIGINT, SIGTERM and SIGHUP become exceptions the executors clean up after
(:class:`SweepTerminated`), held back while a step that must not be cut runs."""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager


class SweepTerminated(SystemExit):
    """A sweep stopped by SIGTERM or SIGHUP: finished points are kept, workers are stopped.
    Its code is the conventional exit status 128 + signal number."""


@contextmanager
def _stop_on_signals():
    """While a sweep runs: SIGINT raises ``KeyboardInterrupt`` and SIGTERM/SIGHUP raise
    :class:`SweepTerminated`, each once, so the executors' clean-up runs instead of the process
    dying with its workers left behind. A signal the process ignores (``nohup``) stays ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired = []

    def handler(signum, frame):
        if _HELD["depth"]:  # in a step that must not be cut (starting a worker): after it
            _HELD["pending"].append(signum)
            return
        if fired:  # already stopping: let the clean-up finish
            return
        fired.append(signum)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        name = signal.Signals(signum).name
        try:
            sys.stderr.write(f"sweep: stopped by {name}; finished points are kept\n")
            sys.stderr.flush()
        except (OSError, ValueError):
            pass
        raise SweepTerminated(128 + signum)

    sigs = [signal.SIGINT, signal.SIGTERM] + ([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])
    old = {s: signal.getsignal(s) for s in sigs}
    for s in sigs:
        if old[s] is not signal.SIG_IGN:
            signal.signal(s, handler)
    outer = _HELD["handler"]
    _HELD["handler"] = handler
    try:
        yield
    finally:
        _HELD["handler"] = outer
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


# the stop signals held back while a worker starts (see _signals_held): its depth, the signals
# that came meanwhile, and the handler of the sweep running (None outside one)
_HELD = {"depth": 0, "pending": [], "handler": None}


@contextmanager
def _signals_held():
    """Hold back the sweep's stop signals (:func:`_stop_on_signals`) for a step that must not be
    cut, and act on them after it.

    Starting a pool worker is such a step: a signal that lands inside ``Process.start`` stops
    the sweep after the forkserver made the worker but before the pool recorded it, so it is
    never stopped; it goes on starting, finds its queues' semaphores gone with the sweep, and
    prints a traceback on the terminal.
    """
    _HELD["depth"] += 1
    try:
        yield
    finally:
        _HELD["depth"] -= 1
        if not _HELD["depth"] and _HELD["pending"]:
            signum = _HELD["pending"][0]
            _HELD["pending"].clear()
            if _HELD["handler"] is not None:
                _HELD["handler"](signum, None)
