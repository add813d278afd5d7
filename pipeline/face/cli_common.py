"""What every ``replay`` command shares: the one-line errors, the options used by several
commands (``--force``, ``--tracker``, ``--tracker-time-limit``), where the bundled data live.
"""

from __future__ import annotations

from pathlib import Path

import click

from trackreplay.errors import InputError


DEMO_NAME = "radar_tws_demo.mcap"


class UserError(click.ClickException):
    exit_code = 2

    def show(self, file=None):
        click.echo(f"replay: error: {self.format_message()}", err=True)


def bundled_data_dir() -> Path:
    """``data/`` of the source tree when run from a clone, else the installed copy."""
    local = Path.cwd() / "data"
    if (local / "baselines").is_dir():
        return local
    try:
        from importlib.resources import files

        return Path(str(files("replay_data")))
    except ModuleNotFoundError:
        return Path(__file__).resolve().parents[2] / "data"


def checkout_data_dir(start: Path | None = None) -> Path | None:
    """``data/`` of the source checkout that ``start`` (default: the current folder) is in:
    the nearest folder upwards holding ``pyproject.toml`` and ``data/baselines/``."""
    here = (start or Path.cwd()).resolve()
    for folder in (here, *here.parents):
        if (folder / "pyproject.toml").is_file() and (folder / "data" / "baselines").is_dir():
            return folder / "data"
    return None


def inside_installed_package(path: Path) -> bool:
    """True when ``path`` lies in an installed package (site-packages, dist-packages or an
    interpreter's library folder), where nothing should be written."""
    import site
    import sysconfig

    resolved = Path(path).resolve()
    if any(part in ("site-packages", "dist-packages") for part in resolved.parts):
        return True
    roots = {sysconfig.get_paths().get(k) for k in ("purelib", "platlib")}
    try:
        roots |= set(site.getsitepackages())
    except AttributeError:  # some virtualenvs lack it
        pass
    for root in filter(None, roots):
        try:
            resolved.relative_to(Path(root).resolve())
            return True
        except ValueError:
            continue
    return False


TRACKER_HELP = ("A plugged tracker to run beside the built-ins: FILE.py:CLASS, MODULE:CLASS or the name of an "
                "installed (entry-point) tracker; repeat for several (see `replay trackers`).")


def force_option(f):
    """``--force``: replace the output file if it exists (without it, an existing one is refused)."""
    return click.option("--force", is_flag=True, help="Replace the output file if it exists.")(f)


def tracker_option(f):
    """The ``--tracker SPEC`` option (repeatable) shared by run, eval, check, sweep and trackers."""
    return click.option("--tracker", "tracker_specs", multiple=True, metavar="SPEC", help=TRACKER_HELP)(f)


def tracker_time_limit_option(f):
    """``--tracker-time-limit SECONDS``: how long a plugged tracker may run (run and sweep)."""
    from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S

    return click.option("--tracker-time-limit", "tracker_time_limit_s", type=click.FloatRange(min=0),
                        default=DEFAULT_TRACKER_TIME_LIMIT_S, show_default=True, metavar="SECONDS",
                        help="Seconds a plugged (--tracker) tracker may take, its first import included, before "
                             "it is stopped and reported as failed; 0: no limit. Plugged trackers run in a child "
                             "process (one that exits or hangs fails alone); the built-ins run unlimited.")(f)


def resolve_tracker_specs(specs, time_limit_s: float | None = None) -> list[str]:
    """``--tracker`` values as loadable specs, each loaded once here so that a bad one fails
    before any work with one line.

    ``FILE.py:CLASS`` and ``MODULE:CLASS`` stay as given; the name of an installed
    (entry-point) tracker becomes its ``module:Class`` spec; a built-in's name is dropped (the
    built-ins run anyway).

    Raises
    ------
    InputError
        A file, module or class that does not load, a class that is not a Tracker, an unknown
        name, or two trackers with one name.
    """
    from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S
    from trackreplay.registry import available_trackers

    limit = DEFAULT_TRACKER_TIME_LIMIT_S if time_limit_s is None else time_limit_s
    out = []
    installed = None
    for spec in dict.fromkeys(s.strip() for s in specs):
        if ":" in spec:
            out.append(spec)
            continue
        installed = installed if installed is not None else available_trackers((), limit)
        entry = installed.get(spec)
        if entry is None:
            raise InputError(f"--tracker {spec!r}: no installed tracker has that name (known: "
                             f"{', '.join(sorted(installed))}); give FILE.py:CLASS or MODULE:CLASS")
        if not entry.builtin:
            out.append(entry.spec)
    if out:  # the plugged trackers load, and no name clashes with another tracker
        available_trackers(out, limit)
    return out


class InternalError(UserError):
    """A failure that is the program's, not the input's: one line still, exit status 3."""

    exit_code = 3


def fail_on_tracker_errors(lines) -> None:
    """Print one ``replay: error:`` line per failed tracker and exit 2 (after the outputs are written)."""
    if lines:
        for line in lines:
            click.echo(f"replay: error: {line}", err=True)
        raise click.exceptions.Exit(2)


def _parameter_options(args) -> dict:
    """Extra ``--name value`` / ``--name=value`` options of ``simulate`` → scenario overrides
    (``--emitter-velocity-mps`` names ``emitter_velocity_mps``), exactly like ``--set name=value``."""
    out, i = {}, 0
    while i < len(args):
        arg = args[i]
        if not arg.startswith("--") or arg == "--":
            raise InputError(f"unexpected argument {arg!r} (scenario parameters go as --name value or --set name=value)")
        name, eq, value = arg[2:].partition("=")
        if not eq:
            if i + 1 >= len(args) or args[i + 1].startswith("--"):
                raise InputError(f"option --{name} needs a value")
            value, i = args[i + 1], i + 1
        out[name.replace("-", "_")] = value
        i += 1
    return out


def _json_value(v):
    if isinstance(v, float) and v != v:
        return None
    return v


# The evaluation design values of every stage with their defaults (Stage.evaluation_defaults;
# tests/test_evaluation_design_values.py keeps this text equal to them): written out here so
# that `--help` needs no import of the stages.
EVALUATION_VALUES_EPILOG = """Evaluation design values (--set NAME=VALUE) with each stage's fixed defaults; a data set's
scenario record, or the data set itself, may give others (docs/evaluation.md, "Evaluation design values"):

\b
  radar      ospa_cutoff_m=1000, ospa_order=2, assignment_gate_m=500,
             hota_distance_m=1000, gospa_switch_penalty_m=1000, siap_gate_m=500
  xcorr      ospa_cutoff_deg=10, ospa_order=2, assignment_gate_deg=5
  array      ospa_cutoff_deg=10, ospa_order=2, assignment_gate_deg=3
  tdoa-fdoa  ospa_cutoff_m=5000, ospa_order=2, assignment_gate_m=2000
  colored    ospa_cutoff_m=100, ospa_order=2, assignment_gate_m=50"""


EVALUATION_SET_HELP = ("Score with this evaluation design value (the matching gate, the GOSPA cut-off and order, "
                       "HOTA's distance scale, the SIAP gate; listed below); repeatable.")
