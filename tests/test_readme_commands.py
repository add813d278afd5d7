"""The README's main command, exactly as written, on a copy of the repository in a fresh virtual
environment (the test command itself is what runs this suite, via scripts/install-test-deps.sh)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import venv
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _first_command(readme: str) -> str:
    block = re.search(r"```bash\n(.+?)\n```", readme, re.S)
    assert block, "the README has no bash block"
    return block.group(1).strip()


def _repository_copy(target: Path) -> None:
    """The files a clone has (tracked and new, not ignored), without build or output folders."""
    listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                            capture_output=True, text=True)
    names = listed.stdout.splitlines() if listed.returncode == 0 else None
    if names is None:
        shutil.copytree(REPO, target, ignore=shutil.ignore_patterns(".git", "replay-out", "*.egg-info", "build"))
        return
    for name in names:
        src = REPO / name
        if src.is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, target / name)


def test_the_readme_main_command_runs_as_written_in_a_fresh_environment(tmp_path):
    command = _first_command((REPO / "README.md").read_text())
    assert command == "pip install . && replay data/radar_tws_demo.mcap"
    clone = tmp_path / "clone"
    _repository_copy(clone)
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    bin_dir = env_dir / ("Scripts" if os.name == "nt" else "bin")
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "VIRTUAL_ENV": str(env_dir),
           "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    env.pop("PYTHONPATH", None)
    res = subprocess.run(["bash", "-c", command], cwd=clone, env=env, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert "rmse_position_m" in res.stdout
    assert (clone / "replay-out" / "radar_tws_demo" / "tracks.mcap").is_file()
    assert (clone / "replay-out" / "radar_tws_demo" / "metrics.csv").is_file()
