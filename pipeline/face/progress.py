"""Progress bars and timings of the ``replay`` commands, on stderr only.

A bar is drawn only when stderr is a terminal: a run piped into a file or another program, a CI
log or a test prints no bar and no label line, so its stdout and stderr hold only results and
errors. ``--quiet`` (on ``replay`` or on any command) turns the bars off on a terminal too;
``--verbose`` adds one ``timing:`` line per phase on stderr (also when stderr is not a
terminal).

Use from a command::

    from trackreplay.face import progress

    with progress.bar(len(points), "sweep radar-tws", show_pos=True) as bar:
        for point in points:
            ...
            bar.update(1)            # same call as click.progressbar's bar.update
            bar.echo("a line")       # prints above the bar without garbling it
    progress.timing("write", seconds)   # "timing: write 0.12 s" with --verbose

``bar()`` and ``timing()`` read the settings of the running command (``--quiet``,
``--verbose``); outside a click command they take the defaults (bars on a terminal, no
timings). :func:`progress_options` adds ``--quiet``/``--verbose`` to a command,
:func:`add_progress_options` to an existing command object.
"""

from __future__ import annotations

import shutil
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass

import click

_META_KEY = "replay.progress"
_REDRAW_S = 0.1  # at most ten redraws a second: per-scan updates cost nothing


@dataclass
class Settings:
    """What the user asked for: ``quiet`` (no bars), ``verbose`` (timings)."""

    quiet: bool = False
    verbose: bool = False


def settings(ctx: click.Context | None = None) -> Settings:
    """The progress settings of the running command (shared by the group and its commands)."""
    ctx = ctx or click.get_current_context(silent=True)
    if ctx is None:
        return Settings()
    return ctx.meta.setdefault(_META_KEY, Settings())


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def bars_enabled() -> bool:
    """True when a bar would be drawn now: stderr is a terminal and ``--quiet`` was not given."""
    return not settings().quiet and _is_terminal(sys.stderr)


def verbose() -> bool:
    return settings().verbose


def _set_quiet(ctx, param, value):
    if value:
        settings(ctx).quiet = True


def _set_verbose(ctx, param, value):
    if value:
        settings(ctx).verbose = True


QUIET_HELP = "No progress bars (they are drawn only when stderr is a terminal)."
VERBOSE_HELP = "Print the time of each phase on stderr."


def _options() -> list[click.Option]:
    return [click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, is_eager=True, callback=_set_quiet,
                         help=QUIET_HELP),
            click.Option(["-v", "--verbose"], is_flag=True, expose_value=False, is_eager=True, callback=_set_verbose,
                         help=VERBOSE_HELP)]


def progress_options(f):
    """Decorator: ``--quiet`` and ``--verbose`` on a command (values land in :func:`settings`)."""
    f = click.option("-v", "--verbose", is_flag=True, expose_value=False, is_eager=True, callback=_set_verbose,
                     help=VERBOSE_HELP)(f)
    return click.option("-q", "--quiet", is_flag=True, expose_value=False, is_eager=True, callback=_set_quiet,
                        help=QUIET_HELP)(f)


def add_progress_options(command: click.Command) -> None:
    """Add ``--quiet``/``--verbose`` to an existing command (and to a group's commands), unless
    it has them already."""
    names = {n for p in command.params for n in getattr(p, "opts", ())}
    if "--quiet" not in names:
        taken = names | {n for p in command.params for n in getattr(p, "secondary_opts", ())}
        for opt in _options():
            opt.opts = [o for o in opt.opts if o not in taken]
            command.params.append(opt)
    for sub in getattr(command, "commands", {}).values():
        add_progress_options(sub)


def timing(label: str, seconds: float) -> None:
    """``timing: LABEL 1.23 s`` on stderr with ``--verbose`` (nothing otherwise)."""
    if verbose():
        click.echo(f"timing: {label} {seconds:.2f} s", err=True)


