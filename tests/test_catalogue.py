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

from trackreplay.face.cli import main

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
    files.update(_structured_files())
    for name, data in files.items():
        (folder / name).write_bytes(data)
    (folder / "adir.mcap").mkdir()
    shutil.copy(DEMO, folder / "good.mcap")
    (folder / "afile").write_text("")
    return files


_STRUCTURED: dict = {}


def _structured_files() -> dict:
    """Well-formed MCAP files (valid CRCs) holding what the audit fed the tool (issue 30, item 4):
    built once from a small radar data set with the fuzzer's assembler (``tests/fuzz_mcap.py``)."""
    if _STRUCTURED:
        return _STRUCTURED
    import tempfile
    from dataclasses import replace

    import numpy as np
    from mcap.records import Channel, Metadata

    import fuzz_mcap as fz

    with tempfile.TemporaryDirectory() as tmp:
        model = fz.parse(fz.small_dataset(Path(tmp)).read_bytes())

    def each_scan(edit):
        m = fz._copy(model)
        for ci, j in fz._messages(m):
            rec = m.chunks[ci][j]
            msg = fz._scan_class(fz._schema_of(m, rec.channel_id)).FromString(rec.data)
            edit(m.chunks[ci][j].channel_id, msg)
            m.chunks[ci][j] = replace(rec, data=msg.SerializeToString())
        return fz.assemble(m)

    def shift_times(cid, msg):
        msg.time_s -= 1000.0

    def scalar_truth(cid, msg):
        for col in msg.columns:
            if col.name == "state":
                del col.shape[:]
                col.layout, col.offsets = 0, b""
                col.values = np.zeros(msg.frame_count, "<f8").tobytes()

    def range_2d(cid, msg):
        for col in msg.columns:
            if col.name == "range_m":
                col.shape.append(1)

    def times_back(cid, msg):
        if msg.scan == 5:
            msg.time_s = 1.0

    renamed = fz._copy(model)
    first = renamed.chunks[0]
    k = next(j for j, r in enumerate(first) if isinstance(r, Channel) and r.topic == "/radar/truth")
    first[k] = replace(first[k], topic="/radar/elsewhere")

    def deep_metadata(name, key):
        m = fz._copy(model)
        for records in (m.metadata_before, m.metadata_after):
            for i, rec in enumerate(records):
                if rec.name == name:
                    records[i] = Metadata(name=name, metadata={**rec.metadata, key: "[" * 100000 + "]" * 100000})
        return fz.assemble(m)

    _STRUCTURED.update({
        "lz4-zstd.mcap": fz.assemble(model, fz.ChunkDamage(2, label="lz4", actual="zstd")),
        "lz4-raw.mcap": fz.assemble(model, fz.ChunkDamage(2, label="lz4", actual="")),
        "negative-times.mcap": each_scan(shift_times),
        "scalar-truth.mcap": each_scan(scalar_truth),
        "range-2d.mcap": each_scan(range_2d),
        "times-back.mcap": each_scan(times_back),
        "renamed-channel.mcap": fz.assemble(renamed),
        "deep-layout.mcap": deep_metadata("replay.layout", "/radar/plots"),
        "deep-params.mcap": deep_metadata("replay.scenario", "params"),
        "deep-json.mcap": _json_positions_with("{\"t_ms\": 0, \"position\": " + "[" * 100000 + "]" * 100000 + "}"),
        "json_map.toml": (REPO / "data" / "samples" / "json_positions_map.toml").read_bytes(),
    })
    return _STRUCTURED


def _json_positions_with(first_message: str) -> bytes:
    """The bundled JSON positions sample (``replay convert mcap``'s input) with its first message replaced."""
    from sample_files import json_positions_with_first

    return json_positions_with_first(first_message.encode())


def _flip(data: bytes, at: int) -> bytes:
    b = bytearray(data)
    b[at] ^= 0x10
    return bytes(b)


