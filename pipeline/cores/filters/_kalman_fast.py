"""Fast forms of the one Kalman filter, private to it: each computes what a plain function of
:mod:`trackreplay.cores.filters.kalman` computes, for one shape of work, and a test holds it to
that function (tests/test_kalman.py, tests/test_long_recording.py,
tests/test_multitarget_trackers.py). This module imports the plain one, never the other way:
callers that want speed call the forms here (:func:`joseph_covariance_fast` and
:func:`cv_position_update_components_fast` choose the fast form where it pays and the plain
function elsewhere); the scan-axis forms are called by the radar TWS tracker's steady blocks.

* :func:`_joseph_terms_contracted`: :func:`~trackreplay.cores.filters.kalman.joseph_covariance`'s
  products for a stack of thousands of matrices.
* :func:`_cv_position_update_rows`: :func:`~trackreplay.cores.filters.kalman.cv_position_update_components`
  with its rows stacked (a dozen NumPy calls on ``(8, runs)`` arrays instead of ninety on
  ``(runs,)`` ones), the same operations in the same order: the same numbers to the bit.
* :func:`_cv_position_scan_rows`: one scan of predict, update and state for a few hundred runs
  (the radar TWS tracker's steady stretches of many runs), row by row into the caller's arrays.
* The CV kernel along the scan axis (many scans of few runs, a long recording): a scan loop over
  one-element arrays pays a NumPy call per operation, so what does not depend on the previous
  scan is taken for all scans at once and what does runs on Python floats.
"""

from __future__ import annotations

from itertools import chain

import numpy as np

from trackreplay.cores.filters.kalman import (
    A00, A01, A11, B00, B01, B10, B11, C00, C01, C11,
    _cv_predict_terms,
    cv_apply_gain_components,
    cv_position_update_components,
    cv_predict_components,
    joseph_covariance,
)

# --------------------------------------------------------------------------- Joseph products

#: stacks of at least this many matrices take the Joseph products as two contractions
#: (:func:`_joseph_terms_contracted`)
_CONTRACTION_BATCH = 512


def joseph_covariance_fast(P, K, H, R):
    """:func:`~trackreplay.cores.filters.kalman.joseph_covariance`, a stack of at least
    ``_CONTRACTION_BATCH`` matrices through :func:`_joseph_terms_contracted`, the same to rounding
    (tests/test_multitarget_trackers.py); anything else through the plain function itself."""
    if not (P.ndim == 3 and P.shape[0] >= _CONTRACTION_BATCH):
        return joseph_covariance(P, K, H, R)
    A = np.eye(P.shape[-1]) - K @ H
    P_post = _joseph_terms_contracted(A, P, K, R)
    return 0.5 * (P_post + np.swapaxes(P_post, -1, -2))


def _joseph_terms_contracted(A, P, K, R):
    """``A P Aᵀ + K R Kᵀ`` of a stack ``(N, n, n)`` as two :func:`numpy.einsum` contractions with
    an optimised path: for thousands of small matrices (a multi-target tracker's updates) it
    costs less than four batched ``matmul`` calls (tests/test_multitarget_trackers.py holds the
    two equal)."""
    return (np.einsum("nij,njk,nlk->nil", A, P, A, optimize=_PATH_APA)
            + np.einsum("nij,jk,nlk->nil", K, R, K, optimize=_PATH_KRK))


# the contraction order, fixed once: left to right, as the matmul form multiplies
_PATH_APA = ["einsum_path", (0, 1), (0, 1)]
_PATH_KRK = ["einsum_path", (0, 1), (0, 1)]

# --------------------------------------------------------------------------- CV kernel, rows stacked

# Every gain entry and every entry of M = R S⁻¹ is (first · S_alternate − second · S01) / |S|, with
# S_alternate S11 for the even rows and S00 for the odd ones (Cramer's rule); the posterior's A
# and B rows are M times two components, its C rows C − K_vel B. The rows each takes:
_GAIN_FIRST = np.array([A00, A01, A01, A11, B00, B10, B01, B11])
_GAIN_SECOND = np.array([A01, A00, A11, A01, B10, B00, B11, B01])
_MB_LEFT = np.array([A00, A01, A01, B00, B01, B00, B01])
_MB_RIGHT = np.array([A01, A11, A11, B10, B11, B10, B11])
_M_LEFT, _M_RIGHT = np.array([0, 0, 2, 0, 0, 2, 2]), np.array([1, 1, 3, 1, 1, 3, 3])
_C_ROWS, _KB_LEFT, _KB_RIGHT = np.array([C00, C01, C11]), np.array([B00, B01, B01]), np.array([B10, B11, B11])
_K_LEFT, _K_RIGHT = np.array([4, 4, 6]), np.array([5, 5, 7])


