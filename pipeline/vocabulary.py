"""The shared vocabulary of the data contract: channel names, measurement families, the tracker
output vocabulary and the one table of flag bits.

This module is the *what* of the contract; :mod:`trackreplay.contract` is the *how* (MCAP frames on
disk). It imports nothing but the standard library, so numerical cores, recorders, trackers,
stages and evaluators can all name a channel or a flag without pulling in file I/O.
See ``docs/contract.md`` for the full description with shapes and units.

Units are SI and angles are radians everywhere inside; degrees appear only in configuration
values whose names end in ``_deg``.
"""

from __future__ import annotations

from dataclasses import dataclass

# --------------------------------------------------------------------------- channels
# One table of channel names. Recorders write them, stages read them, nothing else spells them.

CHANNELS = {
    "radar_plots": "/radar/plots",            # ragged range_m, bearing_rad (origin: target id or -1) per run and scan
    "radar_truth": "/radar/truth",            # state [x, y, vx, vy] (m, m/s); a set: ragged state + target_id
    "xcorr_peaks": "/xcorr/peaks",            # ragged bearing_rad, amplitude, origin (target or -1)
    "xcorr_truth": "/xcorr/truth",            # bearing_rad, bearing_rate_radps per target
    "array_snapshots": "/array/snapshots",    # complex snapshots (sensors, snapshots)
    "array_truth": "/array/truth",            # angle_rad per target, snr_db
    "emitter_measurements": "/emitter/measurements",  # tdoa_s, fdoa_hz, sigmas, pairs, carrier_hz
    "emitter_sensors": "/emitter/sensors",    # position_m, velocity_mps (sensors, 2)
    "emitter_prior": "/emitter/prior",        # state [x, y, vx, vy] initial guess
    "emitter_truth": "/emitter/truth",        # state [x, y, vx, vy]
    "colored_measurements": "/colored/measurements",  # position_m per axis
    "colored_truth": "/colored/truth",        # state [p, v, a] per axis, alpha
}


#: channels whose scans are instants of one recording, so their times must increase (a filter
#: steps from one to the next); the emitter family's epochs each stand alone (a noise study's
#: "scans" are noise levels at one instant) and may share a time
TIME_ORDERED = frozenset(CHANNELS[k] for k in ("radar_plots", "radar_truth", "xcorr_peaks", "xcorr_truth",
                                               "array_snapshots", "array_truth", "colored_measurements",
                                               "colored_truth"))


# --------------------------------------------------------------------------- values
# What every input array may hold, declared once per channel and checked when a file is read
# (trackreplay.contract.check_values): the number kind (f float, c complex, i integer; a boolean
# or complex array where floats are expected is refused, not cast), and the range of its values.
# Bounds are physical limits or, where physics sets none, sanity limits far beyond any real
# recording that keep squares and products finite (1e12 m is seven times the Sun's distance).

@dataclass(frozen=True)
class ValueSpec:
    """Allowed values of one input array: ``kinds`` (numpy dtype kinds), ``low``/``high``
    (inclusive; None: unbounded), ``finite`` (NaN/Inf refused)."""

    kinds: str = "fi"
    low: float | None = None
    high: float | None = None
    finite: bool = True


_FAR_M = 1e12
_FAST_MPS = 1e9
_TURNS = 1e3  # radians: angles may be unwrapped, but not astronomically
_MAX_TARGET_ID = (1 << 31) - 1  # target identities are non-negative integers (int64 on disk)

