"""Fit the paper's stochastic peak model back from any peak data set (spec: "The stochastic model").

Around a reference bearing per track and scan (the truth when the data carry it, else a
tracker's estimate, as the paper used PDA tracks) a gate of width V collects the peaks with
amplitude ≥ the threshold. Within a gate the model is (spec table, eqs. 4–7 of the paper):

* at most one true peak, present with probability ``P_D``: position ``N(ref, σ_p²)``
  truncated to the gate, amplitude ``N(ẑ_a, σ_a²)`` truncated to ``z_a ≥ τ``;
* clutter: Poisson count with mean ``λV``, positions uniform over the gate, amplitudes
  ``α e^{−α (z_a − τ)}`` (the exponential is memoryless, so a threshold only shifts it).

The log-likelihood of G gates with ``n_g`` peaks is, up to a constant,

    ℓ = −G·λV + N log λV + Σ_j log f_c(z_j) + Σ_g log[(1 − P_D) + (P_D/λV) Σ_{j∈g} f_t(z_j) / f_c(z_j)]

(the PDA hypotheses "no true peak" / "peak j is true" summed exactly per gate), maximised over
``(P_D, λV, σ_p, ẑ_a, σ_a, α)`` by L-BFGS on unconstrained transforms, started from robust
moments; standard errors come from the numerical Hessian. Background (clutter only) is
fitted on gates at least one gate away from every reference: λV is the mean count, α the
exponential MLE ``1/mean(z_a − τ)``; the count dispersion (variance/mean, 1 for Poisson) and
a Kolmogorov–Smirnov p-value of positions against uniform say how well the model fits.

Gates that another reference comes within V of, or that stick out of the sensor's field, are
left out: there the clutter would not be the model's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats
from scipy.linalg import solve_triangular
from scipy.special import expit, logit, ndtr

from trackreplay.errors import InputError

PARAMS = ("detection_probability", "clutter_per_gate", "sigma_p_deg", "amplitude_mean", "amplitude_std",
          "clutter_alpha")


@dataclass
class TrackFit:
    """Fitted model of the gates around one reference track."""

    values: dict
    stderr: dict
    gates: int
    peaks: int
    log_likelihood: float
    converged: bool


@dataclass
class BackgroundFit:
    clutter_per_gate: float
    clutter_alpha: float
    gates: int
    peaks: int
    count_dispersion: float
    uniform_ks_pvalue: float
    exponential_ks_pvalue: float


@dataclass
class PeakModelFit:
    tracks: list
    background: BackgroundFit | None
    gate_deg: float
    threshold: float
    reference: str
    notes: list = field(default_factory=list)


def _gate_terms(offset, amplitude, gate_id, n_gates, theta, half_gate, threshold, amp_scale):
    """Negative log-likelihood of one track's gates for transformed parameters ``theta``."""
    pd = expit(theta[0])
    mu = np.exp(theta[1])
    sp = np.exp(theta[2])
    ma = theta[3] * amp_scale
    sa = np.exp(theta[4]) * amp_scale
    alpha = np.exp(theta[5]) / amp_scale
    V = 2 * half_gate
    log_fc = -np.log(V) + np.log(alpha) - alpha * (amplitude - threshold)
    pos_mass = 2 * ndtr(half_gate / sp) - 1
    amp_mass = np.maximum(ndtr((ma - threshold) / sa), 1e-300)
    log_ft = (-0.5 * (offset / sp) ** 2 - np.log(np.sqrt(2 * np.pi) * sp * pos_mass)
              - 0.5 * ((amplitude - ma) / sa) ** 2 - np.log(np.sqrt(2 * np.pi) * sa * amp_mass))
    ratio = np.exp(np.clip(log_ft - log_fc, -700, 700))
    per_gate = np.bincount(gate_id, weights=ratio, minlength=n_gates)
    ll = (-n_gates * mu + offset.size * np.log(mu) + log_fc.sum()
          + np.sum(np.log((1 - pd) + pd / mu * per_gate)))
    return -ll


