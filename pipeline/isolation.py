"""Plugged code run in a child process, so that it cannot decide for the tool.

A plugged tracker (``--tracker``, an entry point) is code the package did not write. Run in this
process, a tracker that calls ``os._exit`` ends the replay silently with status 0 and a tracker
that never returns hangs it; a thread cannot be stopped from outside. So a plugged tracker's
construction and its ``track()`` run in a *forked* child (:func:`run_in_child`), and so does a
first, trial import of its file or module (:func:`trackreplay.registry.load_spec`):

* the child starts as a copy of this process (``fork``), so the measurements it reads cost
  nothing to hand over; only what it returns travels back, through a pipe, as pickle protocol 5
  with the arrays' bytes sent out of band and read straight into the arrays' own buffers (one
  copy, no pickled bytes of the data);
* the child ends with ``os._exit`` whatever happens, so no clean-up of this process (buffered
  output files, ``atexit``) runs twice; a child whose parent dies is killed by the kernel
  (``PR_SET_PDEATHSIG`` on Linux, else a thread that watches its parent);
* Ctrl-C reaches the whole process group: the child ignores it and this process, which gets
  ``KeyboardInterrupt``, kills the child on its way out, so the replay stops with its one line;
* a child that ends without an answer (``os._exit``, a signal) raises :class:`ChildEnded`, one
  that is still running at the time limit is killed and raises :class:`ChildTimedOut`; the
  caller turns either into that tracker's one-line failure.

The built-in trackers run in this process, without a limit: they are the package's own code
and pay nothing for the isolation (``docs/trackers.md``, section "A tracker that hangs or ends
the process"). Without ``fork`` (Windows) plugged code runs in this process too, unlimited.
"""

from __future__ import annotations

import os
import pickle
import select
import signal
import struct
import sys
import threading
import time
import warnings

from trackreplay.errors import InputError

#: seconds a plugged tracker (its construction and ``track()`` together), or the trial import of
#: its file, may take before it is stopped; ``--tracker-time-limit`` changes it, 0 means no limit
DEFAULT_TRACKER_TIME_LIMIT_S = 600.0

_LENGTH = struct.Struct("<Q")


class ChildEnded(Exception):
    """The child process ended without an answer; ``how`` says how (exit status or signal)."""

    def __init__(self, how: str):
        self.how = how
        super().__init__(how)


class ChildTimedOut(Exception):
    """The child process was still running at its time limit (``seconds``) and was killed."""

    def __init__(self, seconds: float):
        self.seconds = seconds
        super().__init__(f"still running after {seconds:g} s")


class ChildRaised(Exception):
    """The job raised something that is not an :class:`InputError` in the child: its type name and
    message, as text (the exception itself may not survive a pickle)."""


def can_isolate() -> bool:
    """Whether plugged code can run in a forked child here (POSIX ``fork``)."""
    return hasattr(os, "fork")


def run_in_child(job, time_limit_s: float | None = None):
    """``job()`` run in a forked child process; its return value, sent back through a pipe.

    Parameters
    ----------
    job : callable
        Takes no arguments; what it returns must pickle (arrays travel without a copy of their
        bytes in the pickle).
    time_limit_s : float, optional
        Seconds from the fork until the whole answer is back; None or 0: no limit.

    Returns
    -------
    object
        What ``job()`` returned. Without ``fork`` (see :func:`can_isolate`) ``job()`` runs here.

    Raises
    ------
    InputError
        (or a subclass, e.g. :class:`~trackreplay.trackers.interface.TrackerError`) what ``job``
        raised, rebuilt with its message and file.
    ChildRaised
        ``job`` raised any other exception (``SystemExit`` included).
    ChildEnded
        The child ended without an answer (``os._exit``, killed by a signal).
    ChildTimedOut
        The child was still running at ``time_limit_s`` and was killed.
    """
    if not can_isolate():
        return job()
    limit = time_limit_s if time_limit_s else None
    for stream in (sys.stdout, sys.stderr):  # else the child's copy of the buffers prints them again
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    read_end, write_end = os.pipe()
    parent = os.getpid()
    with warnings.catch_warnings():  # Python ≥ 3.12 warns about fork with threads; the child runs no other
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:  # the child: never returns into the caller's stack
        try:
            os.close(read_end)
            _child(job, write_end, parent)
        finally:
            os._exit(0)
    os.close(write_end)
    deadline = None if limit is None else time.monotonic() + limit
    reader = _PipeReader(read_end, pid, deadline)
    answered = False
    try:
        (meta_size,) = _LENGTH.unpack(reader.read(_LENGTH.size))
        header_size, sizes = pickle.loads(reader.read(meta_size))
        header = reader.read(header_size)
        buffers = [reader.read(n) for n in sizes]
        answer = pickle.loads(header, buffers=buffers)
        answered = True
    except _Eof:
        # its end of the pipe closed: it is ending (it may still be on its way out)
        status = reader.reaped if reader.reaped is not None else _end(pid, deadline or float("inf"))
        reader.reaped = status
        if status is None:
            raise ChildTimedOut(limit) from None
        raise ChildEnded(_how_it_ended(status)) from None
    except _Late:
        raise ChildTimedOut(limit) from None
    finally:
        os.close(read_end)
        if reader.reaped is None:  # answered: it is leaving (what it printed is flushed); else stop it now
            _end(pid, time.monotonic() + 5.0 if answered else None)
    kind = answer[0]
    if kind == "ok":
        return answer[1]
    if kind == "input":
        _, cls, problem, path = answer
        try:
            error = cls(problem, path)
        except TypeError:  # a subclass built another way: its message all the same
            error = InputError(problem, path)
        raise error
    raise ChildRaised(answer[1])