VALUES = {
    "radar_plots": {"range_m": ValueSpec(low=0.0, high=_FAR_M), "bearing_rad": ValueSpec(low=-_TURNS, high=_TURNS),
                    "origin": ValueSpec(kinds="iu", low=-1, high=_MAX_TARGET_ID)},
    "radar_truth": {"state": ValueSpec(low=-_FAR_M, high=_FAR_M),
                    "target_id": ValueSpec(kinds="iu", low=0, high=_MAX_TARGET_ID)},
    "xcorr_peaks": {"bearing_rad": ValueSpec(low=-_TURNS, high=_TURNS), "amplitude": ValueSpec(low=0.0, high=1e30),
                    "origin": ValueSpec(kinds="iu", low=-1, high=1 << 24)},
    "xcorr_truth": {"bearing_rad": ValueSpec(low=-_TURNS, high=_TURNS),
                    "bearing_rate_radps": ValueSpec(low=-_TURNS, high=_TURNS)},
    "array_snapshots": {"snapshots": ValueSpec(kinds="fc", low=-1e30, high=1e30)},
    "array_truth": {"angle_rad": ValueSpec(low=-_TURNS, high=_TURNS), "snr_db": ValueSpec(low=-400.0, high=400.0)},
    "emitter_measurements": {"tdoa_s": ValueSpec(low=-1e3, high=1e3), "fdoa_hz": ValueSpec(low=-1e12, high=1e12),
                             "sigma_tdoa_s": ValueSpec(low=0.0, high=1e3), "sigma_fdoa_hz": ValueSpec(low=0.0, high=1e12),
                             "pairs": ValueSpec(kinds="iu", low=0, high=1 << 16),
                             "carrier_hz": ValueSpec(low=0.0, high=1e15)},
    "emitter_sensors": {"position_m": ValueSpec(low=-_FAR_M, high=_FAR_M),
                        "velocity_mps": ValueSpec(low=-_FAST_MPS, high=_FAST_MPS)},
    "emitter_prior": {"state": ValueSpec(low=-_FAR_M, high=_FAR_M, finite=False)},
    "emitter_truth": {"state": ValueSpec(low=-_FAR_M, high=_FAR_M)},
    "colored_measurements": {"position_m": ValueSpec(low=-_FAR_M, high=_FAR_M)},
    "colored_truth": {"state": ValueSpec(low=-_FAR_M, high=_FAR_M), "alpha": ValueSpec(low=-1.0, high=1.0)},
}
# arrays of a channel that list the same items (one entry per plot, per peak): equal lengths in
# every frame
PARALLEL = {
    "radar_plots": ("range_m", "bearing_rad", "origin"),
    "radar_truth": ("state", "target_id"),
    "xcorr_peaks": ("bearing_rad", "amplitude", "origin"),
}
TIME_LIMIT_S = 1e10  # scan times: finite and within ±317 years of the recording's epoch


@dataclass(frozen=True)
class Family:
    """A measurement family, declared once: what a tracker consumes, what its state means, and
    where its pieces live.

    One name per paper: the family's ``name`` is also its stage's name, its outputs' prefix
    (``/tracks/<name>/``), and, with ``-`` written ``_``, the stem of every module that is the
    family's own (``stages/<stem>.py``, ``face/rerun_<stem>.py``, ``evaluators/<stem>.py``,
    ``face/cli_<stem>.py``, ``trackers/<stem>*.py``) and of its page ``docs/papers/<name>.md``.
    The registries of stages, trackers, Rerun views and paper commands read this table; no other
    module branches on a family (``tests/test_families.py`` counts it).

    Attributes
    ----------
    name : str
        The family's name (``Tracker.family`` names it).
    inputs : tuple of str
        Channels that must all be present.
    truth : str
        The channel holding ground truth, when a file has it.
    state : str
        The state vector's components and units, in words.
    state_components : tuple of (str, str)
        ``(name, unit)`` of one track slot's state components, as exports label them; names with
        an ``{axis}`` field repeat per axis (``x, vx, ax, y, vy, ay`` for two axes).
    space : str
        The space the generic evaluators compare tracks and truth in.
    scenario : str
        The bundled scenario whose parameters name the family's design values (and give their
        defaults for its simulations; a recording's sensor values come from the recording).
    measurement_class : str
        The class of :mod:`trackreplay.trackers.interface` a tracker of the family is given.
    stage_class : str
        The class of ``stages/<stem>.py`` that decodes, runs and scores the family.
    tracker_modules : tuple of str
        Modules of ``trackers/`` holding the family's built-in trackers (each exposes TRACKERS).
    commands : bool
        Whether ``face/cli_<stem>.py`` adds paper-specific commands to ``replay``.
    former_output_prefixes : tuple of str
        Prefixes earlier versions wrote the family's outputs on (their files still read).
    sensor_keys : tuple of str
        The design values that describe the sensor (the rest of a stage's design values are the
        trackers' own choices): a data set says them, or they are unknown
        (:mod:`trackreplay.sensor_values`).
    estimable_keys : tuple of str
        Sensor values the family estimates from the data when a recording does not say them.
    sensor_arrays : tuple of str
        Sensor values the measurements themselves carry (one per pair and epoch, say).
    former_names : tuple of str
        Names earlier versions gave the family (a plugged tracker or mapping file that uses one
        is told the new name).
    """

    name: str
    inputs: tuple[str, ...]
    truth: str
    state: str
    state_components: tuple[tuple[str, str], ...]
    space: str
    scenario: str
    measurement_class: str
    stage_class: str
    tracker_modules: tuple[str, ...]
    commands: bool = False
    former_output_prefixes: tuple[str, ...] = ()
    sensor_keys: tuple[str, ...] = ()
    estimable_keys: tuple[str, ...] = ()
    sensor_arrays: tuple[str, ...] = ()
    former_names: tuple[str, ...] = ()

    @property
    def stem(self) -> str:
        """The family's name as a module name."""
        return self.name.replace("-", "_")

    @property
    def output_prefix(self) -> str:
        """Tracker ``NAME`` writes its outputs on ``output_prefix + NAME``."""
        return f"/tracks/{self.name}/"

    @property
    def output_prefixes(self) -> tuple[str, ...]:
        """Every prefix the family's outputs are read from: today's first."""
        return (self.output_prefix, *self.former_output_prefixes)

    @property
    def stage(self) -> str:
        """``module:Class`` of the family's stage."""
        return f"trackreplay.stages.{self.stem}:{self.stage_class}"

    @property
    def view(self) -> str:
        """The module that draws the family's results in Rerun."""
        return f"trackreplay.face.rerun_{self.stem}"

    @property
    def builtin_tracker_modules(self) -> tuple[str, ...]:
        return tuple(f"trackreplay.trackers.{m}" for m in self.tracker_modules)

    @property
    def command_module(self) -> str | None:
        return f"trackreplay.face.cli_{self.stem}" if self.commands else None


