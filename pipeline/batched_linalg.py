"""Linear algebra of many small matrices at once, entry by entry.

Tracking states and measurements are small (n ≤ 10 or so) and come in stacks of millions: one per
run, scan, track or model. LAPACK called per matrix spends most of its time on the call (numpy's
``linalg`` loops over the stack), and at a few runs the call overhead of each routine dominates
instead. Here every entry of a factor is one vectorised operation over the whole stack, a few
dozen operations in all whatever its size, and a matrix that is missing or not positive definite
simply comes out NaN (no exception).

Layout: a stack of ``r × c`` matrices is an array ``(*lead, r, c, N)`` with the stack last, so
that an entry ``A[..., i, j, :]`` is a contiguous vector; constants broadcast as
``(*lead, r, c, 1)``, vectors are ``(*lead, r, N)``. :func:`whiten` takes the stack first, as the
trackers' outputs hold it. Numpy only, no I/O: the IMM cores (Kwon 1997, ch. IV.3; Blom &
Bar-Shalom 1988), the trackers' output checks (``trackreplay.trackers.interface``) and the
evaluators' NEES/NIS (``trackreplay.evaluators.consistency``) share it (``docs/evaluation.md``,
``docs/papers/colored.md``).
"""

from __future__ import annotations

import numpy as np

_sum = np.add.reduce   # without ndarray.sum's Python wrapper: these arrays are small


