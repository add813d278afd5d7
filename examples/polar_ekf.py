"""A plugged tracker: an extended Kalman filter updated in range and bearing.

Run it beside the built-in radar trackers::

    replay data/radar_tws_demo.mcap --tracker examples/polar_ekf.py:PolarEKF

The built-in ``kalman`` reference converts each plot to Cartesian ``(r cos θ, r sin θ)`` and
linearises the *noise* (converted covariance ``R = D diag(σ_r², r²σ_θ²) Dᵀ``). This filter keeps
the plot polar and linearises the *measurement function* instead (the extended Kalman filter of
Bar-Shalom, Li & Kirubarajan 2001, §10.3):

* state ``x = [x, y, ẋ, ẏ]`` (m, m/s), radar at the origin;
* motion: constant velocity driven by piecewise-constant white acceleration of standard deviation
  σ_v (Bar-Shalom et al. 2001, §6.3.2), per axis ``Q = σ_v² [[dt⁴/4, dt³/2], [dt³/2, dt²]]`` with
  the scan's own interval ``dt`` — the same Q as the built-ins;
* measurement ``z = h(x) + w`` with ``h(x) = (√(x² + y²), atan2(y, x))`` (bearing from the +x axis
  towards +y, as in :class:`trackreplay.trackers.interface.RadarPlots`) and
  ``R = diag(σ_r², σ_θ²)``;
* Jacobian ``H = [[x/ρ, y/ρ, 0, 0], [−y/ρ², x/ρ², 0, 0]]`` at the prediction, ``ρ = √(x² + y²)``;
* bearing innovation wrapped to (−π, π], so a target crossing the ±π bearing does not see a 2π jump;
* gain ``K = P Hᵀ S⁻¹`` from a 2×2 solve (Cramer's rule, no matrix inverse); covariance in the Joseph
  form ``(I − KH) P (I − KH)ᵀ + K R Kᵀ``, symmetrised.

Track start and plot choice are those of the built-ins (``track_plots`` in
``pipeline/trackers/radar_tws.py``, ``docs/papers/radar.md``): the first plot is remembered,
the second gives position and velocity difference with the two-point covariance
``[[R₁, R₁/Δt], [R₁/Δt, (R₀ + R₁)/Δt²]]`` (``R`` the converted covariance of each plot), filtering
starts at the third plot, and when a scan holds several plots the one nearest (in x/y) to the
predicted position is used. Flags: ``NO_TRACK`` before a track exists, ``INITIALISING`` at the
start scan, ``COASTED`` when a started track's scan has no plot (the state is the prediction).

Its ``innovation`` is (range m, bearing rad), not the converted x/y of the built-ins, and it
returns no ``measurement``: the radar evaluator's ``rms_innovation_m`` (metres) is therefore
left empty for it, while position/velocity RMSE, NPE and the consistency scores are computed
as for any tracker.

All Monte Carlo runs are filtered together (batch form): arrays carry the run axis first and
the loop is over scans only. ``docs/trackers.md`` compares it with the built-ins on the demo.
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay import Param, Tracker


def wrap_angle(a):
    """Angle(s) wrapped to (−π, π]."""
    return a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))


def cv_model(dt: float, sigma_v: float):
    """Transition ``F`` and white-acceleration ``Q`` (4×4, state order [x, y, ẋ, ẏ])."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    q = sigma_v * sigma_v
    Q = np.zeros((4, 4))
    Q[0, 0] = Q[1, 1] = q * dt**4 / 4.0
    Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = q * dt**3 / 2.0
    Q[2, 2] = Q[3, 3] = q * dt * dt
    return F, Q


def converted_covariance(r, cos_b, sin_b, sigma_r: float, sigma_b: float):
    """``D diag(σ_r², r²σ_θ²) Dᵀ`` per plot, ``(n, 2, 2)`` (for the two-point start)."""
    along, cross = sigma_r**2, (r * sigma_b) ** 2
    out = np.empty(r.shape + (2, 2))
    out[:, 0, 0] = along * cos_b**2 + cross * sin_b**2
    out[:, 0, 1] = out[:, 1, 0] = (along - cross) * cos_b * sin_b
    out[:, 1, 1] = along * sin_b**2 + cross * cos_b**2
    return out