_XY = (("x", "m"), ("y", "m"), ("vx", "m/s"), ("vy", "m/s"))
_BEARING = (("bearing", "rad"), ("bearing_rate", "rad/s"))

FAMILIES = {
    f.name: f for f in (
        Family(
            name="radar", inputs=(CHANNELS["radar_plots"],), truth=CHANNELS["radar_truth"],
            state="[x, y, vx, vy] in m and m/s, one track per run or per track slot", state_components=_XY,
            space="position (m)", scenario="radar-tws", measurement_class="RadarPlots", stage_class="RadarStage",
            tracker_modules=("radar_tws", "radar_multi_target"),
            sensor_keys=("scan_period_s", "sigma_range_m", "sigma_bearing_deg", "detection_probability",
                         "clutter_per_scan", "min_range_m", "max_range_m", "sector_half_width_deg"),
            estimable_keys=("scan_period_s",), former_names=("radar-plots",)),
        Family(
            name="xcorr", inputs=(CHANNELS["xcorr_peaks"],), truth=CHANNELS["xcorr_truth"],
            state="[bearing, bearing rate] in rad and rad/s per track slot", state_components=_BEARING,
            space="bearing (rad)", scenario="xcorr-crossing", measurement_class="BearingPeaks",
            stage_class="XcorrStage", tracker_modules=("xcorr",), commands=True,
            sensor_keys=("scan_period_s", "strong_sigma_p_deg", "weak_sigma_p_deg", "field_min_deg", "field_max_deg"),
            estimable_keys=("scan_period_s",), former_names=("bearing-peaks",)),
        Family(
            name="array", inputs=(CHANNELS["array_snapshots"],), truth=CHANNELS["array_truth"],
            state="[bearing, bearing rate] in rad and rad/s per track slot", state_components=_BEARING,
            space="bearing (rad)", scenario="array-crossing", measurement_class="ArraySnapshots",
            stage_class="ArrayStage", tracker_modules=("array",), commands=True,
            sensor_keys=("scan_period_s", "spacing_wavelengths"), former_names=("array-snapshots",)),
        Family(
            name="tdoa-fdoa", inputs=(CHANNELS["emitter_measurements"], CHANNELS["emitter_sensors"]),
            truth=CHANNELS["emitter_truth"], state="[x, y, vx, vy] in m and m/s, one estimate per epoch",
            state_components=_XY, space="position (m)", scenario="tdoa-fdoa", measurement_class="TdoaFdoa",
            stage_class="TdoaFdoaStage", tracker_modules=("tdoa_fdoa",), commands=True,
            sensor_arrays=("carrier_hz", "sigma_tdoa_s", "sigma_fdoa_hz"),
            former_output_prefixes=("/tracks/emitter/", "/emitter/estimates/")),
        Family(
            name="colored", inputs=(CHANNELS["colored_measurements"],), truth=CHANNELS["colored_truth"],
            state="[p, v, a] in m, m/s, m/s² per axis, axes concatenated",
            state_components=(("{axis}", "m"), ("v{axis}", "m/s"), ("a{axis}", "m/s²")),
            space="position (m)", scenario="colored-imm", measurement_class="ColoredPositions",
            stage_class="ColoredStage", tracker_modules=("colored",), commands=True,
            sensor_keys=("measurement_variance_m2",), former_names=("colored-position",)),
    )
}
FORMER_FAMILY_NAMES = {old: f.name for f in FAMILIES.values() for old in f.former_names}


# --------------------------------------------------------------------------- tracker outputs


@dataclass(frozen=True)
class OutputArray:
    """One name of the output vocabulary.

    ``shape`` uses R runs, K scans, T track slots (absent for single-track families), n state
    components, m measurement components, M models. ``required`` outputs every tracker returns.
    """

    name: str
    shape: str
    dtype: str
    meaning: str
    required: bool = False


