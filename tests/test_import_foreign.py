"""Recordings made by other tools: foreign MCAP (ROS 2, JSON, protobuf) through a mapping file.

Each foreign file is written here with the MCAP ecosystem's writers (``mcap_ros2.writer``,
``mcap_protobuf.writer``, ``mcap.writer`` for JSON), converted and replayed through the CLI;
the converted arrays must equal, exactly, what the same rows give through
:func:`trackreplay.recorders.tables.dataset_from_table` directly. Every bad input is one line and exit 2.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from click.testing import CliRunner

from trackreplay.contract import read_dataset, scenario_metadata
from trackreplay.face.cli import main
from conftest import assert_mapped_recording_refused
from trackreplay.recorders.foreign_mcap import load_mapping, read_foreign_mcap
from trackreplay.recorders.simulated import write_simulated

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "data" / "samples"

SCAN_MSGDEF = """std_msgs/Header header
uint32 run
Return[] returns
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: test_radar_msgs/Return
float64 range
float64 azimuth
string label
"""

RADAR_MAP = """family = "radar"
[measurements]
topic = "/radar/scan"
time = "header.stamp"
items = "returns"
run = "/run"
range_m = { field = "range", unit = "km" }
bearing_rad = { field = "azimuth", unit = "deg" }
"""


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def radar_scans(runs=2, scans=8, seed=0):
    """(run, sec, nanosec, [(range km, azimuth deg)]) with 1–3 returns per scan."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(scans):
        for r in range(runs):
            n = int(rng.integers(1, 4))
            target = (11.0 - 0.05 * k + rng.normal(0, 0.1), 120.0 - 0.3 * k + rng.normal(0, 1.0))
            rest = [(float(rng.uniform(2, 20)), float(rng.uniform(0, 180))) for _ in range(n - 1)]
            out.append((r, 1_700_000_000 + 5 * k, 250_000_000, [(float(target[0]), float(target[1])), *rest]))
    return out


def write_ros2(path: Path, scans, msgdef=SCAN_MSGDEF, label="ok") -> Path:
    from mcap_ros2.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("test_radar_msgs/msg/Scan", msgdef)
        for i, (run, sec, nsec, returns) in enumerate(scans):
            msg = {"header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": "radar"}, "run": run,
                   "returns": [{"range": a, "azimuth": b, "label": label} for a, b in returns]}
            w.write_message("/radar/scan", schema, msg, log_time=10**9 * (i + 1), publish_time=10**9 * (i + 1))
        w.finish()
    return path


def expected_radar_rows(scans) -> pl.DataFrame:
    """The rows a table importer would be given for the same scans (SI, radians)."""
    run, t, rng, az = [], [], [], []
    for r, sec, nsec, returns in scans:
        for a, b in returns:
            run.append(r)
            t.append(sec + nsec * 1e-9)
            rng.append(a)
            az.append(b)
    return pl.DataFrame({"run": np.asarray(run, np.int64), "time_s": np.asarray(t),
                         "range_m": np.asarray(rng) * 1000.0, "bearing_rad": np.asarray(az) * (math.pi / 180.0)})


def write_json(path: Path, bodies, topic="/fix", log_times=None, encoding="json") -> Path:
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        schema = w.register_schema("test.Fix", "jsonschema", b"{}")
        ch = w.register_channel(topic, encoding, schema)
        for i, body in enumerate(bodies):
            lt = 10**9 * (i + 1) if log_times is None else log_times[i]
            data = body if isinstance(body, bytes) else json.dumps(body).encode()
            w.add_message(ch, log_time=lt, publish_time=lt, sequence=i, data=data)
        w.finish()
    return path


