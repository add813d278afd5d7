"""TDOA/FDOA measurement model g(θ) and its analytic Jacobian, for any list of sensor pairs.

Kim et al. (2013), eqs. 1–5 and 9–14 (see ``docs/papers/tdoa-fdoa.md``).
Emitter θ = [x, y, ẋ, ẏ] (position p, velocity v); sensors s_i, ṡ_i::

    r_i = ‖p − s_i‖                                  (1)
    ṙ_i = (v − ṡ_i)ᵀ (p − s_i) / r_i                 (3)
    τ_k = (r_i − r_j) / c          k = (i, j)        (2)
    f_k = (f₀ / c) (ṙ_i − ṙ_j)                       (4)
    g(θ) = [τ₁ … τ_N, f₁ … f_N]                      (5)

Jacobian (eq. 9), derived from the model rather than copied from the paper, whose printed
∂τ/∂p (eq. 10) has the opposite sign; every entry is tested against central differences::

    ∂r_i/∂p = u_iᵀ,  u_i = (p − s_i)/r_i
    ∂ṙ_i/∂p = ((v − ṡ_i) − ṙ_i u_i)ᵀ / r_i              (eqs. 12–13, corrected)
    ∂ṙ_i/∂v = u_iᵀ        ⇒ ∂f/∂v = f₀ ∂τ/∂p           (eq. 14)
    ∂τ/∂v  = 0                                         (eq. 11)

All functions broadcast over leading axes: θ (..., 4) against sensors (..., M, 2), so one call
evaluates every Monte Carlo run (or every point of a CEP plane) at once. SI units throughout.
"""

from __future__ import annotations

import itertools

import numpy as np

SPEED_OF_LIGHT_MPS = 299_792_458.0
STATE_NAMES = ("x_m", "y_m", "vx_mps", "vy_mps")
POSITION = (0, 1)
VELOCITY = (2, 3)
#: Which measurement rows each estimator uses.
MEASUREMENT_KINDS = ("joint", "tdoa", "fdoa")


