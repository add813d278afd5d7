"""Kim et al. (2013): moving-emitter localisation from TDOA and FDOA by Gauss-Newton.

The paper estimates an emitter's position and velocity θ = [x, y, ẋ, ẏ] from the time and
frequency differences of arrival of sensor pairs (eqs. 1–5) by Gauss-Newton on the weighted
least-squares cost J(θ) (eqs. 6, 8, 15–17), and bounds it by the CRLB (eqs. 18–22). See
``docs/papers/tdoa-fdoa.md``. One epoch is one scan of the data contract; every (run, epoch)
is one independent estimate, all of them in one vectorised Gauss-Newton pass
(:func:`trackreplay.cores.localisation.gauss_newton.gauss_newton`).

Three estimators, one per measurement kind (:data:`TRACKERS`):

``joint``  TDOA and FDOA of every pair (the paper's method): position and velocity;
``tdoa``   TDOA only: position (velocity is not estimated: NaN, flagged ``NOT_ESTIMATED``);
``fdoa``   FDOA only: position and velocity.

With ``stationary_emitter`` (the paper's Fig. 7) the velocity is known to be zero: every
estimator solves for the position alone and reports the velocity as 0 with zero variance; such a
covariance is singular by construction, and the output check flags it ``NOT_POSITIVE_DEFINITE``
(``docs/contract.md``, Flags), as it does a covariance that rounding has made singular (e.g. at
σ_FDOA = 10⁻⁹ Hz, where the position and velocity variances differ by more than double
precision holds).

Outputs (:data:`trackreplay.vocabulary.OUTPUTS`): ``state`` (4), ``covariance`` (4 × 4, the
inverse Fisher information (HᵀΨ⁻¹H)⁻¹ at the estimate, eq. 18) and ``flags`` (``CONVERGED``,
``NOT_CONVERGED``, ``DIVERGED``, ``RANK_DEFICIENT``, ``INVALID_START``, ``UNDERDETERMINED``,
``NOT_ESTIMATED``), with the extras ``iterates`` (iterations + 1, 4: every Gauss-Newton
iterate θ̂₀ … θ̂_n), ``cost`` (J at the estimate, eq. 6), ``iterations`` (steps taken) and
``step_sigma`` (the last step in standard deviations).

An estimator with fewer independent equations than unknowns for the pair list (FDOA only, three
sensors, moving emitter: 2 equations for 4 unknowns) is not run: its state is NaN and every
cell carries ``UNDERDETERMINED | NOT_ESTIMATED``. A cell whose estimate has no covariance (the
Jacobian is singular there, or the start was not finite) reports a NaN state flagged
``NOT_ESTIMATED`` beside the reason; its ``iterates`` keep the path it took.

Starting points (``initial_guess``): ``prior`` reads :attr:`TdoaFdoa.prior_state` (the paper's
"truth plus 1 % MSE" start, recorded as ``/emitter/prior``); ``grid`` searches a coarse position
grid around the sensors with the least-squares velocity per point
(:func:`trackreplay.cores.localisation.coarse_grid_search.coarse_grid_start`).
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.cores.localisation.coarse_grid_search import coarse_grid_start
from trackreplay.cores.localisation.gauss_newton import gauss_newton
from trackreplay.cores.localisation.tdoa_fdoa_model import (measurement_model, measurement_rows, underdetermined_reason,
                                                         unknowns)
from trackreplay.errors import InputError
from trackreplay.trackers.interface import Param, TdoaFdoa, Tracker

INITIAL_GUESSES = ("prior", "grid")

PARAMS = (
    Param("initial_guess", None, "", "start: prior (/emitter/prior) or grid (coarse grid search, no prior needed)"),
    Param("iterations", None, "", "Gauss-Newton steps at most (the paper compares 5 and 10)"),
    Param("step_tolerance_sigma", None, "σ", "converged when the last step is shorter than this many standard deviations"),
    Param("stationary_emitter", None, "", "velocity known to be 0: estimate the position only (Fig. 7)"),
    Param("grid_extent_m", None, "m", "grid start: half-width of the grid around the sensors' centroid"),
    Param("grid_step_m", None, "m", "grid start: spacing"),
    Param("divergence_range_m", None, "m", "an iterate farther than this from the sensors' centroid has diverged"),
)


def _underdetermined_outputs(R: int, E: int, iterations: int) -> dict:
    return {"state": np.full((R, E, 4), np.nan), "covariance": np.full((R, E, 4, 4), np.nan),
            "flags": np.full((R, E), vocab.UNDERDETERMINED | vocab.NOT_ESTIMATED, vocab.FLAG_DTYPE),
            "iterates": np.full((R, E, iterations + 1, 4), np.nan), "cost": np.full((R, E), np.nan),
            "iterations": np.zeros((R, E), np.int32), "step_sigma": np.full((R, E), np.nan)}


class _GaussNewtonEstimator(Tracker):
    """Gauss-Newton on the measurement rows of :attr:`kind` (Kim et al. 2013, eqs. 15–17)."""

    family = "tdoa-fdoa"
    form = "batch"
    params = PARAMS
    kind = ""

    def __init__(self, **design):
        super().__init__(**design)
        if self.initial_guess not in INITIAL_GUESSES:
            raise InputError(f"initial_guess must be 'prior' or 'grid', not {self.initial_guess!r}")
        self.iterations = int(self.iterations)
        if self.iterations < 1:
            raise InputError("iterations must be ≥ 1")
        for key in ("step_tolerance_sigma", "grid_extent_m", "grid_step_m", "divergence_range_m"):
            value = float(self.design[key])
            if not (np.isfinite(value) and value >= 0) or (key != "step_tolerance_sigma" and value == 0):
                raise InputError(f"{key} must be a finite number {'≥' if key == 'step_tolerance_sigma' else '>'} 0 "
                                 f"(got {self.design[key]!r})")
            setattr(self, key, value)
        self.stationary_emitter = bool(self.stationary_emitter)

    def _start(self, m: TdoaFdoa, rows, free) -> np.ndarray:
        R, E = m.measured.shape[:2]
        if self.initial_guess == "prior":
            if m.prior_state is None:
                raise InputError("no /emitter/prior for initial_guess=prior; use --set initial_guess=grid")
            return np.array(m.prior_state, float).reshape(R * E, 4)
        M = m.sensor_position_m.shape[2]
        return coarse_grid_start(m.measured.reshape(R * E, -1), m.sigma.reshape(R * E, -1),
                                 m.sensor_position_m.reshape(R * E, M, 2), m.sensor_velocity_mps.reshape(R * E, M, 2),
                                 m.pairs, m.carrier_hz.reshape(-1), rows, len(free) == 4, self.grid_extent_m,
                                 self.grid_step_m)

    def track(self, m: TdoaFdoa) -> dict:
        R, E = m.measured.shape[:2]
        M = m.sensor_position_m.shape[2]
        pairs = np.asarray(m.pairs, np.int64)
        stationary = self.stationary_emitter
        if underdetermined_reason(self.kind, pairs, M, stationary):
            return _underdetermined_outputs(R, E, self.iterations)
        rows = measurement_rows(self.kind, len(pairs))
        free = unknowns(self.kind, stationary)
        theta0 = self._start(m, rows, free)
        if stationary:
            theta0[:, 2:] = 0.0
        limit = self.divergence_range_m

        # every kind's rows are one run of consecutive rows of g: taken as a slice, a view (the
        # model is called at every iteration; a gather would copy g and H each time)
        take = slice(int(rows[0]), int(rows[-1]) + 1)
        if not np.array_equal(rows, np.arange(take.start, take.stop)):
            take = rows

        def model(theta, sensor_pos, sensor_vel, carrier_hz):
            g, H = measurement_model(theta, sensor_pos, sensor_vel, pairs, carrier_hz)
            return g[:, take], H[:, take]

        def diverged(theta, sensor_pos, sensor_vel, carrier_hz):
            centre = sensor_pos.mean(axis=1)
            return np.linalg.norm(theta[:, :2] - centre, axis=1) > limit

        batch = {"sensor_pos": m.sensor_position_m.reshape(R * E, M, 2),
                 "sensor_vel": m.sensor_velocity_mps.reshape(R * E, M, 2),
                 "carrier_hz": m.carrier_hz.reshape(R * E)}
        res = gauss_newton(model, theta0, m.measured.reshape(R * E, -1)[:, rows], m.sigma.reshape(R * E, -1)[:, rows],
                           free=free, iterations=self.iterations, step_tolerance=self.step_tolerance_sigma,
                           batch=batch, diverged=diverged)
        state, iterates, cov, flags = res.theta, res.iterates, res.covariance, res.flags.astype(vocab.FLAG_DTYPE)
        fixed = np.setdiff1d(np.arange(4), free)
        if stationary:  # the velocity is known (0): exact, zero variance
            cov[:, fixed, :] = 0.0
            cov[:, :, fixed] = 0.0
        else:  # not estimated (TDOA only): NaN, not "known"
            state[:, fixed] = np.nan
            iterates[:, :, fixed] = np.nan
        # an estimate without a covariance (singular at the estimate, no start) is no estimate
        no_cov = ~np.all(np.isfinite(cov[:, free[:, None], free[None, :]]), axis=(1, 2))
        state[no_cov] = np.nan
        flags[np.isnan(state).any(axis=1)] |= vocab.NOT_ESTIMATED
        return {"state": state.reshape(R, E, 4), "covariance": cov.reshape(R, E, 4, 4), "flags": flags.reshape(R, E),
                "iterates": iterates.reshape(R, E, self.iterations + 1, 4), "cost": res.cost.reshape(R, E),
                "iterations": res.iterations.reshape(R, E).astype(np.int32),
                "step_sigma": res.step_sigma.reshape(R, E)}


class JointTdoaFdoa(_GaussNewtonEstimator):
    """TDOA and FDOA of every pair: position and velocity (Kim et al. 2013, the proposed method)."""

    name = "joint"
    label = "TDOA + FDOA"
    kind = "joint"


class TdoaOnly(_GaussNewtonEstimator):
    """TDOA only: position (the velocity does not enter eq. 2, so it is not estimated)."""

    name = "tdoa"
    label = "TDOA only"
    kind = "tdoa"


class FdoaOnly(_GaussNewtonEstimator):
    """FDOA only: position and velocity (underdetermined with three sensors and a moving emitter)."""

    name = "fdoa"
    label = "FDOA only"
    kind = "fdoa"


TRACKERS = (JointTdoaFdoa, TdoaOnly, FdoaOnly)
