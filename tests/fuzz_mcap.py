"""Mutation fuzzing of MCAP inputs: every damaged file is either read as the original data (same
metrics, to the bit) or refused with one ``replay: error:`` line; never a traceback.

Used by ``tests/test_fuzz.py`` (a few hundred mutants) and as a script for a long run::

    python tests/fuzz_mcap.py --mutants 10000 --seed 1

which prints: mutants tried, refused cleanly, accepted with the original metrics, accepted with
different metrics (silently wrong), tracebacks (or internal errors, exit status 3).
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def small_dataset(folder: Path) -> Path:
    """A small radar data set (3 runs × 10 scans) written through the real recorder."""
    from recorders.scenarios import load_scenario
    from recorders.simulated import record

    path = folder / "small.mcap"
    record(path, load_scenario("radar-tws").with_overrides({"n_scans": 10}), runs=3, seed=9)
    return path


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One random damage: bit flips, byte overwrites, a truncation, a deleted or duplicated span,
    or a large integer written over a field."""
    b = bytearray(data)
    kind = rng.randrange(6)
    if kind == 0:
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif kind == 1:
        i = rng.randrange(len(b))
        for j in range(i, min(len(b), i + rng.randint(1, 16))):
            b[j] = rng.randrange(256)
    elif kind == 2:
        del b[rng.randrange(len(b)):]
    elif kind == 3:
        i = rng.randrange(len(b))
        del b[i:i + rng.randint(1, 64)]
    elif kind == 4:
        i = rng.randrange(len(b))
        span = b[i:i + rng.randint(1, 256)]
        b[i:i] = span
    else:
        i = rng.randrange(max(1, len(b) - 8))
        b[i:i + 8] = rng.choice([2**63 - 1, 2**32, 65536, 2**40]).to_bytes(8, "little")
    return bytes(b)


def rewrite_with_damaged_message(data: bytes, rng: random.Random) -> bytes:
    """Damage the payload of one message (or one metadata value) and write the file again with
    valid CRCs, so the damage reaches the decoder instead of the CRC check."""
    import io

    from mcap.reader import make_reader
    from mcap.writer import Writer

    reader = make_reader(io.BytesIO(data))
    messages = list(reader.iter_messages())
    metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    victim = rng.randrange(len(messages) + len(metadata))
    out = io.BytesIO()
    w = Writer(out)
    w.start()
    if victim >= len(messages):
        name, values = metadata[victim - len(messages)]
        key = rng.choice(sorted(values))
        values[key] = rng.choice(["", "{", "nan", "-1", "1e400", "65536", values[key][::-1], values[key] + "]"])
    for name, values in metadata:
        w.add_metadata(name, values)
    schemas, channels = {}, {}
    for i, (schema, channel, message) in enumerate(messages):
        if schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channels:
            channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding, schemas[schema.id],
                                                      channel.metadata)
        payload = message.data
        if i == victim:
            payload = mutate(payload, rng) if payload else b"\xff"
        w.add_message(channels[channel.id], message.log_time, payload, message.publish_time)
    w.finish()
    return out.getvalue()


def metrics_of(path: Path):
    """What the command line reports for a data set: (exit code, stdout JSON or error line, traceback)."""
    from click.testing import CliRunner

    from pipeline.face.cli import main

    res = CliRunner().invoke(main, ["eval", str(path), "--json"])
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        return res.exit_code, None, "".join(traceback.format_exception(res.exception))
    if res.exit_code == 3:  # the CLI's one-line report of a bug of ours: as bad as a traceback here
        return res.exit_code, None, res.stderr
    # a refusal is judged by what the user sees on stderr (a tracker that fails on odd but
    # well-formed data is reported there too, after the others' metrics on stdout)
    return res.exit_code, res.stdout if res.exit_code == 0 else res.stderr, None


def run(mutants: int, seed: int, folder: Path | None = None) -> dict:
    """Fuzz ``mutants`` damaged copies of a small data set; returns counts and examples."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(folder or tmp)
        original = small_dataset(folder)
        code, reference, tb = metrics_of(original)
        assert code == 0 and tb is None, tb
        reference = json.loads(reference)
        rng = random.Random(seed)
        data = original.read_bytes()
        # raw damage must be refused or read as the original ("silently_different" counts failures);
        # a rewritten file with valid CRCs is well-formed MCAP holding other values, which may be
        # accepted ("rewritten_accepted") but never with a traceback
        counts = {"tried": 0, "refused": 0, "same_metrics": 0, "silently_different": 0, "tracebacks": 0,
                  "not_one_line": 0, "rewritten_accepted": 0}
        examples = []
        target = folder / "mutant.mcap"
        for i in range(mutants):
            # half the mutants damage raw bytes (caught by the CRCs), half rewrite the file with
            # valid CRCs around a damaged message or metadata value (reaching the decoder)
            raw = i % 2 == 0
            target.write_bytes(mutate(data, rng) if raw else rewrite_with_damaged_message(data, rng))
            code, out, tb = metrics_of(target)
            counts["tried"] += 1
            if tb is not None:
                counts["tracebacks"] += 1
                examples.append(tb.strip().splitlines()[-1])
            elif code == 0:
                same = json.loads(out) == reference
                if not raw and not same:
                    counts["rewritten_accepted"] += 1
                    continue
                counts["same_metrics" if same else "silently_different"] += 1
                if not same:
                    examples.append(f"mutant {i}: accepted with different metrics")
            else:
                lines = [l for l in out.splitlines() if l.strip()]
                ok = len(lines) == 1 and lines[0].startswith("replay: error:")
                counts["refused"] += 1
                if not ok:
                    counts["not_one_line"] += 1
                    examples.append(f"mutant {i}: {out[-300:]}")
        counts["examples"] = examples[:10]
        return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mutants", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    t0 = time.perf_counter()
    c = run(args.mutants, args.seed)
    print(f"mutants tried {c['tried']}, refused with one line {c['refused'] - c['not_one_line']}, "
          f"refused otherwise {c['not_one_line']}, accepted with the original metrics {c['same_metrics']}, "
          f"accepted with different metrics {c['silently_different']}, tracebacks {c['tracebacks']}; "
          f"rewritten with valid CRCs and accepted as other data {c['rewritten_accepted']} "
          f"({time.perf_counter() - t0:.0f} s, seed {args.seed})")
    for e in c["examples"]:
        print("  example:", e)


if __name__ == "__main__":
    main()
