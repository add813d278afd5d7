"""A seeded sample of the structure-aware fuzzer (``tests/fuzz_mcap.py``; the full run is
``python tests/fuzz_mcap.py --mutants 10000 --seed 1``): every mutant of every base file is
refused with one line naming it, or accepted with the metrics that an independent decoder's
reading of it gives. No exit 3, traceback, hang, silent corruption or modified input."""

from __future__ import annotations

import fuzz_mcap
from fuzz_mcap import FAILURES, MUTATIONS, run


def test_mutants_are_refused_in_one_line_or_read_as_what_they_hold(tmp_path):
    counts = run(mutants=200, seed=2024, folder=tmp_path, timeout=60)
    assert counts["failures"] == 0, counts["examples"]
    for outcome in (*FAILURES, "inconsistent"):  # (inconsistent: eval and replay disagree on a file)
        assert counts[outcome] == 0, (outcome, counts["examples"])
    # the damage reached the reader, and well-formed mutants got through to be judged
    assert counts["refused_one_line"] > 100 and counts["accepted_correct"] > 25, counts
    assert set(counts["by_kind"]) == {m[0] for m in MUTATIONS}
    assert set(counts["by_base"]) == {b[0] for b in fuzz_mcap.BASES} | {"radar-lz4"}


def test_the_mutants_of_a_seed_are_the_same_bytes(tmp_path):
    """Same seed, same mutants (whatever the number of workers): a failure found is found again."""
    bases = fuzz_mcap.prepare_bases(tmp_path, names={"radar"})
    first = [fuzz_mcap.make_mutant(bases, 7, i) for i in range(40)]
    assert first == [fuzz_mcap.make_mutant(bases, 7, i) for i in range(40)]
    assert len({m[2] for m in first}) > 30