def cholesky_lower(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor ``L`` (``P = L Lᵀ``) of a stack of symmetric positive definite
    matrices ``(*lead, n, n, runs)``; only the lower triangle of ``P`` is read.

    A matrix that is not positive definite gives NaN entries (no exception), as a square root of
    a negative pivot does.
    """
    n = P.shape[-2]
    L = np.zeros_like(P)
    for j in range(n):
        # pivot: P_jj − Σ_k<j L_jk²; the column below it: (P_ij − Σ_k<j L_ik L_jk) / L_jj
        if j == 0:
            d = np.sqrt(P[..., 0, 0, :])
            L[..., 0, 0, :] = d
            if n > 1:
                np.divide(P[..., 1:, 0, :], d[..., None, :], out=L[..., 1:, 0, :])
            continue
        Lj = L[..., j, :j, :]                                           # (*lead, j, runs)
        d = np.sqrt(P[..., j, j, :] - _sum(Lj * Lj, -2))
        L[..., j, j, :] = d
        if j + 1 < n:
            below = P[..., j + 1:, j, :] - _sum(L[..., j + 1:, :j, :] * Lj[..., None, :, :], -2)
            np.divide(below, d[..., None, :], out=L[..., j + 1:, j, :])
    return L


def forward_substitute(L: np.ndarray, B: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``L⁻¹ B`` for lower triangular ``L`` ``(*lead, n, n, runs)`` and ``B`` ``(*lead, n, k, runs)``
    (row by row; ``L``'s upper triangle is not read). ``out`` may be ``B`` itself: row i is read
    before it is written and only rows above it are read after."""
    n = L.shape[-2]
    X = np.empty(np.broadcast_shapes(B.shape, L.shape[:-3] + (n, B.shape[-2], L.shape[-1]))) if out is None else out
    for i in range(n):
        row = B[..., i, :, :]
        if i:
            row = row - _sum(L[..., i, :i, None, :] * X[..., :i, :, :], -3)
        np.divide(row, L[..., i, i, None, :], out=X[..., i, :, :])
    return X


def back_substitute(U: np.ndarray, B: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``U⁻¹ B`` for upper triangular ``U`` ``(*lead, n, n, runs)`` and ``B`` ``(*lead, n, k, runs)``
    (row by row from the last; ``U``'s lower triangle is not read). ``out`` may be ``B`` itself."""
    n = U.shape[-2]
    X = np.empty(np.broadcast_shapes(B.shape, U.shape[:-3] + (n, B.shape[-2], U.shape[-1]))) if out is None else out
    for i in range(n - 1, -1, -1):
        row = B[..., i, :, :]
        if i < n - 1:
            row = row - _sum(U[..., i, i + 1:, None, :] * X[..., i + 1:, :, :], -3)
        np.divide(row, U[..., i, i, None, :], out=X[..., i, :, :])
    return X


def householder_triangularise(A: np.ndarray, columns: int) -> np.ndarray:
    """Triangularise the first ``columns`` columns of ``A`` ``(*lead, r, c, runs)`` in place by
    Householder reflections (the ``R`` of a QR factorisation, as ``numpy.linalg.qr(mode="r")``
    gives it up to the signs of its rows); returns ``A``.

    Every column after the first ``columns`` is carried along by the same reflections. The
    entries below the diagonal of the triangularised columns are left as they are (they are
    zero in exact arithmetic, and no caller reads them). The reflection of a column ``a`` is
    ``I − 2 v vᵀ / (vᵀ v)`` with ``v = a + s e₁``, ``s = sign(a₁) ‖a‖`` (the sign that avoids
    cancellation), so the new diagonal is ``−s`` and ``vᵀ v / 2 = ‖a‖² + |a₁| ‖a‖``.
    """
    cols = A.shape[-2]
    for j in range(columns):
        a = A[..., j:, j, :]                                            # (*lead, rows, runs)
        norm2 = _sum(a * a, -2)
        a0 = A[..., j, j, :]
        s = np.copysign(np.sqrt(norm2), a0)
        half_vtv = norm2 + a0 * s
        v = a.copy()
        v[..., 0, :] += s
        np.negative(s, out=a0)
        if j + 1 < cols:
            rest = A[..., j:, j + 1:, :]                                # (*lead, rows, c', runs)
            proj = _sum(v[..., :, None, :] * rest, -3)                  # vᵀ rest: (*lead, c', runs)
            proj /= half_vtv[..., None, :]
            rest -= v[..., :, None, :] * proj[..., None, :, :]
    return A


def whiten(e, P):
    """``w = L⁻¹ e`` with ``P = L Lᵀ`` for stacks ``e`` (N, n) and ``P`` (N, n, n), the stack
    first, so that ``eᵀ P⁻¹ e = ‖w‖²``; NaN rows where ``e`` or ``P`` is missing or ``P`` is not
    positive definite."""
    with np.errstate(invalid="ignore", divide="ignore"):
        # one copy into the stack-last layout: every entry is then a contiguous vector
        L = cholesky_lower(np.ascontiguousarray(np.moveaxis(P, 0, -1)))  # (n, n, N)
        w = forward_substitute(L, np.ascontiguousarray(e.T)[:, None, :])[:, 0, :].T  # (N, n)
    bad = ~positive_definite(L) | ~all_finite(w)
    w[bad] = np.nan
    return w


def _whitened_entries(e, P, w_out=None):
    """``‖w‖²`` of ``w = L⁻¹ e`` (``P = L Lᵀ``) for stacks ``e`` (..., n) and ``P`` (..., n, n) of
    any layout, and ``w`` itself into ``w_out`` (..., n) when given; NaN (in every component of
    ``w``) where :func:`whiten` gives NaN. The values of :func:`whiten` and then
    :func:`sum_squares`, to the bit (tests/test_evaluation_speed_paths.py).

    Every entry of the factor, of ``w`` and of the sum is one operation over the stack in the
    order :func:`cholesky_lower`, :func:`forward_substitute` and :func:`sum_squares` take them
    (the sums over ``k < j`` left to right, as their reductions over a short outer axis add),
    but on the entries of ``P`` and ``e`` where they lie (no copy into the stack-last layout),
    the factor's entries kept one by one (no zeroed upper triangle), and the checks of
    :func:`whiten` (every pivot in (0, ∞), every component of ``w`` finite) read from the sum:
    where no pivot and no sum is infinite, a row fails them exactly where its sum is NaN (a NaN
    or zero pivot or a NaN component makes the sum NaN or infinite, an infinite component makes
    it infinite), so only a stack holding an infinity pays for the checks one by one.
    """
    n = e.shape[-1]
    lead = np.broadcast_shapes(e.shape[:-1], P.shape[:-2])
    e, P = np.broadcast_to(e, lead + (n,)), np.broadcast_to(P, lead + (n, n))
    tmp = np.empty(lead)

    def dot(a, b, count):
        """Σ_{k<count} a_k b_k, left to right, in a fresh array."""
        acc = np.multiply(a[0], b[0])
        for k in range(1, count):
            acc += np.multiply(a[k], b[k], out=tmp)
        return acc

    L = [[None] * n for _ in range(n)]
    w = [None] * n
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for j in range(n):
            if j == 0:
                d = np.sqrt(P[..., 0, 0])
            else:
                acc = dot(L[j], L[j], j)
                d = np.sqrt(np.subtract(P[..., j, j], acc, out=acc), out=acc)
            L[j][j] = d
            for i in range(j + 1, n):
                if j == 0:
                    L[i][0] = np.divide(P[..., i, 0], d)
                else:
                    acc = dot(L[i], L[j], j)
                    L[i][j] = np.divide(np.subtract(P[..., i, j], acc, out=acc), d, out=acc)
        for i in range(n):
            if i == 0:
                w[0] = np.divide(e[..., 0], L[0][0])
            else:
                acc = dot(L[i], w, i)
                w[i] = np.divide(np.subtract(e[..., i], acc, out=acc), L[i][i], out=acc)
        total = np.multiply(w[0], w[0])          # (0 + w₀², as sum_squares starts, is w₀²: a square is never −0)
        for i in range(1, n):
            total += np.multiply(w[i], w[i], out=tmp)
        pivots = L[0][0].copy()
        for i in range(1, n):
            pivots += L[i][i]
        if np.isinf(total).any() or np.isinf(pivots).any():
            # an infinite pivot leaves w finite, and a sum may overflow: the checks one by one
            bad = ~_positive_definite_entries([L[i][i] for i in range(n)])
            for i in range(n):
                bad |= ~np.isfinite(w[i])
        else:
            bad = np.isnan(total)
    np.copyto(total, np.nan, where=bad)          # the NaN whiten writes, whatever NaN the row made
    if w_out is not None:
        for i in range(n):
            np.copyto(w[i], np.nan, where=bad)
            w_out[..., i] = w[i]
    return total


def _positive_definite_entries(pivots):
    """:func:`positive_definite` of a factor's pivots given one array each."""
    ok = np.ones(np.shape(pivots[0]), bool)
    for d in pivots:
        ok &= (d > 0) & (d < np.inf)
    return ok


def positive_definite(L):
    """Where a factor of :func:`cholesky_lower` (``(*lead, n, n, N)``) exists: every pivot finite
    and > 0 (a matrix that is not positive definite has a NaN or zero one)."""
    n = L.shape[-2]
    ok = np.ones(L.shape[:-3] + L.shape[-1:], bool)
    for i in range(n):
        d = L[..., i, i, :]
        ok &= (d > 0) & (d < np.inf)
    return ok


def sum_squares(a):
    """``Σ a_i²`` over the last, short axis of a float stack ``a`` (..., n), one whole-stack
    operation per component, left to right: numpy's reduction along a short inner axis steps
    through the stack n elements at a time and costs several times as much, and the squares
    are never held whole."""
    a = np.asarray(a)
    total = np.zeros(a.shape[:-1], dtype=np.result_type(a.dtype, float))
    for i in range(a.shape[-1]):
        total += a[..., i] * a[..., i]
    return total


def all_finite(a):
    """Whether every component of each short vector of ``a`` (..., n) is finite, (...): as
    ``np.isfinite(a).all(axis=-1)``, a component at a time (see :func:`sum_squares`)."""
    a = np.asarray(a)
    ok = np.ones(a.shape[:-1], bool)
    for i in range(a.shape[-1]):
        ok &= np.isfinite(a[..., i])
    return ok


#: how :func:`over_stack` computes a stack of independent matrix problems: ``None``, in one call.
#: Cores start no threads; the replay layer installs a runner that shares a large stack among the
#: cores (:func:`trackreplay.stack_threads.split_over_threads`, the same bits), so where the work is
#: parallel is decided by whoever runs the trackers, not by the algorithm
stack_runner = None


def over_stack(function, stack: np.ndarray):
    """``function(stack)`` for a numpy ``linalg`` function that works matrix by matrix over a
    stack ``(..., m, m)`` (``eigh``, ``inv`` …), through the installed :data:`stack_runner`
    when there is one (every matrix meets the same routine either way)."""
    runner = stack_runner
    return function(stack) if runner is None else runner(function, stack)


#: how :func:`over_blocks` computes independent pieces of work: ``None``, one after the other in
#: the calling thread. Installed by the replay layer as :data:`stack_runner` is
#: (:func:`trackreplay.stack_threads.blocks_over_threads`: the pieces on the cores at once)
block_runner = None


def over_blocks(function, pieces) -> list:
    """``[function(piece) for piece in pieces]``, through the installed :data:`block_runner` when
    there is one.

    For a core's independent blocks of work (runs of a Monte Carlo set, each its own problem)
    whose numpy calls release the GIL: every piece is computed by the same calls either way, so
    the results are the same to the bit; only where they run differs. ``function`` must not
    depend on the order of the pieces (it may write into disjoint parts of a shared array).
    """
    runner = block_runner
    return [function(piece) for piece in pieces] if runner is None else runner(function, list(pieces))