def ranges_and_rates(theta, sensor_pos, sensor_vel):
    """Ranges r_i, range rates ṙ_i, unit vectors u_i and relative velocities v − ṡ_i.

    Parameters
    ----------
    theta : ndarray (..., 4)
    sensor_pos, sensor_vel : ndarray (..., M, 2)

    Returns
    -------
    r, rdot : ndarray (..., M)
    u, w : ndarray (..., M, 2)
    """
    theta = np.asarray(theta, float)
    d = theta[..., None, :2] - sensor_pos
    r = np.sqrt(np.sum(d * d, axis=-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = d / r[..., None]
    w = theta[..., None, 2:] - sensor_vel
    rdot = np.sum(w * u, axis=-1)
    return r, rdot, u, w


def measurement_model(theta, sensor_pos, sensor_vel, pairs, carrier_hz, jacobian: bool = True):
    """Noise-free TDOA and FDOA of every pair, and optionally the Jacobian ∂g/∂θ.

    Parameters
    ----------
    theta : ndarray (..., 4)
        Emitter state [x, y, ẋ, ẏ] in m and m/s.
    sensor_pos, sensor_vel : ndarray (..., M, 2)
        Sensor positions (m) and velocities (m/s), broadcast against ``theta``'s leading axes.
    pairs : ndarray of int (N, 2)
        Sensor pairs (i, j); any list, no common reference sensor needed.
    carrier_hz : float or ndarray (...)
        Carrier frequency f₀.
    jacobian : bool
        Also return H.

    Returns
    -------
    g : ndarray (..., 2N)
        [τ₁ … τ_N (s), f₁ … f_N (Hz)].
    H : ndarray (..., 2N, 4), only if ``jacobian``
        Rows in the order of ``g``, columns [x, y, ẋ, ẏ].

    Notes
    -----
    Gauss-Newton evaluates this once per iteration, on one run as often as on thousands, so
    the number and the shape of the array operations matter more than the arithmetic: the
    coordinate and sensor axes are moved in front (views, no copies) so that every operation
    runs over the long leading (run or grid) axes instead of trailing axes of length 2 or M;
    the per-sensor quantities are written into one array and the pair differences are one
    gather of it (``take``: a third of the fixed cost of fancy indexing); g and H are filled
    in place. The arithmetic is that of :func:`ranges_and_rates` and eqs. 2–4, 9–14
    operation for operation, so the results are the same to the last bit.
    """
    theta = np.asarray(theta, float)
    sensor_pos = np.asarray(sensor_pos, float)
    sensor_vel = np.asarray(sensor_vel, float)
    carrier_hz = np.asarray(carrier_hz, float)
    i, j = np.asarray(pairs, dtype=np.int64).T
    n = len(i)
    c = SPEED_OF_LIGHT_MPS
    # the leading (broadcast) axes: pad every input to the same number so that they line up
    # once the coordinate and sensor axes are in front
    nd = max(theta.ndim - 1, sensor_pos.ndim - 2, sensor_vel.ndim - 2, carrier_hz.ndim)
    lead = tuple(range(nd))
    # (..., 4) → (4, ...) and (..., M, 2) → (2, M, ...), each padded to nd leading axes. A
    # contiguous copy of θ: the arrays computed from it are then laid out with the run axes
    # innermost (numpy allocates results in the inputs' memory order)
    if theta.ndim != nd + 1:
        theta = theta.reshape((1,) * (nd + 1 - theta.ndim) + theta.shape)
    if sensor_pos.ndim != nd + 2:
        sensor_pos = sensor_pos.reshape((1,) * (nd + 2 - sensor_pos.ndim) + sensor_pos.shape)
    if sensor_vel.ndim != nd + 2:
        sensor_vel = sensor_vel.reshape((1,) * (nd + 2 - sensor_vel.ndim) + sensor_vel.shape)
    th = np.ascontiguousarray(theta.transpose(nd, *lead))
    d = th[:2, None] - sensor_pos.transpose(nd + 1, nd, *lead)       # (2, M, ...)
    w = th[2:, None] - sensor_vel.transpose(nd + 1, nd, *lead)
    if carrier_hz.ndim != nd:
        carrier_hz = carrier_hz.reshape((1,) * (nd - carrier_hz.ndim) + carrier_hz.shape)
    k_f = carrier_hz / c
    # per sensor, sensor axis second: [r, ṙ] and, for H, [u_x, u_y, ∂ṙ/∂x, ∂ṙ/∂y]
    per = np.empty(((6,) if jacobian else (2,)) + d.shape[1:])
    r, rdot = per[0], per[1]
    np.sqrt(np.add.reduce(d * d, axis=0), out=r)  # np.sum without its wrapper: the same sums
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.divide(d, r, out=per[2:4]) if jacobian else d / r
        np.add.reduce(w * u, axis=0, out=rdot)
        if jacobian:
            np.divide(w - rdot * u, r, out=per[4:6])
    diff = per.take(i, axis=1) - per.take(j, axis=1)  # (·, N, ...)
    g = np.empty(diff.shape[2:] + (2 * n,))
    g_t = g.transpose(nd, *lead)
    np.divide(diff[0], c, out=g_t[:n])
    np.multiply(k_f, diff[1], out=g_t[n:])
    if not jacobian:
        return g
    H = np.zeros(g.shape + (4,))                  # ∂τ/∂v = 0 (eq. 11)
    H_t = H.transpose(nd, nd + 1, *lead)          # (2N, 4, ...)
    du = diff[2:4].swapaxes(0, 1)                 # (N, 2, ...)
    np.divide(du, c, out=H_t[:n, :2])
    np.multiply(k_f, diff[4:6].swapaxes(0, 1), out=H_t[n:, :2])
    np.multiply(k_f, du, out=H_t[n:, 2:])
    return g, H


def measurement_rows(kind: str, n_pairs: int) -> np.ndarray:
    """Indexes into g of the measurements an estimator uses (``joint``, ``tdoa`` or ``fdoa``)."""
    if kind == "joint":
        return np.arange(2 * n_pairs)
    if kind == "tdoa":
        return np.arange(n_pairs)
    if kind == "fdoa":
        return np.arange(n_pairs, 2 * n_pairs)
    raise ValueError(f"unknown measurement kind {kind!r} (have: {', '.join(MEASUREMENT_KINDS)})")


def unknowns(kind: str, stationary: bool) -> np.ndarray:
    """State components an estimator solves for.

    TDOA does not depend on velocity, so TDOA-only estimates position only; a stationary
    emitter (velocity known to be zero, the paper's Fig. 7) has position unknowns only.
    """
    if stationary or kind == "tdoa":
        return np.array(POSITION)
    return np.arange(4)


def independent_differences(pairs, n_sensors: int) -> int:
    """How many of the pair differences (r_i − r_j) are linearly independent.

    The differences of a pair list are the edges of a graph on the sensors; their span has
    dimension (sensors touched) − (connected components). Three sensors with pairs a–b, b–c,
    a–c give 2: τ_ac = τ_ab + τ_bc. The same count holds for FDOA.
    """
    parent = list(range(n_sensors))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    touched = set()
    for a, b in np.asarray(pairs, dtype=np.int64):
        touched.update((int(a), int(b)))
        ra, rb = find(int(a)), find(int(b))
        if ra != rb:
            parent[ra] = rb
    components = len({find(a) for a in touched})
    return len(touched) - components


def independent_equations(kind: str, pairs, n_sensors: int) -> int:
    """Independent scalar equations an estimator gets per epoch (structurally, any geometry)."""
    per_type = independent_differences(pairs, n_sensors)
    return 2 * per_type if kind == "joint" else per_type


def all_pairs(n_sensors: int) -> np.ndarray:
    """Every pair (i < j) of ``n_sensors`` sensors."""
    return np.array(list(itertools.combinations(range(n_sensors), 2)), dtype=np.int64).reshape(-1, 2)


def underdetermined_reason(kind: str, pairs, n_sensors: int, stationary: bool) -> str | None:
    """Why an estimator cannot run on this pair list (None if it can)."""
    n_eq = independent_equations(kind, pairs, n_sensors)
    q = len(unknowns(kind, stationary))
    if n_eq < q:
        pair_text = ",".join(f"{i}-{j}" for i, j in pairs)
        return (f"{kind}: pairs {pair_text} give {n_eq} independent equation(s) for {q} unknowns")
    return None


def equivalent_sigmas(sigma, carrier_hz, n_pairs: int) -> tuple[np.ndarray, np.ndarray]:
    """Measurement noise in range units per epoch: σ_r = c σ_TDOA (m) and σ_v = c σ_FDOA / f₀ (m/s).

    The paper's Fig. 7 axis (0.1 σ_r = σ_v), averaged over runs and pairs.

    Parameters
    ----------
    sigma : ndarray (R, E, 2N)
        σ of each measurement in g's layout (σ_TDOA for the N TDOAs, then σ_FDOA).
    carrier_hz : ndarray (R, E)
    n_pairs : int

    Returns
    -------
    sigma_range_m, sigma_rate_mps : ndarray (E,)
    """
    sigma = np.asarray(sigma, float)
    n = int(n_pairs)
    sigma_r = SPEED_OF_LIGHT_MPS * np.mean(sigma[..., :n], axis=(0, 2))
    sigma_v = SPEED_OF_LIGHT_MPS * np.mean(sigma[..., n:] / np.asarray(carrier_hz, float)[..., None], axis=(0, 2))
    return sigma_r, sigma_v
