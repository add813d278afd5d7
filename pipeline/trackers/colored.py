"""Kwon (1997): tracking with AR(1) coloured measurement noise — AR(1) estimation,
decorrelation, the square-root information filter and IMMs built on them.

The thesis (ch. III–V; see ``docs/papers/colored.md``) models the position
measurement noise as ``ν_k = α ν_{k−1} + η_k``, estimates α and ``σ_η²`` online (Wu & Chang
1996, eqs. 3.2.3–3.2.51: :mod:`trackreplay.cores.filters.ar1_estimation`), whitens the measurements
by differencing, ``y_k = z_k − ᾱ z_{k−1}`` with ``Ĥ = H − ᾱ H Φ⁻¹`` (eqs. 3.1.1–3.1.6:
:mod:`trackreplay.cores.filters.decorrelation`), and compares five filters on the whitened or plain
measurements. All run on the one IMM core (:mod:`trackreplay.cores.filters.imm`, eqs. 4.3.1–4.3.17,
a single model being the IMM with one model) with Kalman (:mod:`trackreplay.cores.filters.kalman`)
or square-root information (:mod:`trackreplay.cores.filters.srif`, eqs. 4.2.18–4.2.22) model filters:

``kf``      one CA model (Ψ = [T²/2, T, 1], eq. 2.5), plain measurements (ignores the colour);
``kf_dp``   the same model with the decorrelation process and the AR estimator;
``imm``     CV + CA (transition) + CA (steady) (ch. V.3), Kalman filters, plain measurements;
``mimm_k``  the same models, Kalman filters, decorrelation + AR estimator;
``pimm``    the same models, square-root information filters, decorrelation + AR estimator.

State ``[p, v, a]`` per axis, axes concatenated (family ``colored``). The filters
update from scan 1 (a decorrelated measurement needs ``z_{k−1}``); scan 0 holds the start.

Start (``track_start``): ``"truth"`` starts every filter at the true state of scan 0 with
``P₀ = initial_variance · I``, as the thesis does (ch. V); ``"measurements"`` needs no truth;
``"auto"`` (default) is ``"truth"`` when the file has it and ``"measurements"`` for a recording.
With ``"measurements"``: position from the first measurement with variance ``measurement_variance_m2``, zero
velocity and acceleration with the large variances :data:`START_VELOCITY_VARIANCE` and
:data:`START_ACCELERATION_VARIANCE` (``initial_variance`` is then unused).

Flags (``trackreplay.vocabulary.FLAGS``, decorrelating trackers only): the AR estimator's
``CLAMPED`` (discriminant clamped), ``LIMITED`` (|α̂| limited), ``FLOORED`` (``σ_η²`` floored),
bit-or over the axes, and ``NOT_WARM`` while the estimator has not settled (the filter then
uses the plain measurement). Each decorrelating tracker runs the estimator itself (three
all-pole filters, well under the filters' cost); :func:`ar1_outputs` gives its arrays for the
stage's ``ar_estimator`` output.

Outputs: ``state``, ``covariance``, ``flags``; ``model_probabilities`` (IMMs, models in the
order of :data:`MODEL_NAMES`); ``innovation`` and ``innovation_covariance`` (single Kalman
models: of ``z_k``, or of ``y_k`` for ``kf_dp``); extras ``log_likelihood`` and ``nis`` per
model (for the SRIF models ``nis`` is ``‖e_k‖²``, the squared SRIF residual).
"""

from __future__ import annotations

import numpy as np

from trackreplay import vocabulary as vocab
from trackreplay.cores.association.track_management import ConfirmationRule, confirmation_scans
from trackreplay.cores.filters.ar1_estimation import check_design, estimate_ar1, scan_flags
from trackreplay.cores.filters.imm import (MeasurementStream, ModelFilter, check_transition, imm_filter,
                                        kinematic_model, single_model_filter)
from trackreplay.errors import InputError
from trackreplay.trackers.interface import ColoredPositions, Param, Tracker

MODEL_NAMES = ("cv", "ca_transition", "ca_steady")
TRACK_STARTS = ("auto", "truth", "measurements")
# track_start="measurements": zero velocity and acceleration with these variances (1 km/s and
# 100 m/s² standard deviations: far wider than any target of the scenarios, so the first
# updates, not the start, fix them)
START_VELOCITY_VARIANCE = 1.0e6      # m²/s²
START_ACCELERATION_VARIANCE = 1.0e4  # m²/s⁴


