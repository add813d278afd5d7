"""A plugged tracker in the per-run form: FilterPy's ``KalmanFilter`` on converted plots.

Run it beside the built-in radar trackers::

    replay data/radar_tws_demo.mcap --tracker examples/filterpy_kf.py:FilterPyKF

This is an adapter: a ``filterpy.kalman.KalmanFilter`` (Labbe, *Kalman and Bayesian Filters in
Python*) configured to do what the built-in ``kalman`` reference tracker does
(``pipeline/trackers/radar_tws.py``, ``docs/papers/radar.md``), scan by scan and one run at
a time:

* each plot ``(r, θ)`` is converted to ``z = (r cos θ, r sin θ)`` with the converted covariance
  ``R = D diag(σ_r², r²σ_θ²) Dᵀ`` (``D`` the rotation by θ), passed to ``update(z, R=R)``;
* ``F`` and the white-acceleration ``Q = σ_v² [[dt⁴/4, dt³/2], [dt³/2, dt²]]`` per axis
  (Bar-Shalom, Li & Kirubarajan 2001, §6.3.2) are set before each ``predict()`` with the scan's
  own interval ``dt``;
* two-point start: state ``[z₁, (z₁ − z₀)/Δt]``, covariance ``[[R₁, R₁/Δt], [R₁/Δt, (R₀ + R₁)/Δt²]]``,
  filtering from the third plot; the plot nearest (x/y) to the predicted position when a scan
  holds several, the first plot while no track exists;
* flags ``NO_TRACK`` before the track exists, ``INITIALISING`` at its start scan, ``COASTED``
  when a scan has no plot (the state is then FilterPy's prediction).

FilterPy updates the covariance in the Joseph form and the built-in in the short form
``P − KHP``; for the optimal gain both are the same matrix, so on the bundled demo the two
trackers' states and covariances agree to rounding (``tests/test_examples.py`` checks ≤ 1e-9
relative).

Form ``"run"``: the pipeline calls :meth:`FilterPyKF.track_run` once per Monte Carlo run with
that run's plots (no run axis) and stacks the results; that costs one Python call per run and
here one FilterPy ``predict``/``update`` per scan, far more than the built-in's vectorised loop
(see ``docs/trackers.md``).
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter

from trackreplay import vocabulary as vocab
from trackreplay import Param, Tracker


def _cv(dt: float, sigma_v: float):
    """``F`` and white-acceleration ``Q`` for state [x, y, ẋ, ẏ]."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    q = sigma_v * sigma_v
    Q = np.zeros((4, 4))
    Q[0, 0] = Q[1, 1] = q * dt**4 / 4.0
    Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = q * dt**3 / 2.0
    Q[2, 2] = Q[3, 3] = q * dt * dt
    return F, Q


def _converted(r: float, theta: float, sigma_r: float, sigma_b: float):
    """Converted plot ``(x, y)`` and its covariance ``D diag(σ_r², r²σ_θ²) Dᵀ``."""
    c, s = np.cos(theta), np.sin(theta)
    along, cross = sigma_r**2, (r * sigma_b) ** 2
    R = np.array([[along * c * c + cross * s * s, (along - cross) * c * s],
                  [(along - cross) * c * s, along * s * s + cross * c * c]])
    return np.array([r * c, r * s]), R


class FilterPyKF(Tracker):
    """FilterPy Kalman filter on converted plots, the built-in ``kalman`` reference re-done.

    Parameters (``replay --set NAME=VALUE``; ``None`` takes the data set's recorded radar-tws
    scenario value, as for the built-ins)
    ----------
    design_sigma_v_mps2 : float
        Design acceleration noise σ_v (m/s²).
    sigma_range_m : float
        Range noise σ_r (m) of the converted covariance.
    sigma_bearing_deg : float
        Bearing noise σ_θ (degrees; radians inside) of the converted covariance.
    """

    name = "filterpy_kf"
    label = "FilterPy KF"
    family = "radar"
    form = "run"
    params = (
        Param("design_sigma_v_mps2", None, "m/s²", "design acceleration noise σ_v", low=0.0),
        Param("sigma_range_m", None, "m", "plot range noise σ_r of the converted covariance", low=0.0),
        Param("sigma_bearing_deg", None, "deg", "plot bearing noise σ_θ of the converted covariance", low=0.0),
    )

    def __init__(self, **design):
        super().__init__(**design)  # checks every value against its Param's bounds
        self.sigma_v = float(self.design_sigma_v_mps2)
        self.sigma_r = float(self.sigma_range_m)
        self.sigma_b = float(np.deg2rad(self.sigma_bearing_deg))

    def track_run(self, plots):
        """Filter one run (:class:`~trackreplay.trackers.interface.RadarPlots` without its run axis:
        ``range_m``, ``bearing_rad`` ``(K, W)``, ``counts`` ``(K,)``).

        Returns
        -------
        dict
            ``state (K, 4)``, ``covariance (K, 4, 4)``, ``flags (K,)``, ``innovation (K, 2)``
            (converted x/y, m), ``innovation_covariance (K, 2, 2)``, ``gain (K, 4, 2)`` and
            ``measurement (K, 2)``, the converted plot used (NaN when the scan had none).
        """
        times = np.asarray(plots.times_s, float)
        counts = np.asarray(plots.counts)
        n_scans = len(times)
        rng = np.asarray(plots.range_m, float).reshape(n_scans, -1)
        brg = np.asarray(plots.bearing_rad, float).reshape(n_scans, -1)

        state = np.full((n_scans, 4), np.nan)
        cov = np.full((n_scans, 4, 4), np.nan)
        innov = np.full((n_scans, 2), np.nan)
        s_out = np.full((n_scans, 2, 2), np.nan)
        k_out = np.full((n_scans, 4, 2), np.nan)
        used = np.full((n_scans, 2), np.nan)
        flags = np.zeros(n_scans, np.uint32)

        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
        started = False
        first = None  # (time, z, R) of the first plot
        for k in range(n_scans):
            if started:
                kf.F, kf.Q = _cv(float(times[k] - times[k - 1]), self.sigma_v)
                kf.predict()
            z = R = None
            if counts[k] > 0:
                j = 0
                if started and counts[k] > 1:
                    xy = rng[k, :counts[k], None] * np.stack([np.cos(brg[k, :counts[k]]),
                                                              np.sin(brg[k, :counts[k]])], axis=-1)
                    j = int(np.argmin(np.sum((xy - kf.x[:2, 0]) ** 2, axis=-1)))
                z, R = _converted(rng[k, j], brg[k, j], self.sigma_r, self.sigma_b)
                used[k] = z
            if started and z is not None:
                kf.update(z, R=R)
                innov[k], s_out[k], k_out[k] = kf.y[:, 0], kf.S, kf.K
            elif started:
                flags[k] |= vocab.COASTED
            elif z is not None and first is not None:
                t0, z0, R0 = first
                gap = times[k] - t0
                kf.x = np.concatenate([z, (z - z0) / gap])[:, None]
                kf.P = np.block([[R, R / gap], [R / gap, (R0 + R) / gap**2]])
                flags[k] |= vocab.INITIALISING
                started = True
            elif z is not None:
                first = (times[k], z, R)
            if started:
                state[k], cov[k] = kf.x[:, 0], kf.P
            else:
                flags[k] |= vocab.NO_TRACK
        return {"state": state, "covariance": cov, "flags": flags, "innovation": innov,
                "innovation_covariance": s_out, "gain": k_out, "measurement": used}