STRUCTURED_MCAPS = ["lz4-zstd.mcap", "lz4-raw.mcap", "negative-times.mcap", "scalar-truth.mcap", "range-2d.mcap",
                    "times-back.mcap", "renamed-channel.mcap", "deep-layout.mcap", "deep-params.mcap"]
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
    # well-formed files (valid CRCs) holding what reached exit 3 or was read wrongly in the audit (issue 30)
    + [(a(f), f) for f in STRUCTURED_MCAPS for a in (
        lambda f: [f, "--no-rrd", "--out", "o/tracks.mcap"], lambda f: ["eval", f, "--json"], lambda f: ["info", f],
        lambda f: ["export", "--foxglove", f, "-o", "x.mcap"], lambda f: ["eval", "good.mcap", f],
        lambda f: ["compare", f, "good.mcap", "--data", "good.mcap"])]
    # (convert upgrade copies what it reads as it is: it refuses only what it cannot read or write)
    + [(["convert", "upgrade", f, "-o", "u.mcap"], f)
       for f in ("lz4-zstd.mcap", "lz4-raw.mcap", "negative-times.mcap", "renamed-channel.mcap", "deep-layout.mcap")]
    + [(["convert", "mcap", "deep-json.mcap", "--map", "json_map.toml", "-o", "c.mcap"], "deep-json.mcap"),
       (["deep-json.mcap", "--map", "json_map.toml", "--no-rrd", "--out", "o/tracks.mcap"], "deep-json.mcap")]
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


def run_case(folder: Path, args: list, named: str | None) -> dict:
    """One case in a fresh ``folder`` (the working directory meanwhile): exit status, the error
    lines, whether a traceback escaped, whether the right file is named, and what changed."""
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        _bad_files(folder)
        before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}
        dirs_before = {p for p in folder.rglob("*") if p.is_dir()}
        res = CliRunner().invoke(main, args)
        lines = [l for l in res.stderr.splitlines() if l.strip() and not l.startswith("sweep ")]
        after = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}
    finally:
        os.chdir(cwd)
    traceback = "Traceback" in res.output or not isinstance(res.exception, SystemExit)
    return {"code": res.exit_code, "lines": lines, "traceback": traceback, "output": res.output,
            "one_line": len(lines) == 1 and lines[0].startswith("replay: error: "),
            "named": named is None or (len(lines) == 1 and named in lines[0]),
            "inputs_modified": sorted(str(p) for p in before if after.get(p) != before[p]),
            "left": sorted(str(p) for p in set(after) - set(before))
                    + sorted(str(p) for p in {p for p in folder.rglob("*") if p.is_dir()} - dirs_before)}


def is_clean(r: dict) -> bool:
    return r["code"] == 2 and r["one_line"] and r["named"] and not r["traceback"] and not r["inputs_modified"] \
        and not r["left"]


@pytest.mark.parametrize("args, named", CASES, ids=[" ".join(a)[:60] for a, _ in CASES])
def test_bad_input_gives_one_line_and_leaves_everything_as_it_was(tmp_path, args, named):
    r = run_case(tmp_path, args, named)
    assert r["code"] == 2, (args, r["output"])
    assert r["one_line"], (args, r["lines"])
    assert not r["traceback"], (args, r["output"])
    assert r["named"], (args, r["lines"])
    assert not r["inputs_modified"], (args, r["inputs_modified"])
    assert not r["left"], (args, r["left"])


def test_the_catalogue_covers_every_command():
    used = {a[0] for a, _ in CASES}
    assert len(CASES) >= 60
    for command in ("eval", "export", "fit-peaks", "colored-report", "convert", "compare", "simulate", "scenarios",
                    "sweep", "check", "view", "help", "run", "trackers"):
        assert command in used, command


if __name__ == "__main__":  # the figures: python tests/test_catalogue.py
    import sys
    import tempfile

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    results = []
    for args, named in CASES:
        with tempfile.TemporaryDirectory() as tmp:
            results.append((args, run_case(Path(tmp).resolve(), args, named)))
    print(f"catalogue: cases {len(results)}, clean {sum(is_clean(r) for _, r in results)}, "
          f"exit 3 {sum(r['code'] == 3 for _, r in results)}, "
          f"tracebacks {sum(r['traceback'] for _, r in results)}, "
          f"inputs modified {sum(bool(r['inputs_modified']) for _, r in results)}, "
          f"outputs left {sum(bool(r['left']) for _, r in results)}")
    for args, r in results:
        if not is_clean(r):
            print("  not clean:", " ".join(args), r["code"], r["lines"][-1:] if r["lines"] else r["output"][-200:])
