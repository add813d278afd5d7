"""Where trackers come from: built in, installed packages (entry points), or a file or module
given on the command line.

A *spec* says how to load a tracker and travels to sweep workers as text, so a tracker given
by path loads the same way on a process-pool or Dask worker:

* ``path/to/file.py:ClassName`` — a class in a plain Python file;
* ``package.module:ClassName`` — a class in an importable module;
* a name registered in the entry-point group ``trackreplay.trackers`` (the entry point's object
  is a :class:`~trackreplay.trackers.interface.Tracker` subclass, or a list of them).

A file or module not yet imported is first imported in a child process
(:func:`trackreplay.isolation.run_in_child`) and only then here: an import that ends its process
(``os._exit``) or never finishes is one line naming the file, not the end of the tool or a hang.

See ``docs/trackers.md``.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path

from trackreplay import vocabulary as vocab
from trackreplay.errors import InputError
from trackreplay.isolation import DEFAULT_TRACKER_TIME_LIMIT_S, ChildEnded, ChildRaised, ChildTimedOut, run_in_child
from trackreplay.trackers.interface import Tracker, tracker_name

ENTRY_POINT_GROUP = "trackreplay.trackers"

# The modules that hold each family's built-in trackers (each exposing TRACKERS, a tuple of
# classes), from the families' declaration; a replay imports only its family's numerics
BUILTIN_FAMILY_MODULES = {f.name: f.builtin_tracker_modules for f in vocab.FAMILIES.values()}
BUILTIN_MODULES = tuple(m for modules in BUILTIN_FAMILY_MODULES.values() for m in modules)


@dataclass(frozen=True)
class TrackerEntry:
    """A tracker the registry knows: its class, where it came from and how to load it again."""

    name: str
    cls: type
    source: str  # "built-in", "entry point <dist>", or the spec it was loaded from
    spec: str    # loads the class again in another process ("" for built-ins)

    @property
    def family(self) -> str:
        return self.cls.family

    @property
    def builtin(self) -> bool:
        return self.source == "built-in"


def _check_class(obj, spec: str) -> type:
    if not (isinstance(obj, type) and issubclass(obj, Tracker)):
        what = f"class {obj.__qualname__}" if isinstance(obj, type) else f"{type(obj).__name__} {obj!r}"
        raise InputError(f"{spec}: {what} is not a Tracker subclass (see docs/trackers.md)")
    if obj.family in vocab.FORMER_FAMILY_NAMES:
        raise InputError(f"{spec}: tracker {tracker_name(obj)!r} has family {obj.family!r}, which is now called "
                         f"{vocab.FORMER_FAMILY_NAMES[obj.family]!r} (family = {vocab.FORMER_FAMILY_NAMES[obj.family]!r})")
    if obj.family not in vocab.FAMILIES:
        raise InputError(f"{spec}: tracker {tracker_name(obj)!r} has family {obj.family!r}; known families: "
                         f"{', '.join(vocab.FAMILIES)}")
    if obj.form not in ("batch", "run"):
        raise InputError(f"{spec}: tracker {tracker_name(obj)!r} has form {obj.form!r}; use 'batch' or 'run'")
    method = "track" if obj.form == "batch" else "track_run"
    if getattr(obj, method) is getattr(Tracker, method):
        raise InputError(f"{spec}: tracker {tracker_name(obj)!r} has form {obj.form!r} but does not implement "
                         f"{method}()")
    return obj


def _tried_in_child(load, where, time_limit_s: float | None) -> None:
    """Run ``load`` (an import) in a child process first, so that plugged code that ends its
    process or never returns while it is imported fails by name instead of ending or hanging
    this one.

    Raises
    ------
    InputError
        Naming ``where`` (the file or module): the import ended the process, or was still
        running at ``time_limit_s``; an import that raises an :class:`InputError` in the child
        raises it here (any other exception is left to the import in this process).
    """
    def trial():
        load()  # the module stays in the child; nothing comes back but the outcome

    try:
        run_in_child(trial, time_limit_s)
    except ChildTimedOut as exc:
        raise InputError(f"importing it did not finish within {exc.seconds:g} s and was stopped "
                         "(--tracker-time-limit sets the limit; 0 lifts it)", where) from None
    except ChildEnded as exc:
        raise InputError(f"importing it ended the process ({exc.how})", where) from None
    except ChildRaised:
        pass  # an exception: the import here raises it again, and says it as it always has


def _file_module_name(path: Path) -> str:
    return "trackreplay_user_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]


def _load_file_module(path: Path, spec: str):
    if not path.is_file():
        raise InputError("no such file" if not path.exists() else "not a file", path)
    resolved = path.resolve()
    mod_name = _file_module_name(path)
    if mod_name in sys.modules:
        return sys.modules[mod_name]
    module_spec = importlib.util.spec_from_file_location(mod_name, resolved)
    if module_spec is None or module_spec.loader is None:
        raise InputError("cannot be loaded as a Python module", path)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[mod_name] = module
    # the file's folder is on the path while it loads, as for a script run from there: a tracker
    # file imports the modules beside it
    folder = str(resolved.parent)
    added = folder not in sys.path
    if added:
        sys.path.insert(0, folder)
    try:
        module_spec.loader.exec_module(module)
    except (Exception, SystemExit) as exc:  # sys.exit() at import is the file's failure, not the tool's exit
        del sys.modules[mod_name]
        raise InputError(f"importing it raised {type(exc).__name__}: {exc}", path) from None
    finally:
        if added:
            sys.path.remove(folder)
    return module


def load_spec(spec: str, time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S) -> type:
    """The tracker class a ``--tracker`` spec names (``file.py:Class`` or ``module:Class``).

    A file or module not imported yet is imported in a child process first, stopped at
    ``time_limit_s`` seconds (0 or None: no limit).
    """
    target, sep, attr = spec.rpartition(":")
    if not sep or not target or not attr:
        raise InputError(f"--tracker {spec!r}: expected FILE.py:CLASS or MODULE:CLASS")
    if target.endswith(".py") or "/" in target or "\\" in target:
        path = Path(target)
        if path.is_file() and _file_module_name(path) not in sys.modules:
            _tried_in_child(lambda: _load_file_module(path, spec), path, time_limit_s)
        module = _load_file_module(path, spec)
        where = target
    else:
        if target not in sys.modules:
            _tried_in_child(lambda: _import_module(target, spec), target, time_limit_s)
        module = _import_module(target, spec)
        where = target
    if not hasattr(module, attr):
        have = sorted(n for n, v in vars(module).items()
                      if isinstance(v, type) and issubclass(v, Tracker) and v is not Tracker)
        raise InputError(f"no class {attr!r} (trackers defined there: {', '.join(have) or 'none'})", where)
    return _check_class(getattr(module, attr), spec)


def _import_module(target: str, spec: str):
    try:
        return importlib.import_module(target)
    except (Exception, SystemExit) as exc:
        raise InputError(f"--tracker {spec!r}: cannot import {target!r} ({type(exc).__name__}: {exc})") from None


def canonical_spec(spec: str) -> str:
    """A spec with its file made absolute, so that workers in other folders load the same file."""
    target, sep, attr = spec.rpartition(":")
    if sep and (target.endswith(".py") or "/" in target):
        return f"{Path(target).resolve()}:{attr}"
    return spec


def _builtin_entries(modules=BUILTIN_MODULES) -> list[TrackerEntry]:
    out = []
    for module in modules:
        for cls in importlib.import_module(module).TRACKERS:
            out.append(TrackerEntry(tracker_name(cls), cls, "built-in", ""))
    return out


@functools.lru_cache(maxsize=8)
def _entry_points_on(search_path: tuple[str, ...]) -> tuple:
    """The tracker entry points of the distributions on ``search_path``: scanning them costs
    5–8 ms, and a replay asks once per scoring of every stage (the same ``sys.path`` gives the
    same answer; a path added, as a test's site folder is, scans again)."""
    from importlib.metadata import entry_points

    return tuple(entry_points(group=ENTRY_POINT_GROUP))


def _entry_point_entries(time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S) -> list[TrackerEntry]:
    out = []
    for ep in _entry_points_on(tuple(sys.path)):
        where = f"entry point {ep.name} ({ep.value})"
        if ep.module not in sys.modules:
            _tried_in_child(ep.load, where, time_limit_s)
        try:
            obj = ep.load()
        except (Exception, SystemExit) as exc:
            raise InputError(f"{where}: loading raised {type(exc).__name__}: {exc}") from None
        for cls in (obj if isinstance(obj, (list, tuple)) else [obj]):
            cls = _check_class(cls, where)
            out.append(TrackerEntry(tracker_name(cls), cls, f"entry point {ep.dist.name if ep.dist else ep.name}",
                                    f"{cls.__module__}:{cls.__qualname__}"))
    return out


def available_trackers(specs=(), time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S
                       ) -> dict[str, TrackerEntry]:
    """Every tracker the registry can find: built-in, entry points, then ``specs`` (``--tracker``);
    plugged code not imported yet is tried in a child process first, stopped at
    ``time_limit_s`` (:func:`load_spec`).

    Raises
    ------
    InputError
        A spec that does not load, or two trackers of one family with the same name.
    """
    entries = _builtin_entries() + _entry_point_entries(time_limit_s)
    for spec in specs:
        cls = load_spec(spec, time_limit_s)
        entries.append(TrackerEntry(tracker_name(cls), cls, spec, canonical_spec(spec)))
    table: dict[str, TrackerEntry] = {}
    for e in entries:
        if e.name in table and table[e.name].cls is not e.cls:
            raise InputError(f"two trackers are named {e.name!r} ({table[e.name].source} and {e.source}); "
                             "give one of them another name")
        table[e.name] = e
    return table


def trackers_of_family(family: str, specs=(), time_limit_s: float | None = DEFAULT_TRACKER_TIME_LIMIT_S
                       ) -> list[TrackerEntry]:
    """The trackers of ``family``. Without plugged trackers (``specs``) only that family's
    built-in module is imported; with them every tracker is loaded, so that a name clash with
    any other tracker is refused (:func:`available_trackers`)."""
    if specs:
        return [e for e in available_trackers(specs, time_limit_s).values() if e.family == family]
    entries = _builtin_entries(BUILTIN_FAMILY_MODULES.get(family, ())) + _entry_point_entries(time_limit_s)
    return [e for e in entries if e.family == family]
