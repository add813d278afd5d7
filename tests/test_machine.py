"""What the command line asks of the machine: the allocator keeps freed memory for reuse."""

import subprocess
import sys

import pytest

from trackreplay import machine

# allocate and free a 200 MB array twice, counting the page faults of each; print the two counts
_FAULTS = """
import resource, sys
import numpy as np
from trackreplay.machine import keep_freed_memory
kept = keep_freed_memory() if sys.argv[1] == "keep" else False
counts = []
for _ in range(2):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(25_000_000)  # 200 MB, every page written
    del a
    counts.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(kept, *counts)
"""


def _faults(mode: str):
    out = subprocess.run([sys.executable, "-c", _FAULTS, mode], capture_output=True, text=True, check=True).stdout
    kept, first, second = out.split()
    return kept == "True", int(first), int(second)


def test_freed_memory_is_reused_without_faulting_it_in_again():
    if not sys.platform.startswith("linux"):
        pytest.fail("this machine's allocator is glibc's on Linux; the test says what it checks there")
    kept, first, second = _faults("keep")
    assert kept
    pages = 200e6 / 4096
    # the first array faults its pages in (4 KiB each, or fewer huge pages); the second reuses them
    assert second < 0.1 * max(first, 1) and second < 0.1 * pages
    # without it, glibc maps a block this large afresh: the second array faults again
    _, plain_first, plain_second = _faults("plain")
    assert plain_second > 0.5 * plain_first


def test_the_command_line_keeps_freed_memory_but_a_program_importing_the_package_does_not(monkeypatch):
    calls = []
    monkeypatch.setattr(machine, "keep_freed_memory", lambda: calls.append(1) or True)
    import trackreplay  # noqa: F401  (importing it sets nothing)

    assert calls == []
    from click.testing import CliRunner

    from trackreplay.face.cli import main

    result = CliRunner().invoke(main, ["scenarios"])
    assert result.exit_code == 0, result.output
    assert calls == [1]
