"""Write the sample recordings of *many targets* "made by other tools" in ``data/samples/``.

Both hold a radar scene of several targets (born and dying during the recording, with
identities that are not 0, 1, 2, …), plots with missed detections and clutter (plots of no
known target), some scans in which the radar saw nothing (an empty list of returns), and a
truth list per scan (each target's identity, position and velocity):

* ``ros2_radar_many.mcap``: a ROS 2 recording (CDR, ``ros2msg`` schemas), one run. The plots
  on ``/radar/scan`` (``demo_radar_msgs/msg/RadarScan``, as in ``ros2_radar.mcap``: range in
  metres, azimuth in degrees) and the truth on its own topic ``/radar/truth``
  (``demo_radar_msgs/msg/TargetArray``: a list of targets with ``id``, ``x``, ``y`` in metres,
  ``vx``, ``vy`` in m/s), both stamped with the scan's time. Mapping:
  ``ros2_radar_many_map.toml``.
* ``json_radar_many.mcap``: a JSON recording (``jsonschema``) of two Monte Carlo runs, one
  message per run and scan holding both the plots (range in km, azimuth in degrees) and the
  truth list (position in km, velocity in km/h), the time in milliseconds. Mapping:
  ``json_radar_many_map.toml``.

The scene follows the design values of the bundled ``radar-tws`` scenario (a scan every 5 s,
σ_range = 100 m, σ_bearing = 1°); the detection probability (0.85) and the clutter (1.5 plots
a scan over 1–50 km, ±60°) are given at replay time with ``--set detection_probability=0.85
--set clutter_per_scan=1.5``.

Run from the repository root: ``python scripts/make_foreign_many_samples.py``. The bytes are
the same on every run (fixed seeds, fixed log times, no wall clock) with the same versions of
numpy and the mcap packages.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def _single_target_samples():
    """The generator of the single-target samples beside this file: the RadarScan message
    definition and the recordings' first stamp are shared, not written twice."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_foreign_samples", Path(__file__).with_name(
        "make_foreign_samples.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_BASE = _single_target_samples()
RADAR_SCAN_MSGDEF = _BASE.RADAR_SCAN_MSGDEF
EPOCH_S = _BASE.EPOCH_S  # the recordings' first stamp (a fixed instant, not the wall clock)

SCAN_TOPIC = "/radar/scan"
TRUTH_TOPIC = "/radar/truth"
JSON_TOPIC = "/radar/frame"
PERIOD_S = 5.0
SIGMA_RANGE_M, SIGMA_BEARING_DEG = 100.0, 1.0
DETECTION_PROBABILITY = 0.85
CLUTTER_PER_SCAN = 1.5  # uniform over 1–50 km and ±60° (the multi-target trackers' default region)

# identity, first scan, last scan (inclusive), x0 (m), y0 (m), vx (m/s), vy (m/s): a target is
# alive from its first to its last scan; positions are those at scan 0
TARGETS = (
    (3, 0, 99, 12000.0, 6000.0, -40.0, 10.0),
    (7, 0, 17, 20000.0, -8000.0, 0.0, 60.0),
    (12, 5, 99, 8000.0, -12000.0, 50.0, 45.0),
    (21, 9, 99, 30000.0, 10000.0, -80.0, -20.0),
    (40, 12, 22, 15000.0, 20000.0, 30.0, -70.0),
)

TARGET_ARRAY_MSGDEF = """std_msgs/Header header
Target[] targets
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: demo_radar_msgs/Target
uint32 id
float64 x
float64 y
float64 vx
float64 vy
"""

FRAME_SCHEMA = {
    "title": "demo.RadarFrame",
    "type": "object",
    "properties": {
        "t_ms": {"type": "integer", "description": "milliseconds since the start of the run"},
        "run": {"type": "integer", "description": "Monte Carlo run"},
        "plots": {"type": "array", "items": {"type": "object", "properties": {
            "r_km": {"type": "number"}, "az_deg": {"type": "number"}}}},
        "truth": {"type": "array", "items": {"type": "object", "properties": {
            "id": {"type": "integer"},
            "pos": {"type": "object", "properties": {"x_km": {"type": "number"}, "y_km": {"type": "number"}}},
            "vel": {"type": "object", "properties": {"x_kmh": {"type": "number"}, "y_kmh": {"type": "number"}}}}}},
    },
}


