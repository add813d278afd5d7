"""One interacting-multiple-model (IMM) core for any model set, including models of different
state sizes (Blom & Bar-Shalom 1988; Kwon 1997 ch. IV.3).

Kwon (1997), ch. IV.3 (thesis eqs. 4.3.1–4.3.4 mixing, 4.3.5–4.3.10 model-matched filtering,
4.3.11–4.3.15 model probabilities, 4.3.16–4.3.17 combination); see
``docs/papers/colored.md``. Every model of every Monte Carlo run advances in one pass
per scan.

Models are strategies over the same core:

* a :class:`MotionModel` (Φ, Ψ, q, H, and where its states sit in the common state);
* a filter kind: ``"kf"`` (:func:`~trackreplay.cores.filters.kalman.stacked_kf_step`: the Kalman filter of
  :mod:`trackreplay.cores.filters.kalman` with the gain written through the whitened innovation) or
  ``"srif"`` (:func:`~trackreplay.cores.filters.srif.stacked_srif_step`: the SRIF recursion of :mod:`trackreplay.cores.filters.srif`,
  QR time and measurement updates, likelihood from the residual and the triangular factors);
* the measurement of the whole IMM (:class:`MeasurementStream`): plain ``(z_k, H, R)`` or
  decorrelated ``(y_k, Ĥ, diag σ_η²)`` (:mod:`trackreplay.cores.filters.decorrelation`; ``Ĥ`` per model, since it
  depends on Φ). All models of one IMM see the same measurement, so their likelihoods compare.

The thesis's sets: IMM = plain + KF, MIMM_K = decorrelated + KF, PIMM = decorrelated + SRIF, each
with one 2-state constant-velocity (CV) and two 3-state constant-acceleration (CA) models.
All models of one filter kind are embedded in the common state and stacked on a model axis, with
the runs on the last axis, and filtered by one batched step per scan; model probabilities are
updated in logs, so a model whose likelihood underflows does not break the normalisation.

Speed (``docs/benchmarks.md``, ``benchmarks/bench_imm.py``): a scan costs a fixed number of array
operations over all models and runs. The constant matrices (Φ, Q, H, H Φ⁻¹, the SRIF's
``[−Φ⁻¹Ψ | Φ⁻¹]``) are laid out once; the small factorisations are entry by entry
(:mod:`trackreplay.batched_linalg`) instead of one LAPACK call per matrix; the mixing
is one product with the constant transition matrix for all runs, reusing the terms of the
previous scan's combination.

Mixing rule for unequal state sizes
-----------------------------------
Mixing and combination happen in a *common* state (per axis ``[position, velocity,
acceleration]``). A model's estimate enters it through its embedding: its own components are
copied, components it lacks are filled with a fixed mean and variance, uncorrelated with the
rest. For the CV model that is a zero acceleration whose variance is the CV model's own
white-acceleration variance q_CV (``fill_cov``): the acceleration the CV model assumes, as a
random variable. Mixed initial conditions are computed in the common state (4.3.1–4.3.2) and each
model filters only its own components. This is exactly what an equal-size IMM does with the CV
model written as a 3-state model whose acceleration row and column of Φ are zero and whose process
noise puts q_CV on the acceleration (FilterPy's ``IMMEstimator`` with that embedding gives the same
numbers: ``benchmarks/bench_imm.py`` prints the difference), and it is how the Kalman models run
here; the SRIF models, which need Φ⁻¹, carry the missing components as a decoupled state instead
(see :class:`_Stack`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackreplay.cores.filters.decorrelation import inverse_transition_rows, pseudo_measurements, transition_inverse_check
from trackreplay.cores.filters.kalman import kinematic_transition, piecewise_white_noise_gain, stacked_kf_step
from trackreplay.cores.filters.srif import information_factor, stacked_srif_step
from trackreplay.errors import InputError, require_finite

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
        # per-axis model of trackreplay.cores.filters.kalman.white_acceleration_model (Q = q Ψ Ψᵀ)
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

    @property
    def runs(self) -> int:
        return self.z.shape[0]

    @property
    def scans(self) -> int:
        return self.z.shape[1]

    def runs_last(self) -> "_RunsLast":
        """The stream laid out scan by scan with the runs last, as the IMM core reads it."""
        return _RunsLast(self)


class _RunsLast:
    """A :class:`MeasurementStream` per scan, runs last: ``y`` (m, runs), ``ᾱ`` (m, runs) or None,
    the measurement covariance (m, m, 1 or runs) and, for SRIF models, its information factor
    (m, m, 1 or runs) and ``log|R_ν|`` (scalar or runs). The per-scan covariances of a
    decorrelated stream are formed scan by scan from ``σ_η²`` (a few small operations) rather than
    held for the whole record."""

    def __init__(self, stream: MeasurementStream):
        self.y = np.ascontiguousarray(stream.y.transpose(1, 2, 0))
        self.m = self.y.shape[1]
        if not stream.decorrelate:
            self.alpha = None
            self.R_meas = stream.R[:, :, None]
            self.Rv = stream.Rv[:, :, None]
            self.log_det_Rv = float(np.log(np.abs(np.diag(stream.Rv))).sum())
            return
        self.alpha = np.ascontiguousarray(stream.alpha.transpose(1, 2, 0))
        self.var = np.ascontiguousarray(stream.noise_variance.transpose(1, 2, 0))     # (scans, m, runs)
        self.eye = np.eye(self.m)[:, :, None]

    def at(self, k: int, information: bool = False):
        if self.alpha is None:
            return self.y[k], None, self.R_meas, self.Rv, self.log_det_Rv
        var = self.var[k]
        R_meas = var[None] if self.m == 1 else var[:, None] * self.eye        # diag σ_η²
        if not information:
            return self.y[k], self.alpha[k], R_meas, None, None
        sd = np.sqrt(var)
        Rv = (1.0 / sd)[None] if self.m == 1 else self.eye / sd[:, None]     # its information factor
        return self.y[k], self.alpha[k], R_meas, Rv, -_sum(np.log(sd), 0)


# --------------------------------------------------------------------------- model stacks
#
# Every model of one IMM runs in the common state with the runs on the last axis: per-model
# estimates X (M, N, runs), covariances PP (M, N, N, runs). Models of one filter kind are stacked
# on the model axis and advance in one batched step, with every constant (Φ, Q, H, H Φ⁻¹, the
# SRIF's [−Φ⁻¹Ψ | Φ⁻¹]) laid out once as (models, ..., 1) so that it broadcasts over the runs.
# The small factorisations are entry by entry (trackreplay.batched_linalg): a few
# dozen array operations per scan whatever the number of runs, instead of one LAPACK call per
# matrix.


def _fill_parts(mod: MotionModel, N: int):
    """The model's own index, its missing components, and its fill (checked uncorrelated with
    its own components, as the mixing rule states)."""
    idx = mod.index
    missing = np.setdiff1d(np.arange(N), idx)
    fill_cov = np.asarray(mod.fill_cov, dtype=float)
    fill_mean = np.asarray(mod.fill_mean, dtype=float)
    if np.any(fill_cov[np.ix_(idx, np.arange(N))] != 0) or np.any(fill_mean[idx] != 0):
        raise InputError(f"model {mod.name!r}: the fill must be zero on the model's own components "
                         "(the components it lacks are uncorrelated with the rest)")
    return idx, missing, fill_mean, fill_cov


class _Stack:
    """Models of one filter kind, embedded in the common state and stacked on a model axis."""

    def __init__(self, members: list[int], filters: list[ModelFilter], N: int, m: int):
        self.members = np.asarray(members)
        fs = [filters[i] for i in members]
        self.kind = fs[0].kind
        G = len(fs)
        self.H = np.zeros((G, m, N, 1))
        self.H_Phi_inv = np.zeros((G, m, N, 1))
        self.fill_mean = np.zeros((G, N, 1))
        self.fill_cov = np.zeros((G, N, N, 1))
        for g, f in enumerate(fs):
            idx, _, fm, fc = _fill_parts(f.model, N)
            self.H[g][:, idx, 0] = f.model.H
            self.H_Phi_inv[g][:, idx, 0] = f.model.H_Phi_inv
            self.fill_mean[g, :, 0] = fm
            self.fill_cov[g, :, :, 0] = fc
        self.has_fill = bool(np.any(self.fill_mean != 0))
        getattr(self, f"_init_{self.kind}")(fs, N)

    def measurement_matrix(self, alpha):
        """``H`` (plain) or ``Ĥ = H − Ā H Φ⁻¹`` (eq. 3.1.3) per model and run: (G, m, N, 1 or runs)."""
        return self.H if alpha is None else self.H - alpha[None, :, None, :] * self.H_Phi_inv

    # --- Kalman models: the embedding is exact with Φ's rows and columns of the missing
    # components zero and Q carrying their fill: the prediction then holds the fill, uncorrelated,
    # and the update leaves it alone (its gain rows are zero because its column of H is).

    def _init_kf(self, fs, N):
        G = len(fs)
        self.F = np.zeros((G, N, N))
        self.Q = self.fill_cov.copy()
        for g, f in enumerate(fs):
            own = np.ix_(f.model.index, f.model.index)
            self.F[g][own] = f.model.F
            self.Q[g][own + (0,)] = f.model.Q

    # --- SRIF models: the missing components are made a decoupled state (Φ = I, no noise, no
    # measurement, unit variance) that every orthogonal transformation leaves exactly as it is;
    # afterwards they take their fill back. Process noises of different sizes are padded with
    # decoupled unit-information rows.

    def _init_srif(self, fs, N):
        G = len(fs)
        p = max(f.model.G.shape[1] for f in fs)
        self.p = p
        self.mask = np.zeros((G, N, N, 1))
        self.vmask = np.zeros((G, N, 1))
        self.dummy = np.zeros((G, N, N, 1))
        self.C = np.zeros((G, N, p + N, 1))          # [−Φ⁻¹Ψ | Φ⁻¹] of the decoupled embedding
        self.Rw = np.zeros((G, p, p, 1))
        for g, f in enumerate(fs):
            mod = f.model
            idx, missing, _, _ = _fill_parts(mod, N)
            self.mask[g][np.ix_(idx, idx)] = 1.0
            self.vmask[g, idx] = 1.0
            self.dummy[g, missing, missing] = 1.0
            # Φ⁻¹Ψ and Φ⁻¹ once per model: the model's exact inverse when it knows it (Φ(−T) of a
            # kinematic model), else one solve with Φ (validated non-singular by MotionModel)
            if mod.F_inv is not None:
                Phi_inv = mod.F_inv
                Phi_inv_Psi = mod.F_inv @ mod.G
            else:
                sol = np.linalg.solve(mod.F, np.concatenate([mod.G, np.eye(mod.n)], axis=1))
                Phi_inv_Psi, Phi_inv = sol[:, :mod.G.shape[1]], sol[:, mod.G.shape[1]:]
            pg = mod.G.shape[1]
            self.C[g][np.ix_(idx, np.arange(pg), [0])] = -Phi_inv_Psi[:, :, None]
            self.C[g][np.ix_(idx, p + idx, [0])] = Phi_inv[:, :, None]
            self.C[g, missing, p + missing] = 1.0
            self.Rw[g, :pg, :pg, 0] = f.Rw
            self.Rw[g, pg:, pg:, 0] = np.eye(p - pg)
        self.decoupled = bool(self.dummy.any())
        # log|Φ| − log|R_w| of the embedding, for |R⁻| in the likelihood
        self.log_det_Phi_over_Rw = np.array([np.linalg.slogdet(f.model.F)[1] - np.log(np.abs(np.diag(f.Rw))).sum()
                                             for f in fs])[:, None]


_sum = np.add.reduce   # ndarray.sum's Python wrapper costs more than the sum of a few small arrays


def _stack_models(filters: list[ModelFilter], N: int, m: int) -> list[_Stack]:
    kinds: dict = {}
    for i, f in enumerate(filters):
        kinds.setdefault(f.kind, []).append(i)
    return [_Stack(members, filters, N, m) for members in kinds.values()]


# --------------------------------------------------------------------------- filter steps


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


def _combine(mu, X, PP, E):
    """Combination (4.3.16–4.3.17), runs last: ``x = Σ_j μ_j x_j`` and
    ``P = Σ_j μ_j [P_j + (x_j − x)(x_j − x)ᵀ]``.

    ``mu`` (M, runs), ``X`` (M, N, runs), ``PP`` (M, N, N, runs). ``E`` (M, N + N², runs) receives
    ``[x_j − x, P_j + (x_j − x)(x_j − x)ᵀ]``, which is what the next scan's mixing needs.
    Returns ``x`` (N, runs) and ``P`` (N, N, runs).
    """
    M, N, R = X.shape
    x = _sum(mu[:, None] * X, 0)
    D = E[:, :N]
    T = E[:, N:].reshape(M, N, N, R)
    np.subtract(X, x, out=D)
    np.multiply(D[:, :, None], D[:, None], out=T)
    T += PP
    return x, _sum(mu[:, None, None] * T, 0)


def _mix(p, mu, c, E, tiny):
    """Mixing (4.3.1–4.3.4), runs last, from the previous combination's ``c = x`` and
    ``E = [x_i − c, P_i + (x_i − c)(x_i − c)ᵀ]`` (:func:`_combine`).

    With ``μ_{i|j} = p_ij μ_i / c̄_j`` and ``d_j = Σ_i μ_{i|j} (x_i − c)``: ``x̄_j = c + d_j`` and
    ``P̄_j = Σ_i μ_{i|j} [P_i + (x_i − c)(x_i − c)ᵀ] − d_j d_jᵀ``, which equals
    ``Σ_i μ_{i|j} [P_i + (x_i − x̄_j)(x_i − x̄_j)ᵀ]`` because the weights sum to one. Centred on
    the combined estimate the terms are of the size of the models' spread, so nothing cancels
    beyond it, and the sum over i is one product with the constant ``pᵀ`` for every run.

    Returns ``x̄`` (M, N, runs), ``P̄`` (M, N, N, runs) and ``c̄`` floored at ``tiny`` (M, runs).
    """
    M, K, R = E.shape
    N = c.shape[0]
    cbar = np.maximum(p.T @ mu, tiny)                             # 4.3.3: c̄_j = Σ_i p_ij μ_i
    Z = np.matmul(p.T, (E * mu[:, None]).reshape(M, K * R)).reshape(M, K, R)
    Z /= cbar[:, None]
    d = Z[:, :N]
    P0 = Z[:, N:].reshape(M, N, N, R)
    P0 -= d[:, :, None] * d[:, None]
    return c + d, P0, cbar


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

    Notes
    -----
    All models and runs advance together, one pass per scan, with the runs on the last axis
    (see :mod:`trackreplay.batched_linalg`); the mixing (4.3.1–4.3.4), the model
    probabilities in logs (4.3.14–4.3.15) and the combination (4.3.16–4.3.17) are each a handful
    of array operations over all models and runs.
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
    m_meas = stream.z.shape[-1]
    stacks = _stack_models(filters, N, m_meas)
    one_stack = len(stacks) == 1
    x = np.broadcast_to(np.asarray(x0, dtype=float), (runs, N))
    P = np.broadcast_to(np.asarray(P0, dtype=float), (runs, N, N))
    out = {"state": np.full((runs, scans, N), np.nan), "covariance": np.full((runs, scans, N, N), np.nan),
           "model_probabilities": np.full((runs, scans, M), np.nan),
           "log_likelihood": np.full((runs, scans, M), np.nan), "nis": np.full((runs, scans, M), np.nan)}
    first = max(start - 1, 0)
    out["state"][:, first], out["covariance"][:, first], out["model_probabilities"][:, first] = x, P, mu
    single = M == 1
    innovations = single and filters[0].kind == "kf"
    if innovations:
        out["innovation"] = np.full((runs, scans, m_meas), np.nan)
        out["innovation_covariance"] = np.full((runs, scans, m_meas, m_meas), np.nan)
    # runs last from here on
    mu = np.repeat(mu[:, None], runs, axis=1)                        # (M, runs)
    x = np.ascontiguousarray(x.T)                                    # (N, runs)
    P = np.ascontiguousarray(P.transpose(1, 2, 0))                   # (N, N, runs)
    X = np.repeat(x[None], M, axis=0)                                # (M, N, runs)
    PP = np.repeat(P[None], M, axis=0)
    E = np.zeros((M, N + N * N, runs))                               # [x_i − x, P_i + (x_i − x)(…)ᵀ]
    E[:, N:] = PP.reshape(M, N * N, runs)
    meas = stream.runs_last()
    information = any(st.kind == "srif" for st in stacks)
    tiny = np.finfo(float).tiny
    ll = np.empty((M, runs))
    nis = np.empty((M, runs))
    views = (out["state"].transpose(1, 2, 0), out["covariance"].transpose(1, 2, 3, 0),
             out["model_probabilities"].transpose(1, 2, 0), out["log_likelihood"].transpose(1, 2, 0),
             out["nis"].transpose(1, 2, 0))
    for k in range(start, scans):
        y, alpha, R_meas, Rv, log_det_Rv = meas.at(k, information)
        if single:
            X0, P0m = X, PP
        else:
            X0, P0m, cbar = _mix(p, mu, x, E, tiny)                   # 4.3.1–4.3.4, common state
        for st in stacks:
            J = st.members
            xs, Ps = (X0, P0m) if one_stack else (X0[J], P0m[J])
            H = st.measurement_matrix(alpha)
            if st.kind == "kf":
                xs, Ps, llj, nisj, nu, S = stacked_kf_step(st.F, st.Q, st.fill_mean if st.has_fill else None, xs, Ps, y, H, R_meas)
                if innovations:
                    out["innovation"][:, k] = nu[0].T
                    out["innovation_covariance"][:, k] = S[0].transpose(2, 0, 1)
            else:
                xs, Ps, llj, nisj = stacked_srif_step(st, xs, Ps, y, H, Rv, log_det_Rv)
            if one_stack:
                X, PP = xs, Ps
                ll, nis = llj, nisj
            else:
                X[J], PP[J], ll[J], nis[J] = xs, Ps, llj, nisj
        if single:
            mu = np.ones((1, runs))
            x, P = X[0], PP[0]
        else:
            # 4.3.14–4.3.15 in logs (a far-off model's likelihood underflows otherwise); the floor
            # keeps every reachable model's c̄ positive
            logw = np.log(cbar)
            logw += ll
            logw -= logw.max(axis=0)
            mu = np.exp(logw)
            mu /= _sum(mu, 0)
            np.maximum(mu, tiny, out=mu)
            x, P = _combine(mu, X, PP, E)                              # 4.3.16–4.3.17
        views[0][k], views[1][k], views[2][k], views[3][k], views[4][k] = x, P, mu, ll, nis
    return out


def single_model_filter(f: ModelFilter, x0, P0, stream: MeasurementStream, start: int = 1) -> dict:
    """One model's filter: the IMM core with that model alone (mixing and combination are
    identities then, which tests/test_colored_imm.py checks against independent loops)."""
    return imm_filter([f], [[1.0]], x0, P0, stream, start=start)
