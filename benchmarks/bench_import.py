"""Import throughput: every importer on an input of about 100 MB, beside the MCAP read paths.

What it measures
----------------
For each importer an input of about ``--size-mb`` MB (default 100) is generated in a temporary
folder (not timed), then the import is timed ``--repeats`` times (default 5): the file in, the
validated arrays of the data set out (:class:`trackreplay.recorders.simulated.SimulatedData`, what is then
written), without writing them.

* **tables** (``trackreplay.recorders.tables``): ``read_table`` + ``dataset_from_table``, for radar plots
  (CSV and Parquet, 100 runs, 20 plots per scan), cross-correlation peaks (CSV, 100 runs, 8
  peaks per scan), positions (CSV, 100 runs, 2 axes) and TDOA/FDOA (CSV measurements and
  sensors tables exported from a simulated data set, 4 sensors). Throughput in rows/s.
* **foreign MCAP** (``trackreplay.recorders.foreign_mcap``): a ROS 2 recording (CDR, the sample's
  ``demo_radar_msgs/msg/RadarScan``, 20 returns per scan, written with ``mcap_ros2.writer``)
  and a JSON recording of the same scans, each through its mapping file onto radar plots:
  decode (``mcap_ros2`` / ``json``), gather the fields, ``dataset_from_table``. Throughput in
  messages/s.

Beside them, the read paths of MCAP itself:

* **mcap iter_messages**: the ``mcap`` package's reader over the same foreign file without
  decoding (the floor of a foreign import), and ``iter_decoded_messages`` with the ROS 2
  decoder (the ecosystem's decode alone, the ceiling of the ROS 2 import);
* **read_dataset**: ``trackreplay.contract.read_dataset`` of a replay data set of about the same
  size (radar-tws simulated with ``replay simulate``), what every replay starts with.

MB/s are of the input file's size on disk. The table gives medians with min–max over the
repeats (``time.perf_counter``).

How to run
----------
From the repository root, with the package installed (``pip install -e .``)::

    python benchmarks/bench_import.py                  # about 100 MB per input, 5 repeats
    python benchmarks/bench_import.py --size-mb 5 --repeats 5   # a quick run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import polars as pl

from timing import print_table, time_repeats, time_spread as fmt

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))

from make_foreign_samples import RADAR_SCAN_MSGDEF  # noqa: E402  (the sample's message type)

RETURNS_PER_SCAN = 20
RADAR_MAP = """family = "radar"
[measurements]
topic = "/radar/scan"
time = "header.stamp"
items = "returns"
range_m = { field = "range", unit = "m" }
bearing_rad = { field = "azimuth", unit = "deg" }
"""


# --------------------------------------------------------------------------- inputs


def _rows_for(size_mb: float, bytes_per_row: float) -> int:
    return max(1000, int(size_mb * 1e6 / bytes_per_row))


def _scan_rows(n_rows: int, entries: int, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``run`` and ``time_s`` of 100 runs × K scans × ``entries`` rows per scan (about ``n_rows``)."""
    runs = 100
    scans = max(3, n_rows // (runs * entries))
    shape = (runs, scans, entries)
    run = np.broadcast_to(np.arange(runs)[:, None, None], shape).ravel()
    t = np.broadcast_to((np.arange(scans) * period_s)[None, :, None], shape).ravel()
    return run, t


def radar_table(n_rows: int, seed: int = 0) -> pl.DataFrame:
    """100 runs × K scans × 20 plots of radar rows."""
    run, t = _scan_rows(n_rows, RETURNS_PER_SCAN, 5.0)
    rng = np.random.default_rng(seed)
    return pl.DataFrame({"run": run, "time_s": t, "range_m": rng.uniform(1e3, 2e4, run.size),
                         "bearing_rad": rng.uniform(-np.pi, np.pi, run.size)})


def peaks_table(n_rows: int, seed: int = 1) -> pl.DataFrame:
    run, t = _scan_rows(n_rows, 8, 0.1)
    rng = np.random.default_rng(seed)
    return pl.DataFrame({"run": run, "time_s": t, "bearing_rad": rng.uniform(1.3, 1.8, run.size),
                         "amplitude": rng.uniform(0, 5, run.size)})


def positions_table(n_rows: int, seed: int = 2) -> pl.DataFrame:
    runs = 100
    scans = max(4, n_rows // runs)
    rng = np.random.default_rng(seed)
    run = np.repeat(np.arange(runs), scans)
    t = np.tile(np.arange(scans) * 0.05, runs)
    return pl.DataFrame({"run": run, "time_s": t, "x_m": rng.normal(1e3, 10, run.size),
                         "y_m": rng.normal(-5e2, 10, run.size)})


def tdoa_tables(folder: Path, size_mb: float) -> tuple[Path, Path]:
    """A simulated tdoa-fdoa data set exported as tables, runs scaled to about ``size_mb``."""
    from trackreplay.contract import read_dataset
    from trackreplay.recorders.tables import tables_from_dataset

    def export(runs: int) -> tuple[Path, Path]:
        ds_path = folder / f"tdoa-{runs}.mcap"
        _simulate("tdoa-fdoa", runs, ds_path)
        tabs = tables_from_dataset(read_dataset(ds_path), "tdoa-fdoa")
        m, s = folder / "tdoa.csv", folder / "tdoa_sensors.csv"
        tabs["measurements"].write_csv(m)
        tabs["sensors"].write_csv(s)
        ds_path.unlink()
        return m, s

    m, s = export(20)
    per_run = (m.stat().st_size + s.stat().st_size) / 20
    runs = max(20, int(size_mb * 1e6 / per_run))
    return export(runs) if runs != 20 else (m, s)


def _simulate(scenario: str, runs: int, out: Path) -> None:
    exe = shutil.which("replay")
    cmd = [exe] if exe else [sys.executable, "-m", "trackreplay.face.cli"]
    subprocess.run([*cmd, "simulate", scenario, "--runs", str(runs), "--seed", "1", "-o", str(out), "--force", "-q"],
                   check=True, capture_output=True)


def _scan(k: int, rng) -> tuple[int, list]:
    vals = rng.uniform(0.0, 1.0, (RETURNS_PER_SCAN, 5))
    vals[:, 0] = 1e3 + 2e4 * vals[:, 0]
    vals[:, 1] = 360.0 * vals[:, 1] - 180.0
    return 1_700_000_000 * 10**9 + k * 100_000_000, vals.tolist()


def _message(stamp_ns: int, returns: list) -> dict:
    return {"header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": "radar"},
            "returns": [{"range": r, "azimuth": a, "elevation": e, "doppler_velocity": d, "amplitude": p}
                        for r, a, e, d, p in returns]}


def ros2_mcap(path: Path, size_mb: float) -> int:
    """Radar scans as ROS 2 messages until the file holds about ``size_mb``; returns the count."""
    from mcap_ros2.writer import Writer

    rng = np.random.default_rng(3)
    n = _rows_for(size_mb, 777)  # bytes per message of 20 returns (CDR, zstd chunks of random floats)
    with open(path, "wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("demo_radar_msgs/msg/RadarScan", RADAR_SCAN_MSGDEF)
        for k in range(n):
            stamp, returns = _scan(k, rng)
            w.write_message("/radar/scan", schema, _message(stamp, returns), log_time=stamp, publish_time=stamp)
        w.finish()
    return n


def json_mcap(path: Path, size_mb: float) -> int:
    """The same scans as JSON messages until the file holds about ``size_mb``."""
    from mcap.writer import Writer

    def write(n: int) -> None:
        rng = np.random.default_rng(4)
        with open(path, "wb") as f:
            w = Writer(f)
            w.start(profile="", library="bench")
            schema = w.register_schema("demo.RadarScan", "jsonschema", b"{}")
            ch = w.register_channel("/radar/scan", "json", schema)
            for k in range(n):
                stamp, returns = _scan(k, rng)
                w.add_message(ch, log_time=stamp, publish_time=stamp, sequence=k,
                              data=json.dumps(_message(stamp, returns)).encode())
            w.finish()

    write(2000)  # calibrate: JSON compresses in the chunks by an amount that depends on the numbers
    n = _rows_for(size_mb, path.stat().st_size / 2000)
    write(n)
    return n


# --------------------------------------------------------------------------- timing


def rate(count: float, times: list[float]) -> str:
    r = count / statistics.median(times)
    return f"{r / 1e6:.2f} M/s" if r >= 1e6 else f"{r / 1e3:.1f} k/s"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size-mb", type=float, default=100.0, help="size of each generated input, MB (default 100)")
    ap.add_argument("--repeats", type=int, default=5, help="timed repetitions per input (≥ 5 recommended)")
    ap.add_argument("--keep", type=Path, help="generate the inputs here and keep them (default: a temporary folder)")
    args = ap.parse_args()

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from trackreplay.contract import read_dataset
    from trackreplay.recorders.foreign_mcap import dataset_from_foreign, load_mapping
    from trackreplay.recorders.tables import dataset_from_table, read_table

    work = args.keep or Path(tempfile.mkdtemp(prefix="bench-import-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"python {platform.python_version()}, numpy {np.__version__}, polars {pl.__version__}, "
          f"{os.cpu_count()} cpu(s); ~{args.size_mb:g} MB per input, {args.repeats} repeats; files in {work}")
    rows = []  # (importer, file, MB, count, unit, times)

    def measure(label: str, path: Path, count: int, unit: str, fn, also=()) -> None:
        _, times, _ = time_repeats(fn, args.repeats)
        mb = sum(p.stat().st_size for p in (path, *also)) / 1e6
        rows.append((label, path.name, mb, count, unit, times))
        print(f"measured {label}: {fmt(times)}")

    try:
        t0 = time.perf_counter()
        tables = {
            "radar plots CSV": ("radar", work / "plots.csv", lambda p: radar_table(_rows_for(args.size_mb, 52)).write_csv(p)),
            "radar plots Parquet": ("radar", work / "plots.parquet",
                                    lambda p: radar_table(_rows_for(args.size_mb, 16.5)).write_parquet(p)),
            "peaks CSV": ("xcorr", work / "peaks.csv", lambda p: peaks_table(_rows_for(args.size_mb, 50)).write_csv(p)),
            "positions CSV": ("colored", work / "positions.csv",
                              lambda p: positions_table(_rows_for(args.size_mb, 48)).write_csv(p)),
        }
        for label, (family, path, make) in tables.items():
            make(path)
            n = read_table(path).height
            measure(label, path, n, "rows", lambda f=family, p=path: dataset_from_table(f, read_table(p), p))
        m, s = tdoa_tables(work, args.size_mb)
        n = read_table(m).height + read_table(s).height
        measure("TDOA/FDOA CSV (+ sensors)", m, n, "rows",
                lambda: dataset_from_table("tdoa-fdoa", read_table(m), m, read_table(s), s), also=(s,))
        print(f"tables generated and measured in {time.perf_counter() - t0:.0f} s")

        mapping_path = work / "radar.toml"
        mapping_path.write_text(RADAR_MAP)
        mapping = load_mapping(mapping_path)
        floors = {}
        for label, path, make in (("ROS 2 MCAP", work / "ros2.mcap", ros2_mcap),
                                  ("JSON MCAP", work / "json.mcap", json_mcap)):
            t0 = time.perf_counter()
            n = make(path, args.size_mb)
            print(f"wrote {path.name}: {n:,} messages, {path.stat().st_size / 1e6:.1f} MB in "
                  f"{time.perf_counter() - t0:.0f} s")
            measure(label, path, n, "messages", lambda p=path: dataset_from_foreign(p, mapping))

            def iterate(p=path, factories=()):
                with open(p, "rb") as f:
                    for _ in make_reader(f, decoder_factories=factories).iter_decoded_messages(log_time_order=False) \
                            if factories else make_reader(f).iter_messages(log_time_order=False):
                        pass

            _, times, _ = time_repeats(iterate, args.repeats)
            floors[label] = [(f"mcap iter_messages of {path.name} (no decode)", n, times)]
            if label == "ROS 2 MCAP":
                _, times, _ = time_repeats(lambda: iterate(factories=[DecoderFactory()]), args.repeats)
                floors[label].append((f"mcap iter_decoded_messages of {path.name} (mcap_ros2)", n, times))

        # the replay data set: radar-tws, runs scaled to about the same size (from the size that
        # 200 runs add to 20: a file's fixed part, metadata and summary, is large at this scale)
        sizes = {}
        for r in (20, 200):
            _simulate("radar-tws", r, work / f"radar-tws-{r}.mcap")
            sizes[r] = (work / f"radar-tws-{r}.mcap").stat().st_size
        per_run = (sizes[200] - sizes[20]) / 180
        runs = max(20, int((args.size_mb * 1e6 - (sizes[20] - 20 * per_run)) / per_run))
        ds_big = work / f"radar-tws-{runs}.mcap"
        _simulate("radar-tws", runs, ds_big)
        frames = sum(c.run.size for c in read_dataset(ds_big).channels.values())
        ds_mb = ds_big.stat().st_size / 1e6
        _, read_times, _ = time_repeats(lambda: read_dataset(ds_big), args.repeats)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)

    head = ("importer", "input", "MB", "count", "time (median [min–max])", "items/s", "MB/s")
    table = []
    for label, name, mb, count, unit, times in rows:
        table.append((label, name, f"{mb:.1f}", f"{count:,} {unit}", fmt(times), rate(count, times),
                      f"{mb / statistics.median(times):.1f}"))
        for floor, n, ftimes in floors.get(label, []):
            table.append((f"  beside it: {floor}", "", "", f"{n:,} messages", fmt(ftimes), rate(n, ftimes),
                          f"{mb / statistics.median(ftimes):.1f}"))
    table.append(("MCAP read path: read_dataset", f"radar-tws, {runs:,} runs", f"{ds_mb:.1f}", f"{frames:,} frames",
                  fmt(read_times), rate(frames, read_times), f"{ds_mb / statistics.median(read_times):.1f}"))
    print()
    print_table(head, table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
