"""What a replay imports: nothing beyond the import floor that it does not use (issue 27).

A 10-run replay is mostly start-up (``docs/benchmarks.md``, the import floor of
``benchmarks/bench_replay.py``): a SciPy submodule, matplotlib or the Rerun SDK imported by a
module the replay only lists (the registry imports every built-in tracker of the family) costs
0.1–0.4 s of every such replay. Each bundled demo is replayed here in a fresh process with
``--no-rrd --figures none`` and the modules it ended with are checked.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: loaded on first use only: not by a replay that writes no recording and no figures
NOT_AT_START_UP = ("scipy.optimize", "scipy.linalg", "scipy.sparse", "scipy.stats", "scipy.signal", "matplotlib",
                   "rerun", "dask", "pandas")

_LIST_MODULES = """
import atexit, sys
atexit.register(lambda: print("MODULES", " ".join(sorted(sys.modules))))
sys.argv = ["replay"] + sys.argv[1:]
from trackreplay.face.cli import main
main()
"""


@pytest.mark.parametrize("demo", ["radar_tws_demo.mcap", "array_crossing_demo.mcap"])
def test_a_replay_without_recording_imports_no_unused_heavy_module(demo, tmp_path):
    proc = subprocess.run([sys.executable, "-c", _LIST_MODULES, "-q", str(REPO / "data" / demo), "--out",
                           str(tmp_path / "tracks.mcap"), "--no-rrd", "--figures", "none"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    modules = next(line for line in proc.stdout.splitlines() if line.startswith("MODULES ")).split()[1:]
    loaded = sorted({heavy for heavy in NOT_AT_START_UP for m in modules if m == heavy or m.startswith(heavy + ".")})
    assert loaded == [], f"a replay of {demo} imported {loaded}"


def test_help_imports_neither_numpy_nor_polars(tmp_path):
    """``replay --help`` (target < 0.15 s, ``benchmarks/bench_replay.py``) lists the commands
    without the numerical stack: numpy alone is about 0.07 s of CPU."""
    proc = subprocess.run([sys.executable, "-c", _LIST_MODULES, "--help"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    modules = next(line for line in proc.stdout.splitlines() if line.startswith("MODULES ")).split()[1:]
    loaded = sorted({top for top in ("numpy", "polars", "scipy", "mcap", "google") for m in modules
                     if m == top or m.startswith(top + ".")})
    assert loaded == [], f"replay --help imported {loaded}"
