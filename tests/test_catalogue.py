"""The bad-input catalogue: every command, every kind of bad input a user gives it.

Each case must end with exit status 2, exactly one line on stderr of the form
``replay: error: <file>: <problem>`` (or ``replay: error: <problem>`` for a bad option), no
traceback, every input byte for byte as it was, and no output left behind.
"""

from __future__ import annotations

import hashlib
import os
import random
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from pipeline.face.cli import main

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "radar_tws_demo.mcap"


def _bad_files(folder: Path) -> dict:
    """Inputs that are not what they claim to be."""
    rng = random.Random(3)
    files = {
        "garbage.mcap": bytes(rng.randrange(256) for _ in range(4096)),
        "empty.mcap": b"",
        "text.mcap": b"time,range_m,bearing_deg\n0,1,2\n",
        "truncated.mcap": DEMO.read_bytes()[: DEMO.stat().st_size // 2],
        "flipped.mcap": _flip(DEMO.read_bytes(), 5000),
        "garbage.csv": bytes(rng.randrange(256) for _ in range(512)),
        "empty.csv": b"",
        "nan.csv": b"time,range_m,bearing_deg\n0,nan,10\n5,1001,10\n10,1002,10\n",
        "letters.csv": b"time,range_m,bearing_deg\n0,abc,10\n5,1001,10\n10,1002,10\n",
        "negative.csv": b"time,range_m,bearing_deg\n0,-5,10\n5,1001,10\n10,1002,10\n",
        "garbage.wav": bytes(rng.randrange(256) for _ in range(512)),
        "empty.wav": b"",
        "garbage.toml": b"name = \n[[[",
        "norecorder.toml": b'name = "x"\n[params]\n',
        "garbage.rrd": bytes(rng.randrange(256) for _ in range(512)),
        "notracker.py": b"x = 1\n",
        "broken.py": b"raise RuntimeError('boom')\n",
    }
    for name, data in files.items():
        (folder / name).write_bytes(data)
    (folder / "adir.mcap").mkdir()
    shutil.copy(DEMO, folder / "good.mcap")
    (folder / "afile").write_text("")
    return files


def _flip(data: bytes, at: int) -> bytes:
    b = bytearray(data)
    b[at] ^= 0x10
    return bytes(b)


MCAP_INPUTS = ["garbage.mcap", "empty.mcap", "text.mcap", "truncated.mcap", "flipped.mcap", "adir.mcap", "missing.mcap"]

CASES = (
    # replay FILE / run / eval / export / fit-peaks / colored-report / convert upgrade on every bad MCAP
    [([f], f) for f in MCAP_INPUTS]
    + [(["eval", f], f) for f in MCAP_INPUTS]
    + [(["eval", "good.mcap", f], f) for f in ("garbage.mcap", "truncated.mcap", "missing.mcap", "good.mcap")]
    + [(["export", "--foxglove", f, "-o", "x.mcap"], f) for f in ("garbage.mcap", "empty.mcap", "missing.mcap")]
    + [(["fit-peaks", f], f) for f in ("garbage.mcap", "truncated.mcap", "good.mcap")]
    + [(["colored-report", f, "-o", "rep"], f) for f in ("garbage.mcap", "good.mcap")]
    + [(["convert", "upgrade", f, "-o", "u.mcap"], f) for f in ("garbage.mcap", "truncated.mcap", "missing.mcap")]
    + [(["convert", "upgrade", "good.mcap", "-o", "good.mcap"], "good.mcap")]
    + [(["compare", f, "good.mcap", "--data", "good.mcap"], f) for f in ("garbage.mcap", "good.mcap")]
    # converters
    + [(["convert", "plots-csv", f, "-o", "p.mcap"], f)
       for f in ("garbage.csv", "empty.csv", "nan.csv", "letters.csv", "negative.csv", "missing.csv")]
    + [(["convert", "array-wav", f, "-o", "w.mcap", "--spacing-m", "0.05", "--frequency-hz", "2000"], f)
       for f in ("garbage.wav", "empty.wav", "missing.wav")]
    # scenarios and simulate
    + [(["simulate", f, "-o", "s.mcap"], f) for f in ("garbage.toml", "norecorder.toml", "missing.toml")]
    + [(["simulate", "no-such-scenario", "-o", "s.mcap"], None),
       (["simulate", "radar-tws", "-o", "s.mcap", "--set", "sigma_range_m=abc"], None),
       (["simulate", "radar-tws", "-o", "s.mcap", "--set", "no_such_param=1"], None),
       (["simulate", "radar-tws", "-o", "s.mcap", "--runs", "0"], None),
       (["simulate", "radar-tws", "-o", "s.mcap", "--seed", "-3"], None),
       (["simulate", "radar-tws", "-o", "afile/s.mcap"], None),
       (["scenarios", "no-such-scenario"], None)]
    # design values and trackers
    + [(["good.mcap", "--no-rrd", "--set", s], None)
       for s in ("nominal_cross_range_m=nan", "design_sigma_v_mps2=0", "sigma_range_m=-1", "sigma_range_m=1e-6",
                 "nominal_cross_range_m=1e-6", "no_such_param=3", "sigma_bearing_deg=abc")]
    + [(["good.mcap", "--no-rrd", "--set", s], None) for s in ("ospa_cutoff_m=-1", "ospa_order=0", "assignment_gate_m=inf")]
    + [(["good.mcap", "--no-rrd", "--tracker", t], None)
       for t in ("notracker.py:X", "broken.py:X", "missing.py:X", "no_such_module_xyz:X", "noclass")]
    + [(["good.mcap", "--no-rrd", "--trackers", "no_such_tracker"], None),
       (["good.mcap", "--out", "good.mcap"], "good.mcap"),
       (["good.mcap", "--out", "afile/o/tracks.mcap", "--no-rrd"], None)]
    # sweep, check, view, usage
    + [(["sweep", "radar-tws", "--param", p, "--runs", "2", "-o", "sw"], None)
       for p in ("sigma_range_m", "sigma_range_m=", "no_such_param=1,2", "sigma_range_m=a,b")]
    + [(["check", "afile"], None), (["check", "missing_dir"], None),
       (["view", "garbage.rrd", "--screenshot", "v.png"], None), (["view", "missing.rrd", "--screenshot", "v.png"], None),
       (["simlate", "radar-tws"], None), (["help", "no-such-command"], None), (["run", "--no-such-option"], None),
       (["trackers", "--tracker", "missing.py:X"], None)]
)


@pytest.mark.parametrize("args, named", CASES, ids=[" ".join(a)[:60] for a, _ in CASES])
def test_bad_input_gives_one_line_and_leaves_everything_as_it_was(tmp_path, monkeypatch, args, named):
    monkeypatch.chdir(tmp_path)
    _bad_files(tmp_path)
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in tmp_path.rglob("*") if p.is_file()}
    dirs_before = {p for p in tmp_path.rglob("*") if p.is_dir()}
    res = CliRunner().invoke(main, args)
    lines = [l for l in res.stderr.splitlines() if l.strip() and not l.startswith("sweep ")]
    assert res.exit_code == 2, (args, res.output)
    assert len(lines) == 1 and lines[0].startswith("replay: error: "), (args, res.stderr)
    assert "Traceback" not in res.output and isinstance(res.exception, SystemExit), (args, res.output)
    if named is not None:
        assert named in lines[0], (args, lines[0])
    after = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in tmp_path.rglob("*") if p.is_file()}
    assert after == before, (args, sorted(set(map(str, after)) ^ set(map(str, before))))
    new_dirs = {p for p in tmp_path.rglob("*") if p.is_dir()} - dirs_before
    assert not new_dirs, (args, new_dirs)


def test_the_catalogue_covers_every_command():
    used = {a[0] for a, _ in CASES}
    assert len(CASES) >= 60
    for command in ("eval", "export", "fit-peaks", "colored-report", "convert", "compare", "simulate", "scenarios",
                    "sweep", "check", "view", "help", "run", "trackers"):
        assert command in used, command
