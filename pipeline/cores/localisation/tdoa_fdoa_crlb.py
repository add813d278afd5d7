"""The TDOA/FDOA Cramér-Rao bound at a given emitter state, for one geometry or every cell.

Kim et al. (2013), eqs. 18–22 (see ``docs/papers/tdoa-fdoa.md``): the
bound of an estimator that uses the measurement rows of its kind (``joint`` TDOA + FDOA,
``tdoa`` or ``fdoa`` only, :func:`trackreplay.cores.localisation.tdoa_fdoa_model.measurement_rows`)
and solves for its unknowns (:func:`trackreplay.cores.localisation.tdoa_fdoa_model.unknowns`)::

    A = Ψ^{-1/2} H(θ)[rows, unknowns],   I = AᵀA,   CRLB = I⁻¹     (18)

* :func:`truth_geometry` — ``A`` and the CRLB at the true state of every (run, epoch) cell: what
  the evaluator's run classification (d² = ‖A e‖²) and efficiency need;
* :func:`truth_bounds` — the same for every estimator kind, as the named arrays of the stage's
  ``crlb`` extra output (read by :mod:`trackreplay.evaluators.tdoa_fdoa`);
* :func:`crlb_summary` — the bound of one geometry with its projections (eq. 19), slices
  (eq. 20), ellipses and CEPs (eqs. 21–22) as plain numbers (``replay crlb``).

The CRLB comes from the QR factor of the whitened, column-scaled Jacobian
(:func:`trackreplay.cores.localisation.batched_least_squares.information_covariance`); the
information matrix is neither formed nor inverted.
"""

from __future__ import annotations

import numpy as np

from trackreplay.cores.localisation.batched_least_squares import information_covariance
from trackreplay.cores.localisation.crlb import (cep_approx, cep_exact, cep_paper, crlb, error_ellipse,
                                              projection_covariance, slice_covariance, whitened_jacobian)
from trackreplay.cores.localisation.tdoa_fdoa_model import (MEASUREMENT_KINDS, STATE_NAMES, independent_equations,
                                                         measurement_model, measurement_rows, underdetermined_reason,
                                                         unknowns)
from trackreplay.errors import InputError


def truth_geometry(truth_state, sensor_pos, sensor_vel, pairs, carrier_hz, sigma, kind, stationary):
    """Whitened Jacobian at the truth and the CRLB over the estimator's unknowns.

    Parameters
    ----------
    truth_state : ndarray (..., 4)
        True [x, y, ẋ, ẏ] per cell (any leading shape, e.g. runs × epochs).
    sensor_pos, sensor_vel : ndarray (..., M, 2)
    pairs : ndarray of int (N, 2)
    carrier_hz : ndarray (...)
    sigma : ndarray (..., 2N)
        σ of every measurement in g's layout (eq. 5).
    kind : str
        ``joint``, ``tdoa`` or ``fdoa``.
    stationary : bool
        Velocity known (position unknowns only).

    Returns
    -------
    A : ndarray (..., m, q)
        Ψ^{-1/2} H over the kind's m rows and q unknowns (the first q state components).
    cov : ndarray (..., q, q)
        CRLB (eq. 18), NaN where singular.
    singular : ndarray of bool (...)
        No CRLB (e.g. emitter collinear with the sensors, or non-finite Jacobian).
    """
    rows = measurement_rows(kind, len(pairs))
    free = unknowns(kind, stationary)
    with np.errstate(all="ignore"):
        _, H = measurement_model(truth_state, sensor_pos, sensor_vel, pairs, carrier_hz)
        A = H[..., rows, :][..., free] / sigma[..., rows, None]
    finite = np.all(np.isfinite(A), axis=(-2, -1))
    cov, singular = information_covariance(np.where(finite[..., None, None], A, 0.0))
    return A, cov, singular | ~finite


