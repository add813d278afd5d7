"""Per-track filters: one object owns a track's motion model, measurement prediction, innovation
covariance, gate and update, so a multi-target loop never computes any of them itself.

A multi-target tracker (:mod:`trackreplay.trackers.radar_multi_target`) keeps a batch of tracks,
``x`` ``(..., n)`` and ``P`` ``(..., n, n)`` over any leading axes (runs, track slots), and asks
its filter, scan by scan, to

1. :meth:`~TrackFilter.predict` every track over the scan interval;
2. :meth:`~TrackFilter.predict_measurement`: the predicted measurement ``ẑ``, its Jacobian
   ``H`` and the innovation covariance ``S = H P Hᵀ + R``;
3. :meth:`~TrackFilter.innovations` of every track against every plot (angles wrapped) and
   their squared Mahalanobis distances, which the association gates with a χ² quantile;
4. :meth:`~TrackFilter.update` with one innovation per track (nearest neighbour, GNN) or with
   a combined innovation and its spread (PDA, :func:`trackreplay.cores.association.jpda.pda_update_gaussian`);
5. :meth:`~TrackFilter.start` a track from one plot no track claimed.

The filter here is the extended Kalman filter of a nearly-constant-velocity target seen in range
and bearing (Bar-Shalom, Li & Kirubarajan 2001, §6.2 for the continuous white-noise acceleration
model, §10.3 for the polar EKF). Another filter (a UKF, a converted-measurement KF, an IMM) is one
more class with the same five methods; no loop changes. Every product goes through the one Kalman
filter of :mod:`trackreplay.cores.filters.kalman`.

State ``[x, y, ẋ, ẏ]`` (m, m/s); measurement ``[r, θ]`` (m, rad), θ counter-clockwise from +x.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from trackreplay.cores.filters._kalman_fast import joseph_covariance_fast
from trackreplay.cores.filters.kalman import continuous_white_noise_model, kalman_gain


def wrap_angle(angle):
    """``angle`` into [−π, π)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class TrackFilter:
    """Interface of a per-track filter (see the module docstring). Subclasses set ``state_size``
    and ``measurement_size`` and implement the five methods; arrays are batched over leading axes."""

    state_size = 0
    measurement_size = 0
    #: the measurement component the gating's coarse windows sort plots along, and its period
    #: when it is an angle (None otherwise); see :mod:`trackreplay.cores.association.gating`
    window_component = 0
    window_period = None
    #: measurement components that are angles (wrapped in the innovation)
    angular_components = ()

    def predict(self, x, P, dt: float):  # pragma: no cover - interface
        """``(x⁻, P⁻)`` after ``dt`` seconds."""
        raise NotImplementedError

    def predict_measurement(self, x, P):  # pragma: no cover - interface
        """``(ẑ, H, S)``: predicted measurement ``(..., m)``, Jacobian ``(..., m, n)`` and
        innovation covariance ``(..., m, m)``."""
        raise NotImplementedError

    def innovation(self, z, z_pred):  # pragma: no cover - interface
        """``z − ẑ`` element by element (shapes broadcast), angles wrapped."""
        raise NotImplementedError

    def innovations(self, z, z_pred):
        """``z − ẑ`` for plots ``z`` ``(..., W, m)`` against tracks ``ẑ`` ``(..., S, m)``:
        ``(..., S, W, m)``, every track against every plot."""
        return self.innovation(z[..., None, :, :], z_pred[..., :, None, :])

    def update(self, x, P, H, S, innovation):
        """Kalman update of ``(x, P)`` with one innovation per track (Joseph form).

        Returns ``(x⁺, P⁺, K)``."""
        R = self.measurement_covariance(x)
        K, _ = kalman_gain(P, H, R, S)
        x_post = x + np.einsum("...ij,...j->...i", K, innovation)
        return x_post, joseph_covariance_fast(P, K, H, R), K

    def start(self, z):  # pragma: no cover - interface
        """``(x₀, P₀)`` of tracks started from single plots ``z`` ``(..., m)``."""
        raise NotImplementedError

    def measurement_covariance(self, x):  # pragma: no cover - interface
        raise NotImplementedError


