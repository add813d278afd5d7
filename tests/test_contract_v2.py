"""Contract v2 (one message per channel and scan, columns in bulk): the same arrays as v1,
v1 files still read and upgrade, damage is named, claims are bounded, bytes are reproducible."""

from __future__ import annotations

import hashlib
import re
import struct
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

import trackreplay.face.cli
from trackreplay.contract import (
    CONTRACT_V1,
    CONTRACT_V2,
    FRAME_SCHEMA_V1,
    MAX_FRAMES_PER_MESSAGE,
    OUTPUT_ZSTD_LEVEL,
    METADATA_LAYOUT,
    METADATA_SCENARIO,
    SCAN_SCHEMA,
    Scan,
    read_dataset,
    rewrite_dataset,
    write_dataset,
)
from trackreplay.errors import InputError
from trackreplay.recorders.scenarios import load_scenario
from trackreplay.recorders.simulated import record

REPO = Path(__file__).resolve().parents[1]
BUNDLED = sorted((REPO / "data").glob("*.mcap"))


# --------------------------------------------------------------------------- helpers


def outcome(call):
    """What a ChannelData call gives: ``("ok", [arrays])``, or ``("error", its line without the file)``."""
    try:
        with warnings.catch_warnings():  # ragged() of complex snapshots casts to float in v1 and v2 alike
            warnings.simplefilter("ignore", np.exceptions.ComplexWarning)
            out = call()
    except InputError as exc:
        return "error", exc.problem
    if out is None:
        return "ok", []
    return "ok", list(out) if isinstance(out, (tuple, list)) else [out]


def assert_same_dataset(a, b):
    """Every decoded view of every channel is identical (bytes, dtypes, shapes, error texts)."""
    assert list(a.channels) == list(b.channels)
    assert a.metadata.keys() == b.metadata.keys()
    for topic in a.channels:
        x, y = a.channel(topic), b.channel(topic)
        for attr in ("run", "scan", "time_s"):
            u, v = getattr(x, attr), getattr(y, attr)
            assert u.dtype == v.dtype and u.tobytes() == v.tobytes(), (topic, attr)
        assert (x.n_runs, x.n_scans) == (y.n_runs, y.n_scans)
        assert x.times().tobytes() == y.times().tobytes()
        assert outcome(x.require_every_frame) == outcome(y.require_every_frame)
        assert list(x.arrays) == list(y.arrays), topic
        for name in x.arrays:
            for view in ("array", "grid", "ragged"):
                (kp, p), (kq, q) = outcome(lambda: getattr(x, view)(name)), outcome(lambda: getattr(y, view)(name))
                assert kp == kq, (topic, name, view, p, q)
                if kp == "error":
                    assert p == q, (topic, name, view)
                    continue
                assert len(p) == len(q), (topic, name, view)
                for u, v in zip(p, q):
                    assert isinstance(u, np.ndarray) and isinstance(v, np.ndarray), (topic, name, view)
                    assert u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes(), (topic, name, view)


def frame_bytes(path) -> bytes:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def invoke(*args):
    return CliRunner().invoke(trackreplay.face.cli.main, [str(a) for a in args])


def chunk_offsets(path) -> list[tuple[int, int]]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)


