"""Stacks of small matrix problems shared among the cores: the replay layer's choice, not a core's.

numpy's ``linalg`` loops release the GIL while LAPACK runs but keep to one core. The array
trackers' EVDs (one per run and scan) are most of an array replay's filtering, so a replay
shares such a stack among the cores this process may use. The cores themselves start no
threads: they call :func:`trackreplay.batched_linalg.over_stack`, which computes the stack in one
call until :func:`install` (called by :func:`trackreplay.replay.replay`) hands it the splitter
below. The same holds for blocks of runs a core computes one after the other
(:func:`trackreplay.batched_linalg.over_blocks`: the array trackers' PAST passes, batch EVDs and
innovations, whose element-wise numpy calls release the GIL as well): once installed, the blocks
run on the cores at once (:func:`blocks_over_threads`). Benchmarks against single-core peers leave
it uninstalled or set :data:`MAX_THREADS` to 1.
"""

from __future__ import annotations

import threading

import numpy as np

from trackreplay import batched_linalg
from trackreplay.machine import usable_cores


def install() -> None:
    """Let :func:`trackreplay.batched_linalg.over_stack` share large stacks, and
    :func:`trackreplay.batched_linalg.over_blocks` its blocks, among the cores."""
    batched_linalg.stack_runner = split_over_threads
    batched_linalg.block_runner = blocks_over_threads


#: work a thread takes at the least in :func:`split_over_threads`, in matrices × m³ (about 300
#: EVDs of 15 × 15): below, the threads cost more than they save
THREAD_MIN_WORK = 1 << 20
#: threads :func:`split_over_threads` uses at the most (1: every stack in one call, on one core,
#: as the per-core comparisons with peer libraries in ``benchmarks/`` set it)
MAX_THREADS = 4


_cores = usable_cores  # (a module name of its own, so that tests can set the count)
#: set in a thread that computes one of :func:`blocks_over_threads`' pieces: a stack inside it is
#: not split again (the pieces keep the cores busy already)
_in_piece = threading.local()


def blocks_over_threads(function, pieces: list) -> list:
    """``[function(piece) for piece in pieces]`` with the pieces on up to :data:`MAX_THREADS`
    threads at once (as many as the cores this process may use), the results in order.

    For independent blocks of runs whose numpy calls release the GIL (element-wise passes over a
    block, LAPACK stacks): each piece is computed by the same calls as in one thread, so the
    results are the same to the bit. A stack that a piece hands to :func:`split_over_threads` is
    computed in that piece's thread, and pieces started from inside a piece run in its thread,
    one after the other. An exception a piece raises is raised here (the other pieces finish
    first). The caller must not hold a lock that a finalizer may take (see
    :func:`split_over_threads`).
    """
    threads = min(_cores(), MAX_THREADS, len(pieces))
    if threads < 2 or getattr(_in_piece, "active", False):
        return [function(piece) for piece in pieces]
    from concurrent.futures import ThreadPoolExecutor

    def run(piece):
        _in_piece.active = True
        try:
            return function(piece)
        finally:
            _in_piece.active = False

    # a pool per call, not kept: a process forked later (a sweep's workers) must not inherit it
    with ThreadPoolExecutor(threads) as pool:
        return list(pool.map(run, pieces))



def split_over_threads(function, stack: np.ndarray):
    """``function(stack)`` for a numpy ``linalg`` function that works matrix by matrix over a
    stack ``(..., m, m)`` (``eigh``, ``inv`` …), with the stack split across threads.

    numpy's linalg loops release the GIL while LAPACK runs, but each call keeps to one core: a
    stack of a few hundred small matrices or more is cut into one piece per available core (at
    most :data:`MAX_THREADS`, at least :data:`THREAD_MIN_WORK` of work each) and the pieces
    run at once. Every matrix goes through the same routine as in one call, so the result is
    identical to the bit; an error a piece raises is raised here. Returns what ``function``
    returns, arrays (or tuples of them) joined along the stack.

    The caller waits for the pieces, so it must not hold a lock that a weak-reference callback
    or finalizer may take: a garbage collection can run on a worker thread (an earlier array
    front end whose memo held a lock while its EVDs ran on a thread of their own hung once that
    way, commit 37f9e75; the memo now takes no lock at all).
    """
    stack = np.asarray(stack)
    lead = stack.shape[:-2]
    n = int(np.prod(lead, dtype=np.int64)) if lead else 1
    threads = min(_cores(), MAX_THREADS, n * stack.shape[-1] ** 3 // THREAD_MIN_WORK)
    if getattr(_in_piece, "active", False):
        threads = 1  # one of blocks_over_threads' pieces: the other pieces use the other cores
    if threads < 2:
        return function(stack)
    from concurrent.futures import ThreadPoolExecutor

    flat = stack.reshape((n,) + stack.shape[-2:])
    bounds = np.linspace(0, n, threads + 1).astype(int)
    # a pool per call, not kept: a process forked later (a sweep's workers) must not inherit it
    with ThreadPoolExecutor(threads) as pool:
        parts = [f.result() for f in [pool.submit(function, flat[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]]

    def joined(pieces):
        whole = np.concatenate(pieces)
        return whole.reshape(lead + whole.shape[1:])

    if isinstance(parts[0], tuple):
        return tuple(joined([p[i] for p in parts]) for i in range(len(parts[0])))
    return joined(parts)