@dataclass(frozen=True)
class PolarConstantVelocityEKF(TrackFilter):
    """Nearly-constant-velocity motion, range-bearing plots, extended Kalman filter.

    Attributes
    ----------
    process_noise_m2ps3 : float
        Spectral density q of the white acceleration per axis (m²/s³):
        ``Q = q [[T³/3, T²/2], [T²/2, T]]`` per axis (continuous white-noise acceleration).
    sigma_range_m, sigma_bearing_rad : float
        Plot noise: ``R = diag(σ_r², σ_θ²)``.
    initial_speed_sigma_mps : float
        Standard deviation of each velocity component of a track started from one plot (a
        velocity prior of zero mean: the start knows the position only).
    """

    process_noise_m2ps3: float
    sigma_range_m: float
    sigma_bearing_rad: float
    initial_speed_sigma_mps: float

    state_size = 4
    measurement_size = 2
    window_component = 1         # bearing: plots spread over the sector, each gate a sliver of it
    window_period = 2.0 * np.pi
    angular_components = (1,)

    def motion_model(self, dt: float):
        """``F``, ``Q`` ``(4, 4)`` for state ``[x, y, ẋ, ẏ]``: the per-axis continuous white-noise
        model of :func:`~trackreplay.cores.filters.kalman.continuous_white_noise_model`, both axes.
        Built once per scan interval (a recording's scans are mostly evenly spaced)."""
        return _cv_model(float(dt), self.process_noise_m2ps3)

    def predict(self, x, P, dt: float):
        """``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q``."""
        F, Q = self.motion_model(dt)
        x_pred = x @ F.T
        P_pred = _congruence(F, P)
        P_pred += Q
        P_pred += np.swapaxes(P_pred, -1, -2).copy()  # symmetric to the last bit, in place
        P_pred *= 0.5
        return x_pred, P_pred

    def measurement_covariance(self, x=None):
        return np.diag([self.sigma_range_m ** 2, self.sigma_bearing_rad ** 2])

    def predict_measurement(self, x, P):
        """``ẑ = [r, θ]``, ``H = ∂ẑ/∂x`` and ``S = H P Hᵀ + R``."""
        px, py = x[..., 0], x[..., 1]
        r2 = px * px + py * py
        r = np.sqrt(r2)
        H = np.zeros(x.shape[:-1] + (2, 4))
        H[..., 0, 0], H[..., 0, 1] = px / r, py / r
        H[..., 1, 0], H[..., 1, 1] = -py / r2, px / r2
        return np.stack([r, np.arctan2(py, px)], axis=-1), H, _position_innovation_covariance(
            H, P, self.measurement_covariance())

    def innovation(self, z, z_pred):
        nu = z - z_pred
        # both bearings lie in [−π, π], so their difference is within one turn of [−π, π): one
        # correction wraps it, as wrap_angle would, without a floating-point remainder
        turn = nu[..., 1]
        turn -= (2.0 * np.pi) * (turn >= np.pi)
        turn += (2.0 * np.pi) * (turn < -np.pi)
        return nu

    def start(self, z):
        r, b = z[..., 0], z[..., 1]
        c, s = np.cos(b), np.sin(b)
        x = np.zeros(z.shape[:-1] + (4,))
        x[..., 0], x[..., 1] = r * c, r * s
        # converted position covariance D diag(σ_r², r²σ_θ²) Dᵀ, velocity prior independent of it
        along, cross = self.sigma_range_m ** 2, (r * self.sigma_bearing_rad) ** 2
        P = np.zeros(z.shape[:-1] + (4, 4))
        P[..., 0, 0] = along * c * c + cross * s * s
        P[..., 1, 1] = along * s * s + cross * c * c
        P[..., 0, 1] = P[..., 1, 0] = (along - cross) * c * s
        P[..., 2, 2] = P[..., 3, 3] = self.initial_speed_sigma_mps ** 2
        return x, P


def _position_innovation_covariance(H, P, R):
    """``H P Hᵀ + R`` for a Jacobian ``H`` ``(..., 2, n)`` that is zero beyond its first two
    columns (the measurement sees the position only), written out entry by entry: a batched
    ``matmul`` of thousands of small matrices pays per matrix (tests/test_multitarget_trackers.py
    holds it against ``H @ P @ Hᵀ + R``)."""
    a, b, c, d = H[..., 0, 0], H[..., 0, 1], H[..., 1, 0], H[..., 1, 1]
    p00, p01, p11 = P[..., 0, 0], 0.5 * (P[..., 0, 1] + P[..., 1, 0]), P[..., 1, 1]
    S = np.empty(H.shape[:-2] + (2, 2))
    S[..., 0, 0] = a * a * p00 + 2.0 * a * b * p01 + b * b * p11 + R[0, 0]
    S[..., 1, 1] = c * c * p00 + 2.0 * c * d * p01 + d * d * p11 + R[1, 1]
    S[..., 0, 1] = S[..., 1, 0] = a * c * p00 + (a * d + b * c) * p01 + b * d * p11 + R[0, 1]
    return S


