"""User-facing errors.

Anything raised as :class:`InputError` is a problem with what the user gave us (a file, a
parameter, a channel); the CLI prints its one-line message and exits non-zero without a
traceback. Every other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # annotations only: the cores import this module and do no file work
    from pathlib import Path


class InputError(Exception):
    """A problem with user input, reported as one line: ``<file>: <problem>``."""

    def __init__(self, problem: str, path: str | Path | None = None):
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path else problem)


class DesignValueError(InputError, ValueError):
    """A design value its parameter does not accept (:meth:`trackreplay.trackers.interface.Param.check`):
    the user's input (one line, exit 2) and, to code that builds a tracker, a ``ValueError``."""


def require_finite(name: str, values, path: str | Path | None = None) -> None:
    """Raise :class:`InputError` if ``values`` holds NaN or Inf.

    Parameters
    ----------
    name : str
        What the values are, for the message.
    values : array_like
        Numbers to check.
    path : str or Path, optional
        The file they came from.
    """
    import numpy as np

    arr = np.asarray(values)
    if arr.dtype.kind in "fc" and not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise InputError(f"{name} holds {bad} NaN/Inf value(s)", path)


def check_all(checks, path: str | Path | None = None) -> None:
    """Raise :class:`InputError` with the message of the first failed check.

    Parameters
    ----------
    checks : iterable of (bool, str)
        ``(condition, message)`` pairs, in the order they should be reported; a condition
        that is false makes its message the error.
    path : str or Path, optional
        The file the checked values came from.

    Raises
    ------
    InputError
        At the first false condition.
    """
    for ok, message in checks:
        if not ok:
            raise InputError(message, path)


def require_finite_params(params, path: str | Path | None = None) -> None:
    """Raise :class:`InputError` if a float parameter is NaN or ±Inf.

    Parameters
    ----------
    params : mapping of str to value
        Scenario or design parameters; only float values are checked (lists and strings
        have their own parsers and checks).
    path : str or Path, optional
        The file the parameters came from.

    Raises
    ------
    InputError
        ``parameter '<key>' must be finite`` for the first offending key.
    """
    import math

    for key, value in params.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"parameter {key!r} must be finite", path)