#: Widest batch :func:`cv_position_update_components_fast` takes on stacked rows: beyond, the
#: stacked temporaries outgrow the cache and the row-by-row form costs less (measured: 45 against
#: 52 us at 512 runs, even at 1,024, 147 against 90 us at 1,536 and 121 against 115 at 2,048).
ROWS_STACKED_RUNS = 1024


def cv_position_update_components_fast(c, r00, r01, r11):
    """:func:`~trackreplay.cores.filters.kalman.cv_position_update_components`, batches of up to
    :data:`ROWS_STACKED_RUNS` runs on stacked rows (:func:`_cv_position_update_rows`, the same
    numbers to the bit, tests/test_kalman.py), wider ones through the plain function itself."""
    if 0 < c[0].size <= ROWS_STACKED_RUNS:
        return _cv_position_update_rows(c, r00, r01, r11)
    return cv_position_update_components(c, r00, r01, r11)


def _cv_position_update_rows(c, r00, r01, r11):
    """:func:`~trackreplay.cores.filters.kalman.cv_position_update_components` (its gain and
    posterior, the same operations in the same order) on stacked rows: ``(gain (8, ...),
    c_post (10, ...))`` for components ``c`` ``(10, ...)``."""
    rest = c.shape[1:]
    s = np.empty((3,) + rest)
    s[0], s[1], s[2] = c[A00] + r00, c[A01] + r01, c[A11] + r11   # S = A + R
    s00, s01, s11 = s
    inv_det = 1.0 / (s00 * s11 - s01 * s01)
    alternate = s[2::-2]                                  # S11, S00
    gain = (c.take(_GAIN_FIRST, 0).reshape((4, 2) + rest) * alternate
            - c.take(_GAIN_SECOND, 0).reshape((4, 2) + rest) * s01) * inv_det
    gain = gain.reshape((8,) + rest)
    r = np.empty((4,) + rest)                             # R's entries in the gain's pattern
    r[0], r[1], r[2], r[3] = r00, r01, r01, r11
    m = (r.reshape((2, 2) + rest) * alternate - r[[1, 0, 3, 2]].reshape((2, 2) + rest) * s01) * inv_det
    m = m.reshape((4,) + rest)                            # M = R S⁻¹: m00, m01, m10, m11
    n = np.empty_like(c)
    n[:7] = m.take(_M_LEFT, 0) * c.take(_MB_LEFT, 0) + m.take(_M_RIGHT, 0) * c.take(_MB_RIGHT, 0)
    n[7:] = c.take(_C_ROWS, 0) - (gain.take(_K_LEFT, 0) * c.take(_KB_LEFT, 0)
                                  + gain.take(_K_RIGHT, 0) * c.take(_KB_RIGHT, 0))
    return gain, n


# --------------------------------------------------------------------------- CV kernel, one scan fused


