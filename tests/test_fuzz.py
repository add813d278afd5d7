"""Seeded, bounded fuzzing of the input path (see ``tests/fuzz_mcap.py`` for the long run)."""

from __future__ import annotations

from fuzz_mcap import run


def test_damaged_files_are_refused_in_one_line_or_read_as_the_original(tmp_path):
    counts = run(mutants=250, seed=2024, folder=tmp_path)
    assert counts["tracebacks"] == 0, counts["examples"]
    assert counts["not_one_line"] == 0, counts["examples"]
    assert counts["silently_different"] == 0
    assert counts["refused"] > 100  # the damage really reached the reader
