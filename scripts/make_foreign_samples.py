"""Write the sample recordings "made by other tools" in ``data/samples/``.

* ``ros2_radar.mcap``: a ROS 2 recording (CDR, ``ros2msg`` schema) of a made-up but plausible
  radar message, ``demo_radar_msgs/msg/RadarScan``: a ``std_msgs/Header`` and a list of
  returns with range in metres and azimuth in degrees. One scan every 5 s for 64 scans: the
  target of the bundled ``radar-tws`` scenario plus a few clutter returns. Mapping:
  ``ros2_radar_map.toml``.
* ``json_positions.mcap``: a JSON recording (``jsonschema``) of a position sensor, one message
  every 50 ms with the time in milliseconds and the position in feet: the manoeuvring target
  of the ``colored-imm`` scenario with AR(1) coloured noise. Mapping: ``json_positions_map.toml``.

Run from the repository root: ``python scripts/make_foreign_samples.py``. The bytes are the
same on every run (fixed seeds, fixed log times, no wall clock) with the same versions of
numpy and the mcap packages.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

RADAR_TOPIC = "/radar/scan"
POSITION_TOPIC = "/tracker/position"
EPOCH_S = 1_700_000_000  # the recordings' first stamp (a fixed instant, not the wall clock)

RADAR_SCAN_MSGDEF = """std_msgs/Header header
RadarReturn[] returns
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: demo_radar_msgs/RadarReturn
float64 range
float64 azimuth
float64 elevation
float64 doppler_velocity
float64 amplitude
"""

POSITION_SCHEMA = {
    "title": "demo.PositionFix",
    "type": "object",
    "properties": {
        "t_ms": {"type": "integer", "description": "milliseconds since the start of the recording"},
        "sensor": {"type": "string"},
        "position": {"type": "object", "properties": {"x": {"type": "number", "description": "feet"}}},
    },
}


def radar_scans(seed: int = 11, n_scans: int = 64, period_s: float = 5.0):
    """(stamp in ns, [(range m, azimuth deg, elevation deg, doppler m/s, amplitude)]) per scan."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_scans) * period_s
    x, y = -5500.0 + 15.0 * t, 9500.0 - 12.0 * t          # the radar-tws target, m
    rng_m = np.hypot(x, y) + rng.normal(0.0, 100.0, n_scans)
    az_deg = np.degrees(np.arctan2(y, x)) + rng.normal(0.0, 1.0, n_scans)
    doppler = (x * 15.0 + y * -12.0) / np.hypot(x, y)
    scans = []
    for k in range(n_scans):
        returns = [(float(rng_m[k]), float(az_deg[k]), 0.0, float(doppler[k]), float(rng.uniform(20.0, 30.0)))]
        for _ in range(int(rng.poisson(1.0))):  # clutter, far from the target's plot on average
            returns.append((float(rng.uniform(2000.0, 20000.0)), float(rng.uniform(0.0, 180.0)), 0.0,
                            float(rng.normal(0.0, 1.0)), float(rng.uniform(5.0, 15.0))))
        returns.sort(key=lambda ret: -ret[4])  # listed by amplitude, strongest first, as many radars do
        scans.append((EPOCH_S * 10**9 + int(round(t[k] * 1e9)), returns))
    return scans


def write_ros2_radar(path: Path) -> int:
    """The ROS 2 sample; returns the messages written."""
    from mcap_ros2.writer import Writer

    scans = radar_scans()
    with open(path, "wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef("demo_radar_msgs/msg/RadarScan", RADAR_SCAN_MSGDEF)
        for stamp_ns, returns in scans:
            msg = {"header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": "radar"},
                   "returns": [{"range": r, "azimuth": a, "elevation": e, "doppler_velocity": d, "amplitude": p}
                               for r, a, e, d, p in returns]}
            # logged 40 ms after the stamp, as a bag recorder would
            writer.write_message(RADAR_TOPIC, schema, msg, log_time=stamp_ns + 40_000_000, publish_time=stamp_ns)
        writer.finish()
    return len(scans)


def positions(seed: int = 12, n: int = 400, period_s: float = 0.05):
    """(t in ms, x in ft) of a 1-D target that accelerates for 5 s, seen with AR(1) noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * period_s
    accel = np.where((t >= 5.0) & (t < 10.0), 20.0, 0.0)
    v = 150.0 + np.concatenate([[0.0], np.cumsum(accel[:-1]) * period_s])
    x = 1000.0 + np.concatenate([[0.0], np.cumsum(v[:-1]) * period_s])
    noise = np.empty(n)
    noise[0] = rng.normal(0.0, 10.0)
    alpha = math.exp(-period_s / 0.25)
    for k in range(1, n):
        noise[k] = alpha * noise[k - 1] + rng.normal(0.0, 10.0 * math.sqrt(1 - alpha**2))
    return [(int(round(tk * 1000)), float(round((xk + nk) / 0.3048, 3))) for tk, xk, nk in zip(t, x, noise)]


def write_json_mcap(path: Path, schema_name: str, schema: dict, topic: str, messages) -> int:
    """A JSON MCAP of one channel: ``messages`` are ``(log time in ns, body)`` in order (the
    sequence numbers count them); returns how many were written."""
    from mcap.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="trackreplay sample")
        channel = writer.register_channel(topic, "json", writer.register_schema(
            schema_name, "jsonschema", json.dumps(schema, sort_keys=True).encode()))
        count = 0
        for seq, (log_time, body) in enumerate(messages):
            writer.add_message(channel, log_time=log_time, publish_time=log_time, sequence=seq,
                               data=json.dumps(body, sort_keys=True).encode())
            count += 1
        writer.finish()
    return count


def write_json_positions(path: Path) -> int:
    """The JSON sample; returns the messages written."""
    return write_json_mcap(path, "demo.PositionFix", POSITION_SCHEMA, POSITION_TOPIC,
                           ((EPOCH_S * 10**9 + t_ms * 10**6, {"t_ms": t_ms, "sensor": "fix-1", "position": {"x": x_ft}})
                            for t_ms, x_ft in positions()))


def write_samples(description: str, writers) -> int:
    """The command line of a sample generator: ``--out FOLDER`` (default data/samples), then each
    ``(file name, writer)`` of ``writers`` writes its file there and says how many messages."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "data" / "samples",
                    help="folder to write into (default: data/samples)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name, write in writers:
        n = write(args.out / name)
        print(f"wrote {args.out / name}: {n} messages")
    return 0


def main() -> int:
    return write_samples(__doc__.split("\n")[0], (("ros2_radar.mcap", write_ros2_radar),
                                                  ("json_positions.mcap", write_json_positions)))


if __name__ == "__main__":
    raise SystemExit(main())
