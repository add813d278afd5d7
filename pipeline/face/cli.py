"""The ``replay`` command line.

``replay DATA.mcap`` replays a data set (``replay`` alone replays the bundled demo); the other
commands simulate, convert, evaluate, check against baselines, sweep parameters, view and
export. User errors print one line and exit with status 2; only bugs show a traceback. Progress
bars go to stderr, only when it is a terminal (:mod:`trackreplay.face.progress`); results go to
stdout.

This module holds the ``replay`` group itself (how a first argument is read, how errors become
one line and an exit status) and ``replay help``; the commands live in ``cli_<group>.py``
modules beside it (:data:`COMMAND_MODULES`), the text they print in ``cli_text.py``, what they
share in ``cli_common.py``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

# numpy asks the kernel for transparent huge pages on every array of 4 MB and more; a replay
# makes its large arrays once, fills them once and frees them, and on this 2-core machine the
# page faults (with compaction) cost more than the huge pages save: 10,000 radar runs 0.13–0.48 s
# faster without, in 6 of 6 interleaved pairs, 1,000 array runs 0.43–0.96 s in 3 of 3, no change
# on 500 coloured-noise or 10 radar runs (docs/benchmarks.md). numpy reads this when it is first
# imported, which the command line does lazily, after this line; a value the user set stands.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
# the Rerun SDK logs its own failures (a full disk, say) as lines on stderr; they reach the user
# as the one line naming the file (trackreplay.paths.disk_error), so its log stays off unless asked
os.environ.setdefault("RUST_LOG", "off")

import click

from trackreplay.face import lazy_imports

lazy_imports.defer()  # numpy.f2py, which scipy's import pulls in for nothing: 0.08–0.15 s of every replay

from trackreplay import __version__
from trackreplay.errors import InputError
from trackreplay.face import progress
from trackreplay.face.cli_common import InternalError, UserError
from trackreplay.face.cli_data import convert_group
from trackreplay.vocabulary import FAMILIES


class ReplayGroup(click.Group):
    """``replay FILE`` means ``replay run FILE``; a mistyped command gets a suggestion; every user
    error, click's own usage errors included, becomes one line and exit status 2."""

    def parse_args(self, ctx, args):
        args = list(args)
        # the group's own flags (--quiet, --verbose) may come first: `replay -q data.mcap`
        i = 0
        while i < len(args) and args[i] in GROUP_FLAGS:
            i += 1
        if i == len(args):
            if not any(a in ("-h", "--help", "--version") for a in args):
                args = [*args, "run"]
        elif args[i] not in self.commands and not args[i].startswith("-"):
            if not _looks_like_data(args[i]):
                import difflib

                close = difflib.get_close_matches(args[i], list(self.commands), n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                raise click.UsageError(f"no such command or file {args[i]!r}{hint}; see `replay --help`")
            args = [*args[:i], "run", *args[i:]]
        elif args[i].split("=")[0] in self._run_options():
            # `replay --rerun-run 5 data.mcap`: options of run before the data file mean run too
            args = [*args[:i], "run", *args[i:]]
        return super().parse_args(ctx, args)

    def _run_options(self) -> set:
        run = self.commands.get("run")
        names = {o for p in (run.params if run is not None else ()) for o in getattr(p, "opts", ())}
        return {n for n in names if n.startswith("-")} - {"-h", "--help", "-q", "--quiet", "-v", "--verbose"}

    def invoke(self, ctx):
        from trackreplay.machine import keep_freed_memory

        # this process runs one command and ends: its large arrays reuse the memory freed by the
        # ones before them rather than being faulted in afresh (not under --help, which never
        # gets here)
        keep_freed_memory()
        try:
            return super().invoke(ctx)
        except InputError as exc:
            raise UserError(str(exc)) from None
        except BrokenPipeError:
            # the reader of our output went away (`replay trackers | head`): nothing is wrong and
            # nothing is left to say, as with any Unix tool; stdout goes to /dev/null so that the
            # interpreter's final flush does not complain either
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            sys.exit(141)  # 128 + SIGPIPE, what a shell reports for a tool stopped by its pipe
        except OSError as exc:
            # the file system's answer (a folder that is a file, no permission, disk full)
            where = f"{exc.filename}: " if exc.filename else ""
            raise UserError(f"{where}{exc.strerror or exc}") from None
        except MemoryError:
            raise UserError("not enough memory for this data set (MemoryError)") from None
        except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except Exception as exc:  # a bug of ours: one line for the user, the traceback with --verbose
            from trackreplay.face import progress

            if progress.verbose():
                raise
            raise InternalError(f"internal error: {type(exc).__name__}: {exc} (run again with --verbose for the "
                                "traceback, and please report it)") from None

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        import warnings

        # numerical warnings on odd but accepted data would break the one-line error contract;
        # what they signal reaches the user as flags in the outputs or as a one-line error
        warnings.filterwarnings("ignore", category=RuntimeWarning)
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as exc:
            where = f" ({exc.ctx.command_path})" if exc.ctx is not None and exc.ctx.command_path != "replay" else ""
            click.echo(f"replay: error: {exc.format_message()}{where}", err=True)
            sys.exit(2)
        except click.ClickException as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except click.exceptions.Abort:
            click.echo("replay: interrupted", err=True)
            sys.exit(130)
        except KeyboardInterrupt:
            click.echo("replay: interrupted", err=True)
            sys.exit(130)
        if isinstance(rv, int) and standalone_mode:
            sys.exit(rv)
        if standalone_mode:
            sys.exit(0)
        return rv


GROUP_FLAGS = ("-q", "--quiet", "-v", "--verbose")


def _looks_like_data(arg: str) -> bool:
    """A first argument that is a data set rather than a (mistyped) command name."""
    path = Path(arg)
    return path.exists() or path.suffix != "" or "/" in arg or "\\" in arg


@click.group(cls=ReplayGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="replay")
@progress.progress_options
def main():
    """Offline replay and evaluation of target-tracking algorithms.

    Progress bars appear on stderr when it is a terminal; --quiet (here or on any command)
    turns them off, --verbose adds the time of each phase.

    \b
    Examples:
      replay                                   # the bundled demo data set
      replay data/radar_tws_demo.mcap
      replay simulate radar-tws --runs 500 --seed 7 -o radar.mcap
      replay scenarios radar-tws               # its parameters, units and defaults
      replay eval radar.mcap --json
      replay check
      replay sweep radar-tws --param sigma_bearing_deg=0.5,1,2 --runs 100 -o study/
      replay export --foxglove replay-out/radar_tws_demo/tracks.mcap -o view.mcap
    """


@main.command("help")
@click.argument("command", required=False)
@click.pass_context
def help_cmd(ctx, command):
    """The help of replay, or of one command.

    \b
    Example:
      replay help
      replay help sweep
    """
    group = ctx.parent.command
    if command is None:
        click.echo(group.get_help(ctx.parent))
        return
    cmd = group.get_command(ctx.parent, command)
    if cmd is None:
        import difflib

        close = difflib.get_close_matches(command, list(group.commands), n=1)
        raise click.UsageError(f"no such command {command!r}" + (f" (did you mean '{close[0]}'?)" if close else ""))
    with click.Context(cmd, info_name=command, parent=ctx.parent) as sub:
        click.echo(cmd.get_help(sub))


# The commands, one module per group of them; each exposes COMMANDS, added to `replay` (the
# modules never import this one: the group, its error handling and `help` live here alone)
COMMAND_MODULES: tuple[str, ...] = (
    "trackreplay.face.cli_run",       # run (what `replay DATA.mcap` means)
    "trackreplay.face.cli_data",      # simulate, scenarios, convert
    "trackreplay.face.cli_eval",      # eval, plot, compare, check
    "trackreplay.face.cli_sweep",     # sweep
    "trackreplay.face.cli_trackers",  # trackers
    "trackreplay.face.cli_export",    # view, export
)

# Paper-specific commands (e.g. `replay crlb`) live next to their paper's code, in
# face/cli_<stem>.py of the families declared with commands (trackreplay.vocabulary.FAMILIES); the
# convert modules below add importers. Each module exposes COMMANDS, a list of click commands added
# to `replay`, and may expose CONVERT_COMMANDS, added under `replay convert` (the modules never
# import this one: no circle).
EXTENSION_MODULES: tuple[str, ...] = tuple(f.command_module for f in FAMILIES.values() if f.commands) + (
    "trackreplay.face.cli_convert_upgrade",
    "trackreplay.face.cli_convert_tables",
    "trackreplay.face.cli_convert_foreign",
    "trackreplay.face.cli_info",
)


def _register_extensions() -> None:
    import importlib

    for name in COMMAND_MODULES + EXTENSION_MODULES:
        module = importlib.import_module(name)
        for cmd in module.COMMANDS:
            main.add_command(cmd)
        for cmd in getattr(module, "CONVERT_COMMANDS", ()):
            convert_group.add_command(cmd)


_register_extensions()
for _command in main.commands.values():  # --quiet / --verbose are accepted by every command
    progress.add_progress_options(_command)

if __name__ == "__main__":  # pragma: no cover
    main()