@pytest.fixture(scope="module")
def radar_v2(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("v2") / "radar.mcap"
    record(path, load_scenario("radar-tws"), runs=12, seed=3)
    return path


# --------------------------------------------------------------------------- v1 and v2 agree


@pytest.mark.parametrize("path", BUNDLED, ids=[p.stem for p in BUNDLED])
def test_bundled_data_sets_are_v2_and_read_exactly_as_their_v1_copies(path, tmp_path):
    v2 = read_dataset(path)
    assert v2.contract == CONTRACT_V2 and v2.metadata[METADATA_SCENARIO]["contract"] == CONTRACT_V2
    rep = rewrite_dataset(path, tmp_path / "v1.mcap", contract=CONTRACT_V1)
    v1 = read_dataset(tmp_path / "v1.mcap")
    assert v1.contract == CONTRACT_V1 and rep.frames == sum(c.run.size for c in v2.channels.values())
    assert v1.metadata[METADATA_SCENARIO]["contract"] == CONTRACT_V1
    assert_same_dataset(v1, v2)
    # and back: upgrading the v1 copy gives the bundled file byte for byte
    rewrite_dataset(tmp_path / "v1.mcap", tmp_path / "v2.mcap")
    assert (tmp_path / "v2.mcap").read_bytes() == path.read_bytes()


@pytest.mark.parametrize("scenario, runs", [("radar-tws", 4), ("xcorr-crossing", 3), ("array-crossing", 1),
                                            ("colored-imm", 2), ("tdoa-fdoa-noise", 3)])
def test_simulated_v1_and_v2_files_decode_identically(scenario, runs, tmp_path):
    sc = load_scenario(scenario)
    if scenario == "colored-imm":
        sc = sc.with_overrides({"n_samples": 60, "manoeuvre_first_sample": 20, "manoeuvre_last_sample": 40})
    record(tmp_path / "v1.mcap", sc, runs, 11, contract=CONTRACT_V1)
    record(tmp_path / "v2.mcap", sc, runs, 11)
    assert_same_dataset(read_dataset(tmp_path / "v1.mcap"), read_dataset(tmp_path / "v2.mcap"))
    # upgrading the v1 file is exactly what simulate writes in v2
    rewrite_dataset(tmp_path / "v1.mcap", tmp_path / "up.mcap")
    assert (tmp_path / "up.mcap").read_bytes() == (tmp_path / "v2.mcap").read_bytes()


ARRAY = st.sampled_from([np.float64, np.int32, np.complex64, np.bool_])


@st.composite
def frame_lists(draw):
    """Frames as a hand-written file may hold them: runs in any order, arrays missing from some
    frames, shapes, dtypes and times changing from frame to frame (each run and scan once: a
    duplicated frame is refused, see test_duplicated_frames_are_refused_by_both_contracts)."""
    frames, seen = [], set()
    for _ in range(draw(st.integers(1, 14))):
        run, scan = draw(st.integers(0, 3)), draw(st.integers(0, 3))
        if (run, scan) in seen:
            continue
        seen.add((run, scan))
        t = draw(st.sampled_from([0.0, 0.5, float(scan)]))
        arrays = {}
        for name in draw(st.lists(st.sampled_from(["a", "b", "c"]), unique=True, max_size=3)):
            shape = tuple(draw(st.lists(st.integers(0, 3), max_size=2)))
            dtype = draw(ARRAY)
            arrays[name] = (np.arange(int(np.prod(shape))) + run * 10 + scan).astype(dtype).reshape(shape)
        frames.append((run, scan, t, arrays))
    return frames


@settings(max_examples=60, deadline=None)
@given(frames=frame_lists(), batched=st.booleans())
def test_any_frames_read_the_same_in_v1_and_v2(tmp_path_factory, frames, batched):
    d = tmp_path_factory.mktemp("h")
    for contract in (CONTRACT_V1, CONTRACT_V2):
        with write_dataset(d / f"{contract}.mcap", contract=contract) as w:
            for run, scan, t, arrays in frames:
                w.write("/x", run, scan, t, arrays)
            if batched:
                w.write_grid("/g", np.arange(3.0), {"s": np.arange(24.0).reshape(2, 3, 4)})
    assert_same_dataset(read_dataset(d / f"{CONTRACT_V1}.mcap"), read_dataset(d / f"{CONTRACT_V2}.mcap"))


def test_duplicated_frames_are_refused_by_both_contracts(tmp_path):
    messages = set()
    for contract in (CONTRACT_V1, CONTRACT_V2):
        path = tmp_path / f"{contract}.mcap"
        with write_dataset(path, contract=contract) as w:
            for scan in (0, 1, 1):
                w.write("/x", 0, scan, float(scan), {"a": np.arange(3.0)})
        with pytest.raises(InputError) as err:
            read_dataset(path)
        messages.add(err.value.problem)
    assert messages == {"/x holds 1 duplicated frame(s), the first at run 0 scan 1"}


def test_ragged_writes_equal_frame_by_frame_writes(tmp_path):
    rng = np.random.default_rng(4)
    counts = rng.integers(0, 4, size=(5, 3))
    vals = rng.normal(size=(5, 3, 4, 2))
    with write_dataset(tmp_path / "a.mcap") as w:
        for k in range(3):
            w.write_ragged("/p", k, 0.1 * k, {"v": vals[:, k]}, counts[:, k])
            w.flush()
    with write_dataset(tmp_path / "b.mcap") as w:
        for k in range(3):
            for r in range(5):
                w.write("/p", r, k, 0.1 * k, {"v": vals[r, k, :counts[r, k]]})
            w.flush()
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    got, c = read_dataset(tmp_path / "a.mcap").channel("/p").ragged("v")
    np.testing.assert_array_equal(c, counts)
    for r in range(5):
        for k in range(3):
            np.testing.assert_array_equal(got[r, k, :counts[r, k]], vals[r, k, :counts[r, k]])


@pytest.mark.parametrize("runs", [1, 3, 40])
def test_grid_writes_equal_scan_by_scan_batch_writes(tmp_path, runs):
    """``write_grid`` builds its messages directly; the file is the one that scan-by-scan
    ``write_batch`` calls write, byte for byte (strided, big-endian, 0-d and bool entries)."""
    rng = np.random.default_rng(5)
    scans = 23
    arrays = {"state": rng.normal(size=(runs, scans, 4)),
              "covariance": rng.normal(size=(runs, scans, 4, 4)),
              "flags": rng.integers(0, 9, size=(runs, scans)).astype(np.uint16),
              "strided": rng.normal(size=(scans, runs, 2)).transpose(1, 0, 2),
              "big_endian": rng.normal(size=(runs, scans, 3)).astype(">f8"),
              "hit": rng.random(size=(runs, scans)) < 0.5}
    times = np.cumsum(rng.uniform(0.5, 1.5, scans))
    with write_dataset(tmp_path / "grid.mcap") as w:
        w.write_grid("/tracks/x", times, arrays)
        w.write_grid("/tracks/y", times, {"state": arrays["state"][:, :, :2]})
    with write_dataset(tmp_path / "scans.mcap") as w:
        for topic, grid in (("/tracks/x", arrays), ("/tracks/y", {"state": arrays["state"][:, :, :2]})):
            for k in range(scans):
                w.write_batch(topic, k, times[k], {name: a[:, k] for name, a in grid.items()})
            w._emit(topic)  # a complete grid's last scan is written at once, not left pending
    assert (tmp_path / "grid.mcap").read_bytes() == (tmp_path / "scans.mcap").read_bytes()
    got = read_dataset(tmp_path / "grid.mcap").channel("/tracks/x")
    for name, a in arrays.items():
        np.testing.assert_array_equal(got.grid(name), a)


def test_one_run_grid_keeps_its_shape(tmp_path):
    state = np.arange(12.0).reshape(1, 3, 4)
    with write_dataset(tmp_path / "one.mcap") as w:
        w.write_grid("/tracks", np.arange(3.0), {"state": state})
    np.testing.assert_array_equal(read_dataset(tmp_path / "one.mcap").channel("/tracks").grid("state"), state)


def test_v2_message_is_one_scan_of_every_run_and_self_describing(radar_v2):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with open(radar_v2, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert {s.name for s in summary.schemas.values()} == {SCAN_SCHEMA}
        assert summary.statistics.message_count == 64 * 2
        decoded = [d for _, ch, _, d in reader.iter_decoded_messages(topics=["/radar/plots"], log_time_order=False)]
        layout = {m.name: m.metadata for m in reader.iter_metadata()}[METADATA_LAYOUT]
    assert [d.scan for d in decoded] == list(range(64)) and all(d.frame_count == 12 for d in decoded)
    rng = next(c for c in decoded[5].columns if c.name == "range_m")
    values = np.frombuffer(rng.values, rng.dtype)
    if rng.layout == 1:  # RAGGED: values + offsets
        offsets = np.frombuffer(rng.offsets, "<i8")
        entries = [values[offsets[i]:offsets[i + 1]] for i in range(12)]
    else:
        entries = list(values.reshape(12, *rng.shape))
    ref_vals, ref_counts = read_dataset(radar_v2).channel("/radar/plots").ragged("range_m")
    for r in range(12):
        np.testing.assert_array_equal(entries[r], ref_vals[r, 5, :ref_counts[r, 5]])
    assert '"runs": 12' in layout["/radar/plots"] and '"scans": 64' in layout["/radar/plots"]


# --------------------------------------------------------------------------- v1 files and upgrade


def test_v1_file_still_reads_and_upgrades_on_the_command_line(radar_v2, tmp_path):
    v1 = tmp_path / "old.mcap"
    rewrite_dataset(radar_v2, v1, contract=CONTRACT_V1)
    with open(v1, "rb") as f:
        from mcap.reader import make_reader

        assert {s.name for s in make_reader(f).get_summary().schemas.values()} == {FRAME_SCHEMA_V1}
    old = read_dataset(v1)
    assert old.contract == CONTRACT_V1
    res = invoke("convert", "upgrade", v1, "-o", tmp_path / "new.mcap")
    assert res.exit_code == 0, res.output
    assert "replay.v1" in res.output and "→ 128 messages (replay.v2)" in res.output
    assert (tmp_path / "new.mcap").read_bytes() == radar_v2.read_bytes()
    # never in place: an input is never written over
    before = v1.read_bytes()
    res = invoke("convert", "upgrade", v1, "-o", v1)
    assert res.exit_code == 2 and "refusing to write an output over the input" in res.stderr
    assert v1.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.mcap", "old.mcap"]


def test_upgrade_of_a_bad_file_is_one_line_and_writes_nothing(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    res = invoke("convert", "upgrade", bad, "-o", tmp_path / "out.mcap")
    assert res.exit_code == 2 and res.stderr.startswith(f"replay: error: {bad}: ") and "Traceback" not in res.output
    assert not (tmp_path / "out.mcap").exists()


# --------------------------------------------------------------------------- damage is named


def test_chunk_crc_flip_is_named_and_recover_keeps_the_other_chunks(radar_v2, tmp_path):
    data = bytearray(radar_v2.read_bytes())
    chunks = chunk_offsets(radar_v2)
    start, _ = chunks[7]
    data[start + 1 + 8 + 8 + 8 + 8] ^= 0x01  # the chunk record's uncompressed_crc field
    bad = tmp_path / "flip.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(InputError) as exc:
        read_dataset(bad)
    assert str(exc.value).startswith(f"{bad}: chunk 8 of 64 (byte {start}): CRC mismatch")
    assert "126 message(s) in intact chunks are recoverable with --recover" in str(exc.value)
    kept = read_dataset(bad, recover=True)
    full = read_dataset(radar_v2)
    assert kept.recovered_messages == 126
    truth, ref = kept.channel("/radar/truth").grid("state"), full.channel("/radar/truth").grid("state")
    assert np.isnan(truth[:, 7]).all()
    np.testing.assert_array_equal(np.delete(truth, 7, axis=1), np.delete(ref, 7, axis=1))
    # the command line says it in one line, exit 2
    res = invoke(bad, "--no-rrd")
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.stderr.strip().splitlines()[-1].startswith(f"replay: error: {bad}: chunk 8 of 64")


@pytest.mark.parametrize("where", ["payload", "metadata", "summary"])
def test_any_flipped_bit_is_an_input_error(radar_v2, tmp_path, where):
    data = bytearray(radar_v2.read_bytes())
    chunks = chunk_offsets(radar_v2)
    pos = {"payload": chunks[3][0] + chunks[3][1] - 50, "metadata": 60, "summary": len(data) - 120}[where]
    data[pos] ^= 0x10
    bad = tmp_path / f"{where}.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(InputError, match="CRC mismatch") as exc:
        read_dataset(bad)
    assert str(bad) in str(exc.value) and "--recover" in str(exc.value)


def test_dependency_failures_on_bad_bytes_are_input_errors(radar_v2, tmp_path):
    """Bytes that make zstd, struct, protobuf or the mcap reader fail never escape as tracebacks."""
    data = radar_v2.read_bytes()
    rng = np.random.default_rng(0)
    for i, pos in enumerate(rng.integers(0, len(data), 60)):
        broken = bytearray(data)
        broken[pos:pos + 4] = rng.integers(0, 256, 4, dtype=np.uint8).tobytes()
        p = tmp_path / f"b{i}.mcap"
        p.write_bytes(bytes(broken))
        for recover in (False, True):
            try:
                read_dataset(p, recover=recover)
            except InputError as exc:
                assert str(exc).startswith(str(p)) and "\n" not in str(exc)


def test_undecodable_message_with_a_valid_crc_names_chunk_and_channel(tmp_path):
    from trackreplay.contract import McapFrameWriter

    p = tmp_path / "garbage.mcap"
    with open(p, "wb") as f:
        w = McapFrameWriter(f)
        w.write("/x", 0, 0, 0.0, {"a": np.zeros(3)})
        w.flush()
        w._add_message("/x", 1.0, b"\xff\xff\xff")  # not a Scan message
        w.finish()
    with pytest.raises(InputError, match=r"chunk 2 of 2 \(byte \d+\): bad message on /x: DecodeError"):
        read_dataset(p)
    assert read_dataset(p, recover=True).channel("/x").run.tolist() == [0]


# --------------------------------------------------------------------------- bounded memory


@pytest.mark.parametrize("contract", [CONTRACT_V1, CONTRACT_V2])
@pytest.mark.parametrize("run, scan", [(65536, 0), (65536, 65536), (2**32 - 1, 7)])
def test_a_frame_claiming_a_huge_run_fails_fast_and_small(tmp_path, contract, run, scan):
    p = tmp_path / "claim.mcap"
    with write_dataset(p, contract=contract) as w:  # 3.6 kB per frame: a [run, scan] grid would be huge
        w.write("/array/snapshots", run, scan, 0.0, {"snapshots": np.ones((15, 30), np.complex64)})
    assert p.stat().st_size < 4096
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(InputError, match=f"run[^;]* {run}") as exc:
            read_dataset(p)
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert elapsed < 1.0 and peak < 500e6, (elapsed, peak)
    assert str(exc.value).startswith(str(p))
    res = invoke(p, "--no-rrd")
    assert res.exit_code == 2 and res.stderr.startswith(f"replay: error: {p}: ") and "Traceback" not in res.output


def test_a_frame_beyond_the_declared_layout_is_refused(tmp_path):
    p = tmp_path / "layout.mcap"
    with write_dataset(p) as w:
        for r in range(3):
            w.write("/x", r, 0, 0.0, {"a": np.zeros(2)})
        w.flush()
        w.write("/x", 65536, 1, 1.0, {"a": np.zeros(2)})
        w._layout["/x"] = [3, 2, 4]  # what a consistent writer of 3 runs would have declared
    with pytest.raises(InputError, match=r"chunk 2 of 2 .*claims run 65536 scan 1, but the file's replay.layout "
                                         r"record declares 3 run\(s\) × 2 scan\(s\)"):
        read_dataset(p)


def test_a_message_claiming_too_many_frames_is_refused(tmp_path):
    from trackreplay.contract import McapFrameWriter

    p = tmp_path / "count.mcap"
    with open(p, "wb") as f:
        w = McapFrameWriter(f)
        w._add_message("/x", 0.0, Scan(scan=0, frame_count=MAX_FRAMES_PER_MESSAGE + 1).SerializeToString())
        w._add_message("/y", 0.0, Scan(scan=0, frame_count=2, runs=struct.pack("<I", 5)).SerializeToString())
        w.finish()
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=f"claims {MAX_FRAMES_PER_MESSAGE + 1} frames"):
            read_dataset(p)
        with pytest.raises(InputError, match="runs holds 4 bytes for 2 frame"):
            read_dataset(p, topics=["/y"])
        assert tracemalloc.get_traced_memory()[1] < 50e6
    finally:
        tracemalloc.stop()


def test_reading_2000_runs_peaks_at_a_small_multiple_of_the_decoded_size(tmp_path):
    p = tmp_path / "r2000.mcap"
    record(p, load_scenario("radar-tws"), runs=2000, seed=1)
    tracemalloc.start()
    try:
        ds = read_dataset(p)
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    decoded = sum(ch.run.nbytes + ch.scan.nbytes + ch.time_s.nbytes for ch in ds.channels.values())
    decoded += sum(ch.grid("state").nbytes for ch in [ds.channel("/radar/truth")])
    decoded += sum(ch.ragged(n)[0].nbytes for ch in [ds.channel("/radar/plots")] for n in ch.arrays)
    assert decoded > 10e6
    assert peak < 2.5 * decoded, (peak, decoded)


# --------------------------------------------------------------------------- reproducible


@pytest.mark.parametrize("contract", [CONTRACT_V1, CONTRACT_V2])
def test_same_seed_same_bytes(tmp_path, contract):
    sc = load_scenario("xcorr-crossing")
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        record(tmp_path / f"{name}.mcap", sc, 3, seed, contract=contract)
    assert frame_bytes(tmp_path / "a.mcap") == frame_bytes(tmp_path / "b.mcap")
    assert frame_bytes(tmp_path / "a.mcap") != frame_bytes(tmp_path / "c.mcap")


@pytest.mark.parametrize("path", BUNDLED, ids=[p.stem for p in BUNDLED])
def test_a_complete_scan_major_grid_is_a_read_only_view_of_the_same_values(path):
    # the read path hands out the decoded values themselves when every frame is there in the
    # writer's order; the scatter it skips is done here by hand and must give the same grid
    from trackreplay.contract import FIXED

    ds = read_dataset(path)
    views = candidates = 0
    for topic, ch in ds.channels.items():
        for name in ch.arrays:
            column = ch._column(name)
            if column is None or column.kind != FIXED or column.dtype.kind in "iub":
                continue
            candidates += 1
            grid = ch.grid(name)
            expected = np.full(grid.shape, np.nan, dtype=grid.dtype)
            expected[ch.run, ch.scan] = column.values
            np.testing.assert_array_equal(grid, expected, err_msg=f"{topic} {name}")
            if ch._scan_major():
                assert not grid.flags.writeable and np.shares_memory(grid, column.values)
                views += 1
    # every bundled data set with a fixed-shape float channel reads it as a view (a multi-target
    # data set's channels are all ragged lists)
    assert views or not candidates



def test_ragged_of_equal_length_lists_in_writer_order_is_a_read_only_view(radar_v2, tmp_path):
    # one plot in every frame (the radar scenario without clutter): ragged() hands out the values
    # themselves; the scatter it skips is done here by hand and must give the same array
    from trackreplay.contract import FIXED

    ch = read_dataset(radar_v2).channel("/radar/plots")
    column = ch._column("range_m")
    assert column.kind == FIXED and ch._scan_major()
    values, counts = ch.ragged("range_m")
    expected = np.full((ch.n_runs, ch.n_scans) + column.shape, np.nan)
    expected[ch.run, ch.scan] = column.values
    np.testing.assert_array_equal(values, expected)
    np.testing.assert_array_equal(counts, np.full((ch.n_runs, ch.n_scans), column.shape[0]))
    assert not values.flags.writeable and np.shares_memory(values, column.values)
    with pytest.raises(ValueError):
        counts[0, 0] = 2  # a broadcast count, not a table to write into
    # the same frames in another order, or with a frame missing, take the scatter
    with write_dataset(tmp_path / "gap.mcap") as w:
        for r, k in ((0, 0), (1, 0), (0, 1)):
            w.write("/radar/plots", r, k, float(k), {"range_m": np.array([1.0 + r]), "bearing_rad": np.array([0.5])})
    v, c = read_dataset(tmp_path / "gap.mcap").channel("/radar/plots").ragged("range_m")
    assert v.flags.writeable and c.tolist() == [[1, 1], [1, 0]] and np.isnan(v[1, 1, 0])


# --------------------------------------------------------------------------- frames kept per message


@st.composite
def message_blocks(draw):
    """Messages as (scan, first_run, count, time): in the writer's order or any other."""
    n = draw(st.integers(1, 8))
    return [(draw(st.integers(0, 5)), draw(st.integers(0, 6)), draw(st.integers(1, 4)),
             draw(st.sampled_from([0.0, -0.0, 0.5, 2.0]))) for _ in range(n)]


@settings(max_examples=200, deadline=None)
@given(blocks=message_blocks(), writer_order=st.tuples(st.integers(1, 4), st.integers(1, 4), st.integers(1, 3)))
def test_frames_kept_per_message_equal_the_per_frame_arrays(blocks, writer_order):
    """A channel that keeps its messages' (scan, first run, count, time) answers run, scan,
    time_s, the grid's size, scan-major order and the scan times as the per-frame arrays do."""
    from trackreplay.contract import ChannelData
    from trackreplay.contract.dataset import _FrameBlocks

    runs, scans, split = writer_order  # also the writer's own layout: every scan whole, maybe split in parts
    ordered = [(k, first, min(split, runs - first), float(k)) for k in range(scans) for first in range(0, runs, split)]
    for rows in (blocks, ordered):
        scan, first, count, time_s = (np.array(c) for c in zip(*rows))
        index = _FrameBlocks(scan.astype(np.int64), first.astype(np.int64), count.astype(np.int64),
                             time_s.astype(np.float64))
        lazy = ChannelData.of_blocks(index, {})
        run = np.concatenate([np.arange(f, f + c) for f, c in zip(first, count)]).astype(np.int64)
        eager = ChannelData(run, np.repeat(scan, count).astype(np.int64), np.repeat(time_s, count).astype(np.float64), {})
        for attr in ("run", "scan", "time_s"):
            u, v = getattr(lazy, attr), getattr(eager, attr)
            assert u.dtype == v.dtype and u.tobytes() == v.tobytes(), attr
        assert (lazy.n_frames, lazy.n_runs, lazy.n_scans) == (eager.n_frames, eager.n_runs, eager.n_scans)
        assert lazy._scan_major() == eager._scan_major()
        assert lazy.times().tobytes() == eager.times().tobytes()
    assert ChannelData.of_blocks(_FrameBlocks(*(np.array(c) for c in zip(*ordered))), {})._scan_major()


def test_a_channel_read_from_whole_scans_keeps_no_per_frame_arrays(radar_v2):
    ds = read_dataset(radar_v2)
    for ch in ds.channels.values():
        assert ch._run is None and ch._blocks is not None
        assert ch.n_frames == ch.run.size == 12 * 64


# --------------------------------------------------------------------------- symmetric matrices


def symmetric_grid(rng, shape):
    a = rng.normal(size=shape)
    return a + np.swapaxes(a, -1, -2)


def column_layouts(path, topic):
    """{array name: set of layouts} over the messages of ``topic``, as stored."""
    from mcap.reader import make_reader

    layouts = {}
    with open(path, "rb") as f:
        for _, _, message in make_reader(f).iter_messages(topics=[topic]):
            scan = Scan()
            scan.ParseFromString(message.data)
            for c in scan.columns:
                layouts.setdefault(c.name, set()).add(c.layout)
    return layouts


def test_symmetric_grids_are_stored_as_triangles_and_read_back_to_the_bit(tmp_path, monkeypatch):
    import trackreplay.contract.writing
    from trackreplay.contract import FIXED, SYMMETRIC

    monkeypatch.setattr(trackreplay.contract.writing, "PACK_BLOCK_BYTES", 1)  # one scan per block: decided scan by scan

    rng = np.random.default_rng(11)
    runs, scans = 7, 5
    cov = symmetric_grid(rng, (runs, scans, 4, 4))
    cov[2, 1] = np.nan                      # NaN, ±0 and ±inf on both sides of the diagonal
    cov[3, 2, 0, 1] = cov[3, 2, 1, 0] = -0.0
    cov[4, 3, 2, 3] = cov[4, 3, 3, 2] = np.inf
    cov = cov.transpose(1, 0, 2, 3).copy().transpose(1, 0, 2, 3)   # strided, as a tracker may give it
    nearly = symmetric_grid(rng, (runs, scans, 3, 3))
    nearly[5, 4, 0, 2] = np.nextafter(nearly[5, 4, 2, 0], np.inf)  # one scan off by one ulp
    minus_zero = symmetric_grid(rng, (runs, scans, 2, 2))
    minus_zero[0, 0, 0, 1], minus_zero[0, 0, 1, 0] = 0.0, -0.0      # equal as numbers, not as bits
    arrays = {"covariance": cov, "nearly": nearly, "minus_zero": minus_zero,
              "per_target": symmetric_grid(rng, (runs, scans, 3, 2, 2)),
              "single": rng.normal(size=(runs, scans, 1, 1)), "wide": rng.normal(size=(runs, scans, 2, 3)),
              "complex": (symmetric_grid(rng, (runs, scans, 2, 2)) + 0j), "counts": np.ones((runs, scans, 2, 2), np.int64),
              "f32": symmetric_grid(rng, (runs, scans, 3, 3)).astype(np.float32)}
    times = np.arange(scans, dtype=float)
    for pack in (False, True):
        path = tmp_path / f"pack{pack}.mcap"
        with write_dataset(path, pack_symmetric=pack) as w:
            w.write_grid("/tracks/a", times, arrays)
        got = read_dataset(path).channel("/tracks/a")
        for name, a in arrays.items():
            g = np.ascontiguousarray(got.grid(name))
            a = a if a.dtype.kind in "fc" else a.astype(np.float64)  # grid() gives integers as floats
            assert g.dtype == a.dtype and g.shape == a.shape
            assert g.tobytes() == np.ascontiguousarray(a).tobytes(), name
        layouts = column_layouts(path, "/tracks/a")
        if not pack:
            assert all(v == {FIXED} for v in layouts.values())
            continue
        assert layouts["covariance"] == layouts["per_target"] == layouts["f32"] == {SYMMETRIC}
        assert layouts["nearly"] == layouts["minus_zero"] == {FIXED, SYMMETRIC}  # the one scan that is not
        assert layouts["single"] == layouts["wide"] == layouts["complex"] == layouts["counts"] == {FIXED}
    packed, whole = (tmp_path / "packTrue.mcap").stat().st_size, (tmp_path / "packFalse.mcap").stat().st_size
    assert packed < whole
    # blocks of scans (here all in one): the scan that is not symmetric keeps its block whole
    monkeypatch.setattr(trackreplay.contract.writing, "PACK_BLOCK_BYTES", 1 << 20)
    with write_dataset(tmp_path / "block.mcap", pack_symmetric=True) as w:
        w.write_grid("/tracks/a", times, arrays)
    got = read_dataset(tmp_path / "block.mcap").channel("/tracks/a")
    assert np.ascontiguousarray(got.grid("nearly")).tobytes() == nearly.tobytes()
    layouts = column_layouts(tmp_path / "block.mcap", "/tracks/a")
    assert layouts["nearly"] == {FIXED} and layouts["covariance"] == {SYMMETRIC}


def test_only_files_that_pack_carry_the_symmetric_layout_in_their_schema(tmp_path):
    from mcap.reader import make_reader

    from trackreplay.contract import PACKED_SCAN_DESCRIPTOR_SET, SCAN_DESCRIPTOR_SET

    assert b"SYMMETRIC" in PACKED_SCAN_DESCRIPTOR_SET and b"SYMMETRIC" not in SCAN_DESCRIPTOR_SET
    for pack in (False, True):
        with write_dataset(tmp_path / "a.mcap", pack_symmetric=pack) as w:
            w.write_grid("/t", np.arange(2.0), {"s": np.zeros((2, 2, 2))})
        with open(tmp_path / "a.mcap", "rb") as f:
            (schema,) = make_reader(f).get_summary().schemas.values()
        assert schema.data == (PACKED_SCAN_DESCRIPTOR_SET if pack else SCAN_DESCRIPTOR_SET)


@pytest.mark.parametrize("shape, n_values, problem", [
    ((3, 3), 5, "claims 2 entries of symmetric (3, 3) (float64) but holds 40 bytes"),
    ((2, 3), 6, "stored as symmetric matrices but has entries of shape (2, 3)"),
    ((4,), 4, "stored as symmetric matrices but has entries of shape (4,)"),
])
def test_a_bad_symmetric_column_is_an_input_error(tmp_path, shape, n_values, problem):
    from trackreplay.contract import McapFrameWriter, SYMMETRIC

    p = tmp_path / "sym.mcap"
    msg = Scan(scan=0, frame_count=2)
    col = msg.columns.add(name="covariance", dtype="<f8", layout=SYMMETRIC, values=np.zeros(n_values).tobytes())
    col.shape.extend(shape)
    with open(p, "wb") as f:
        w = McapFrameWriter(f, pack_symmetric=True)
        w._add_message("/tracks/x", 0.0, msg.SerializeToString())
        w.finish()
    with pytest.raises(InputError, match=re.escape(problem)):
        read_dataset(p)


def test_starting_the_writeback_between_grids_keeps_every_byte(tmp_path):
    """The writer hands what it wrote to the disk between large writes without waiting
    (``start_writeback``, the kernel dropping the pages already written from its cache): the file
    read back holds every array, and is the same file as one written without it."""
    rng = np.random.default_rng(3)
    grids = [{"state": rng.normal(size=(300, 20, 4)), "covariance": np.tile(np.eye(4), (300, 20, 1, 1)) * 2.0}
             for _ in range(3)]
    times = np.arange(20) * 0.5
    digests = []
    for with_writeback in (True, False):
        path = tmp_path / f"out-{with_writeback}.mcap"
        with write_dataset(path, {}, zstd_level=OUTPUT_ZSTD_LEVEL, pack_symmetric=True) as w:
            for i, grid in enumerate(grids):
                w.write_grid(f"/tracks/radar/t{i}", times, grid)
                if with_writeback:
                    w.start_writeback()
        digests.append(hashlib.sha256(path.read_bytes()).hexdigest())
        ds = read_dataset(path)
        for i, grid in enumerate(grids):
            for name, a in grid.items():
                np.testing.assert_array_equal(ds.channels[f"/tracks/radar/t{i}"].grid(name), a)
    assert digests[0] == digests[1]