def _cv_position_scan_rows(x, c, dt: float, sigma_v: float, z, r, x_out, nu_out, s_out, gain_out, c_out):
    """One scan of the CV Kalman filter with a position measurement, written into the arrays
    given: :func:`cv_predict_components` of state ``x`` ``(4, n)`` and components ``c`` ``(10, n)``,
    the innovation ``ν = z − H x⁻`` (``nu_out`` ``(2, n)``; ``z`` ``(2, n)``), the entries
    ``(s00, s01, s11)`` of ``S = H P⁻ Hᵀ + R`` (``s_out`` ``(3, n)``),
    :func:`~trackreplay.cores.filters.kalman.cv_position_update_components`'s gain and posterior
    (``gain_out`` ``(8, n)``, ``c_out`` ``(10, n)``; ``r`` ``(3, n)`` is R's ``r00, r01, r11``) and
    :func:`cv_apply_gain_components`'s state (``x_out`` ``(4, n)``).

    For a few hundred runs, where a scan costs its NumPy calls rather than its arithmetic: each
    row is one positional ufunc call writing where its result is kept, products two rows share
    are formed once (some 130 calls where those functions with their temporaries, index
    arithmetic and copies take 170). Stacking the rows into 2-D calls does not pay at this size:
    a call that broadcasts a row over others, or reads rows at a stride, costs more than the row
    calls it replaces. The same operations in the same order as those functions, so the same
    numbers to the bit (tests/test_long_recording.py).
    """
    mul, add, sub = np.multiply, np.add, np.subtract
    q = sigma_v * sigma_v
    q4, q3, q2 = q * dt**4 / 4, q * dt**3 / 2, q * dt * dt
    dt2, dt_2 = dt * dt, 2 * dt
    a00, a01, a11, b00, b01, b10, b11, c00, c01, c11 = c
    # the prediction (_cv_predict_terms): A' = A + dt(B + Bᵀ) + dt² C + q₄ I, B' = B + dt C + q₃ I,
    # C' = C + q₂ I, each sum in its order there; A's entries in one block, for S = A + R in one call
    A = np.empty((3,) + a00.shape)
    A00, A01, A11 = A
    mul(b00, dt_2, A00)
    add(a00, A00, A00)
    add(A00, mul(c00, dt2), A00)
    add(A00, q4, A00)
    add(b01, b10, A01)
    mul(A01, dt, A01)
    add(a01, A01, A01)
    add(A01, mul(c01, dt2), A01)
    mul(b11, dt_2, A11)
    add(a11, A11, A11)
    add(A11, mul(c11, dt2), A11)
    add(A11, q4, A11)
    B00 = mul(c00, dt)
    add(b00, B00, B00)
    add(B00, q3, B00)
    dc01 = mul(c01, dt)
    B01, B10 = add(b01, dc01), add(b10, dc01)
    B11 = mul(c11, dt)
    add(b11, B11, B11)
    add(B11, q3, B11)
    xp = mul(x[2:], dt)                                   # the predicted position (x, y)
    add(x[:2], xp, xp)
    # S = A⁻ + R and 1/|S|
    r00, r01, r11 = r
    s00, s01, s11 = s_out
    add(A, r, s_out)
    inv_det = mul(s00, s11)
    sub(inv_det, mul(s01, s01), inv_det)
    np.divide(1.0, inv_det, inv_det)
    # the gain (cv_position_gain_components): (first · S_alternate − second · s01) / |S|
    g0, g1, g2, g3, g4, g5, g6, g7 = gain_out
    a01_s01 = mul(A01, s01)
    for g, first, alternate, second_s01 in ((g0, A00, s11, a01_s01), (g1, A01, s00, mul(A00, s01)),
                                            (g2, A01, s11, mul(A11, s01)), (g3, A11, s00, a01_s01),
                                            (g4, B00, s11, mul(B10, s01)), (g5, B10, s00, mul(B00, s01)),
                                            (g6, B01, s11, mul(B11, s01)), (g7, B11, s00, mul(B01, s01))):
        mul(first, alternate, g)
        sub(g, second_s01, g)
        mul(g, inv_det, g)
    # M = R S⁻¹ (cv_position_update_components), alike
    r01_s01 = mul(r01, s01)
    ms = []
    for first, alternate, second_s01 in ((r00, s11, r01_s01), (r01, s00, mul(r00, s01)), (r01, s11, mul(r11, s01)),
                                         (r11, s00, r01_s01)):
        m = mul(first, alternate)
        sub(m, second_s01, m)
        mul(m, inv_det, m)
        ms.append(m)
    m00, m01, m10, m11 = ms
    # the posterior: A⁺ = M A, B⁺ = M B, C⁺ = C − K_vel B
    n00, n01, n11, n_b00, n_b01, n_b10, n_b11, n_c00, n_c01, n_c11 = c_out
    for n, m_left, left, m_right, right in ((n00, m00, A00, m01, A01), (n01, m00, A01, m01, A11),
                                            (n11, m10, A01, m11, A11), (n_b00, m00, B00, m01, B10),
                                            (n_b01, m00, B01, m01, B11), (n_b10, m10, B00, m11, B10),
                                            (n_b11, m10, B01, m11, B11)):
        mul(m_left, left, n)
        add(n, mul(m_right, right), n)
    for n, C, k_left, left, k_right, right in ((n_c00, c00, g4, B00, g5, B10), (n_c01, c01, g4, B01, g5, B11),
                                               (n_c11, c11, g6, B01, g7, B11)):
        t = mul(k_left, left)
        add(t, mul(k_right, right), t)
        if C is c00 or C is c11:
            sub(add(C, q2), t, n)               # C⁻ = C + q₂ on the diagonal
        else:
            sub(C, t, n)
    # the state (cv_apply_gain_components): x⁻ + K ν
    sub(z, xp, nu_out)
    nu0, nu1 = nu_out
    for out, before, k0, k1 in zip(x_out, (xp[0], xp[1], x[2], x[3]), (g0, g2, g4, g6), (g1, g3, g5, g7)):
        mul(k0, nu0, out)
        add(before, out, out)
        add(out, mul(k1, nu1), out)