def fit_track_gates(offset: np.ndarray, amplitude: np.ndarray, gate_id: np.ndarray, n_gates: int,
                    gate: float, threshold: float = 0.0) -> TrackFit:
    """Maximum-likelihood fit of one track's gates.

    Parameters
    ----------
    offset : ndarray (peaks,)
        Peak bearing minus the reference bearing (rad), all within ``±gate/2``.
    amplitude : ndarray (peaks,)
        Peak amplitudes (all ≥ ``threshold``).
    gate_id : ndarray of int (peaks,)
        Which gate each peak is in, ``0 … n_gates − 1``.
    n_gates : int
        Number of gates (including empty ones).
    gate : float
        Gate width V (rad).
    threshold : float
        Amplitude threshold τ applied before the fit.
    """
    if n_gates < 10 or offset.size < 10:
        raise InputError(f"too few gates ({n_gates}) or peaks ({offset.size}) to fit the peak model")
    half = gate / 2
    gate_id = np.asarray(gate_id, np.int64)
    # Start: the largest peak of a gate is usually the true one.
    order = np.lexsort((-amplitude, gate_id))
    first = order[np.r_[True, gate_id[order][1:] != gate_id[order][:-1]]]
    amp_scale = float(np.median(amplitude[first]))
    top_amp, top_off = amplitude[first], offset[first]
    rest = np.setdiff1d(np.arange(offset.size), first)
    clutter_mean = float(np.mean(amplitude[rest] - threshold)) if rest.size else amp_scale / 4
    pd0 = min(0.95, max(0.05, first.size / n_gates))
    mu0 = max(0.05, (offset.size - first.size) / n_gates)
    sp0 = max(1.4826 * float(np.median(np.abs(top_off))), gate / 200)
    ma0 = float(np.median(top_amp))
    sa0 = max(1.4826 * float(np.median(np.abs(top_amp - ma0))), 1e-3 * amp_scale)
    theta0 = np.array([logit(pd0), np.log(mu0), np.log(sp0), ma0 / amp_scale, np.log(sa0 / amp_scale),
                       np.log(amp_scale / max(clutter_mean, 1e-9 * amp_scale))])
    fun = lambda th: _gate_terms(offset, amplitude, gate_id, n_gates, th, half, threshold, amp_scale)
    res = optimize.minimize(fun, theta0, method="L-BFGS-B")
    th = res.x
    values = {
        "detection_probability": float(expit(th[0])), "clutter_per_gate": float(np.exp(th[1])),
        "sigma_p_deg": float(np.rad2deg(np.exp(th[2]))), "amplitude_mean": float(th[3] * amp_scale),
        "amplitude_std": float(np.exp(th[4]) * amp_scale), "clutter_alpha": float(np.exp(th[5]) / amp_scale),
    }
    stderr = _delta_stderr(fun, th, amp_scale)
    return TrackFit(values, stderr, int(n_gates), int(offset.size), float(-res.fun), bool(res.success))


def _delta_stderr(fun, th, amp_scale) -> dict:
    """Standard errors from the inverse numerical Hessian, mapped through the transforms."""
    n = th.size
    h = 1e-4 * np.maximum(1.0, np.abs(th))
    H = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            ei, ej = np.eye(n)[i] * h[i], np.eye(n)[j] * h[j]
            H[i, j] = H[j, i] = (fun(th + ei + ej) - fun(th + ei - ej) - fun(th - ei + ej) + fun(th - ei - ej)) / (4 * h[i] * h[j])
    try:
        # var_i = (H⁻¹)_ii = ‖L⁻¹ e_i‖² with H = L Lᵀ: one triangular solve, no inverse
        Linv = solve_triangular(np.linalg.cholesky(H), np.eye(n), lower=True)
        sd = np.sqrt(np.sum(Linv * Linv, axis=0))
    except np.linalg.LinAlgError:
        sd = np.full(n, np.nan)
    pd = expit(th[0])
    jac = np.array([pd * (1 - pd), np.exp(th[1]), np.rad2deg(np.exp(th[2])), amp_scale,
                    np.exp(th[4]) * amp_scale, np.exp(th[5]) / amp_scale])
    return {k: float(abs(j) * s) for k, j, s in zip(PARAMS, jac, sd)}


