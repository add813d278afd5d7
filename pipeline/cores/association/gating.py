"""χ² gating of one scan's plots against every track: the track–plot pairs an association sees.

A plot ``z`` is inside track t's gate when its squared Mahalanobis distance
``d² = νᵀ S_t⁻¹ ν`` (``ν = z − ẑ_t``) is at most the gate ``γ``, the χ² quantile of the chance
P_G that a target's own plot falls inside (Bar-Shalom, Li & Kirubarajan 2001, §2.6 and §10.3;
docs/trackers.md, "Multi-target trackers"). Hundreds of tracks meet hundreds of plots in a busy
scan, yet each track gates a few; so the result keeps, per track, only the plots inside its gate,
side by side (:class:`GatedPairs`), and the association works on those.

:func:`gate_pairs` is the definition: every track against every plot. :func:`_gate_pairs_windowed`
gives the same pairs (tests/test_multitarget_trackers.py holds them equal) without forming every
pair: the ellipse ``d² ≤ γ`` lies inside ``|ν_c| ≤ √(γ S_cc)`` along any one component c, so with
the plots sorted along c each track needs only the plots within that window (a binary search at
each end); the same box along the other, non-angular components (a radar's range) thins those
candidates with one number each, and d² is then computed for the survivors alone. For an angle
(a radar's bearing) the window wraps around the circle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay.cores.filters.track_filter import squared_distance

#: relative and absolute widening of the coarse windows: the exact test ``d² ≤ γ`` decides, the
#: windows only have to hold every plot that can pass it despite rounding
_WINDOW_MARGIN_REL, _WINDOW_MARGIN_ABS = 1e-9, 1e-12


@dataclass(frozen=True)
class GatedPairs:
    """The plots inside each track's gate, side by side: ``(R, S, G)`` with ``G`` the most any
    track gates (padding where a track gates fewer).

    Attributes
    ----------
    plot : ndarray of int (R, S, G)
        Index of the plot on the scan's plot axis, −1 in padding; increasing along G.
    innovation : ndarray (R, S, G, m)
        ``z − ẑ`` of each pair (0 in padding).
    squared_distance : ndarray (R, S, G)
        ``νᵀ S⁻¹ ν`` (∞ in padding).
    plots : int
        Width W of the scan's plot axis.
    """

    plot: np.ndarray
    innovation: np.ndarray
    squared_distance: np.ndarray
    plots: int

    @property
    def inside(self) -> np.ndarray:
        """``(R, S, G)`` bool: a real pair (not padding)."""
        return self.plot >= 0


def gate_pairs(track_filter, z, valid, z_pred, S, gate_chi2: float, live, windows: bool = True) -> GatedPairs:
    """The track–plot pairs with ``d² ≤ gate_chi2``: every live track against every valid plot.

    Parameters
    ----------
    track_filter : trackreplay.cores.filters.track_filter.TrackFilter
        Gives the innovations (angles wrapped) and the component the windows sort along.
    z : ndarray (R, W, m)
        Plots (anything where not ``valid``); angles within one period centred on 0.
    valid : ndarray of bool (R, W)
    z_pred : ndarray (R, S, m), S : ndarray (R, S, m, m)
        Predicted measurements and innovation covariances of the tracks.
    gate_chi2 : float
    live : ndarray of bool (R, S)
        Slots holding a track.
    windows : bool
        Find the pairs through the coarse windows of :func:`_gate_pairs_windowed` (the same
        pairs, fewer computed); False forms every pair, as written below.

    Returns
    -------
    GatedPairs
    """
    if windows:
        return _gate_pairs_windowed(track_filter, z, valid, z_pred, S, gate_chi2, live)
    nu = track_filter.innovations(np.where(valid[..., None], z, 0.0), z_pred)
    d2 = squared_distance(nu, S[..., None, :, :])
    inside = live[..., None] & valid[:, None, :] & (d2 <= gate_chi2)
    run, slot, plot = np.nonzero(inside)
    return _side_by_side(run, slot, plot, nu[run, slot, plot], d2[run, slot, plot], live.shape, z.shape[1])


def _gate_pairs_windowed(track_filter, z, valid, z_pred, S, gate_chi2: float, live) -> GatedPairs:
    """:func:`gate_pairs` through coarse windows along the filter's ``window_component`` (see the
    module docstring); ``window_period`` (2π for a bearing) when that component is an angle in
    [−period/2, period/2]."""
    component, period = track_filter.window_component, track_filter.window_period
    R, W, m = z.shape
    run_w, plot_w = np.nonzero(valid)
    track_run, track_slot = np.nonzero(live)
    if run_w.size == 0 or track_run.size == 0:
        return _side_by_side(*(np.zeros(0, np.int64),) * 3, np.zeros((0, m)), np.zeros(0), live.shape, W)
    value = z[run_w, plot_w, component]
    centre = z_pred[track_run, track_slot, component]
    half = np.sqrt(gate_chi2 * S[track_run, track_slot, component, component])
    if period is None:
        span = float(value.max() - value.min()) + 1.0
        shift = float(value.min())
        keys = run_w * (3.0 * span) + (value - shift + span)       # each run in its own segment
        # a window clipped to its run's plots (keys span … 2 span − 1 within the segment)
        base = track_run * (3.0 * span)
        lo_key = base + np.clip(centre - shift + span - half, span - 0.5, 2.0 * span - 0.5)
        hi_key = base + np.clip(centre - shift + span + half, span - 0.5, 2.0 * span - 0.5)
        scale = 3.0 * span * R
        copy_of = np.arange(run_w.size)
    else:
        # three copies of every plot, one turn apart, so that a window crossing ±period/2 is one
        # contiguous range; a window never spans a full turn (such a track takes the middle copy,
        # every plot once)
        p = float(period)
        u = value + 1.5 * p                                         # [p, 2p]
        base = run_w * (4.0 * p)
        c = track_run * (4.0 * p) + centre + 1.5 * p
        whole = half >= 0.5 * p
        lo_key = np.where(whole, track_run * (4.0 * p) + p, c - half)
        hi_key = np.where(whole, track_run * (4.0 * p) + 2.0 * p, c + half)
        scale = 4.0 * p * R
        margin = _WINDOW_MARGIN_REL * np.abs(hi_key - lo_key) + _WINDOW_MARGIN_ABS * max(scale, 1.0)
        own = track_run * (4.0 * p)
        if np.any((lo_key - margin < own + p) | (hi_key + margin > own + 2.0 * p)):
            keys = np.concatenate([base + u - p, base + u, base + u + p])
            copy_of = np.tile(np.arange(run_w.size), 3)
        else:  # no window reaches across ±period/2 (a radar's sector, say): one copy will do
            keys, copy_of = base + u, np.arange(run_w.size)
    if period is None:
        margin = _WINDOW_MARGIN_REL * np.abs(hi_key - lo_key) + _WINDOW_MARGIN_ABS * max(scale, 1.0)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    lo = np.searchsorted(sorted_keys, lo_key - margin, side="left")
    hi = np.searchsorted(sorted_keys, hi_key + margin, side="right")
    counts = hi - lo
    track = np.repeat(np.arange(track_run.size), counts)
    position = np.repeat(lo - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    candidate = copy_of[order[position]]
    # the same box along the other components, one number per candidate, before the full d²
    # (plots at every range share a bearing window)
    for other in range(m):
        if other != component and other not in track_filter.angular_components:
            reach = np.sqrt(gate_chi2 * S[track_run, track_slot, other, other]) * (1.0 + _WINDOW_MARGIN_REL)
            near = np.abs(z[run_w, plot_w, other][candidate] - z_pred[track_run, track_slot, other][track]) <= reach[track]
            track, candidate = track[near], candidate[near]
    run, slot, plot = track_run[track], track_slot[track], plot_w[candidate]
    nu = track_filter.innovation(z[run, plot], z_pred[run, slot])
    d2 = squared_distance(nu, S[run, slot])
    keep = d2 <= gate_chi2
    run, slot, plot, nu, d2 = run[keep], slot[keep], plot[keep], nu[keep], d2[keep]
    # the same order as gate_pairs': by run, slot (the tracks' order already), then plot
    by = np.argsort(track[keep] * W + plot, kind="stable")
    return _side_by_side(run[by], slot[by], plot[by], nu[by], d2[by], live.shape, W)


def _side_by_side(run, slot, plot, nu, d2, tracks_shape, plots: int) -> GatedPairs:
    """Pairs sorted by (run, slot) as ``(R, S, G)`` arrays."""
    R, S = tracks_shape
    m = nu.shape[-1]
    flat = run * S + slot
    per_track = np.bincount(flat, minlength=R * S)
    G = int(per_track.max(initial=0))
    first = np.cumsum(per_track) - per_track
    k = np.arange(flat.size) - first[flat]
    plot_index = np.full((R, S, G), -1, np.int64)
    innovation = np.zeros((R, S, G, m))
    distance = np.full((R, S, G), np.inf)
    plot_index[run, slot, k] = plot
    innovation[run, slot, k] = nu
    distance[run, slot, k] = d2
    return GatedPairs(plot_index, innovation, distance, plots)