# --------------------------------------------------------------------------- CV kernel, scan axis


#: Up to this many runs, the scan-axis recursions below run on Python floats, run by run.
SCALAR_RUNS = 4

def _cv_states_with_gains(x, gain, zx, zy, dt, scalar_runs: int = SCALAR_RUNS):
    """The states of ``L`` scans of a CV filter whose gains ``(8, L, runs)`` are known:
    ``x⁻ = F x``, ``x = x⁻ + K (z − H x⁻)`` with position measurements ``zx``, ``zy`` ``(L, runs)``
    and scan intervals ``dt`` ``(L,)``; ``x`` ``(4, runs)`` enters, ``(4, L, runs)`` leaves.

    A fast form of :func:`cv_predict_components` then :func:`cv_apply_gain_components` scan after
    scan: the same operations in the same order, so the same numbers to the bit
    (tests/test_kalman.py). Up to ``scalar_runs`` runs it runs on Python floats, run by run (a
    scan is then some twenty float operations instead of as many NumPy calls on one-element
    arrays); beyond, one scan at a time on arrays over the runs.
    """
    L, n_runs = zx.shape
    out = np.empty((4, L, n_runs))
    if n_runs <= scalar_runs:
        dts = dt.tolist()
        for r in range(n_runs):
            x0, x1, x2, x3 = x[:, r].tolist()
            rows = []
            for d, zxj, zyj, g0, g1, g2, g3, g4, g5, g6, g7 in zip(dts, zx[:, r].tolist(), zy[:, r].tolist(),
                                                                     *gain[:, :, r].tolist()):
                p0 = x0 + d * x2
                p1 = x1 + d * x3
                n0 = zxj - p0
                n1 = zyj - p1
                x0 = p0 + g0 * n0 + g1 * n1
                x1 = p1 + g2 * n0 + g3 * n1
                x2 = x2 + g4 * n0 + g5 * n1
                x3 = x3 + g6 * n0 + g7 * n1
                rows.append((x0, x1, x2, x3))
            out[:, :, r] = np.fromiter(chain.from_iterable(rows), float, 4 * L).reshape(L, 4).T
        return out
    for j in range(L):
        d = float(dt[j])
        xp = np.empty_like(x)
        xp[:2] = x[:2] + d * x[2:]
        xp[2:] = x[2:]
        nu = np.stack([zx[j] - xp[0], zy[j] - xp[1]])
        x = out[:, j] = cv_apply_gain_components(xp, gain[:, j], nu)
    return out