def _child(job, write_end: int, parent: int) -> None:
    """The child's whole life: signals, the job, the answer."""
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's; it ends this process
        for name in ("SIGTERM", "SIGHUP"):  # the parent's handlers (a sweep's) are not this process's
            if hasattr(signal, name):
                signal.signal(getattr(signal, name), signal.SIG_DFL)
    except (ValueError, OSError):  # not the main thread of an embedding interpreter: left as they are
        pass
    _die_with(parent)
    try:
        answer = ("ok", job())
    except InputError as exc:
        answer = ("input", type(exc), exc.problem, exc.path)
    except BaseException as exc:  # noqa: BLE001 - sent to the parent, which names the plugged code
        answer = ("raised", f"{type(exc).__name__}: {exc}")
    buffers = []
    try:
        header = pickle.dumps(answer, protocol=5, buffer_callback=buffers.append)
    except Exception as exc:  # noqa: BLE001 - an answer that does not pickle is the job's failure
        buffers = []
        header = pickle.dumps(("raised", f"its result could not be sent back ({type(exc).__name__}: {exc})"),
                              protocol=5)
    views = [b.raw() for b in buffers]
    meta = pickle.dumps((len(header), [v.nbytes for v in views]))
    try:
        for part in (_LENGTH.pack(len(meta)), meta, header, *views):
            _write_all(write_end, memoryview(part).cast("B"))
        os.close(write_end)
    except OSError:  # the parent is gone or stopped listening
        pass
    for stream in (sys.stdout, sys.stderr):  # what a tracker printed
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass


def _write_all(fd: int, view: memoryview) -> None:
    while view.nbytes:
        view = view[os.write(fd, view):]


def _die_with(parent: int) -> None:
    """Have the kernel kill this process when its parent dies (Linux), else watch the parent."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, signal.SIGKILL, 0, 0, 0) != 0:  # PR_SET_PDEATHSIG
            raise OSError
    except (OSError, AttributeError):
        def watch():
            while os.getppid() == parent:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


class _Eof(Exception):
    pass


class _Late(Exception):
    pass


class _PipeReader:
    """Reads exact byte counts from the child's pipe into fresh (writable) buffers, giving up at
    ``deadline`` or when the child is gone without having written them."""

    def __init__(self, fd: int, pid: int, deadline: float | None):
        self.fd, self.pid, self.deadline = fd, pid, deadline
        self.reaped = None  # the child's wait status once it has ended

    def read(self, n: int) -> bytearray:
        out = bytearray(n)
        view = memoryview(out)
        while view.nbytes:
            wait = 0.5 if self.deadline is None else min(0.5, self.deadline - time.monotonic())
            if wait <= 0:
                raise _Late
            ready, _, _ = select.select([self.fd], [], [], wait)
            if not ready:
                # no data: a child that ended while a process it started holds the pipe open
                # sends no end of file; its status says it is gone
                if self.reaped is None:
                    done, status = os.waitpid(self.pid, os.WNOHANG)
                    if done:
                        self.reaped = status
                elif not select.select([self.fd], [], [], 0)[0]:
                    raise _Eof
                continue
            got = os.readv(self.fd, [view])
            if got == 0:
                raise _Eof
            view = view[got:]
        return out


def _end(pid: int, until: float | None = None):
    """Reap the child: wait for it to end on its own until ``until`` (monotonic seconds; None:
    not at all), then kill it. Returns its wait status when it ended on its own, else None."""
    while until is not None and time.monotonic() < until:
        try:
            done, status = os.waitpid(pid, os.WNOHANG)
        except ChildProcessError:
            return 0
        if done:
            return status
        time.sleep(0.01)
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass
    return None


def _how_it_ended(status: int) -> str:
    if os.WIFSIGNALED(status):
        number = os.WTERMSIG(status)
        try:
            name = signal.Signals(number).name
        except ValueError:
            name = f"signal {number}"
        return f"killed by {name}"
    return f"exit status {os.waitstatus_to_exitcode(status)}"


def plugged_failure_text(error: Exception) -> str:
    """What happened to plugged code that ran in a child, as the tail of a one-line message."""
    if isinstance(error, ChildTimedOut):
        return (f"did not finish within {error.seconds:g} s and was stopped (--tracker-time-limit sets the "
                "limit; 0 lifts it)")
    if isinstance(error, ChildEnded):
        return f"ended its process ({error.how}) instead of returning"
    return f"raised {error}"


def run_plugged_tracker(name: str, where: str, job, time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S):
    """``job()`` (a plugged tracker's construction and :func:`~trackreplay.trackers.interface.call_tracker`)
    in a child process (:func:`run_in_child`); its checked outputs.

    Raises
    ------
    TrackerError
        One line naming the tracker: what ``job`` raised as a ``TrackerError``, or that the
        tracker ended its process, or that it was stopped at ``time_limit_s``.
    InputError
        What ``job`` raised as an ``InputError`` (a design value the tracker refuses).
    """
    from trackreplay.trackers.interface import TrackerError

    try:
        return run_in_child(job, time_limit_s)
    except (ChildEnded, ChildTimedOut, ChildRaised) as exc:
        raise TrackerError(f"tracker {name!r}: {plugged_failure_text(exc)}", where) from None
