"""Inputs that reached exit 3 ("internal error") or were read silently wrong, found by the audit
and by ``tests/fuzz_mcap.py`` (issue 30, item 4): each is now one line ``replay: error: <file>:
<problem>`` and exit 2 in ``replay eval`` and ``replay``, the input untouched, no output left.

The damaged files are built by the fuzzer's own MCAP assembler (``fuzz_mcap.assemble``), which
writes valid CRCs around the damage so that it reaches the decoder.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from mcap.records import Channel

import fuzz_mcap as fz
from trackreplay.face.cli import main

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def radar_model(tmp_path_factory):
    path = fz.small_dataset(tmp_path_factory.mktemp("base"))
    return fz.parse(path.read_bytes()), path


def _refused_everywhere(runner, path: Path, *fragments: str) -> None:
    """``replay eval`` and ``replay`` both refuse ``path`` with one line naming it and every fragment."""
    before = path.read_bytes()
    for args in (["eval", str(path), "--json"], [str(path), "--out", "o/tracks.mcap", "--no-rrd", "--figures", "none"]):
        res = runner.invoke(main, args)
        lines = [line for line in res.stderr.splitlines() if line.strip()]
        assert res.exit_code == 2, (args, res.output)
        assert len(lines) == 1 and lines[0].startswith(f"replay: error: {path}: "), (args, res.stderr)
        for fragment in fragments:
            assert fragment in lines[0], (fragment, lines[0])
        assert "Traceback" not in res.output and isinstance(res.exception, SystemExit)
    assert path.read_bytes() == before and not Path("o").exists()


def test_lz4_chunks_read_as_the_same_data(runner, radar_model, tmp_path):
    """The same records in lz4 chunks give the same metrics as the zstd file, to the byte."""
    model, original = radar_model
    lz4 = tmp_path / "lz4.mcap"
    lz4.write_bytes(fz.assemble(replace(model, compression="lz4")))
    a = runner.invoke(main, ["eval", str(original), "--json"])
    b = runner.invoke(main, ["eval", str(lz4), "--json"])
    assert a.exit_code == b.exit_code == 0 and a.stdout == b.stdout


@pytest.mark.parametrize("actual", ["zstd", "", "garbage"])
def test_an_lz4_marked_chunk_holding_other_bytes_is_one_line(runner, radar_model, tmp_path, actual):
    """It was an lz4 RuntimeError and exit 3 (8 of the audit's mutants)."""
    model, _ = radar_model
    if actual == "garbage":  # starts like an lz4 frame (its magic number), then the raw records
        damage = fz.ChunkDamage(2, label="lz4", actual="", inner=lambda raw, offs: b"\x04\x22\x4d\x18" + raw[4:])
    else:
        damage = fz.ChunkDamage(2, label="lz4", actual=actual)
    path = tmp_path / "lz4-other.mcap"
    path.write_bytes(fz.assemble(model, damage))
    _refused_everywhere(runner, path, "chunk 3 of", "lz4")


def test_an_lz4_chunk_larger_than_declared_is_refused_without_inflating_it(runner, radar_model, tmp_path):
    """A chunk whose lz4 frame expands far beyond the size its record declares is refused after
    that size (plus one byte), not after decompressing all of it."""
    import resource

    model, _ = radar_model
    zeros = 512 << 20  # 512 MiB of zeros, a few MB of lz4
    damage = fz.ChunkDamage(1, label="lz4", actual="lz4", inner=lambda raw, offs: raw + bytes(zeros),
                            size_delta=-zeros)
    path = tmp_path / "lz4-bomb.mcap"
    path.write_bytes(fz.assemble(model, damage))
    peak_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    res = runner.invoke(main, ["eval", str(path), "--json"])
    grown_mib = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak_before) / 1024
    assert res.exit_code == 2 and "chunk 2 of" in res.stderr and "bytes uncompressed" in res.stderr, res.output
    assert grown_mib < 256, grown_mib


def test_a_channel_redefined_inside_a_chunk_is_refused(runner, radar_model, tmp_path):
    """A chunk that defines channel 2 (the truth) again under another topic moved the truth to
    that topic: the radar was scored without truth and accepted (the fuzzer's silent corruption:
    the plain mcap reader, trusting the summary, reads the truth where it was)."""
    model, _ = radar_model
    model = fz._copy(model)
    first = model.chunks[0]
    k = next(j for j, r in enumerate(first) if isinstance(r, Channel) and r.topic == "/radar/truth")
    first[k] = replace(first[k], topic="/radar/elsewhere")
    path = tmp_path / "renamed.mcap"
    path.write_bytes(fz.assemble(model))
    assert fz.decode_independently(path).frames.keys() == {"/radar/plots", "/radar/truth"}
    _refused_everywhere(runner, path, "chunk 1 of", "channel id", "defined twice", "/radar/elsewhere")


@pytest.mark.parametrize("shift", [-1000.0, -1e-3])
def test_negative_scan_times_are_one_line(runner, radar_model, tmp_path, shift):
    """``eval`` accepted them and ``replay`` failed writing its outputs (MCAP log times are
    unsigned): exit 3. Times count from the recording's start, as every importer writes them."""
    model, _ = radar_model
    model = fz._copy(model)
    for ci, j in fz._messages(model):
        rec = model.chunks[ci][j]
        msg = fz._scan_class(fz._schema_of(model, rec.channel_id)).FromString(rec.data)
        msg.time_s += shift
        model.chunks[ci][j] = replace(rec, data=msg.SerializeToString())
    path = tmp_path / "negative-times.mcap"
    path.write_bytes(fz.assemble(model))
    _refused_everywhere(runner, path, "scan time", "is negative")