def _cv_position_filter_covariances(c, r_cov, dt, sigma_v: float, scalar_runs: int = SCALAR_RUNS):
    """The covariance recursion of a CV Kalman filter with a position measurement each scan (it
    does not depend on the states): :func:`cv_predict_components` then
    :func:`cv_position_update_components` for ``L`` scans, from the components ``c`` ``(10, runs)``,
    with measurement covariances ``r_cov = (r00, r01, r11)`` each ``(L, runs)`` and intervals
    ``dt`` ``(L,)``. Returns the gains ``(8, L, runs)`` and posterior covariances ``(10, L, runs)``.

    A fast form of those two functions: up to ``scalar_runs`` runs on Python floats, written as
    they write it (the same numbers to the bit, tests/test_kalman.py); beyond, their own calls
    one scan at a time."""
    r00, r01, r11 = r_cov
    L, n_runs = r00.shape
    gains = np.empty((8, L, n_runs))
    posts = np.empty((10, L, n_runs))
    if n_runs > scalar_runs:
        x = np.zeros((4, n_runs))
        for j in range(L):
            _, cp = cv_predict_components(x, c, float(dt[j]), sigma_v)
            gains[:, j], c = cv_position_update_components_fast(cp, r00[j], r01[j], r11[j])
            posts[:, j] = c
        return gains, posts
    q = sigma_v * sigma_v
    for r in range(n_runs):
        a00, a01, a11, b00, b01, b10, b11, c00, c01, c11 = c[:, r].tolist()
        g_rows, c_rows = [], []
        for d, q00, q01, q11 in zip(dt.tolist(), r00[:, r].tolist(), r01[:, r].tolist(), r11[:, r].tolist()):
            # cv_predict_components
            q4, q3, q2 = q * d**4 / 4, q * d**3 / 2, q * d * d
            d2 = d * d
            a00, a01, a11, b00, b01, b10, b11, c00, c11 = (
                a00 + 2 * d * b00 + d2 * c00 + q4, a01 + d * (b01 + b10) + d2 * c01, a11 + 2 * d * b11 + d2 * c11 + q4,
                b00 + d * c00 + q3, b01 + d * c01, b10 + d * c01, b11 + d * c11 + q3, c00 + q2, c11 + q2)
            # cv_position_gain_components
            s00, s01, s11 = a00 + q00, a01 + q01, a11 + q11
            inv_det = 1.0 / (s00 * s11 - s01 * s01)
            g = ((a00 * s11 - a01 * s01) * inv_det, (a01 * s00 - a00 * s01) * inv_det,
                 (a01 * s11 - a11 * s01) * inv_det, (a11 * s00 - a01 * s01) * inv_det,
                 (b00 * s11 - b10 * s01) * inv_det, (b10 * s00 - b00 * s01) * inv_det,
                 (b01 * s11 - b11 * s01) * inv_det, (b11 * s00 - b01 * s01) * inv_det)
            # cv_position_update_components (its S and 1/det are the gain's, recomputed alike)
            m00 = (q00 * s11 - q01 * s01) * inv_det
            m01 = (q01 * s00 - q00 * s01) * inv_det
            m10 = (q01 * s11 - q11 * s01) * inv_det
            m11 = (q11 * s00 - q01 * s01) * inv_det
            a00, a01, a11, b00, b01, b10, b11, c00, c01, c11 = (
                m00 * a00 + m01 * a01, m00 * a01 + m01 * a11, m10 * a01 + m11 * a11,
                m00 * b00 + m01 * b10, m00 * b01 + m01 * b11, m10 * b00 + m11 * b10, m10 * b01 + m11 * b11,
                c00 - (g[4] * b00 + g[5] * b10), c01 - (g[4] * b01 + g[5] * b11), c11 - (g[6] * b01 + g[7] * b11))
            g_rows.append(g)
            c_rows.append((a00, a01, a11, b00, b01, b10, b11, c00, c01, c11))
        gains[:, :, r] = np.fromiter(chain.from_iterable(g_rows), float, 8 * L).reshape(L, 8).T
        posts[:, :, r] = np.fromiter(chain.from_iterable(c_rows), float, 10 * L).reshape(L, 10).T
    return gains, posts


def _cv_predict_components_scans(x, c, dt, sigma_v: float):
    """:func:`cv_predict_components` of ``(4, L, runs)`` states and ``(10, L, runs)`` covariances,
    scan ``j`` predicted over ``dt[j]`` (``dt`` ``(L,)``): many scans in one call, the same numbers
    to the bit (the process-noise terms are formed on Python floats, as there)."""
    q = sigma_v * sigma_v
    dts = dt.tolist()
    q4 = np.array([q * d**4 / 4 for d in dts])[:, None]
    q3 = np.array([q * d**3 / 2 for d in dts])[:, None]
    q2 = np.array([q * d * d for d in dts])[:, None]
    return _cv_predict_terms(x, c, dt[:, None], q4, q3, q2)