def parse_matrix(text: str, name: str) -> np.ndarray:
    """``"0.99 0.01; 0.3 0.7"`` → 2-D array (rows separated by ``;``)."""
    try:
        rows = [[float(v) for v in row.replace(",", " ").split()] for row in str(text).split(";") if row.strip()]
        return np.array(rows, dtype=float)
    except ValueError:
        raise InputError(f"parameter {name!r}: cannot read {text!r} as rows of numbers separated by ';'") from None


def sample_period(times_s) -> float:
    """The scan interval T of evenly spaced scan times (an :class:`InputError` otherwise)."""
    t = np.asarray(times_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise InputError(f"need at least 2 scan times, got shape {t.shape}")
    dt = np.diff(t)
    if not (np.all(np.isfinite(dt)) and dt[0] > 0 and np.all(np.abs(dt - dt[0]) <= 1e-9 * max(abs(dt[0]), 1.0))):
        raise InputError("scans are not evenly spaced in time (the models use one T)")
    return float(dt[0])


def ar1_outputs(measurements: ColoredPositions, beta: float, rho: float) -> dict:
    """The AR(1) estimator's arrays (``alpha``, ``alpha_biased``, ``noise_variance``, ``flags``
    per axis, ``warm`` per scan) for the stage's ``ar_estimator`` output.

    Parameters
    ----------
    measurements : ColoredPositions
    beta, rho : float
        Forgetting factor β and zero-cancelling pole ρ (eqs. 3.2.7, 3.2.17–3.2.18).

    Returns
    -------
    dict of ndarray
        ``(runs, scans, axes)`` arrays and ``warm`` (runs, scans) uint8.
    """
    z = np.asarray(measurements.position_m, dtype=float)
    ar = estimate_ar1(z, float(beta), float(rho))
    runs, scans = z.shape[:2]
    return {"alpha": ar.alpha, "alpha_biased": ar.alpha_biased, "noise_variance": ar.noise_variance,
            "warm": np.broadcast_to(ar.warm.astype(np.uint8), (runs, scans)).copy(), "flags": ar.flags}


# --------------------------------------------------------------------------- the trackers

P_MEASUREMENT = Param("measurement_variance_m2", None, "m²", "measurement noise variance R per axis (R positive "
                      "definite)", low=0.0)
P_INITIAL = Param("initial_variance", None, "", "P₀ = initial_variance · I at the true start state", low=0.0)
P_START = Param("track_start", "auto", "",
                "'truth': start at the true state of scan 0 (thesis); 'measurements': position from z₀, "
                "zero velocity/acceleration with a large variance; 'auto': truth when the file has it, "
                "else measurements (a recording)")
P_CONFIRM = (Param("confirm_hits", 3, "scans", "M of M-of-N confirmation of a track started from measurements "
                    "(tentative, flag INITIALISING, until M of its first N scans had a measurement; a truth start "
                    "is confirmed; 0: no confirmation)", low=-1),
             Param("confirm_window", 4, "scans", "N of M-of-N confirmation", low=-1))
P_AR = (Param("ar_forgetting_factor", None, "", "AR estimator forgetting factor β, 0 < β < 1"),
        Param("ar_zero_pole", None, "", "AR estimator zero-cancelling pole ρ, 0 ≤ ρ < 1"))
# the process noises are positive: the square-root information filter needs Q⁻¹
P_KF = (Param("kf_process_noise", None, "m²/s⁴", "CA model's acceleration-increment variance per sample", low=0.0),)
P_IMM = (Param("cv_process_noise", None, "m²/s⁴", "CV model's white-acceleration variance", low=0.0),
         Param("ca_transition_process_noise", None, "m²/s⁶", "transition CA model's white-jerk variance", low=0.0),
         Param("ca_steady_process_noise", None, "m²/s⁶", "steady CA model's white-jerk variance", low=0.0),
         Param("imm_transition", None, "", "Markov transition matrix p_ij, rows 'a b c; ...' (CV, CA tr., CA st.)"))


class _ColoredNoiseTracker(Tracker):
    """One of the thesis's five filters on the IMM core (see the module docstring)."""

    family = "colored"
    form = "batch"
    decorrelate = False
    filter_kind = "kf"

    def __init__(self, **design):
        super().__init__(**design)
        self.R = float(self.measurement_variance_m2)  # each number's range is its Param's
        self.P0_scale = float(self.initial_variance)
        if self.track_start not in TRACK_STARTS:
            raise InputError(f"track_start must be one of {', '.join(TRACK_STARTS)}, got {self.track_start!r}")
        if self.decorrelate:
            check_design(float(self.ar_forgetting_factor), float(self.ar_zero_pole))
        if 0 < int(self.confirm_hits) and int(self.confirm_window) < int(self.confirm_hits):
            raise InputError(f"confirm_hits (M = {self.confirm_hits}) must be ≤ confirm_window (N = {self.confirm_window})")

    # --- pieces shared by the five

    def start(self, m: ColoredPositions, axes: int):
        """``x₀`` (runs, 3·axes) and ``P₀`` (3·axes, 3·axes) of scan 0 (see ``track_start``)."""
        N = 3 * axes
        start = self.resolved_start(m)
        if start == "truth":
            if m.truth_state is None:
                raise InputError("track_start='truth' needs the true state (use track_start=measurements)")
            x0 = np.asarray(m.truth_state, dtype=float)[:, 0]
            if x0.shape[-1] != N:
                raise InputError(f"true state has {x0.shape[-1]} components, expected {N} ([p, v, a] per axis)")
            return x0, np.eye(N) * self.P0_scale
        z0 = np.asarray(m.position_m, dtype=float)[:, 0]
        x0 = np.zeros((z0.shape[0], N))
        x0[:, 0::3] = z0
        P0 = np.diag(np.tile([self.R, START_VELOCITY_VARIANCE, START_ACCELERATION_VARIANCE], axes))
        return x0, P0

    def resolved_start(self, m: ColoredPositions) -> str:
        """``track_start`` with ``auto`` resolved for these data."""
        if self.track_start == "auto":
            return "truth" if m.truth_state is not None else "measurements"
        return self.track_start

    def measurement_stream(self, z):
        """Plain ``(z, H, R)`` or decorrelated ``(y, Ĥ, diag σ̂_η²)`` stream, and the flags."""
        runs, scans, axes = z.shape
        R = np.eye(axes) * self.R
        if not self.decorrelate:
            return MeasurementStream(z, R), np.zeros((runs, scans), np.dtype(vocab.FLAG_DTYPE))
        ar = estimate_ar1(z, float(self.ar_forgetting_factor), float(self.ar_zero_pole))
        warm = ar.warm[None, :, None]
        stream = MeasurementStream(z, R, True, np.where(warm, ar.alpha, np.nan),
                                   np.where(warm, ar.noise_variance, np.nan))
        return stream, scan_flags(ar)

    def run_filter(self, stream, x0, P0, T: float, axes: int) -> dict:  # pragma: no cover - interface
        raise NotImplementedError

    def track(self, m: ColoredPositions) -> dict:
        z = np.asarray(m.position_m, dtype=float)
        if z.ndim != 3:
            raise InputError(f"position_m must be (runs, scans, axes), got shape {z.shape}")
        axes = z.shape[-1]
        T = sample_period(m.times_s)
        x0, P0 = self.start(m, axes)
        stream, flags = self.measurement_stream(z)
        out = self.run_filter(stream, x0, P0, T, axes)
        if self.resolved_start(m) == "measurements":
            # a measurement every scan: the track is tentative until its M-th (track_management)
            rule = ConfirmationRule(int(self.confirm_hits), int(self.confirm_window))
            tentative, _ = confirmation_scans(np.ones(z.shape[:2], bool), rule)
            flags = flags | np.where(tentative, vocab.INITIALISING, 0).astype(flags.dtype)
        out["flags"] = flags
        return out


class _SingleModel(_ColoredNoiseTracker):
    params = (P_MEASUREMENT, P_INITIAL, *P_KF, P_START, *P_CONFIRM)

    def __init__(self, **design):
        super().__init__(**design)
        self.q = float(self.kf_process_noise)

    def run_filter(self, stream, x0, P0, T, axes):
        model = kinematic_model("ca", 3, T, self.q, axes, noise="increment")
        out = single_model_filter(ModelFilter(model, self.filter_kind), x0, P0, stream)
        out.pop("model_probabilities")  # identically 1: not an IMM
        return out


class _ThreeModelImm(_ColoredNoiseTracker):
    params = (P_MEASUREMENT, P_INITIAL, *P_IMM, P_START, *P_CONFIRM)

    def __init__(self, **design):
        super().__init__(**design)
        self.q = [float(self.design[key])
                  for key in ("cv_process_noise", "ca_transition_process_noise", "ca_steady_process_noise")]
        self.transition = check_transition(parse_matrix(self.imm_transition, "imm_transition"), len(MODEL_NAMES))

    def run_filter(self, stream, x0, P0, T, axes):
        models = [kinematic_model(name, order, T, q, axes)
                  for name, order, q in zip(MODEL_NAMES, (2, 3, 3), self.q)]
        return imm_filter([ModelFilter(mod, self.filter_kind) for mod in models], self.transition, x0, P0, stream)


class KalmanFilter(_SingleModel):
    """One CA Kalman filter on the plain measurements (Kwon 1997, ch. V.2: "KF")."""

    name = "kf"


class KalmanFilterDecorrelated(_SingleModel):
    """The CA Kalman filter with the decorrelation process and the AR estimator (Kwon 1997,
    ch. V.2: "KF_DP")."""

    name = "kf_dp"
    decorrelate = True
    params = (P_MEASUREMENT, P_INITIAL, *P_KF, *P_AR, P_START, *P_CONFIRM)


class StandardImm(_ThreeModelImm):
    """CV + two CA models, Kalman filters, plain measurements (Kwon 1997, ch. V.3: "IMM")."""

    name = "imm"


class DecorrelatedImm(_ThreeModelImm):
    """The same IMM on decorrelated measurements with the AR estimator (Kwon 1997, ch. V.3:
    "MIMM_K")."""

    name = "mimm_k"
    decorrelate = True
    params = (P_MEASUREMENT, P_INITIAL, *P_IMM, *P_AR, P_START, *P_CONFIRM)


class SquareRootImm(_ThreeModelImm):
    """The decorrelated IMM with square-root information model filters (Kwon 1997, ch. IV.3,
    V.3: "PIMM")."""

    name = "pimm"
    decorrelate = True
    filter_kind = "srif"
    params = (P_MEASUREMENT, P_INITIAL, *P_IMM, *P_AR, P_START, *P_CONFIRM)


TRACKERS = (KalmanFilter, KalmanFilterDecorrelated, StandardImm, DecorrelatedImm, SquareRootImm)


# --------------------------------------------------------------------------- the bound


def colored_noise_pcrb(truth_alpha, times, process_noise_variance: float, measurement_variance: float) -> np.ndarray:
    """Posterior Cramér–Rao bound of position and velocity per axis and scan for a target with
    white-acceleration motion seen through AR(1) coloured measurement noise (``docs/evaluation.md``).

    The truth's own model (Kwon 1997, eqs. 2.1–2.11): per axis ``x = [p, v]`` with
    ``x_k = Φ x_{k−1} + Ψ (u_k + w_k)``, ``Ψ = [T²/2, T]``, ``w ~ N(0, q)``, and
    ``z_k = p_k + ν_k`` with ``ν_k = α_k ν_{k−1} + η_k``, ``var η_k = (1 − α_k²) R``,
    ``ν_0 ~ N(0, R)``. Appending ``ν`` to the state makes the model linear-Gaussian with an exact
    measurement, whose bound is the Kalman covariance of the augmented state
    (:func:`trackreplay.cores.filters.pcrb.linear_gaussian_bound`). The known input ``u`` does not
    change the information. The start is the true state (as the papers' filters are given it),
    so the bound is zero at scan 0 and holds for any estimator that knows no more than that
    start and the measurements.

    Parameters
    ----------
    truth_alpha : ndarray (runs, scans[, axes])
        α_k of the truth; runs with different histories get their own bound, then averaged.
    times : ndarray (scans,)
    process_noise_variance : float
        q, the truth's white acceleration variance (m²/s⁴).
    measurement_variance : float
        R (m²).

    Returns
    -------
    ndarray (scans, 2, 2)
        Bound covariance of ``[p, v]`` of one axis (every axis has the same), averaged over runs.
    """
    from trackreplay.cores.filters.pcrb import linear_gaussian_bound

    alpha = np.asarray(truth_alpha, float)
    alpha = alpha[..., 0] if alpha.ndim == 3 else alpha          # (runs, scans): the same α on every axis
    histories = np.unique(alpha, axis=0)                         # usually one: every run shares α_k
    n_hist, K = histories.shape
    dt = np.diff(np.asarray(times, float), prepend=np.nan)
    F = np.zeros((K, n_hist, 3, 3))
    Q = np.zeros((K, n_hist, 3, 3))
    F[:, :, 0, 0] = F[:, :, 1, 1] = 1.0
    F[:, :, 0, 1] = dt[:, None]
    F[:, :, 2, 2] = histories.T
    psi = np.stack([dt**2 / 2, dt], axis=-1)                     # (K, 2)
    Q[:, :, :2, :2] = (process_noise_variance * psi[:, :, None] * psi[:, None, :])[:, None]
    Q[:, :, 2, 2] = ((1.0 - histories**2) * measurement_variance).T
    P0 = np.zeros((n_hist, 3, 3))
    P0[:, 2, 2] = measurement_variance                          # the start is the truth; ν₀ ~ N(0, R)
    bound = linear_gaussian_bound(P0, F, Q, np.array([[1.0, 0.0, 1.0]]), np.zeros((1, 1)))
    weight = np.array([np.sum(np.all(alpha == h, axis=1)) for h in histories], float)
    return np.einsum("h,khij->kij", weight / weight.sum(), bound[:, :, :2, :2])