def fit_background(offset: np.ndarray, amplitude: np.ndarray, gate_id: np.ndarray, n_gates: int,
                   gate: float, threshold: float = 0.0) -> BackgroundFit:
    """Clutter-only gates: Poisson mean, exponential α, and goodness-of-fit diagnostics."""
    if n_gates < 2:
        raise InputError("no background gates (every gate is near a track): cannot fit the background")
    counts = np.bincount(gate_id, minlength=n_gates)
    mean = float(counts.mean())
    excess = amplitude - threshold
    alpha = float(1.0 / excess.mean()) if excess.size else float("nan")
    ks_u = stats.kstest(offset / gate + 0.5, "uniform").pvalue if offset.size else float("nan")
    ks_e = stats.kstest(excess * alpha, "expon").pvalue if excess.size else float("nan")
    return BackgroundFit(mean, alpha, int(n_gates), int(offset.size),
                         float(counts.var(ddof=1) / mean) if mean > 0 else float("nan"), float(ks_u), float(ks_e))


def collect_gates(bearing, amplitude, run, scan, reference, gate, threshold, field_rad):
    """Per-track gate contents and background gates.

    Parameters
    ----------
    bearing, amplitude, run, scan : ndarray (peaks,)
        Flat peaks.
    reference : ndarray (R, K, T)
        Reference bearing per run, scan and track (NaN: no gate there).
    gate : float
        V (rad).
    field_rad : (float, float)
        The sensor's field; gates must lie inside it.

    Returns
    -------
    tracks : list of (offset, amplitude, gate_id, n_gates) per track
    background : (offset, amplitude, gate_id, n_gates)
    """
    R, K, T = reference.shape
    lo, hi = field_rad
    usable = amplitude >= threshold
    inside = (reference - gate / 2 >= lo) & (reference + gate / 2 <= hi) & np.isfinite(reference)
    ok = inside.copy()
    for t in range(T):
        for u in range(T):
            if u != t:
                ok[..., t] &= ~(np.abs(reference[..., t] - reference[..., u]) < gate)
    tracks = []
    for t in range(T):
        gate_index = np.full(R * K, -1)
        valid = ok[..., t].ravel()
        gate_index[valid] = np.arange(valid.sum())
        gid = gate_index[run * K + scan]
        off = bearing - reference[run, scan, t]
        sel = usable & (gid >= 0) & (np.abs(off) <= gate / 2)
        tracks.append((off[sel], amplitude[sel], gid[sel], int(valid.sum())))
    centres = lo + gate / 2 + gate * np.arange(int(np.floor((hi - lo) / gate)))
    far = np.all(np.abs(centres[None, None, :, None] - reference[:, :, None, :]) >= gate, axis=-1)
    far &= np.all(np.isfinite(reference), axis=-1)[..., None]  # (R, K, C)
    gate_index = np.full(far.size, -1)
    gate_index[far.ravel()] = np.arange(far.sum())
    slot = np.floor((bearing - lo) / gate).astype(np.int64)
    in_grid = (slot >= 0) & (slot < centres.size)
    gid = np.where(in_grid, gate_index[(run * K + scan) * centres.size + np.clip(slot, 0, max(centres.size - 1, 0))], -1)
    sel = usable & (gid >= 0)
    off = bearing - centres[np.clip(slot, 0, max(centres.size - 1, 0))]
    background = (off[sel], amplitude[sel], gid[sel], int(far.sum()))
    return tracks, background


def fit_peak_model(bearing, amplitude, run, scan, reference, gate: float, threshold: float = 0.0,
                   field_rad=(0.0, np.pi), reference_name: str = "truth") -> PeakModelFit:
    """Fit every track's model and the background from flat peaks and reference bearings."""
    tracks, background = collect_gates(bearing, amplitude, run, scan, reference, gate, threshold, field_rad)
    fits = [fit_track_gates(off, amp, gid, n, gate, threshold) for off, amp, gid, n in tracks]
    bg = None
    notes = []
    try:
        bg = fit_background(*background, gate, threshold)
    except InputError as exc:
        notes.append(str(exc))
    return PeakModelFit(fits, bg, float(np.rad2deg(gate)), float(threshold), reference_name, notes)
