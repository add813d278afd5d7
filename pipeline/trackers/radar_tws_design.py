"""The radar TWS trackers' design values (:class:`TrackerDesign`) and their limits, in a module of
their own: the scan loop (:mod:`trackreplay.trackers.radar_tws`), its update strategies
(:mod:`trackreplay.trackers.radar_tws_strategies`) and its steady blocks
(:mod:`trackreplay.trackers._radar_tws_blocks`) all read them, so each imports them from here and
the imports run one way. Kalata (1984) tracking index; see ``docs/papers/radar.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackreplay.cores.association.track_management import ConfirmationRule, EndingRule
from trackreplay.cores.filters.alpha_beta_gains import tracking_index

#: Largest tracking index λ = σ_v T²/σ of a plot's along- or cross-range error; a smaller σ is
#: floored (flagged ``FLOORED``), and a design whose range index σ_v T²/σ_r or nominal index λ̄
#: exceeds it is refused.
#: The process noise of one scan is rank one per axis and λ²/4 times the measurement variance,
#: so a covariance predicted over a scan has a relative smallest eigenvalue of about 8/λ²: at
#: 10⁵ that is ~10⁶ above rounding. (The α-β gains are α = 1 − 4/λ², β = 2 − 4/λ there already.)
MAX_TRACKING_INDEX = 1e5

#: Range of every design value that must be > 0 (scan period in s, σ_v in m/s², σ_r and the
#: nominal cross-range error in m, σ_θ in degrees): wider than any radar needs, narrow enough
#: that variances, tracking indices and their products stay far from overflow and underflow.
DESIGN_RANGE = (1e-9, 1e9)


@dataclass(frozen=True)
class TrackerDesign:
    """Filter design values (SI units, radians).

    Attributes
    ----------
    scan_period_s : float
        Nominal scan period T used in the gains.
    sigma_v : float
        Design acceleration noise σ_v (m/s²).
    sigma_range_m, sigma_bearing_rad : float
        Plot noise the filters assume.
    nominal_cross_range_m : float
        Cross-range error std at which the fixed gains are designed (λ̄ = σ_v T² / this).
    startup : bool
        α-β strategies use the expanding-memory start-up gains while they exceed the
        steady-state ones (textbook track start; without it a two-point start followed by
        small steady-state gains is worse than the raw plots for several scans).
    gate_chi2 : float
        A started track uses the plot nearest its prediction only when the plot's squared
        Mahalanobis distance ``νᵀ S⁻¹ ν`` is at most this (2 degrees of freedom); otherwise it
        coasts. ``inf``: no gate (the paper's clutter-free scenario).
    confirmation, ending : ConfirmationRule, EndingRule
        Track management (:mod:`trackreplay.cores.association.track_management`): M-of-N
        confirmation counting the two start plots, and the end after coasted scans. A deleted
        track's run starts a new track from its next two plots.
    """

    scan_period_s: float
    sigma_v: float
    sigma_range_m: float
    sigma_bearing_rad: float
    nominal_cross_range_m: float
    startup: bool = True
    gate_chi2: float = np.inf
    confirmation: ConfirmationRule = ConfirmationRule()
    ending: EndingRule = EndingRule()

    @property
    def lam_along(self) -> float:
        return float(tracking_index(self.sigma_v, self.scan_period_s, self.sigma_range_m))

    @property
    def lam_nominal(self) -> float:
        return float(tracking_index(self.sigma_v, self.scan_period_s, self.nominal_cross_range_m))