def position_bodies(n=40):
    rng = np.random.default_rng(3)
    return [{"stamp": {"sec": 100 + k // 20, "nanosec": (k % 20) * 50_000_000},
             "pose": {"position": {"x": float(1000 + 150 * 0.05 * k + rng.normal(0, 10))}}} for k in range(n)]


POSITION_MAP = """family = "colored"
[measurements]
topic = "/fix"
time = "stamp"
x_m = { field = "pose.position.x", unit = "ft" }
"""


def same_dataset(a: Path, b: Path) -> None:
    """Every channel of two data sets holds identical frames and arrays (bytes, dtype, shape)."""
    da, db = read_dataset(a), read_dataset(b)
    assert set(da.channels) == set(db.channels)
    for topic, x in da.channels.items():
        y = db.channel(topic)
        assert np.array_equal(x.run, y.run) and np.array_equal(x.scan, y.scan), topic
        assert np.array_equal(x.time_s, y.time_s), topic
        for name in x.arrays:
            for u, v in zip(x.array(name), y.array(name), strict=True):
                assert u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes(), (topic, name)


def via_table(family: str, rows: pl.DataFrame, path: Path, out: Path, sensors=None) -> Path:
    from trackreplay.recorders.tables import dataset_from_table

    data = dataset_from_table(family, rows, path, sensors=sensors, sensors_path=path if sensors is not None else None)
    # a data set's scan times start at 0 (MCAP log times are unsigned), as every importer writes them
    write_simulated(out, replace(data, times=data.times - data.times[0]), scenario_metadata("table", {}, seed=-1))
    return out


# --------------------------------------------------------------------------- the three decoders


def test_ros2_mcap_converts_to_the_table_rows_exactly_and_replays(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scans = radar_scans()
    src = write_ros2(tmp_path / "scan.mcap", scans)
    (tmp_path / "radar.toml").write_text(RADAR_MAP)
    before = hashlib.sha256(src.read_bytes()).hexdigest()

    got = read_foreign_mcap(src, load_mapping(tmp_path / "radar.toml")).tables["measurements"]
    expected = expected_radar_rows(scans)
    assert got.columns == expected.columns and got.equals(expected)

    res = invoke("convert", "mcap", src, "--map", "radar.toml", "-o", "ours.mcap")
    assert res.exit_code == 0, res.output
    assert f"{len(scans)} messages on /radar/scan → {expected.height} rows" in res.output
    same_dataset(tmp_path / "ours.mcap", via_table("radar", expected, src, tmp_path / "table.mcap"))
    ds = read_dataset(tmp_path / "ours.mcap")
    assert ds.channel("/radar/plots").n_runs == 2

    # the mapping says nothing of the sensor: its noise is given at replay time
    res = invoke(src, "--map", "radar.toml", "--no-rrd", "--set", "sigma_range_m=100", "--set", "sigma_bearing_deg=1")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "replay-out" / "scan" / "tracks.mcap").exists()  # named after the foreign file
    assert hashlib.sha256(src.read_bytes()).hexdigest() == before


def test_json_mcap_converts_to_the_table_rows_exactly_and_replays(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bodies = position_bodies()
    src = write_json(tmp_path / "fix.mcap", bodies)
    (tmp_path / "pos.toml").write_text(POSITION_MAP)
    expected = pl.DataFrame({
        "time_s": np.asarray([b["stamp"]["sec"] + b["stamp"]["nanosec"] * 1e-9 for b in bodies]),
        "x_m": np.asarray([b["pose"]["position"]["x"] for b in bodies]) * 0.3048})
    got = read_foreign_mcap(src, load_mapping(tmp_path / "pos.toml")).tables["measurements"]
    assert got.equals(expected)

    res = invoke("convert", "mcap", src, "--map", "pos.toml", "-o", "ours.mcap")
    assert res.exit_code == 0, res.output
    same_dataset(tmp_path / "ours.mcap", via_table("colored", expected, src, tmp_path / "table.mcap"))
    res = invoke(src, "--map", "pos.toml", "--no-rrd", "--trackers", "kf", "--set", "measurement_variance_m2=100")
    assert res.exit_code == 0, res.output


def test_json_log_time_and_items_in_a_batch_larger_than_one_decode(tmp_path, monkeypatch):
    """Peaks from JSON with the log time as the time source, over more messages than one bulk
    decode takes (several batches), out of log-time order in the file."""
    import trackreplay.recorders.foreign_decoding as fm

    monkeypatch.setattr(fm, "BATCH", 7)
    rng = np.random.default_rng(4)
    bodies = [{"peaks": [{"az_mrad": float(v), "amp": float(a)} for v, a in
                         zip(rng.uniform(-1500, 1500, n), rng.uniform(0, 5, n))]}
              for n in rng.integers(0, 4, 30)]
    log_times = [10**9 * (k + 1) for k in range(30)]
    order = [*range(15, 30), *range(15)]  # the second half of the recording first in the file
    src = write_json(tmp_path / "peaks.mcap", [bodies[i] for i in order], topic="/peaks",
                     log_times=[log_times[i] for i in order])
    (tmp_path / "peaks.toml").write_text('family = "xcorr"\n[measurements]\ntopic = "/peaks"\n'
                                         'time = "log_time"\nitems = "peaks"\n'
                                         'bearing_rad = { field = "az_mrad", unit = "mrad" }\namplitude = "amp"\n')
    got = read_foreign_mcap(src, load_mapping(tmp_path / "peaks.toml")).tables["measurements"]
    t = np.repeat(np.asarray(log_times, np.int64) * 1e-9, [len(b["peaks"]) for b in bodies])
    bearing = np.asarray([p["az_mrad"] for b in bodies for p in b["peaks"]]) * 1e-3
    amp = np.asarray([p["amp"] for b in bodies for p in b["peaks"]])
    assert got.equals(pl.DataFrame({"time_s": t, "bearing_rad": bearing, "amplitude": amp}))


def _protobuf_peaks_class():
    from google.protobuf import descriptor_pb2, descriptor_pool
    from google.protobuf.message_factory import GetMessageClass

    fd = descriptor_pb2.FileDescriptorProto(name="test_peaks.proto", package="testpeaks", syntax="proto3")
    stamp = fd.message_type.add(name="Stamp")
    stamp.field.add(name="seconds", number=1, type=3, label=1)  # int64
    stamp.field.add(name="nanos", number=2, type=5, label=1)  # int32
    peak = fd.message_type.add(name="Peak")
    peak.field.add(name="bearing_deg", number=1, type=1, label=1)  # double
    peak.field.add(name="amplitude", number=2, type=1, label=1)
    peaks = fd.message_type.add(name="Peaks")
    peaks.field.add(name="stamp", number=1, type=11, label=1, type_name=".testpeaks.Stamp")
    peaks.field.add(name="peaks", number=2, type=11, label=3, type_name=".testpeaks.Peak")
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    return GetMessageClass(pool.FindMessageTypeByName("testpeaks.Peaks"))


def test_protobuf_mcap_converts_to_the_table_rows_exactly(tmp_path, monkeypatch):
    from mcap_protobuf.writer import Writer

    monkeypatch.chdir(tmp_path)
    Peaks = _protobuf_peaks_class()
    rng = np.random.default_rng(5)
    rows = []
    with open(tmp_path / "pb.mcap", "wb") as f:
        w = Writer(f)
        for k in range(12):
            msg = Peaks()
            msg.stamp.seconds, msg.stamp.nanos = 50 + k, 500_000_000
            for _ in range(int(rng.integers(1, 4))):
                b, a = float(rng.uniform(75, 105)), float(rng.uniform(0.5, 3))  # inside the sensor field
                p = msg.peaks.add()
                p.bearing_deg, p.amplitude = b, a
                rows.append((50 + k + 500_000_000 * 1e-9, b, a))
            w.write_message("/xcorr/out", msg, log_time=10**9 * (k + 1), publish_time=10**9 * (k + 1))
        w.finish()
    (tmp_path / "pb.toml").write_text('family = "xcorr"\n[measurements]\ntopic = "/xcorr/out"\n'
                                      'time = "stamp"\nitems = "peaks"\n'
                                      'bearing_rad = { field = "bearing_deg", unit = "deg" }\namplitude = "amplitude"\n')
    t, b, a = (np.asarray(c) for c in zip(*rows))
    expected = pl.DataFrame({"time_s": t, "bearing_rad": b * (math.pi / 180.0), "amplitude": a})
    assert read_foreign_mcap(tmp_path / "pb.mcap", load_mapping(tmp_path / "pb.toml")).tables["measurements"].equals(expected)
    res = invoke("convert", "mcap", "pb.mcap", "--map", "pb.toml", "-o", "ours.mcap")
    assert res.exit_code == 0, res.output
    same_dataset(tmp_path / "ours.mcap", via_table("xcorr", expected, tmp_path / "pb.mcap", tmp_path / "t.mcap"))


TDOA_MAP = """family = "tdoa-fdoa"
[measurements]
topic = "/epoch"
time = "t"
items = "pairs"
run = "/run"
sensor_a = "a"
sensor_b = "b"
tdoa_s = { field = "tdoa_us", unit = "us" }
fdoa_hz = "fdoa"
sigma_tdoa_s = "sigma_tdoa"
sigma_fdoa_hz = "sigma_fdoa"
carrier_hz = "/carrier"

[sensors]
topic = "/epoch"
time = "t"
items = "sensors"
run = "/run"
sensor = "index"
x_m = "position[0]"
y_m = "position[1]"
vx_mps = "velocity[0]"
vy_mps = "velocity[1]"
"""


def test_two_tables_from_one_topic_with_message_level_fields(tmp_path, monkeypatch):
    """TDOA/FDOA epochs as JSON: the pairs and the sensors of an epoch in one message, read into
    the measurements and the sensors table; the carrier and the run from the message."""
    from trackreplay.recorders import simulator_for
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.tables import tables_from_dataset

    monkeypatch.chdir(tmp_path)
    sc = load_scenario("tdoa-fdoa")
    write_simulated(tmp_path / "sim.mcap", simulator_for(sc.recorder)(sc.params, 2, 3),
                    scenario_metadata(sc.name, sc.params, 3))
    tabs = tables_from_dataset(read_dataset(tmp_path / "sim.mcap"), "tdoa-fdoa")
    m = tabs["measurements"].select("run", "time_s", "sensor_a", "sensor_b", "tdoa_s", "fdoa_hz", "sigma_tdoa_s",
                                    "sigma_fdoa_hz", "carrier_hz")
    s = tabs["sensors"]
    bodies = []
    for (run, t), group in m.group_by(["run", "time_s"], maintain_order=True):
        sens = s.filter((pl.col("run") == run) & (pl.col("time_s") == t))
        bodies.append({"run": run, "t": t, "carrier": group["carrier_hz"][0],
                       "pairs": [{"a": r["sensor_a"], "b": r["sensor_b"], "tdoa_us": r["tdoa_s"] * 1e6,
                                  "fdoa": r["fdoa_hz"], "sigma_tdoa": r["sigma_tdoa_s"], "sigma_fdoa": r["sigma_fdoa_hz"]}
                                 for r in group.iter_rows(named=True)],
                       "sensors": [{"index": r["sensor"], "position": [r["x_m"], r["y_m"]],
                                    "velocity": [r["vx_mps"], r["vy_mps"]]} for r in sens.iter_rows(named=True)]})
    src = write_json(tmp_path / "epochs.mcap", bodies, topic="/epoch")
    (tmp_path / "tdoa.toml").write_text(TDOA_MAP)
    got = read_foreign_mcap(src, load_mapping(tmp_path / "tdoa.toml")).tables
    # what the JSON holds, in SI: the microseconds written above, converted back
    expected_m = pl.DataFrame({"run": np.asarray([b["run"] for b in bodies for _ in b["pairs"]], np.int64),
                               "time_s": np.asarray([b["t"] for b in bodies for _ in b["pairs"]])}).with_columns(
        sensor_a=pl.Series([p["a"] for b in bodies for p in b["pairs"]], dtype=pl.Int64),
        sensor_b=pl.Series([p["b"] for b in bodies for p in b["pairs"]], dtype=pl.Int64),
        tdoa_s=pl.Series(np.asarray([p["tdoa_us"] for b in bodies for p in b["pairs"]]) * 1e-6),
        fdoa_hz=pl.Series([p["fdoa"] for b in bodies for p in b["pairs"]]),
        sigma_tdoa_s=pl.Series([p["sigma_tdoa"] for b in bodies for p in b["pairs"]]),
        sigma_fdoa_hz=pl.Series([p["sigma_fdoa"] for b in bodies for p in b["pairs"]]),
        carrier_hz=pl.Series([b["carrier"] for b in bodies for _ in b["pairs"]]))
    assert got["measurements"].equals(expected_m)
    assert got["sensors"].equals(s.select(got["sensors"].columns).cast({"sensor": pl.Int64, "run": pl.Int64}))
    res = invoke("convert", "mcap", src, "--map", "tdoa.toml", "-o", "ours.mcap")
    assert res.exit_code == 0, res.output
    same_dataset(tmp_path / "ours.mcap", via_table("tdoa-fdoa", expected_m, src, tmp_path / "t.mcap", sensors=s))


# --------------------------------------------------------------------------- the bundled samples


@pytest.mark.parametrize("sample, mapping, trackers", [("ros2_radar.mcap", "ros2_radar_map.toml", "kalman"),
                                                       ("json_positions.mcap", "json_positions_map.toml", "kf")])
def test_samples_convert_the_same_every_time_and_replay(tmp_path, monkeypatch, sample, mapping, trackers):
    monkeypatch.chdir(tmp_path)
    for out in ("a.mcap", "b.mcap"):
        res = invoke("convert", "mcap", SAMPLES / sample, "--map", SAMPLES / mapping, "-o", out)
        assert res.exit_code == 0, res.output
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()
    res = invoke(SAMPLES / sample, "--map", SAMPLES / mapping, "--no-rrd", "--trackers", trackers)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "replay-out" / Path(sample).stem / "tracks.mcap").exists()


def test_sample_script_writes_the_bundled_bytes(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_foreign_samples", REPO / "scripts" / "make_foreign_samples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.write_ros2_radar(tmp_path / "r.mcap")
    mod.write_json_positions(tmp_path / "j.mcap")
    assert (tmp_path / "r.mcap").read_bytes() == (SAMPLES / "ros2_radar.mcap").read_bytes()
    assert (tmp_path / "j.mcap").read_bytes() == (SAMPLES / "json_positions.mcap").read_bytes()


# --------------------------------------------------------------------------- bad input


def _json_case(tmp_path, bodies, mapping=POSITION_MAP, **kw):
    write_json(tmp_path / "in.mcap", bodies, **kw)
    (tmp_path / "map.toml").write_text(mapping)
    return "in.mcap"


def _ros2_case(tmp_path, mapping=RADAR_MAP, **kw):
    write_ros2(tmp_path / "in.mcap", radar_scans(runs=1, scans=4), **kw)
    (tmp_path / "map.toml").write_text(mapping)
    return "in.mcap"


def _stamped(xs, secs):
    return [{"stamp": {"sec": s, "nanosec": 0}, "pose": {"position": {"x": x}}} for x, s in zip(xs, secs)]


BAD = {
    # case: (builder, file the line names, fragments of the line)
    "unknown topic": (lambda p: _ros2_case(p, RADAR_MAP.replace('"/radar/scan"', '"/radar/scans"')),
                      "in.mcap", ["'/radar/scans' is not in the file", "/radar/scan"]),
    "unknown field": (lambda p: _ros2_case(p, RADAR_MAP.replace('"range"', '"rnage"')),
                      "in.mcap", ["no field 'rnage' in item 0 of returns", "range, azimuth, label"]),
    "unknown message field": (lambda p: _ros2_case(p, RADAR_MAP.replace('"/run"', '"/header.seq"')),
                              "in.mcap", ["no field 'seq' in header"]),
    "index beyond a list": (lambda p: _ros2_case(p, RADAR_MAP.replace('items = "returns"\n', "").replace(
                                '"range"', '"returns[5].range"').replace('"azimuth"', '"returns[0].azimuth"')),
                            "in.mcap", ["index 5 is beyond the list returns"]),
    "items not a list": (lambda p: _ros2_case(p, RADAR_MAP.replace('items = "returns"', 'items = "header"')),
                         "in.mcap", ["items 'header' is a message, not a list"]),
    "text in a number field (ros2 string)": (lambda p: _ros2_case(p, RADAR_MAP.replace('"range"', '"label"')),
                                             "in.mcap", ["range_m holds 'ok' where a number belongs"]),
    "text in a number field (json)": (lambda p: _json_case(p, _stamped([1.0, "12.5", 3.0], [1, 2, 3])),
                                      "in.mcap", ["message 1", "x_m holds '12.5' where a number belongs"]),
    "boolean in a number field": (lambda p: _json_case(p, _stamped([1.0, True, 3.0], [1, 2, 3])),
                                  "in.mcap", ["x_m holds a boolean where a number belongs"]),
    "null in a number field": (lambda p: _json_case(p, _stamped([1.0, None, 3.0], [1, 2, 3])),
                               "in.mcap", ["message 1", "where a number belongs"]),
    "NaN": (lambda p: _json_case(p, [json.loads(f'{{"stamp": {{"sec": {k}, "nanosec": 0}}, "pose": {{"position": '
                                                f'{{"x": {"NaN" if k == 3 else k}}}}}}}') for k in range(1, 7)]),
            "in.mcap", ["x_m", "NaN", "topic /fix, message 2"]),
    "unsorted times": (lambda p: _json_case(p, _stamped([1.0, 2.0, 3.0, 4.0], [1, 3, 2, 4])),
                       "in.mcap", ["message 2", "earlier than the time of message 1"]),
    "duplicated times": (lambda p: _json_case(p, _stamped([1.0, 2.0, 3.0], [1, 2, 2])),
                         "in.mcap", ["message 2", "the same as the time of message 1"]),
    "time not a stamp": (lambda p: _json_case(p, _stamped([1.0, 2.0], [1, 2]), POSITION_MAP.replace(
                             'time = "stamp"', 'time = "pose"')),
                         "in.mcap", ["time 'pose' is a message, neither a number nor a stamp"]),
    "invalid JSON message": (lambda p: _json_case(p, [*_stamped([1.0], [1]), b"{not json"]),
                             "in.mcap", ["message 1: not valid JSON"]),
    "unsupported encoding": (lambda p: _json_case(p, _stamped([1.0], [1]), encoding="ros1"),
                             "in.mcap", ["message encoding 'ros1'", "not supported"]),
    "unknown unit": (lambda p: _ros2_case(p, RADAR_MAP.replace('unit = "km"', 'unit = "furlong"')),
                     "map.toml", ["unit 'furlong' is not known", "nmi"]),
    "unit of another kind": (lambda p: _ros2_case(p, RADAR_MAP.replace('unit = "km"', 'unit = "deg"')),
                             "map.toml", ["unit 'deg' measures angle", "range_m is a length"]),
    "column not of the family": (lambda p: _ros2_case(p, RADAR_MAP.replace("range_m =", "rng_m =")),
                                 "map.toml", ["'rng_m' is not a column of the radar measurements table"]),
    "mapping without family": (lambda p: _ros2_case(p, RADAR_MAP.replace('family = "radar"\n', "")),
                               "map.toml", ["missing key 'family'"]),
    "mapping without topic": (lambda p: _ros2_case(p, RADAR_MAP.replace('topic = "/radar/scan"\n', "")),
                              "map.toml", ["missing key 'topic'"]),
    "mapping without time": (lambda p: _ros2_case(p, RADAR_MAP.replace('time = "header.stamp"\n', "")),
                             "map.toml", ["missing key 'time'"]),
    "mapping without measurements": (lambda p: _ros2_case(p, 'family = "radar"\n'),
                                     "map.toml", ["missing table [measurements]"]),
    "mapping with an unknown key": (lambda p: _ros2_case(p, RADAR_MAP + "[extra]\nx = 1\n"),
                                    "map.toml", ["unknown key 'extra'"]),
    "mapping not TOML": (lambda p: _ros2_case(p, "family = radar\n[[[\n"), "map.toml", ["not a TOML mapping file"]),
    "bad field path": (lambda p: _ros2_case(p, RADAR_MAP.replace('"range"', '"returns..range"')),
                       "map.toml", ["is not a field path"]),
    "mapping missing": (lambda p: (_ros2_case(p), (p / "map.toml").unlink())[0], "map.toml", ["no such file"]),
    "foreign file not MCAP": (lambda p: ((p / "in.mcap").write_text("time,range\n0,1\n"),
                                         (p / "map.toml").write_text(RADAR_MAP))[0] or "in.mcap",
                              "in.mcap", ["not an MCAP file"]),
    "foreign file missing": (lambda p: (p / "map.toml").write_text(RADAR_MAP) and "in.mcap", "in.mcap",
                             ["no such file"]),
}


# every case through `replay convert mcap`; a few through `replay FILE --map` (the same converter)
BAD_RUNS = [(case, "convert") for case in BAD] + [
    (case, "replay") for case in ("unknown field", "NaN", "duplicated times", "mapping not TOML", "foreign file not MCAP")]


@pytest.mark.parametrize("case, how", BAD_RUNS, ids=[f"{how}: {case}" for case, how in BAD_RUNS])
def test_bad_input_is_one_line_and_exit_2(tmp_path, monkeypatch, case, how):
    monkeypatch.chdir(tmp_path)
    build, named, fragments = BAD[case]
    build(tmp_path)
    assert_mapped_recording_refused(tmp_path, how, case, named, fragments)


def test_map_refuses_to_write_over_its_inputs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _ros2_case(tmp_path)
    for out in ("in.mcap", "map.toml"):
        res = invoke("convert", "mcap", "in.mcap", "--map", "map.toml", "-o", out)
        assert res.exit_code == 2 and "refusing to write an output over the input" in res.stderr, res.output
    res = invoke("convert", "mcap", "in.mcap", "--map", "map.toml", "-o", "o.mcap")
    assert res.exit_code == 0
    res = invoke("convert", "mcap", "in.mcap", "--map", "map.toml", "-o", "o.mcap")
    assert res.exit_code == 2 and "--force" in res.stderr
    assert invoke("convert", "mcap", "in.mcap", "--map", "map.toml", "-o", "o.mcap", "--force").exit_code == 0
