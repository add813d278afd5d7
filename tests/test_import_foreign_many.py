"""Recordings of many targets made by other tools: a foreign MCAP whose mapping names a truth
list ([truth]: several targets per message, each with an identity), and plots messages whose
list of returns is empty (a scan without plots, which keeps its truth).

The bundled samples (``scripts/make_foreign_many_samples.py``) are converted and replayed
through the CLI, and their truth set is compared, target by target and scan by scan, with what
the generator wrote. Every bad input is one line and exit 2, with nothing written.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from trackreplay.contract import read_dataset
from trackreplay.face.cli import main
from conftest import assert_mapped_recording_refused
from trackreplay.stages import stage_named
from trackreplay.recorders.foreign_mcap import UNITS

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "data" / "samples"
DESIGN = ("--set", "detection_probability=0.85", "--set", "clutter_per_scan=1.5")
MULTI = ("gnn", "jpda_mt")  # the multi-target trackers a replay runs by default (ukf when named)


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def generator():
    spec = importlib.util.spec_from_file_location("make_foreign_many_samples",
                                                  REPO / "scripts" / "make_foreign_many_samples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


GEN = generator()


def factor(unit: str) -> float:
    return UNITS[unit][1]  # to the SI unit of the truth columns (m, m/s): the converter's factor


def expected_ros2():
    """Per run and scan: (plots [(range m, bearing rad)], {id: state}) as the ROS 2 sample holds them."""
    deg = math.pi / 180.0
    return [[([(r, a * deg) for r, a, _, _ in plots], {i: (x, y, vx, vy) for i, x, y, vx, vy in truth})
             for _, plots, truth in GEN.ros2_scene()]]


def expected_json():
    """The same from the JSON sample's bodies: kilometres, degrees and km/h converted to SI."""
    km, kmh, deg = factor("km"), factor("km/h"), factor("deg")
    runs = {}
    for b in GEN.json_bodies():
        runs.setdefault(b["run"], []).append((
            [(p["r_km"] * km, p["az_deg"] * deg) for p in b["plots"]],
            {t["id"]: (t["pos"]["x_km"] * km, t["pos"]["y_km"] * km, t["vel"]["x_kmh"] * kmh, t["vel"]["y_kmh"] * kmh)
             for t in b["truth"]}))
    return [runs[r] for r in sorted(runs)]


SAMPLE_CASES = [("ros2_radar_many.mcap", "ros2_radar_many_map.toml", expected_ros2, (6, 15)),
                ("json_radar_many.mcap", "json_radar_many_map.toml", expected_json, None)]


def truth_by_scan(path: Path):
    """{id: state} per run and scan, from the converted data set (identity-stable slots)."""
    state, ids = stage_named("radar").decode_truth(read_dataset(path))
    assert state.shape == ids.shape + (4,)
    return [[{int(i): tuple(s) for i, s in zip(ids[r, k], state[r, k]) if i >= 0} for k in range(ids.shape[1])]
            for r in range(ids.shape[0])]


def check_converted(path: Path, expected) -> None:
    stage = stage_named("radar")
    ds = read_dataset(path)
    assert stage.holds_many_targets(ds)
    rng, brg, counts, _ = stage.decode_plots(ds)
    got = truth_by_scan(path)
    assert counts.shape == (len(expected), len(expected[0]))
    for r, scans in enumerate(expected):
        for k, (plots, truth) in enumerate(scans):
            assert counts[r, k] == len(plots), (r, k)
            assert rng[r, k, :counts[r, k]].tolist() == [p[0] for p in plots], (r, k)
            assert brg[r, k, :counts[r, k]].tolist() == [p[1] for p in plots], (r, k)
            assert got[r][k] == truth, (r, k)  # the same identities, the same states, bit for bit


# --------------------------------------------------------------------------- the samples


