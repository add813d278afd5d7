"""Whole replays as a user runs them: wall time and peak memory of ``replay FILE``.

What it measures
----------------
Data sets are simulated with ``replay simulate`` (seed 7) into a work folder (not timed): by
default radar-tws with 10 and 10,000 runs, colored-imm with 10 and 500 runs and array-crossing
with 10 and 1,000 runs. The bundled radar demo (``data/radar_tws_demo.mcap``, 200 runs) is
replayed too, as the README's first command replays it; ``--sets`` also takes ``xcorr-demo``,
``array-demo``, ``colored-demo`` and ``tdoa-demo``. Each is replayed ``--repeats`` times
(default 5) in a fresh process, ``python -m trackreplay.face.cli FILE --out … --force --figures
none`` (figures are drawn after the result, in a process of their own, when ``replay`` runs on
a terminal), with ``--no-rrd`` for simulated sets from 100 runs up (the demos keep their
``.rrd``). The packages of every tree measured are byte-compiled first, as ``pip install .``
leaves them. The wall time is the child's, from ``time.perf_counter`` around it; the peak
memory is its maximum resident set from ``os.wait4``, which on Linux is the largest of the
replay's process and of the process that writes a small replay's recording
(``pipeline/face/recording_process.py``).

With ``--before TREE`` (a checkout of an earlier commit, e.g. a ``git worktree``) every replay
also runs from that tree, interleaved with this tree's, so that both see the same load. The
package ``trackreplay`` is the folder ``pipeline/`` with ``recorders/`` and ``evaluators/`` as
subpackages (setuptools' package-dir, ``pyproject.toml``), which ``PYTHONPATH=TREE`` alone
does not reproduce: the replays run with ``PYTHONPATH`` set to a folder of links
(:func:`package_view`) in which ``trackreplay`` and ``replay_data`` are laid out as installed.

The table gives medians with min–max over the repeats and says PASS/MISS against the speed
issue's targets (docs/benchmarks.md). A 10-run replay's target is issue 27's: within
:data:`FLOOR_FACTOR` × the import floor below (its own dependencies, measured in the same run),
not a fixed time.

A third table splits each replay's time into the phases ``replay --verbose`` prints (filter,
evaluate, and write, which runs on a thread beside the evaluation) and gives, for the 10,000-run
radar set, the targets of the evaluation issues: evaluation at most the filters' time (issue 26)
and evaluation plus writing at most the filters' time (issue 27), as ratios of each repeat's own
times.

Before them, ``replay --help`` is timed in fresh processes (target < 0.15 s). A second table,
the **import floor**, times fresh processes that only import what every replay
needs before it can print a table (numpy, polars, scipy.special for the χ² and t quantiles,
mcap, zstandard, protobuf, click) and, beside it, the same plus the Rerun SDK that writes the
``.rrd``: no 10-run replay can be faster than these. ``--floor-only`` prints just that table.

How to run
----------
From the repository root, with the package installed (``pip install -e .``)::

    python benchmarks/bench_replay.py                        # every set, 5 repeats
    python benchmarks/bench_replay.py --sets radar-10000 --repeats 3
    git worktree add /tmp/before HEAD~3 && python benchmarks/bench_replay.py --before /tmp/before
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from timing import print_table, spread  # benchmarks/ is on sys.path when run as a script

KIB = 1024  # ru_maxrss is in KiB on Linux
MB = 1e6  # peak memory is printed in MB of 10⁶ bytes, as every other figure here (before 2026-11-27 evening: MiB)

#: a 10-run replay's target: this many times the import floor (issue 27)
FLOOR_FACTOR = 2.5
FLOOR = "floor"  # the target of SETS meaning FLOOR_FACTOR × the measured import floor
SETS = {  # name: (scenario, runs, target wall s or FLOOR, target peak MB; None: no target)
    "radar-10": ("radar-tws", 10, FLOOR, None),
    "colored-10": ("colored-imm", 10, FLOOR, None),
    "array-10": ("array-crossing", 10, FLOOR, None),
    "radar-10000": ("radar-tws", 10000, 5.0, 500.0),
    "colored-500": ("colored-imm", 500, 35.0 / 3, 1650.0 / 3),
    "array-1000": ("array-crossing", 1000, 14.0 / 3, 2100.0 / 3),
}
#: the bundled demos, replayed as the README's first command does (with the .rrd); no target
BUNDLED = {
    "radar-demo": "radar_tws_demo.mcap",
    "xcorr-demo": "xcorr_crossing_demo.mcap",
    "array-demo": "array_crossing_demo.mcap",
    "colored-demo": "colored_imm_demo.mcap",
    "tdoa-demo": "tdoa_fdoa_demo.mcap",
}
REPO = Path(__file__).resolve().parents[1]


def package_view(tree: str, into: Path) -> str:
    """A folder under ``into`` for ``PYTHONPATH`` in which a source checkout ``tree`` is laid out
    as installed: ``trackreplay/`` holds links to every entry of ``tree/pipeline`` plus
    ``recorders`` and ``evaluators`` (its subpackages), ``replay_data`` links to ``tree/data``.

    A tree without ``pipeline/`` is returned as it is (already a folder of packages).
    """
    source = Path(tree)
    if not (source / "pipeline" / "__init__.py").exists() or _named_pipeline(tree):
        return tree
    view = into / "package-view"
    package = view / "trackreplay"
    package.mkdir(parents=True)
    for entry in (source / "pipeline").iterdir():
        if entry.name != "__pycache__":
            (package / entry.name).symlink_to(entry)
    for sub in ("recorders", "evaluators"):
        if not (package / sub).exists():
            (package / sub).symlink_to(source / sub)
    (view / "replay_data").symlink_to(source / "data")
    return str(view)


def _named_pipeline(tree: str | None) -> bool:
    """Whether ``tree`` is a checkout from before the package was named ``trackreplay`` (its code
    imports ``pipeline``): it runs from ``PYTHONPATH=tree`` as ``python -m pipeline.face.cli``."""
    cli = Path(tree) / "pipeline" / "face" / "cli.py" if tree is not None else None
    return cli is not None and cli.exists() and "from pipeline" in cli.read_text()


def cli_module(tree: str | None) -> str:
    """The module that is ``replay`` in ``tree``."""
    return "pipeline.face.cli" if _named_pipeline(tree) else "trackreplay.face.cli"


def compile_bytecode(tree: str | None) -> None:
    """Byte-compile the packages a replay imports from ``tree`` (a folder for ``PYTHONPATH``, e.g.
    :func:`package_view`'s; None: the installed ones), not timed.

    ``pip install .`` compiles them when it installs, so a user's replay starts from bytecode;
    a checkout under ``PYTHONDONTWRITEBYTECODE`` (as on the development machine) would otherwise
    compile about 0.15 s of source in every timed process (docs/benchmarks.md). The bytecode goes
    where the interpreter will look for it: beside the path it imports the source from.
    """
    import compileall
    import importlib.util

    if tree is not None:
        # compile_dir skips linked folders: every file by the path the interpreter will see
        roots = ("pipeline", "recorders", "evaluators") if _named_pipeline(tree) else ("trackreplay",)
        for folder, _, files in (w for root in roots for w in os.walk(Path(tree) / root, followlinks=True)):
            for name in files:
                if name.endswith(".py"):
                    compileall.compile_file(os.path.join(folder, name), quiet=1)
        return
    for package in ("trackreplay", "trackreplay.evaluators", "trackreplay.recorders"):  # the folders it maps
        spec = importlib.util.find_spec(package)
        compileall.compile_dir(str(Path(next(iter(spec.submodule_search_locations)))), quiet=1)


def simulate(scenario: str, runs: int, out: Path) -> None:
    subprocess.run([sys.executable, "-m", "trackreplay.face.cli", "simulate", scenario, "--runs", str(runs), "--seed",
                    "7", "-o", str(out)], check=True, capture_output=True)


#: the phases ``replay --verbose`` times on stderr (``timing: filter 1.32 s``), read by replay_once
PHASES = ("filter", "evaluate", "write")
_TIMING = re.compile(r"^timing: (\w+) ([0-9.]+) s", re.MULTILINE)


def replay_once(data: Path, out: Path, tree: str | None, recording: bool) -> tuple[float, float, dict]:
    """(wall seconds, peak resident MB, seconds of each of :data:`PHASES`) of one ``replay`` in a
    fresh process (``--verbose`` prints the phases' times; a tree that does not print one leaves
    it out)."""
    args = [sys.executable, "-m", cli_module(tree), "-q", "--verbose", str(data), "--out", str(out / "tracks.mcap"),
            "--force", "--figures", "none"]
    if not recording:
        args.append("--no-rrd")
    env = dict(os.environ, PYTHONPATH=tree) if tree else None
    t0 = time.perf_counter()
    # run from the data's folder: ``python -m`` puts the working directory first on sys.path,
    # which from the repository root would shadow the --before tree
    child = subprocess.Popen(args, env=env, cwd=data.parent, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - t0
    child.returncode = os.waitstatus_to_exitcode(status)
    err = child.stderr.read().decode()
    if child.returncode:
        raise SystemExit(f"replay {data.name} failed: {err[-400:]}")
    phases = {name: float(value) for name, value in _TIMING.findall(err) if name in PHASES}
    return wall, usage.ru_maxrss * KIB / MB, phases


HELP_TARGET_S = 0.15


def help_once(tree: str | None, cwd: str) -> float:
    """Wall seconds of ``replay --help`` in a fresh process."""
    env = dict(os.environ, PYTHONPATH=tree) if tree else None
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", cli_module(tree), "--help"], env=env, cwd=cwd, check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


FLOOR_IMPORTS = {  # what a replay cannot start without, and the Rerun SDK its recording needs
    "numpy, polars, scipy.special, mcap, zstandard, protobuf, click":
        "import numpy, polars, scipy.special, mcap.reader, mcap.writer, zstandard, google.protobuf, click",
    "the same + rerun, rerun.blueprint (the .rrd)":
        "import numpy, polars, scipy.special, mcap.reader, mcap.writer, zstandard, google.protobuf, click, "
        "rerun, rerun.blueprint",
    "python alone": "pass",
}


def import_floor(repeats: int) -> tuple[list[list[str]], dict]:
    """Rows (imports, wall median [min–max], peak memory) of fresh processes that only import,
    and the walls themselves (seconds, per row label)."""
    walls = {k: [] for k in FLOOR_IMPORTS}
    peaks = {k: [] for k in FLOOR_IMPORTS}
    for _ in range(repeats):  # interleaved, so that every row sees the same load
        for label, code in FLOOR_IMPORTS.items():
            t0 = time.perf_counter()
            child = subprocess.Popen([sys.executable, "-c", code])
            _, status, usage = os.wait4(child.pid, 0)
            walls[label].append(time.perf_counter() - t0)
            peaks[label].append(usage.ru_maxrss * KIB / MB)
            if os.waitstatus_to_exitcode(status):
                raise SystemExit(f"import floor: {code!r} failed")
    return [[label, spread(walls[label], 1.0, 2, "s"), spread(peaks[label], 1.0, 0, "MB")] for label in FLOOR_IMPORTS], walls


#: data sets whose phases have a target: the evaluation at most the filters' time (issue 26), and
#: evaluation and writing together at most the filters' time (issue 27)
PHASE_TARGETS = {"radar-10000"}


def phase_row(name: str, label: str, phases: dict) -> list[str]:
    """One row of the phase table: each phase's median [min–max] and the two ratios to the
    filters' time (of each repeat's own times), with PASS/MISS where the set has a target."""
    if not all(phases[p] for p in PHASES):
        return [name, label, *["(not printed)"] * 5, ""]
    filt, ev, wr = (phases[p] for p in PHASES)
    eval_ratio = [e / f for e, f in zip(ev, filt)]
    both_ratio = [(e + w) / f for e, w, f in zip(ev, wr, filt)]
    verdict = ""
    if name in PHASE_TARGETS:
        verdict = ("evaluate ≤ filter: " + ("PASS" if statistics.median(eval_ratio) <= 1 else "MISS")
                   + "; evaluate + write ≤ filter: " + ("PASS" if statistics.median(both_ratio) <= 1 else "MISS"))
    return [name, label, spread(filt, 1.0, 2, "s"), spread(ev, 1.0, 2, "s"), spread(wr, 1.0, 2, "s"),
            spread(eval_ratio, 1.0, 2, "×"), spread(both_ratio, 1.0, 2, "×"), verdict]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sets", default=",".join([*SETS, "radar-demo"]),
                    help=f"comma-separated, of {', '.join([*SETS, *BUNDLED])}")
    ap.add_argument("--before", help="a checkout of an earlier commit to replay with, interleaved")
    ap.add_argument("--keep", help="work folder to keep (default: a temporary one)")
    ap.add_argument("--floor-only", action="store_true", help="print only the import floor")
    args = ap.parse_args()
    floor, floor_walls = import_floor(args.repeats)
    print(f"import floor: fresh processes that only import, median [min–max] of {args.repeats}")
    print_table(["imports", "wall", "peak memory"], floor)
    floor_s = statistics.median(floor_walls[next(iter(FLOOR_IMPORTS))])
    print(f"a 10-run replay's target: {FLOOR_FACTOR} × the first floor = {FLOOR_FACTOR * floor_s:.2f} s")
    print()
    if args.floor_only:
        return
    chosen = [s.strip() for s in args.sets.split(",") if s.strip()]
    unknown = [s for s in chosen if s not in SETS and s not in BUNDLED]
    if unknown:
        ap.error(f"unknown set(s) {', '.join(unknown)}")
    views = tempfile.TemporaryDirectory()
    trees = {"before": package_view(str(Path(args.before).resolve()), Path(views.name))} if args.before else {}
    trees["after"] = None
    for tree in trees.values():
        compile_bytecode(tree)
    helps = {label: [] for label in trees}
    with tempfile.TemporaryDirectory() as empty:  # a folder without a pipeline/ of its own
        for _ in range(args.repeats):
            for label, tree in trees.items():
                helps[label].append(help_once(tree, empty))
    print(f"replay --help, median [min–max] of {args.repeats}, fresh process each (target < {HELP_TARGET_S} s)")
    print_table(["tree", "wall", ""], [[label, spread(helps[label], 1.0, 3, "s"),
                                        "PASS" if sorted(helps[label])[len(helps[label]) // 2] < HELP_TARGET_S
                                        else "MISS"] for label in trees])
    print()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep or tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows, phase_rows = [], []
        for name in chosen:
            if name in BUNDLED:  # a copy in the work folder: the replay's default outputs go beside it
                data = work / BUNDLED[name]
                if not data.exists():
                    shutil.copyfile(REPO / "data" / BUNDLED[name], data)
                runs, target_s, target_mb, recording = None, None, None, True
            else:
                scenario, runs, target_s, target_mb = SETS[name]
                if target_s == FLOOR:
                    target_s = FLOOR_FACTOR * floor_s
                data = work / f"{scenario}-{runs}.mcap"
                if not data.exists():
                    simulate(scenario, runs, data)
                recording = runs < 100
            walls = {k: [] for k in trees}
            peaks = {k: [] for k in trees}
            phases = {k: {p: [] for p in PHASES} for k in trees}
            for _ in range(args.repeats):
                for label, tree in trees.items():
                    wall, peak, times = replay_once(data, work / f"out-{label}-{name}", tree, recording)
                    walls[label].append(wall)
                    peaks[label].append(peak)
                    for phase, seconds in times.items():
                        phases[label][phase].append(seconds)
            for label in trees:
                phase_rows.append(phase_row(name, label, phases[label]))
            for label in trees:
                if target_s is None:
                    target, verdict = "", ""
                else:
                    wall_ok = sorted(walls[label])[len(walls[label]) // 2] < target_s
                    mem_ok = target_mb is None or sorted(peaks[label])[len(peaks[label]) // 2] < target_mb
                    target = (f"< {target_s:.3g} s" + (f" ({FLOOR_FACTOR} × floor)" if SETS[name][2] == FLOOR else "")
                              + (f", < {target_mb:.0f} MB" if target_mb else ""))
                    verdict = "PASS" if wall_ok and mem_ok else "MISS"
                rows.append([f"{name} ({runs} runs)" if runs else f"{name} ({data.name})", label,
                             spread(walls[label], 1.0, 2, "s"), spread(peaks[label], 1.0, 0, "MB"), target, verdict])
        print(f"replay wall time and peak memory, median [min–max] of {args.repeats}, fresh process each")
        print_table(["data set", "tree", "wall", "peak memory", "target", ""], rows)
        print()
        print(f"where the time goes (the phases --verbose prints; writing runs on a thread beside the evaluation), "
              f"median [min–max] of {args.repeats}")
        print_table(["data set", "tree", "filter", "evaluate", "write", "evaluate / filter", "(evaluate + write) / filter",
                     "target"], phase_rows)
    views.cleanup()


if __name__ == "__main__":
    main()