def truth_bounds(truth_state, sensor_pos, sensor_vel, pairs, carrier_hz, sigma, stationary: bool,
                 kinds=MEASUREMENT_KINDS) -> dict:
    """:func:`truth_geometry` for every estimator kind, as named output arrays.

    Parameters
    ----------
    truth_state : ndarray (R, E, 4) or None
        Without truth the arrays keep their shapes (so the layout of every kind is known) and
        are NaN, with every cell ``singular``.
    sensor_pos, sensor_vel : ndarray (R, E, M, 2)
    pairs : ndarray of int (N, 2)
    carrier_hz : ndarray (R, E)
    sigma : ndarray (R, E, 2N)
    stationary : bool

    Returns
    -------
    dict of ndarray
        Per kind k: ``whitened_jacobian_<k>`` (R, E, m, q), ``crlb_covariance_<k>`` (R, E, q, q)
        and ``crlb_singular_<k>`` (R, E) bool.
    """
    sigma = np.asarray(sigma, float)
    R, E = sigma.shape[:2]
    out = {}
    for kind in kinds:
        if truth_state is None:
            m, q = len(measurement_rows(kind, len(pairs))), len(unknowns(kind, stationary))
            A, cov, singular = np.full((R, E, m, q), np.nan), np.full((R, E, q, q), np.nan), np.ones((R, E), bool)
        else:
            A, cov, singular = truth_geometry(truth_state, sensor_pos, sensor_vel, pairs, carrier_hz, sigma, kind,
                                              stationary)
        out[f"whitened_jacobian_{kind}"] = A
        out[f"crlb_covariance_{kind}"] = cov
        out[f"crlb_singular_{kind}"] = np.asarray(singular, bool)
    return out


def singular_message(A) -> str:
    """Why no CRLB exists, with the rank of the whitened Jacobian ``A`` (m, q)."""
    norms = np.linalg.norm(A, axis=0)
    s = np.linalg.svd(A / np.where(norms > 0, norms, 1.0), compute_uv=False)
    rank = int(np.sum(s > 1e-10 * s.max())) if s.size and s.max() > 0 else 0
    return (f"the Fisher information is singular here (rank {rank} of {A.shape[1]}): the emitter is collinear "
            "with the sensors or the pairs do not separate the unknowns, so no CRLB exists")


def crlb_summary(theta, sensor_pos, sensor_vel, pairs, carrier_hz, sigma, kind: str = "joint",
                 stationary: bool = False, probability: float = 0.5) -> dict:
    """CRLB, projections, slices, ellipses and CEPs of one geometry, as plain numbers.

    Parameters
    ----------
    theta : ndarray (4,)
        Emitter state [x, y, ẋ, ẏ].
    sensor_pos, sensor_vel : ndarray (M, 2)
    pairs : ndarray of int (N, 2)
    carrier_hz : float
    sigma : ndarray (2N,)
    kind : str
        ``joint``, ``tdoa`` or ``fdoa``.
    stationary : bool
    probability : float
        P_e of the ellipses and CEPs.

    Returns
    -------
    dict
        ``estimator``, ``state_names``, ``emitter``, ``independent_equations``, ``unknowns``,
        ``crlb`` (q × q), ``std``, ``probability`` and, per block (``position``, and
        ``velocity`` with 4 unknowns), the ``projection`` (eq. 19) and ``slice`` (eq. 20) with
        their covariance, ellipse semi-axes and angle, and CEP (exact, eq. 21, 0.75·√(λ1+λ2)).

    Raises
    ------
    InputError
        The estimator is underdetermined for the pair list, or no CRLB exists here.
    """
    n_sensors = np.asarray(sensor_pos).shape[0]
    reason = underdetermined_reason(kind, pairs, n_sensors, stationary)
    if reason:
        raise InputError(reason)
    rows, free = measurement_rows(kind, len(pairs)), unknowns(kind, stationary)
    theta = np.asarray(theta, float)
    _, H = measurement_model(theta, sensor_pos, sensor_vel, pairs, carrier_hz)
    Hs, sigma = H[rows][:, free], np.asarray(sigma, float)[rows]
    cov, singular = crlb(Hs[None], sigma[None])
    A = whitened_jacobian(Hs, sigma)
    if singular[0]:
        raise InputError(singular_message(A))
    cov = cov[0]
    out = {"estimator": kind, "state_names": [STATE_NAMES[i] for i in free], "emitter": theta.tolist(),
           "independent_equations": independent_equations(kind, pairs, n_sensors),
           "unknowns": len(free), "crlb": cov.tolist(), "std": np.sqrt(np.diag(cov)).tolist(),
           "probability": probability, "blocks": {}}
    blocks = [("position", [0, 1], "m")] + ([("velocity", [2, 3], "m/s")] if len(free) == 4 else [])
    for label, comps, unit in blocks:
        entry = {"unit": unit}
        for how, c2 in (("projection", projection_covariance(cov, comps)), ("slice", slice_covariance(A, comps))):
            major, minor, angle = error_ellipse(c2, probability)
            entry[how] = {"covariance": c2.tolist(), "semi_major": float(major), "semi_minor": float(minor),
                          "angle_deg": float(np.degrees(angle)), "cep_exact": float(cep_exact(c2, probability)),
                          "cep_paper": float(cep_paper(c2, probability)),
                          "cep_075": float(cep_approx(c2)) if probability == 0.5 else None}
        out["blocks"][label] = entry
    return out