@pytest.mark.parametrize("sample, mapping, expected, blind", SAMPLE_CASES, ids=["ros2", "json"])
def test_sample_converts_with_its_truth_set(tmp_path, monkeypatch, sample, mapping, expected, blind):
    monkeypatch.chdir(tmp_path)
    res = invoke("convert", "mcap", SAMPLES / sample, "--map", SAMPLES / mapping, "-o", "many.mcap")
    assert res.exit_code == 0, res.output
    assert "truth:" in res.output and "with an empty" in res.output and "scans without plots" in res.output
    exp = expected()
    check_converted(tmp_path / "many.mcap", exp)
    # scans without detections keep their truth; plots of no known target are there too
    empty = [(r, k) for r, scans in enumerate(exp) for k, (plots, _) in enumerate(scans) if not plots]
    assert len(empty) >= 2 and all(exp[r][k][1] for r, k in empty)
    if blind is not None:
        assert [k for _, k in empty] == list(blind)
    counts = stage_named("radar").decode_plots(read_dataset(tmp_path / "many.mcap"))[2]
    assert counts.sum() > sum(len(t) for scans in exp for _, t in scans) * 0.85  # clutter beyond the targets' plots
    ids = {i for scans in exp for _, t in scans for i in t}
    assert ids == {3, 7, 12, 21, 40}
    # converting twice gives the same bytes
    assert invoke("convert", "mcap", SAMPLES / sample, "--map", SAMPLES / mapping, "-o", "again.mcap").exit_code == 0
    assert (tmp_path / "again.mcap").read_bytes() == (tmp_path / "many.mcap").read_bytes()


@pytest.mark.parametrize("sample, mapping", [c[:2] for c in SAMPLE_CASES], ids=["ros2", "json"])
def test_sample_replays_through_the_multi_target_trackers(tmp_path, monkeypatch, sample, mapping):
    monkeypatch.chdir(tmp_path)
    res = invoke(SAMPLES / sample, "--map", SAMPLES / mapping, "--no-rrd", *DESIGN)
    assert res.exit_code == 0, res.output
    for name in MULTI:
        assert name in res.output
    for metric in ("gospa_mean_m", "mota", "idf1", "hota"):
        assert metric in res.output
    out = read_dataset(tmp_path / "replay-out" / Path(sample).stem / "tracks.mcap")
    assert {f"/tracks/radar/{name}" for name in MULTI} <= set(out.channels)


def test_sample_script_writes_the_bundled_bytes(tmp_path):
    GEN.write_ros2_radar_many(tmp_path / "r.mcap")
    GEN.write_json_radar_many(tmp_path / "j.mcap")
    assert (tmp_path / "r.mcap").read_bytes() == (SAMPLES / "ros2_radar_many.mcap").read_bytes()
    assert (tmp_path / "j.mcap").read_bytes() == (SAMPLES / "json_radar_many.mcap").read_bytes()
    for name in ("ros2_radar_many.mcap", "json_radar_many.mcap"):
        assert (SAMPLES / name).stat().st_size < 64_000


# --------------------------------------------------------------------------- small recordings


def write_json_topics(path: Path, messages) -> Path:
    """``messages``: (topic, body, log time ns) in file order; one JSON channel per topic."""
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        schema = w.register_schema("test.Any", "jsonschema", b"{}")
        channels = {}
        for i, (topic, body, lt) in enumerate(messages):
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "json", schema)
            w.add_message(channels[topic], log_time=lt, publish_time=lt, sequence=i, data=json.dumps(body).encode())
        w.finish()
    return path