def _json_mcap(path: Path, first_payload: bytes) -> None:
    """The bundled JSON positions sample with its first message replaced."""
    from sample_files import json_positions_with_first

    path.write_bytes(json_positions_with_first(first_payload))


@pytest.mark.parametrize("nesting", [b"[" * 100000 + b"]" * 100000, b'{"x":' * 100000 + b"1" + b"}" * 100000],
                         ids=["arrays", "objects"])
def test_deeply_nested_json_through_convert_mcap_is_one_line(runner, tmp_path, nesting):
    """The json module's RecursionError was exit 3."""
    path = tmp_path / "deep.mcap"
    _json_mcap(path, b'{"t_ms": 0, "position": ' + nesting + b"}")
    before = path.read_bytes()
    mapping = str(REPO / "data/samples/json_positions_map.toml")
    for args in (["convert", "mcap", str(path), "--map", mapping, "-o", "c.mcap"],
                 [str(path), "--map", mapping, "--out", "o/tracks.mcap", "--no-rrd", "--figures", "none"]):
        res = runner.invoke(main, args)
        lines = [line for line in res.stderr.splitlines() if line.strip()]
        assert res.exit_code == 2 and len(lines) == 1, (args, res.output)
        assert lines[0].startswith(f"replay: error: {path}: ") and "nested too deeply" in lines[0], lines[0]
    assert path.read_bytes() == before and not Path("c.mcap").exists() and not Path("o").exists()


def test_a_scalar_truth_state_is_one_line(runner, radar_model, tmp_path):
    """The audit's scalar truth state (exit 3 then): each truth frame's state made a 0-d array."""
    import numpy as np

    model, _ = radar_model
    model = fz._copy(model)
    for ci, j in fz._messages(model):
        rec = model.chunks[ci][j]
        msg = fz._scan_class(fz._schema_of(model, rec.channel_id)).FromString(rec.data)
        for col in msg.columns:
            if col.name == "state":
                del col.shape[:]
                col.layout = 0
                col.offsets = b""
                col.values = np.zeros(msg.frame_count, "<f8").tobytes()
        model.chunks[ci][j] = replace(rec, data=msg.SerializeToString())
    path = tmp_path / "scalar-truth.mcap"
    path.write_bytes(fz.assemble(model))
    _refused_everywhere(runner, path, "/radar/truth", "state has shape ()")


def _metadata_keys(model) -> list[tuple[str, str]]:
    return [(m.name, key) for m in model.metadata_before + model.metadata_after for key in sorted(m.metadata)]


@pytest.mark.parametrize("nesting", ["[" * 100000 + "]" * 100000, '{"a": ' + "[" * 5000 + "]" * 5000 + "}"],
                         ids=["arrays", "in-an-object"])
def test_deeply_nested_json_in_any_metadata_value_is_never_an_internal_error(runner, radar_model, tmp_path, nesting):
    """A metadata value holding JSON nested beyond the parser's recursion (the fuzzer's exit 3 in
    the layout and scenario records): refused in one line or, where the value is not needed,
    read as before; never an internal error."""
    from mcap.records import Metadata

    model, original = radar_model
    reference = runner.invoke(main, ["eval", str(original), "--json"]).stdout
    for n, (name, key) in enumerate(_metadata_keys(model)):
        m = fz._copy(model)
        for records in (m.metadata_before, m.metadata_after):
            for k, rec in enumerate(records):
                if rec.name == name:
                    records[k] = Metadata(name=name, metadata={**rec.metadata, key: nesting})
        path = tmp_path / "deep-metadata.mcap"
        path.write_bytes(fz.assemble(m))
        for args in (["eval", str(path), "--json"], [str(path), "--out", f"o{n}/t.mcap", "--no-rrd", "--figures", "none"]):
            res = runner.invoke(main, args)
            assert res.exit_code in (0, 2) and "Traceback" not in res.output, (name, key, res.output)
            if res.exit_code == 2:
                lines = [line for line in res.stderr.splitlines() if line.strip()]
                assert len(lines) == 1 and lines[0].startswith(f"replay: error: {path}: "), (name, key, lines)
            elif args[0] == "eval":
                assert res.stdout == reference, (name, key)


@pytest.mark.parametrize("gap", ["first", "middle"])
def test_a_scan_no_frame_holds_is_one_line_in_eval_and_replay(runner, radar_model, tmp_path, gap):
    """Scan indices from 1 (the fuzzer: every Scan's index + 1), or scan 5 dropped from the plots:
    that scan's time is unknown. ``eval`` accepted it and ``replay`` failed writing the outputs
    with a line naming a tracker's output channel, not the file."""
    model, _ = radar_model
    model = fz._copy(model)
    plots_id = next(r.id for c in model.chunks for r in c if isinstance(r, Channel) and r.topic == "/radar/plots")
    for ci, j in reversed(fz._messages(model)):
        rec = model.chunks[ci][j]
        msg = fz._scan_class(fz._schema_of(model, rec.channel_id)).FromString(rec.data)
        if gap == "first":
            msg.scan += 1
            model.chunks[ci][j] = replace(rec, data=msg.SerializeToString())
        elif msg.scan == 5 and rec.channel_id == plots_id:
            del model.chunks[ci][j]
    model.metadata_after = [m for m in model.metadata_after if m.name != fz.LAYOUT_RECORD]
    path = tmp_path / f"gap-{gap}.mcap"
    path.write_bytes(fz.assemble(model))
    _refused_everywhere(runner, path, "/radar/plots: no frame holds scan " + ("0" if gap == "first" else "5"))