def scene(seed: int, n_scans: int, blind: tuple):
    """Per scan: (time s, [(range m, azimuth deg, amplitude, origin identity or -1)], [(id, x, y,
    vx, vy)]). In the scans of ``blind`` the radar sees nothing (no plot, no clutter)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_scans):
        t = k * PERIOD_S
        truth, plots = [], []
        for ident, first, last, x0, y0, vx, vy in TARGETS:
            if not first <= k <= last:
                continue
            x, y = x0 + vx * t, y0 + vy * t
            truth.append((ident, x, y, vx, vy))
            if rng.uniform() < DETECTION_PROBABILITY:
                plots.append((math.hypot(x, y) + rng.normal(0.0, SIGMA_RANGE_M),
                              math.degrees(math.atan2(y, x)) + rng.normal(0.0, SIGMA_BEARING_DEG),
                              float(rng.uniform(20.0, 30.0)), ident))
        for _ in range(int(rng.poisson(CLUTTER_PER_SCAN))):
            plots.append((float(rng.uniform(1000.0, 50000.0)), float(rng.uniform(-60.0, 60.0)),
                          float(rng.uniform(5.0, 15.0)), -1))
        if k in blind:
            plots = []
        plots.sort(key=lambda p: -p[2])  # listed by amplitude, strongest first
        out.append((t, plots, truth))
    return out


def ros2_scene():
    return scene(seed=21, n_scans=30, blind=(6, 15))


def json_scene():
    """Two runs of the same targets (their own noise, clutter and misses)."""
    return [scene(seed=31 + r, n_scans=24, blind=((4, 11) if r == 0 else (11, 19))) for r in range(2)]


def _stamp(t: float) -> dict:
    ns = EPOCH_S * 10**9 + int(round(t * 1e9))
    return {"sec": ns // 10**9, "nanosec": ns % 10**9}


def write_ros2_radar_many(path: Path) -> int:
    """The ROS 2 sample; returns the messages written."""
    from mcap_ros2.writer import Writer

    scans = ros2_scene()
    with open(path, "wb") as f:
        writer = Writer(f)
        scan_schema = writer.register_msgdef("demo_radar_msgs/msg/RadarScan", RADAR_SCAN_MSGDEF)
        truth_schema = writer.register_msgdef("demo_radar_msgs/msg/TargetArray", TARGET_ARRAY_MSGDEF)
        for t, plots, truth in scans:
            stamp = _stamp(t)
            stamp_ns = stamp["sec"] * 10**9 + stamp["nanosec"]
            header = {"stamp": stamp, "frame_id": "radar"}
            scan = {"header": header, "returns": [{"range": r, "azimuth": a, "elevation": 0.0, "doppler_velocity": 0.0,
                                                   "amplitude": p} for r, a, p, _ in plots]}
            targets = {"header": header, "targets": [{"id": i, "x": x, "y": y, "vx": vx, "vy": vy}
                                                     for i, x, y, vx, vy in truth]}
            # logged after the stamp, as a bag recorder would; the truth a little later
            writer.write_message(SCAN_TOPIC, scan_schema, scan, log_time=stamp_ns + 40_000_000, publish_time=stamp_ns)
            writer.write_message(TRUTH_TOPIC, truth_schema, targets, log_time=stamp_ns + 45_000_000,
                                 publish_time=stamp_ns)
        writer.finish()
    return 2 * len(scans)


def json_frame(run: int, t: float, plots, truth) -> dict:
    """One JSON message: kilometres, degrees and km/h, as written in the file."""
    return {"t_ms": int(round(t * 1000)), "run": run,
            "plots": [{"r_km": round(r / 1000.0, 4), "az_deg": round(a, 3)} for r, a, _, _ in plots],
            "truth": [{"id": i, "pos": {"x_km": round(x / 1000.0, 4), "y_km": round(y / 1000.0, 4)},
                       "vel": {"x_kmh": round(vx * 3.6, 2), "y_kmh": round(vy * 3.6, 2)}}
                      for i, x, y, vx, vy in truth]}


def json_bodies() -> list:
    """Every message in log-time order: scan by scan, the runs of one scan in turn."""
    runs = json_scene()
    return [json_frame(r, *runs[r][k]) for k in range(len(runs[0])) for r in range(len(runs))]


def write_json_radar_many(path: Path) -> int:
    """The JSON sample; returns the messages written."""
    return _BASE.write_json_mcap(
        path, "demo.RadarFrame", FRAME_SCHEMA, JSON_TOPIC,
        ((EPOCH_S * 10**9 + body["t_ms"] * 10**6 + body["run"] * 1000 + 20_000_000, body) for body in json_bodies()))


def main() -> int:
    return _BASE.write_samples(__doc__.split("\n")[0], (("ros2_radar_many.mcap", write_ros2_radar_many),
                                                        ("json_radar_many.mcap", write_json_radar_many)))


if __name__ == "__main__":
    raise SystemExit(main())