def frames(n=6, empty=(2,), dup=None, drop_id=None, drop_field=None, id_value=None):
    """JSON frames of plots and a truth list of two targets (ids 5 and 9) in one message."""
    out = []
    for k in range(n):
        truth = [{"id": 5, "x": 10000.0 + 50 * k, "y": 2000.0, "vx": 10.0, "vy": 0.0},
                 {"id": 9, "x": 15000.0, "y": -3000.0 + 40 * k, "vx": 0.0, "vy": 8.0}]
        if k == 3 and dup is not None:
            truth.append(dict(truth[0]))
        if k == 3 and drop_id is not None:
            del truth[1]["id"]
        if k == 4 and drop_field is not None:
            del truth[0][drop_field]
        if k == 1 and id_value is not None:
            truth[1]["id"] = id_value
        plots = [] if k in empty else [{"r": 10200.0 + 50 * k, "az": 11.3}, {"r": 30000.0, "az": -20.0 + k}]
        out.append({"stamp": {"sec": 100 + 5 * k, "nanosec": 0}, "plots": plots, "truth": truth})
    return out


MAP = """family = "radar"
[measurements]
topic = "/scan"
time = "stamp"
items = "plots"
range_m = "r"
bearing_rad = { field = "az", unit = "deg" }
[truth]
topic = "/scan"
time = "stamp"
items = "truth"
truth_id = "id"
truth_x_m = "x"
truth_y_m = "y"
truth_vx_mps = "vx"
truth_vy_mps = "vy"
"""


def one_topic(path: Path, bodies) -> Path:
    return write_json_topics(path, [("/scan", b, 10**9 * (i + 1)) for i, b in enumerate(bodies)])


