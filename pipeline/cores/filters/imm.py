"""One interacting-multiple-model (IMM) core for any model set, including models of different
state sizes (Blom & Bar-Shalom 1988; Kwon 1997 ch. IV.3).

Kwon (1997), ch. IV.3 (thesis eqs. 4.3.1–4.3.4 mixing, 4.3.5–4.3.10 model-matched filtering,
4.3.11–4.3.15 model probabilities, 4.3.16–4.3.17 combination); see
``docs/papers/colored-noise-imm.md``. Every Monte Carlo run advances in one call per scan
(leading run axis).

Models are strategies over the same core:

* a :class:`MotionModel` (Φ, Ψ, q, H, and where its states sit in the common state);
* a filter kind: ``"kf"`` (:func:`pipeline.cores.filters.kalman.kf_predict` / :func:`~pipeline.cores.filters.kalman.kf_update`
  and :func:`~pipeline.cores.filters.kalman.gaussian_log_likelihood`) or ``"srif"``
  (:func:`pipeline.cores.filters.srif.srif_predict_update`, the one SRIF recursion: QR time and measurement
  updates, likelihood from the residual and the triangular factors);
* the measurement of the whole IMM (:class:`MeasurementStream`): plain ``(z_k, H, R)`` or
  decorrelated ``(y_k, Ĥ, diag σ_η²)`` (:mod:`pipeline.cores.filters.decorrelation`; ``Ĥ`` per model, since it
  depends on Φ). All models of one IMM see the same measurement, so their likelihoods compare.

The thesis's sets: IMM = plain + KF, MIMM_K = decorrelated + KF, PIMM = decorrelated + SRIF, each
with one 2-state constant-velocity (CV) and two 3-state constant-acceleration (CA) models.
Models with the same filter kind and state layout are stacked on a model axis and filtered in one
batched call (the two CA models share one), and model probabilities are updated in logs, so a
model whose likelihood underflows does not break the normalisation.

Mixing rule for unequal state sizes
-----------------------------------
Mixing and combination happen in a *common* state (per axis ``[position, velocity,
acceleration]``). A model's estimate enters it through its embedding: its own components are
copied, components it lacks are filled with a fixed mean and variance, uncorrelated with the
rest. For the CV model that is a zero acceleration whose variance is the CV model's own
white-acceleration variance q_CV (``fill_cov``): the acceleration the CV model assumes, as a
random variable. Mixed initial conditions are computed in the common state (4.3.1–4.3.2) and each
model takes the sub-vector/sub-matrix of its own components. This is exactly what an equal-size
IMM does with the CV model written as a 3-state model whose acceleration row and column of Φ are
zero and whose process noise puts q_CV on the acceleration (FilterPy's ``IMMEstimator`` with that
embedding gives the same numbers: ``benchmarks/bench_imm.py`` prints the difference).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.cores.filters.decorrelation import (decorrelated_measurement_matrix, inverse_transition_rows, pseudo_measurements,
                                    transition_inverse_check)
from pipeline.errors import InputError, require_finite
from pipeline.cores.filters.kalman import (gaussian_log_likelihood, kf_predict, kf_update, kinematic_transition,
                             piecewise_white_noise_gain)
from pipeline.cores.filters.srif import information_factor, srif_from_moments, srif_moments, srif_predict_update

FILTER_KINDS = ("kf", "srif")


# --------------------------------------------------------------------------- models


@dataclass
class MotionModel:
    """A linear motion model ``x_{k+1} = Φ x_k + Ψ w_k`` with ``E[w wᵀ] = q`` and ``z = H x + ν``.

    Attributes
    ----------
    name : str
    F : ndarray (n, n)
        Φ.
    G : ndarray (n, p)
        Ψ.
    q : ndarray (p, p)
        Process-noise covariance.
    H : ndarray (m, n)
    index : ndarray of int (n,)
        Position of each of the model's states in the common state.
    fill_mean, fill_cov : ndarray (N,), (N, N)
        Mean and covariance of the common components the model does not carry (zero on its own).
    F_inv : ndarray (n, n), optional
        The exact Φ⁻¹ when the model knows it (a kinematic model: Φ(−T)); otherwise ``H Φ⁻¹``
        (eq. 3.1.3) comes from a solve with Φ.
    """

    name: str
    F: np.ndarray
    G: np.ndarray
    q: np.ndarray
    H: np.ndarray
    index: np.ndarray
    fill_mean: np.ndarray
    fill_cov: np.ndarray
    F_inv: np.ndarray | None = None
    Q: np.ndarray = field(init=False)
    H_Phi_inv: np.ndarray = field(init=False)

    def __post_init__(self):
        self.F, self.G, self.q, self.H = (np.asarray(a, dtype=float) for a in (self.F, self.G, self.q, self.H))
        self.Q = self.G @ self.q @ self.G.T
        name = f"Φ of model {self.name!r}"
        if self.F_inv is None:
            self.H_Phi_inv = inverse_transition_rows(self.H, self.F, name)
        else:
            transition_inverse_check(self.F, name, "the decorrelated measurement and the SRIF time update")
            self.F_inv = np.asarray(self.F_inv, dtype=float)
            if not np.allclose(self.F @ self.F_inv, np.eye(self.n), rtol=0.0, atol=1e-9):
                raise InputError(f"F_inv of model {self.name!r} is not the inverse of its Φ")
            self.H_Phi_inv = self.H @ self.F_inv
        self.index = np.asarray(self.index, dtype=np.int64)

    @property
    def n(self) -> int:
        return self.F.shape[0]

    @property
    def common_size(self) -> int:
        return self.fill_mean.shape[0]

    @property
    def identity_embedding(self) -> bool:
        return self.n == self.common_size and np.array_equal(self.index, np.arange(self.n))


def _per_axis(block: np.ndarray, axes: int) -> np.ndarray:
    return np.kron(np.eye(axes), block)


def kinematic_model(name: str, order: int, T: float, q: float, axes: int = 1, noise: str = "white",
                    fill_variance: float | None = None) -> MotionModel:
    """A per-axis kinematic model in the common state ``[p, v, a]`` per axis.

    Parameters
    ----------
    name : str
    order : int
        2 for constant velocity ``[p, v]``, 3 for constant acceleration ``[p, v, a]``.
    T : float
        Sample period (s).
    q : float
        Process-noise variance per axis.
    axes : int
        Number of independent axes (state order: all components of axis 0, then axis 1, ...).
    noise : str
        How ``w`` enters. ``"white"``: the highest derivative's white noise,
        ``Ψ = [T²/2, T]`` (CV, w = acceleration) or ``Ψ = [T³/6, T²/2, T]`` (CA, w = jerk), the
        thesis's IMM models (ch. V.3). ``"increment"`` (CA only): ``Ψ = [T²/2, T, 1]``, the
        thesis's target model (eq. 2.5), w = acceleration increment per sample.
    fill_variance : float, optional
        For CV: variance of the zero acceleration it is given in the common state (default q).

    Returns
    -------
    MotionModel
    """
    if order not in (2, 3):
        raise ValueError("order must be 2 or 3")
    if noise not in ("white", "increment") or (noise == "increment" and order != 3):
        raise ValueError(f"unknown noise form {noise!r} for order {order}")
    F1 = kinematic_transition(T, order)
    if noise == "white":
        # piecewise-constant white noise on the highest derivative: for CV exactly the
        # per-axis model of pipeline.cores.filters.kalman.white_acceleration_model (Q = q Ψ Ψᵀ)
        G1 = piecewise_white_noise_gain(T, order)[:, None]
    else:
        # the increment is applied at the start of the sample and propagates through Φ: Ψ = Φ e_a
        G1 = F1[:, -1:]
    H1 = np.zeros((1, order))
    H1[0, 0] = 1.0
    N = 3 * axes
    index = np.concatenate([3 * a + np.arange(order) for a in range(axes)])
    fill_cov = np.zeros((N, N))
    if order == 2:
        acc = 3 * np.arange(axes) + 2
        fill_cov[acc, acc] = q if fill_variance is None else fill_variance
    return MotionModel(name, _per_axis(F1, axes), _per_axis(G1, axes), q * np.eye(axes), _per_axis(H1, axes),
                       index, np.zeros(N), fill_cov, F_inv=_per_axis(kinematic_transition(-T, order), axes))


@dataclass
class ModelFilter:
    """A model and the filter that runs it (``"kf"`` or ``"srif"``)."""

    model: MotionModel
    kind: str = "kf"

    def __post_init__(self):
        if self.kind not in FILTER_KINDS:
            raise InputError(f"unknown filter kind {self.kind!r} (have: {', '.join(FILTER_KINDS)})")
        if self.kind == "srif":
            self.Rw = information_factor(self.model.q, f"process-noise covariance of model {self.model.name!r}")


# --------------------------------------------------------------------------- measurements


@dataclass
class MeasurementStream:
    """What every model of one IMM sees at each scan.

    Attributes
    ----------
    z : ndarray (runs, scans, m)
        Position measurements.
    R : ndarray (m, m)
        Nominal measurement covariance (used by the plain measurement).
    decorrelate : bool
        Use ``y_k = z_k − Ā z_{k−1}``, ``Ĥ``, ``diag(σ_η²)`` instead of ``z_k, H, R``.
    alpha, noise_variance : ndarray (runs, scans, m), optional
        ``ᾱ`` and ``σ_η²`` per scan (required when decorrelating). NaN entries (estimator not
        started or not warm) fall back to ``ᾱ = 0`` and ``σ_η² = R_ii``: the plain measurement.
    """

    z: np.ndarray
    R: np.ndarray
    decorrelate: bool = False
    alpha: np.ndarray | None = None
    noise_variance: np.ndarray | None = None

    def __post_init__(self):
        self.z = np.asarray(self.z, dtype=float)
        if self.z.ndim != 3:
            raise InputError(f"measurements must be (runs, scans, axes), got shape {self.z.shape}")
        require_finite("measurements", self.z)
        m = self.z.shape[-1]
        self.R = np.atleast_2d(np.asarray(self.R, dtype=float))
        if self.R.shape != (m, m):
            raise InputError(f"measurement covariance R must be {m}×{m}, got {self.R.shape}")
        self.Rv = information_factor(self.R, "measurement-noise covariance R")
        if not self.decorrelate:
            self.y = self.z
            return
        if self.alpha is None or self.noise_variance is None:
            raise InputError("decorrelated measurements need the AR estimates (alpha, noise_variance)")
        self.alpha = np.where(np.isfinite(self.alpha), self.alpha, 0.0)
        var = np.where(np.isfinite(self.noise_variance), self.noise_variance, np.diag(self.R))
        if np.any(var <= 0):
            raise InputError("decorrelated measurement variance σ_η² must be > 0")
        self.noise_variance = var
        self.y = pseudo_measurements(self.z, self.alpha)
        eye = np.eye(m)
        self.R_meas = var[..., :, None] * eye
        self.Rv_meas = eye / np.sqrt(var)[..., :, None]

    @property
    def runs(self) -> int:
        return self.z.shape[0]

    @property
    def scans(self) -> int:
        return self.z.shape[1]

    def at(self, k: int):
        """``(y, R_meas, R_v, alpha)`` at scan ``k ≥ 1``, each with a model axis of length 1 after
        the run axis where it varies per run (alpha is None for the plain measurement)."""
        if not self.decorrelate:
            return self.y[:, k, None], self.R, self.Rv, None
        return self.y[:, k, None], self.R_meas[:, k, None], self.Rv_meas[:, k, None], self.alpha[:, k, None]


# --------------------------------------------------------------------------- model groups


class _Group:
    """Models with the same filter kind and state layout, stacked on a model axis so that one
    batched call filters all of them (the thesis's two CA models share one call)."""

    def __init__(self, members: list[int], filters: list[ModelFilter]):
        self.members = np.asarray(members)
        fs = [filters[i] for i in members]
        mods = [f.model for f in fs]
        self.kind = fs[0].kind
        self.model = mods[0]
        self.identity = self.model.identity_embedding
        self.index = self.model.index
        stack = lambda name: np.stack([getattr(m, name) for m in mods])  # noqa: E731
        self.F, self.Q, self.G, self.H_Phi_inv = (stack(a) for a in ("F", "Q", "G", "H_Phi_inv"))
        self.H = self.model.H
        self.fill_mean, self.fill_cov = stack("fill_mean"), stack("fill_cov")
        if self.kind == "srif":
            self.Rw = np.stack([f.Rw for f in fs])

    def measurement_matrix(self, alpha):
        return self.H if alpha is None else decorrelated_measurement_matrix(self.H, self.H_Phi_inv, alpha)


def _group_models(filters: list[ModelFilter]) -> list[_Group]:
    keys: dict = {}
    for i, f in enumerate(filters):
        m = f.model
        key = (f.kind, m.n, tuple(m.index), m.H.tobytes(), m.G.shape)
        keys.setdefault(key, []).append(i)
    return [_Group(members, filters) for members in keys.values()]


# --------------------------------------------------------------------------- filter steps


def kf_step(g: _Group, x, P, y, H, R_meas, Rv):
    """Model-matched Kalman step (thesis eqs. 4.1.1–4.1.5) plus ``log Λ``, the NIS, the
    innovation ``ν`` and its covariance ``S``."""
    x, P = kf_predict(x, P, g.F, g.Q)
    x, P, nu, S, _ = kf_update(x, P, y, H, R_meas)
    ll, nis, _ = gaussian_log_likelihood(nu, S, return_parts=True)
    return x, P, ll, nis, nu, S


def srif_step(g: _Group, x, P, y, H, R_meas, Rv):
    """Model-matched SRIF step (4.3.5–4.3.13) from the mixed moments (4.3.6–4.3.7): the one SRIF
    recursion (:func:`pipeline.cores.filters.srif.srif_predict_update`) between the moment conversions."""
    R, z = srif_from_moments(x, P)
    R, z, e, ll = srif_predict_update(R, z, g.F, g.G, g.Rw, H, y, Rv)
    x, P = srif_moments(R, z)
    return x, P, ll, e * e, None, None  # the QR gives ‖e‖, not the innovation itself


STEPS = {"kf": kf_step, "srif": srif_step}


# --------------------------------------------------------------------------- the core


def check_transition(transition, n_models: int) -> np.ndarray:
    """Validate a Markov transition matrix ``p_ij`` (rows: from, columns: to)."""
    p = np.asarray(transition, dtype=float)
    if p.shape != (n_models, n_models):
        raise InputError(f"transition matrix must be {n_models}×{n_models} for {n_models} models, got {p.shape}")
    if not np.all(np.isfinite(p)) or np.any(p < 0):
        raise InputError("transition matrix entries must be finite and ≥ 0")
    sums = p.sum(axis=1)
    bad = np.nonzero(np.abs(sums - 1.0) > 1e-9)[0]
    if bad.size:
        i = int(bad[0])
        raise InputError(f"transition matrix row {i + 1} sums to {sums[i]:.6g}, not 1")
    unreachable = np.nonzero(p.sum(axis=0) == 0)[0]
    if unreachable.size:
        raise InputError(f"transition matrix column {int(unreachable[0]) + 1} is all zero: that model can never be entered")
    return p


def _weighted_moments(w, X, PP):
    """``Σ_i w_ij [P_i + (x_i − x̄_j)(x_i − x̄_j)ᵀ]`` and ``x̄_j = Σ_i w_ij x_i`` for every j.

    ``w`` (runs, M, J), ``X`` (runs, M, N), ``PP`` (runs, M, N, N) → (runs, J, N), (runs, J, N, N).
    """
    runs, M, N = X.shape
    xbar = np.swapaxes(w, 1, 2) @ X                                  # (runs, J, N)
    D = X[:, None, :, :] - xbar[:, :, None, :]                        # (runs, J, M, N)
    wt = np.swapaxes(w, 1, 2)[..., None]                              # (runs, J, M, 1)
    spread = np.swapaxes(D * wt, -1, -2) @ D                          # (runs, J, N, N)
    Pbar = (np.swapaxes(w, 1, 2) @ PP.reshape(runs, M, N * N)).reshape(runs, -1, N, N)
    return xbar, Pbar + spread


def imm_filter(filters: list[ModelFilter], transition, x0, P0, stream: MeasurementStream,
               mu0=None, start: int = 1) -> dict:
    """Run an IMM (or, with one model, that model's filter) over every run at once.

    Parameters
    ----------
    filters : list of ModelFilter
        Models and their filters; models may have different state sizes (see module docstring).
    transition : array_like (M, M)
        ``p_ij`` = P(model j at k | model i at k−1); rows must sum to 1.
    x0 : ndarray (runs, N) or (N,)
        Initial common-state estimate (every model starts from it).
    P0 : ndarray (runs, N, N) or (N, N)
    stream : MeasurementStream
    mu0 : array_like (M,), optional
        Initial model probabilities (default uniform).
    start : int
        First scan with a measurement update; scan ``start − 1`` holds the initial values
        (a decorrelated measurement needs ``z_{k−1}``, so the default is 1).

    Returns
    -------
    dict of ndarray
        ``state`` (runs, scans, N), ``covariance`` (runs, scans, N, N), ``model_probabilities``,
        ``log_likelihood``, ``nis`` (runs, scans, M). Scans before ``start − 1`` are NaN.
        A single Kalman model (``M = 1``, kind ``"kf"``) also returns ``innovation``
        (runs, scans, m) and ``innovation_covariance`` (runs, scans, m, m), NaN up to scan
        ``start − 1``: of ``y_k`` (and ``Ĥ``) for a decorrelated stream.
    """
    M = len(filters)
    if M == 0:
        raise InputError("an IMM needs at least one model")
    p = check_transition(transition, M)
    N = filters[0].model.common_size
    if any(f.model.common_size != N for f in filters):
        raise InputError("all models of one IMM must share the common state size")
    if any(f.model.H.shape[0] != stream.z.shape[-1] for f in filters):
        raise InputError("model measurement size does not match the measurements")
    runs, scans = stream.runs, stream.scans
    mu = np.full(M, 1.0 / M) if mu0 is None else np.asarray(mu0, dtype=float)
    if mu.shape != (M,) or np.any(mu < 0) or abs(mu.sum() - 1.0) > 1e-9:
        raise InputError("initial model probabilities must be M values ≥ 0 summing to 1")
    groups = _group_models(filters)
    mu = np.broadcast_to(mu, (runs, M)).copy()
    x = np.broadcast_to(np.asarray(x0, dtype=float), (runs, N)).copy()
    P = np.broadcast_to(np.asarray(P0, dtype=float), (runs, N, N)).copy()
    X = np.repeat(x[:, None], M, axis=1)          # (runs, M, N) per-model estimates, common state
    PP = np.repeat(P[:, None], M, axis=1)         # (runs, M, N, N)
    out = {"state": np.full((runs, scans, N), np.nan), "covariance": np.full((runs, scans, N, N), np.nan),
           "model_probabilities": np.full((runs, scans, M), np.nan),
           "log_likelihood": np.full((runs, scans, M), np.nan), "nis": np.full((runs, scans, M), np.nan)}
    first = max(start - 1, 0)
    out["state"][:, first], out["covariance"][:, first], out["model_probabilities"][:, first] = x, P, mu
    single = M == 1
    m_meas = stream.z.shape[-1]
    if single and filters[0].kind == "kf":
        out["innovation"] = np.full((runs, scans, m_meas), np.nan)
        out["innovation_covariance"] = np.full((runs, scans, m_meas, m_meas), np.nan)
    tiny = np.finfo(float).tiny
    # index grids that read and write a group's own components of the common state in one step
    for g in groups:
        J, idx = g.members, g.index
        g.read_x = (slice(None), J[:, None], idx[None, :])
        g.read_P = (slice(None), J[:, None, None], idx[None, :, None], idx[None, None, :])
    for k in range(start, scans):
        y, R_meas, Rv, alpha = stream.at(k)
        ll = out["log_likelihood"][:, k]              # views: the groups write their columns in place
        nis = out["nis"][:, k]
        if single:
            X0, P0m, cbar = X, PP, np.ones((runs, 1))
        else:
            # 4.3.3–4.3.4: c̄_j = Σ_i p_ij μ_i, μ_{i|j} = p_ij μ_i / c̄_j
            w = p * mu[:, :, None]
            cbar = w.sum(axis=1)
            w /= np.maximum(cbar, tiny)[:, None, :]
            X0, P0m = _weighted_moments(w, X, PP)                     # 4.3.1–4.3.2, common state
        for g in groups:
            J = g.members
            if g.identity:
                xj, Pj = X0[:, J], P0m[:, J]
            else:
                xj, Pj = X0[g.read_x], P0m[g.read_P]
            H = g.measurement_matrix(alpha)
            xj, Pj, ll[:, J], nis[:, J], nu, S = STEPS[g.kind](g, xj, Pj, y, H, R_meas, Rv)
            if single and nu is not None:
                out["innovation"][:, k], out["innovation_covariance"][:, k] = nu[:, 0], S[:, 0]
            if g.identity:
                X[:, J], PP[:, J] = xj, Pj
            else:
                if k == start:   # the components the model lacks take their fixed fill once and keep it
                    X[:, J], PP[:, J] = g.fill_mean, g.fill_cov
                X[g.read_x], PP[g.read_P] = xj, Pj
        # 4.3.14–4.3.15 in logs (a far-off model's likelihood underflows otherwise); the floor keeps
        # every reachable model's c̄ positive
        logw = np.log(np.maximum(cbar, tiny)) + ll
        logw -= logw.max(axis=1, keepdims=True)
        mu = np.exp(logw)
        mu /= mu.sum(axis=1, keepdims=True)
        np.maximum(mu, tiny, out=mu)
        if single:
            x, P = X[:, 0], PP[:, 0]
        else:
            xs, Ps = _weighted_moments(mu[:, :, None], X, PP)          # 4.3.16–4.3.17
            x, P = xs[:, 0], Ps[:, 0]
        out["state"][:, k], out["covariance"][:, k], out["model_probabilities"][:, k] = x, P, mu
    return out


def single_model_filter(f: ModelFilter, x0, P0, stream: MeasurementStream, start: int = 1) -> dict:
    """One model's filter: the IMM core with that model alone (mixing and combination are
    identities then, which tests/test_colored_imm.py checks against independent loops)."""
    return imm_filter([f], [[1.0]], x0, P0, stream, start=start)
