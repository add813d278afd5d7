"""What this process may use of the machine."""

from __future__ import annotations

import os


def usable_cores() -> int:
    """Cores this process may run on: its CPU affinity where the system has one (Linux; a
    container or ``taskset`` may allow fewer than the machine has), else the CPU count."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


# mallopt(3) parameters of glibc's malloc.h
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4


def keep_freed_memory() -> bool:
    """Let glibc's ``malloc`` keep the memory this process frees for its next allocations,
    instead of handing every large block back to the system (True where it took effect).

    glibc maps each block over its mmap threshold (32 MB at the most) afresh and unmaps it when
    freed, so that every large array a replay makes (a tracker's outputs, one after the other;
    the writer's message buffers) is paid again in page faults, the kernel zeroing each page
    before the process touches it. With no mapped blocks and the heap never trimmed, a freed
    block is reused as it is: at 10,000 radar runs that is about 0.8 GB fewer pages faulted in
    (318,000 minor faults down to 110,000) for 13 MB more at the peak (``docs/benchmarks.md``).

    Called by the command line (:mod:`trackreplay.face.cli`) for its own process, which ends
    after one command; a program that imports the package keeps its allocator as it was. Does
    nothing where the C library has no ``mallopt`` (not glibc).
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    # (a threshold of 2³¹ − 1 bytes: mallopt takes an int)
    return bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