def test_an_empty_plots_list_is_a_scan_with_or_without_truth(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bodies = frames(empty=(0, 2, 5))
    one_topic(tmp_path / "in.mcap", bodies)
    (tmp_path / "many.toml").write_text(MAP)
    assert invoke("convert", "mcap", "in.mcap", "--map", "many.toml", "-o", "many.mcap").exit_code == 0
    counts = stage_named("radar").decode_plots(read_dataset(tmp_path / "many.mcap"))[2]
    assert counts.tolist() == [[0, 2, 0, 2, 2, 0]]
    got = truth_by_scan(tmp_path / "many.mcap")[0]
    assert [sorted(g) for g in got] == [[5, 9]] * 6
    assert got[2][9] == (15000.0, -3000.0 + 80, 0.0, 8.0)

    # without truth: the empty scans stay scans (before, the message gave no row and the scan vanished)
    (tmp_path / "plots.toml").write_text(MAP.split("[truth]")[0])
    assert invoke("convert", "mcap", "in.mcap", "--map", "plots.toml", "-o", "plots.mcap").exit_code == 0
    ds = read_dataset(tmp_path / "plots.mcap")
    assert stage_named("radar").decode_plots(ds)[2].tolist() == [[0, 2, 0, 2, 2, 0]]
    assert ds.channels.get("/radar/truth") is None

    # one target's truth read from the message ("/…"): the scan without plots keeps it
    single = MAP.split("[truth]")[0] + "".join(f'{c} = "/truth[0].{f}"\n' for c, f in (
        ("truth_x_m", "x"), ("truth_y_m", "y"), ("truth_vx_mps", "vx"), ("truth_vy_mps", "vy")))
    (tmp_path / "single.toml").write_text(single)
    res = invoke("convert", "mcap", "in.mcap", "--map", "single.toml", "-o", "single.mcap")
    assert res.exit_code == 0, res.output
    state, ids = stage_named("radar").decode_truth(read_dataset(tmp_path / "single.mcap"))
    assert state[0, :, 0, 0].tolist() == [10000.0 + 50 * k for k in range(6)]


def test_truth_on_its_own_topic_matches_the_scans_by_time(tmp_path, monkeypatch):
    """Truth stamped in seconds (a float a fraction of a microsecond off the plots' stamp) joins
    its scan; a truth time no plots message has is a scan without plots, and the converter says so."""
    monkeypatch.chdir(tmp_path)
    bodies = frames(n=7, empty=())
    msgs = []
    for k, b in enumerate(bodies):
        if k != 4:  # the radar's message of scan 4 was lost
            msgs.append(("/scan", {"stamp": b["stamp"], "plots": b["plots"]}, 10**9 * (2 * k + 1)))
        t = b["stamp"]["sec"] + 3e-7  # another clock's rounding
        msgs.append(("/truth", {"t": t, "targets": b["truth"]}, 10**9 * (2 * k + 2)))
    write_json_topics(tmp_path / "in.mcap", msgs)
    (tmp_path / "m.toml").write_text(MAP.replace('topic = "/scan"\ntime = "stamp"\nitems = "truth"',
                                                 'topic = "/truth"\ntime = "t"\nitems = "targets"'))
    res = invoke("convert", "mcap", "in.mcap", "--map", "m.toml", "-o", "out.mcap")
    assert res.exit_code == 0, res.output
    assert "1 truth time(s) on /truth match no message on /scan" in res.output
    assert "scan without plots (the first: message 4, time 120.0000003 s)" in res.output
    ds = read_dataset(tmp_path / "out.mcap")
    counts = stage_named("radar").decode_plots(ds)[2]
    assert counts.tolist() == [[2, 2, 2, 2, 0, 2, 2]]  # 7 scans, not 13: the others joined their plots
    assert np.allclose(ds.channel("/radar/plots").times(), 5.0 * np.arange(7), atol=1e-6)
    got = truth_by_scan(tmp_path / "out.mcap")[0]
    assert [sorted(g) for g in got] == [[5, 9]] * 7


# --------------------------------------------------------------------------- bad input


def _case(tmp_path, bodies, mapping=MAP):
    one_topic(tmp_path / "in.mcap", bodies)
    (tmp_path / "map.toml").write_text(mapping)


BAD = {
    # case: (bodies, mapping, file the line names, fragments of the line)
    "a truth item without id": (frames(drop_id=True), MAP, "in.mcap",
                                ["topic /scan, message 3", "no field 'id' in item 1 of truth"]),
    "an id twice in one scan": (frames(dup=True), MAP, "in.mcap",
                                ["topic /scan, message 3", "item 2 of truth names target 5 again (item 0)",
                                 "once a scan"]),
    "a truth field missing in the message": (frames(drop_field="vy"), MAP, "in.mcap",
                                             ["topic /scan, message 4", "no field 'vy' in item 0 of truth"]),
    "a truth field missing in the mapping": (frames(), MAP.replace('truth_vy_mps = "vy"\n', ""), "map.toml",
                                             ["[truth]: missing column(s) truth_vy_mps"]),
    "a truth id that is text": (frames(id_value="nine"), MAP, "in.mcap",
                                ["topic /scan, message 1", "truth_id holds 'nine' where a number belongs"]),
    "a truth id that is not an integer": (frames(id_value=9.5), MAP, "in.mcap",
                                          ["truth_id", "non-integer value 9.5", "topic /scan, message 1"]),
    "a negative truth id": (frames(id_value=-2), MAP, "in.mcap", ["truth_id", "-2", "topic /scan, message 1"]),
    "an unknown truth column": (frames(), MAP.replace('truth_id = "id"', 'truth_id = "id"\nrange_m = "r"'),
                                "map.toml", ["'range_m' is not a column of the radar truth table"]),
    "truth in both tables": (frames(), MAP.replace('bearing_rad = { field = "az", unit = "deg" }',
                                                   'bearing_rad = { field = "az", unit = "deg" }\ntruth_x_m = "/x"'),
                             "map.toml", ["[measurements] truth_x_m", "comes from there alone"]),
    "the run in one table only": (frames(), MAP.replace('items = "plots"', 'items = "plots"\nrun = "/run"'),
                                  "map.toml", ["[measurements] maps run but [truth] does not"]),
    "truth for another family": (frames(), MAP.replace('"radar"', '"xcorr"'), "map.toml",
                                 ["[truth] (a list of targets with identities) belongs to radar mappings"]),
    "a truth topic not in the file": (frames(), MAP.replace('topic = "/scan"\ntime = "stamp"\nitems = "truth"',
                                                            'topic = "/truth"\ntime = "stamp"\nitems = "truth"'),
                                      "in.mcap", ["'/truth' is not in the file"]),
}

BAD_RUNS = [(case, "convert") for case in BAD] + [
    (case, "replay") for case in ("a truth item without id", "an id twice in one scan",
                                  "a truth field missing in the mapping")]


@pytest.mark.parametrize("case, how", BAD_RUNS, ids=[f"{how}: {case}" for case, how in BAD_RUNS])
def test_bad_input_is_one_line_and_exit_2(tmp_path, monkeypatch, case, how):
    monkeypatch.chdir(tmp_path)
    bodies, mapping, named, fragments = BAD[case]
    _case(tmp_path, bodies, mapping)
    assert_mapped_recording_refused(tmp_path, how, case, named, fragments)


def test_a_good_mapping_of_the_same_frames_converts(tmp_path, monkeypatch):
    """The recording the bad cases start from converts: each case breaks one thing only."""
    monkeypatch.chdir(tmp_path)
    _case(tmp_path, frames())
    res = invoke("convert", "mcap", "in.mcap", "--map", "map.toml", "-o", "out.mcap")
    assert res.exit_code == 0, res.output
    got = truth_by_scan(tmp_path / "out.mcap")[0]
    assert [sorted(g) for g in got] == [[5, 9]] * 6


def test_empty_messages_out_of_order_over_several_batches(tmp_path, monkeypatch):
    """Messages out of log-time order in the file, decoded in batches smaller than the file,
    with empty plot lists and the run read from the message: the same data set as in order."""
    import trackreplay.recorders.foreign_decoding as fm

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(fm, "BATCH", 5)
    msgs = []
    for r in range(2):
        for k, b in enumerate(frames(n=8, empty=(1, 4) if r == 0 else (6,))):
            msgs.append(("/scan", {**b, "run": r}, 10**9 * (2 * k + r + 1)))
    mapping = MAP.replace('items = "plots"', 'items = "plots"\nrun = "/run"').replace(
        'items = "truth"', 'items = "truth"\nrun = "/run"')
    (tmp_path / "m.toml").write_text(mapping)
    write_json_topics(tmp_path / "in_order.mcap", msgs)
    write_json_topics(tmp_path / "shuffled.mcap", [msgs[i] for i in np.random.default_rng(1).permutation(len(msgs))])
    for name in ("in_order", "shuffled"):
        res = invoke("convert", "mcap", f"{name}.mcap", "--map", "m.toml", "-o", f"{name}.out.mcap")
        assert res.exit_code == 0, res.output
        assert "3 message(s) on /scan with an empty plots list" in res.output
    a, b = read_dataset(tmp_path / "in_order.out.mcap"), read_dataset(tmp_path / "shuffled.out.mcap")
    stage = stage_named("radar")
    assert stage.decode_plots(a)[2].tolist() == [[2, 0, 2, 2, 0, 2, 2, 2], [2, 2, 2, 2, 2, 2, 0, 2]]
    for x, y in zip(stage.decode_plots(a), stage.decode_plots(b)):
        assert np.array_equal(x, y, equal_nan=True)
    assert truth_by_scan(tmp_path / "in_order.out.mcap") == truth_by_scan(tmp_path / "shuffled.out.mcap")

    # an empty message at the time of the previous one is a duplicated scan, refused as any other
    dup = [m for m in msgs if m[1]["run"] == 0]
    dup[4] = ("/scan", {**dup[4][1], "stamp": dup[3][1]["stamp"]}, dup[4][2])
    write_json_topics(tmp_path / "dup.mcap", dup)
    res = invoke("convert", "mcap", "dup.mcap", "--map", "m.toml", "-o", "dup.out.mcap")
    assert res.exit_code == 2 and "message 4" in res.stderr and "the same as the time of message 3" in res.stderr, \
        res.output