OUTPUTS = {
    o.name: o for o in (
        OutputArray("state", "(R, K, [T,] n)", "float64",
                    "posterior state estimate in the family's units; NaN only where flags say NO_TRACK "
                    "or NOT_ESTIMATED", required=True),
        OutputArray("flags", "(R, K[, T])", "uint32", "bit mask of FLAGS", required=True),
        OutputArray("covariance", "(R, K, [T,] n, n)", "float64",
                    "posterior covariance, symmetric positive definite where the state is finite"),
        OutputArray("track_id", "(R, K, T)", "int64",
                    "identity of the track in each slot, -1 where the slot is empty; without it slot j is "
                    "track j for the whole run"),
        OutputArray("innovation", "(R, K, [T,] m)", "float64", "measurement minus predicted measurement"),
        OutputArray("innovation_covariance", "(R, K, [T,] m, m)", "float64", "covariance of the innovation"),
        OutputArray("gain", "(R, K, [T,] n, m)", "float64", "gain applied to the innovation"),
        OutputArray("model_probabilities", "(R, K, M)", "float64", "posterior model probabilities (IMM)"),
    )
}
REQUIRED_OUTPUTS = tuple(name for name, o in OUTPUTS.items() if o.required)


# --------------------------------------------------------------------------- flags
# One table of flag bits for every tracker and estimator. Outputs store them as uint32 (32 bits:
# room to grow; files written with uint16 flags read as before, their values unchanged).

FLAGS = {
    "NO_TRACK": 1 << 0,         # no track in this slot at this scan (state is NaN)
    "INITIALISING": 1 << 1,     # track in start-up or tentative: not yet filtered or not yet confirmed
    "COASTED": 1 << 2,          # no measurement used this scan: the state is the prediction
    "CLAMPED": 1 << 3,          # a gain or estimate was clamped into its valid range
    "CLUSTER_SPLIT": 1 << 4,    # association approximated: the cluster had too many tracks
    "NOT_WARM": 1 << 5,         # an online estimate (e.g. AR(1) coefficient) has not settled yet
    "CONVERGED": 1 << 6,        # iterative estimator: last step below its tolerance
    "NOT_CONVERGED": 1 << 7,    # iterative estimator: iteration budget spent
    "DIVERGED": 1 << 8,         # iterative estimator: non-finite or out-of-bounds iterate
    "RANK_DEFICIENT": 1 << 9,   # the problem was numerically singular
    "UNDERDETERMINED": 1 << 10, # fewer independent equations than unknowns: not estimated
    "INVALID_START": 1 << 11,   # the initial guess was not finite
    "NOT_ESTIMATED": 1 << 12,   # some state components are not estimated (NaN)
    "DELETED": 1 << 13,         # the track ended at this scan (with NO_TRACK; NO_TRACK alone after)
    "FLOORED": 1 << 14,         # a variance was raised to its floor
    "LIMITED": 1 << 15,         # a coefficient was limited to its stable range
    # set by the output check every tracker passes through (trackreplay.trackers.interface), never
    # by a tracker: the covariance written is not numerically positive definite (its smallest
    # eigenvalue is within rounding of zero or below it, e.g. a component known exactly), so its
    # inverse, and the NEES it would give, are not to be trusted
    "NOT_POSITIVE_DEFINITE": 1 << 16,
}
FLAG_DTYPE = "uint32"

NO_TRACK = FLAGS["NO_TRACK"]
INITIALISING = FLAGS["INITIALISING"]
COASTED = FLAGS["COASTED"]
CLAMPED = FLAGS["CLAMPED"]
CLUSTER_SPLIT = FLAGS["CLUSTER_SPLIT"]
NOT_WARM = FLAGS["NOT_WARM"]
CONVERGED = FLAGS["CONVERGED"]
NOT_CONVERGED = FLAGS["NOT_CONVERGED"]
DIVERGED = FLAGS["DIVERGED"]
RANK_DEFICIENT = FLAGS["RANK_DEFICIENT"]
UNDERDETERMINED = FLAGS["UNDERDETERMINED"]
INVALID_START = FLAGS["INVALID_START"]
NOT_ESTIMATED = FLAGS["NOT_ESTIMATED"]
DELETED = FLAGS["DELETED"]
FLOORED = FLAGS["FLOORED"]
LIMITED = FLAGS["LIMITED"]
NOT_POSITIVE_DEFINITE = FLAGS["NOT_POSITIVE_DEFINITE"]


def flag_names(mask: int) -> list[str]:
    """Names of the bits set in ``mask`` (for messages and docs)."""
    return [name for name, bit in FLAGS.items() if int(mask) & bit]