def _congruence(F, P):
    """``F P Fᵀ`` of a stack of matrices ``P`` (..., n, n) as one matrix product,
    ``vec(F P Fᵀ) = (F ⊗ F) vec(P)``: thousands of 4 × 4 products in one call instead of a
    batched ``matmul`` that pays per matrix (equal to rounding; tests/test_multitarget_trackers.py).
    The leading axis (a tracker's runs) stays a batch axis of the product: one OpenBLAS call per
    run is small enough to stay on one thread, whereas one call over every run's tracks wakes its
    worker threads, which on a shared machine spin against the scan loop (the GNN at 100 runs
    took 1.7× as long)."""
    n = F.shape[0]
    flat = P.reshape(P.shape[:-2] + (n * n,)) if P.ndim > 3 else P.reshape(-1, n * n)
    return np.matmul(flat, np.kron(F, F).T).reshape(P.shape)


@lru_cache(maxsize=64)
def _cv_model(dt: float, q: float):
    F1, Q1 = continuous_white_noise_model(dt, q, 2)
    eye = np.eye(2)
    F, Q = np.kron(F1, eye), np.kron(Q1, eye)
    F.flags.writeable = Q.flags.writeable = False
    return F, Q


def squared_distance(innovation, S):
    """``νᵀ S⁻¹ ν`` element by element: ``innovation`` ``(..., m)``, ``S`` ``(..., m, m)``
    (leading axes broadcast)."""
    if S.shape[-1] == 2:
        return _squared_distance_2x2(innovation, S)
    return np.einsum("...i,...ij,...j->...", innovation, np.linalg.inv(S), innovation)


def squared_distances(innovation, S):
    """``νᵀ S⁻¹ ν`` of every track-plot pair: ``innovation`` ``(..., S, W, m)``, ``S`` ``(..., S, m, m)``."""
    return squared_distance(innovation, S[..., None, :, :])


def _squared_distance_2x2(innovation, S):
    """:func:`squared_distance` for two measurement components, written out element by element
    (``(d ν₀² − 2 b ν₀ν₁ + a ν₁²) / (a d − b²)`` for ``S = [[a, b], [b, d]]``): a few passes over
    the pairs instead of a generic contraction (tests/test_multitarget_trackers.py holds it
    against the general form)."""
    a, b, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
    n0, n1 = innovation[..., 0], innovation[..., 1]
    return (d * n0 * n0 - 2.0 * b * n0 * n1 + a * n1 * n1) / (a * d - b * b)


@dataclass(frozen=True)
class PolarConstantVelocityUKF(PolarConstantVelocityEKF):
    """The same target and plots, filtered by an unscented Kalman filter (Julier & Uhlmann 2004).

    Only the measurement prediction differs from :class:`PolarConstantVelocityEKF`: the 2n
    symmetric sigma points ``x ± √(n P)`` columns (weights 1/2n) go through the range-bearing
    function, giving ``ẑ``, ``S = P_zz + R`` and the cross-covariance ``P_xz``. The loop's Jacobian
    is the statistical linearisation ``H = P_xzᵀ P⁻¹``, so the gain ``K = P Hᵀ S⁻¹ = P_xz S⁻¹`` is
    the UKF's, and the update is ``P⁺ = P − K S Kᵀ``. The motion model is linear, so the
    prediction is the Kalman filter's.
    """

    def predict_measurement(self, x, P):
        n = x.shape[-1]
        L = np.linalg.cholesky(n * P)                               # (..., n, n)
        spread = np.concatenate([np.swapaxes(L, -1, -2), -np.swapaxes(L, -1, -2)], axis=-2)  # (..., 2n, n)
        points = x[..., None, :] + spread
        r = np.hypot(points[..., 0], points[..., 1])
        b = np.arctan2(points[..., 1], points[..., 0])
        centre = np.arctan2(x[..., 1], x[..., 0])
        # bearings averaged as deviations from the centre's, so the mean never straddles ±π wrongly
        deviation = wrap_angle(b - centre[..., None])
        z_points = np.stack([r, deviation], axis=-1)                # (..., 2n, 2)
        z_mean = z_points.mean(axis=-2)
        dz = z_points - z_mean[..., None, :]
        S = np.einsum("...ki,...kj->...ij", dz, dz) / (2 * n) + self.measurement_covariance()
        P_xz = np.einsum("...ki,...kj->...ij", spread, dz) / (2 * n)  # (..., n, 2)
        H = np.swapaxes(np.linalg.solve(P, P_xz), -1, -2)            # P_xzᵀ P⁻¹ (P symmetric)
        z_pred = np.stack([z_mean[..., 0], wrap_angle(centre + z_mean[..., 1])], axis=-1)
        return z_pred, H, 0.5 * (S + np.swapaxes(S, -1, -2))

    def update(self, x, P, H, S, innovation):
        K = np.swapaxes(np.linalg.solve(S, H @ P), -1, -2)          # P Hᵀ S⁻¹ = P_xz S⁻¹
        x_post = x + np.einsum("...ij,...j->...i", K, innovation)
        P_post = P - K @ S @ np.swapaxes(K, -1, -2)
        return x_post, 0.5 * (P_post + np.swapaxes(P_post, -1, -2)), K
