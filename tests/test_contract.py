"""The MCAP data contract: exact round trips, reproducible bytes, clear errors on bad files."""

import hashlib
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from trackreplay.contract import (
    FRAME_SCHEMA,
    decode_frame,
    encode_frame,
    read_dataset,
    write_dataset,
)
from trackreplay.errors import InputError
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import record

DTYPES = st.sampled_from([np.float64, np.float32, np.complex128, np.int64, np.uint8])


@settings(max_examples=80, deadline=None)
@given(a=arrays(DTYPES, st.lists(st.integers(0, 4), min_size=0, max_size=3).map(tuple)),
       run=st.integers(0, 2**32 - 1), scan=st.integers(0, 2**32 - 1), t=st.floats(0, 1e6))
def test_frame_round_trip_is_bit_exact(a, run, scan, t):
    r, k, tt, out, n = decode_frame(encode_frame(run, scan, t, {"a": a}))
    assert (r, k, tt, n) == (run, scan, t, 1)
    assert out["a"].dtype == a.dtype and out["a"].shape == a.shape
    assert out["a"].tobytes() == a.tobytes()  # bit-exact, NaN payloads included


def test_dataset_round_trip_keeps_every_value(tmp_path):
    rng = np.random.default_rng(0)
    grid = rng.normal(size=(3, 5, 4))
    ragged = [[rng.normal(size=rng.integers(0, 4)) for _ in range(5)] for _ in range(3)]
    times = np.arange(5) * 0.1
    with write_dataset(tmp_path / "x.mcap", {"m": {"k": "v"}}) as w:
        w.write_grid("/grid", times, {"state": grid})  # batched frames
        for k in range(5):
            for r in range(3):
                w.write("/ragged", r, k, times[k], {"v": ragged[r][k]})
    ds = read_dataset(tmp_path / "x.mcap")
    np.testing.assert_array_equal(ds.channel("/grid").grid("state"), grid)
    vals, counts = ds.channel("/ragged").ragged("v")
    for r in range(3):
        for k in range(5):
            np.testing.assert_array_equal(vals[r, k, : counts[r, k]], ragged[r][k])
    np.testing.assert_array_equal(ds.channel("/grid").times(), times)
    assert ds.metadata["m"] == {"k": "v"}


def _message_digest(path):
    from mcap.reader import make_reader

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages():
            h.update(ch.topic.encode() + msg.data)
    return h.hexdigest()


def test_same_seed_gives_identical_bytes(tmp_path):
    sc = load_scenario("radar-tws")
    record(tmp_path / "a.mcap", sc, 5, 99)
    record(tmp_path / "b.mcap", sc, 5, 99)
    record(tmp_path / "c.mcap", sc, 5, 100)
    assert _message_digest(tmp_path / "a.mcap") == _message_digest(tmp_path / "b.mcap")
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    assert _message_digest(tmp_path / "a.mcap") != _message_digest(tmp_path / "c.mcap")


def test_simulated_file_records_scenario_seed_and_version(radar_small):
    from trackreplay import __version__

    sc = read_dataset(radar_small).scenario
    assert sc["scenario"] == "radar-tws" and sc["seed"] == "5"
    assert sc["package_version"] == __version__
    assert sc["params"]["sigma_bearing_deg"] == 1.0


def test_schema_is_self_describing_for_other_tools(radar_small):
    """Decode with mcap_protobuf's generic decoder, which knows nothing of our code."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with open(radar_small, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        schema, channel, message, decoded = next(reader.iter_decoded_messages(topics=["/radar/truth"]))
    assert schema.name == FRAME_SCHEMA
    col = next(c for c in decoded.columns if c.name == "state")  # one message: every run of scan 0
    state = np.frombuffer(col.values, dtype=col.dtype).reshape(decoded.frame_count, *col.shape)
    assert state.shape == (30, 4) and decoded.first_run == 0 and decoded.scan == 0
    np.testing.assert_array_equal(state, read_dataset(radar_small).channel("/radar/truth").grid("state")[:, 0])


def test_empty_file_is_a_clear_error(tmp_path):
    p = tmp_path / "empty.mcap"
    p.write_bytes(b"")
    with pytest.raises(InputError, match="empty file") as e:
        read_dataset(p)
    assert str(p) in str(e.value)


def test_not_mcap_is_a_clear_error(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_text("time,range\n")
    with pytest.raises(InputError, match="not an MCAP file"):
        read_dataset(p)


def test_truncated_file_refused_then_recovered(radar_small, tmp_path):
    data = radar_small.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"truncated.*(\d+) message\(s\).*--recover"):
        read_dataset(cut)
    ds = read_dataset(cut, recover=True)
    full = read_dataset(radar_small)
    assert 0 < ds.recovered_messages < sum(len(c.run) for c in full.channels.values())
    # what was kept is exactly what the full file says for those frames
    rec, ref = ds.channel("/radar/truth"), full.channel("/radar/truth")
    g = rec.grid("state")
    np.testing.assert_array_equal(g[np.isfinite(g)], ref.grid("state")[: g.shape[0], : g.shape[1]][np.isfinite(g)])
    assert ds.scenario["seed"] == "5"  # metadata come first, so they survive


def test_foreign_schema_is_refused(tmp_path):
    from mcap.writer import Writer

    p = tmp_path / "foreign.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("geometry_msgs/Point", "jsonschema", json.dumps({"type": "object"}).encode())
        cid = w.register_channel("/radar/plots", "json", sid)
        w.add_message(cid, 0, b"{}", 0)
        w.finish()
    with pytest.raises(InputError, match="foreign schema geometry_msgs/Point"):
        read_dataset(p)


def test_missing_channel_names_what_is_there(radar_small):
    with pytest.raises(InputError, match=r"missing channel '/array/snapshots'.*/radar/plots"):
        read_dataset(radar_small).channel("/array/snapshots")


def test_failed_write_leaves_no_file_and_keeps_old_one(tmp_path):
    p = tmp_path / "out.mcap"
    p.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with write_dataset(p) as w:
            w.write("/x", 0, 0, 0.0, {"a": np.zeros(2)})
            raise RuntimeError("crash mid-write")
    assert p.read_bytes() == b"old"
    assert [q.name for q in tmp_path.iterdir()] == ["out.mcap"]


def test_other_mcap_tools_read_the_file(radar_small):
    """`rerun mcap info` (shipped with rerun-sdk) knows nothing of our code and reads the file."""
    import shutil
    import subprocess
    import sys

    exe = shutil.which("rerun")
    cmd = [exe] if exe else [sys.executable, "-m", "rerun"]
    out = subprocess.run([*cmd, "mcap", "info", str(radar_small)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "Messages" in out.stdout and "128" in out.stdout  # 64 scans × 2 channels, every run in each