@contextmanager
def timed(label: str):
    """Time a block and report it with :func:`timing`."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timing(label, time.perf_counter() - t0)


class Bar:
    """A progress bar on stderr, drawn only when :func:`bars_enabled` (else every call is a
    no-op apart from :meth:`echo`, which still prints)."""

    def __init__(self, length: int, label: str, show_pos: bool = False, enabled: bool | None = None):
        self.length = max(int(length), 0)
        self.label = label
        self.show_pos = show_pos
        self.pos = 0
        self.enabled = bars_enabled() if enabled is None else enabled
        self._t0 = time.perf_counter()
        self._drawn_at = 0.0
        self._shown = False

    # -- the click.progressbar subset the commands use
    def update(self, n: int = 1) -> None:
        self.pos = min(self.pos + n, self.length) if self.length else self.pos + n
        self._draw()

    def set_label(self, label: str) -> None:
        self.label = label
        self._draw(force=True)

    def advance(self, n: int = 1, label: str | None = None) -> None:
        """Move on by ``n`` steps, optionally under a new label, and redraw now."""
        self.pos = min(self.pos + n, self.length) if self.length else self.pos + n
        if label is not None:
            self.label = label
        self._draw(force=True)

    def echo(self, message: str = "", err: bool = False) -> None:
        """Print a line (stdout, or stderr with ``err``) above the bar."""
        self._clear()
        click.echo(message, err=err)
        self._draw(force=True)

    def __enter__(self) -> "Bar":
        self._draw(force=True)
        return self

    def __exit__(self, *exc) -> bool:
        self._clear()
        return False

    # -- drawing
    def _line(self) -> str:
        width = shutil.get_terminal_size((100, 20)).columns
        elapsed = time.perf_counter() - self._t0
        pos = f" {self.pos}/{self.length}" if self.show_pos and self.length else ""
        tail = f"{pos} {elapsed:5.1f} s"
        if self.length:
            cells = max(10, min(30, width - len(self.label) - len(tail) - 4))
            done = int(cells * self.pos / self.length)
            bar = f" [{'#' * done}{'-' * (cells - done)}]"
        else:
            bar = ""
        return (self.label + bar + tail)[: max(width - 1, 20)]

    def _draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if not force and now - self._drawn_at < _REDRAW_S and self.pos < self.length:
            return
        self._drawn_at = now
        sys.stderr.write("\r\x1b[K" + self._line())
        sys.stderr.flush()
        self._shown = True

    def _clear(self) -> None:
        if self.enabled and self._shown:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()
            self._shown = False


def bar(length: int, label: str, show_pos: bool = False) -> Bar:
    """A :class:`Bar` for ``length`` steps (a context manager; ``update(n)`` like click's)."""
    return Bar(length, label, show_pos)


class Phases:
    """Progress through named phases: one bar step and (with ``--verbose``) one timing line
    per phase. ``step()`` closes the current phase and starts the next; it fits a ``progress``
    callback that is called once per phase (e.g. :func:`trackreplay.replay.replay`'s)."""

    def __init__(self, label: str, phases):
        self.phases = list(phases)
        self.label = label
        self.i = 0
        self._bar = Bar(len(self.phases), self._text())
        self._t = time.perf_counter()

    def _text(self) -> str:
        name = self.phases[self.i] if self.i < len(self.phases) else "done"
        return f"{self.label}: {name}"

    def step(self, n: int = 1, seconds: float | None = None, note: str | None = None) -> None:
        """Close ``n`` phases; ``seconds``: the closed phase's own time, when phases ran
        interleaved (e.g. a replay's filter, evaluate and write, tracker by tracker) and the
        time since the last step is not it; ``note`` follows the time (e.g. that it overlapped
        another phase)."""
        for _ in range(n):
            now = time.perf_counter()
            if self.i < len(self.phases):
                name = self.phases[self.i]
                if verbose():
                    took = now - self._t if seconds is None else seconds
                    self._bar.echo(f"timing: {name} {took:.2f} s" + (f" ({note})" if note else ""), err=True)
                self.i += 1
            self._t = now
            self._bar.advance(1, self._text())

    def echo(self, message: str = "", err: bool = False) -> None:
        self._bar.echo(message, err)

    def __enter__(self) -> "Phases":
        self._bar.__enter__()
        self._t = time.perf_counter()
        return self

    def __exit__(self, *exc) -> bool:
        return self._bar.__exit__(*exc)