def solve_2x2(S, B):
    """``S⁻¹ B`` for symmetric 2×2 ``S`` ``(n, 2, 2)`` and ``B`` ``(n, 2, m)`` by Cramer's rule."""
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    out = np.empty_like(B)
    out[:, 0] = (S[:, 1, 1, None] * B[:, 0] - S[:, 0, 1, None] * B[:, 1]) / det[:, None]
    out[:, 1] = (S[:, 0, 0, None] * B[:, 1] - S[:, 1, 0, None] * B[:, 0]) / det[:, None]
    return out


def ekf_update(x, P, z_range, z_bearing, R):
    """EKF update in range and bearing for ``n`` tracks at once.

    Parameters
    ----------
    x : ndarray (n, 4)
        Predicted states.
    P : ndarray (n, 4, 4)
        Predicted covariances.
    z_range, z_bearing : ndarray (n,)
        The plots (m, rad).
    R : ndarray (2, 2)
        ``diag(σ_r², σ_θ²)``.

    Returns
    -------
    x_post (n, 4), P_post (n, 4, 4), innovation (n, 2), S (n, 2, 2), K (n, 4, 2)
    """
    px, py = x[:, 0], x[:, 1]
    rho2 = px * px + py * py
    rho = np.sqrt(rho2)
    H = np.zeros((x.shape[0], 2, 4))
    H[:, 0, 0], H[:, 0, 1] = px / rho, py / rho
    H[:, 1, 0], H[:, 1, 1] = -py / rho2, px / rho2
    nu = np.stack([z_range - rho, wrap_angle(z_bearing - np.arctan2(py, px))], axis=-1)
    PHt = P @ np.swapaxes(H, -1, -2)                     # (n, 4, 2)
    S = H @ PHt + R
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    K = np.swapaxes(solve_2x2(S, np.swapaxes(PHt, -1, -2)), -1, -2)  # K = P Hᵀ S⁻¹ (S symmetric)
    x_post = x + np.einsum("nij,nj->ni", K, nu)
    A = np.eye(4) - K @ H
    P_post = A @ P @ np.swapaxes(A, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    return x_post, 0.5 * (P_post + np.swapaxes(P_post, -1, -2)), nu, S, K


def select_plots(rng, brg, counts, x_pred, started):
    """The plot each run uses this scan: the first for runs without a track, else the one nearest
    (x/y) to the predicted position; NaN where the scan has none. ``rng``, ``brg`` : (R, W)."""
    n, width = rng.shape
    if width == 0:
        return np.full(n, np.nan), np.full(n, np.nan)
    valid = np.arange(width)[None, :] < counts[:, None]
    dx = rng * np.cos(brg) - x_pred[:, 0, None]
    dy = rng * np.sin(brg) - x_pred[:, 1, None]
    d2 = np.where(valid, dx * dx + dy * dy, np.inf)
    j = np.where(started, np.argmin(d2, axis=1), np.argmax(valid, axis=1))
    rows = np.arange(n)
    has = counts > 0
    return np.where(has, rng[rows, j], np.nan), np.where(has, brg[rows, j], np.nan)


class PolarEKF(Tracker):
    """Extended Kalman filter on polar plots, constant-velocity motion (see the module docstring).

    Parameters (``replay --set NAME=VALUE``; the default ``None`` takes the value recorded in the
    data set's radar-tws scenario, exactly as for the built-in trackers)
    ----------
    design_sigma_v_mps2 : float
        Design acceleration noise σ_v (m/s²) of the white-acceleration model.
    sigma_range_m : float
        Range noise σ_r the filter assumes (m).
    sigma_bearing_deg : float
        Bearing noise σ_θ the filter assumes (degrees; radians inside).
    """

    name = "polar_ekf"
    label = "polar EKF"
    family = "radar"
    form = "batch"
    params = (
        Param("design_sigma_v_mps2", None, "m/s²", "design acceleration noise σ_v (white-acceleration CV model)", low=0.0),
        Param("sigma_range_m", None, "m", "plot range noise σ_r the EKF assumes", low=0.0),
        Param("sigma_bearing_deg", None, "deg", "plot bearing noise σ_θ the EKF assumes", low=0.0),
    )

    def __init__(self, **design):
        super().__init__(**design)  # checks every value against its Param's bounds
        self.sigma_v = float(self.design_sigma_v_mps2)
        self.sigma_r = float(self.sigma_range_m)
        self.sigma_b = float(np.deg2rad(self.sigma_bearing_deg))

    def track(self, plots):
        """Filter every run of ``plots`` (:class:`~trackreplay.trackers.interface.RadarPlots`).

        Returns
        -------
        dict
            ``state (R, K, 4)``, ``covariance (R, K, 4, 4)``, ``flags (R, K)``, ``innovation
            (R, K, 2)`` as (range m, bearing rad), ``innovation_covariance (R, K, 2, 2)`` and
            ``gain (R, K, 4, 2)``; NaN where the quantity does not exist (no track, no update).
        """
        rng = np.asarray(plots.range_m, float)
        brg = np.asarray(plots.bearing_rad, float)
        counts = np.asarray(plots.counts)
        times = np.asarray(plots.times_s, float)
        n_runs, n_scans = counts.shape
        rng = rng.reshape(n_runs, n_scans, -1)
        brg = brg.reshape(n_runs, n_scans, -1)
        R = np.diag([self.sigma_r**2, self.sigma_b**2])

        state = np.full((n_runs, n_scans, 4), np.nan)
        cov = np.full((n_runs, n_scans, 4, 4), np.nan)
        innov = np.full((n_runs, n_scans, 2), np.nan)
        s_out = np.full((n_runs, n_scans, 2, 2), np.nan)
        k_out = np.full((n_runs, n_scans, 4, 2), np.nan)
        flags = np.zeros((n_runs, n_scans), np.uint32)

        x = np.zeros((n_runs, 4))
        P = np.zeros((n_runs, 4, 4))
        started = np.zeros(n_runs, bool)
        have_first = np.zeros(n_runs, bool)
        first_xy = np.zeros((n_runs, 2))
        first_R = np.zeros((n_runs, 2, 2))
        first_t = np.zeros(n_runs)
        for k in range(n_scans):
            has = counts[:, k] > 0
            if started.any():
                dt = float(times[k] - times[k - 1])
                F, Q = cv_model(dt, self.sigma_v)
                s = started
                x[s] = x[s] @ F.T
                Pp = F @ P[s] @ F.T + Q
                P[s] = 0.5 * (Pp + np.swapaxes(Pp, -1, -2))
            z_r, z_b = select_plots(rng[:, k], brg[:, k], counts[:, k], x, started)

            upd = np.flatnonzero(started & has)
            if upd.size:
                x[upd], P[upd], innov[upd, k], s_out[upd, k], k_out[upd, k] = ekf_update(
                    x[upd], P[upd], z_r[upd], z_b[upd], R)
            flags[started & ~has, k] |= vocab.COASTED

            # two-point start (converted plots, as the built-ins)
            init = np.flatnonzero(~started & has & have_first)
            if init.size:
                c, s_ = np.cos(z_b[init]), np.sin(z_b[init])
                zx, zy = z_r[init] * c, z_r[init] * s_
                R1 = converted_covariance(z_r[init], c, s_, self.sigma_r, self.sigma_b)
                gap = (times[k] - first_t[init])[:, None, None]
                x[init] = np.stack([zx, zy, (zx - first_xy[init, 0]) / gap[:, 0, 0],
                                    (zy - first_xy[init, 1]) / gap[:, 0, 0]], axis=-1)
                P[init] = np.block([[R1, R1 / gap], [R1 / gap, (first_R[init] + R1) / gap**2]])
                flags[init, k] |= vocab.INITIALISING
                started[init] = True
            first = np.flatnonzero(~started & has & ~have_first)
            if first.size:
                c, s_ = np.cos(z_b[first]), np.sin(z_b[first])
                first_xy[first] = np.stack([z_r[first] * c, z_r[first] * s_], axis=-1)
                first_R[first] = converted_covariance(z_r[first], c, s_, self.sigma_r, self.sigma_b)
                first_t[first] = times[k]
                have_first[first] = True
            flags[~started, k] |= vocab.NO_TRACK
            state[started, k] = x[started]
            cov[started, k] = P[started]
        return {"state": state, "covariance": cov, "flags": flags, "innovation": innov,
                "innovation_covariance": s_out, "gain": k_out}
