"""Scenario configs: readable TOML files in ``data/scenarios/``, overridable per parameter.

A scenario file names its recorder and lists its parameters with defaults::

    name = "radar-tws"
    recorder = "radar-tws"
    [params]
    sigma_bearing_deg = 1.0

Overrides (``--set name=value`` on the CLI, grid points in sweeps) are parsed to the type of the
default, and an unknown name is an error that lists the known ones. Parameters stated in degrees
carry ``_deg`` in their name and are converted to radians by the recorder, nowhere else.

A parameter's meaning is the comment after it on its line (``sigma_range_m = 100.0  # plot
noise, range``) or, when it has none, the block of comment lines directly above it (read by
:func:`parameter_docs`); its unit the suffix of its name, or for a dimensionless parameter what
kind of number it is (``count``, ``probability``, ``flag``, ...: :func:`parameter_unit`).
``replay scenarios NAME`` shows both.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from trackreplay.errors import InputError


def scenario_dir() -> Path:
    """Folder of the bundled scenario files (installed package data, or the source tree)."""
    try:
        from importlib.resources import files

        return Path(str(files("replay_data.scenarios")))
    except ModuleNotFoundError:
        return Path(__file__).resolve().parents[1] / "data" / "scenarios"


@dataclass
class Scenario:
    """A scenario: its name, the recorder that simulates it, and its parameters."""

    name: str
    recorder: str
    params: dict
    description: str = ""
    source: str = ""
    defaults: dict = field(default_factory=dict)

    def with_overrides(self, overrides: dict) -> "Scenario":
        """A copy with some parameters replaced (values parsed to the default's type)."""
        params = dict(self.params)
        for key, raw in overrides.items():
            if key not in self.defaults:
                known = ", ".join(sorted(self.defaults))
                raise InputError(f"unknown parameter {key!r} for scenario {self.name!r} (known: {known})")
            params[key] = coerce(key, raw, self.defaults[key])
        return Scenario(self.name, self.recorder, params, self.description, self.source, self.defaults)


def coerce(key: str, raw, default):
    """Parse ``raw`` (string or number) to the type of ``default``.

    List parameters take comma-separated values (``snr_db=0,5,10``), each parsed to the type
    of the default's elements (float when the default is empty).
    """
    if isinstance(default, list):
        items = raw if isinstance(raw, (list, tuple)) else [v for v in str(raw).split(",") if v.strip() != ""]
        if not items:
            raise InputError(f"parameter {key!r} has an empty value list")
        element = default[0] if default else 0.0
        return [coerce(key, v, element) for v in items]
    if not isinstance(raw, str):
        value = raw
    else:
        text = raw.strip()
        if text == "":
            raise InputError(f"parameter {key!r} has an empty value")
        try:
            if isinstance(default, bool):
                if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(text)
                value = text.lower() in ("true", "1", "yes")
            elif isinstance(default, int):
                value = int(text)
            elif isinstance(default, float):
                value = float(text)
            else:
                value = text
        except ValueError:
            raise InputError(
                f"parameter {key!r}: cannot read {raw!r} as {type(default).__name__}") from None
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    return value


def parse_assignments(items) -> dict:
    """``["a=1", "b=x"]`` → ``{"a": "1", "b": "x"}`` (values stay strings until coerced)."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise InputError(f"expected NAME=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        out[k.strip()] = v
    return out


def available_scenarios() -> list[str]:
    return sorted(p.stem for p in scenario_dir().glob("*.toml"))


def load_scenario(name_or_path: str) -> Scenario:
    """Load a bundled scenario by name, or any scenario TOML file by path."""
    path = Path(name_or_path)
    if not path.suffix:
        path = scenario_dir() / f"{name_or_path}.toml"
    if not path.exists():
        known = ", ".join(available_scenarios())
        raise InputError(f"unknown scenario {name_or_path!r} (bundled: {known})")
    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not a valid scenario file: {exc}", path) from None
    for key in ("name", "recorder", "params"):
        if key not in doc:
            raise InputError(f"scenario file lacks {key!r}", path)
    params = dict(doc["params"])
    if path.parent.resolve() != scenario_dir().resolve():
        params = _complete_user_params(doc["recorder"], params, path)
    return Scenario(doc["name"], doc["recorder"], params, doc.get("description", ""), str(path), dict(params))


def _complete_user_params(recorder: str, params: dict, path: Path) -> dict:
    """A user's scenario file checked against the bundled scenario of its recorder: parameters
    it leaves out take the bundled defaults, each value is read as its default's type, and a
    parameter the recorder does not know is refused (a typo would otherwise be ignored)."""
    from trackreplay.recorders import recorder_names

    known = recorder_names()
    if recorder not in known:
        raise InputError(f"unknown recorder {recorder!r} (known: {', '.join(sorted(known))})", path)
    template = None
    for name in available_scenarios():
        bundled = tomllib.loads((scenario_dir() / f"{name}.toml").read_text())
        if bundled.get("recorder") == recorder:
            template = bundled["params"]
            break
    if template is None:
        return params
    unknown = sorted(set(params) - set(template))
    if unknown:
        raise InputError(f"unknown parameter(s) {', '.join(map(repr, unknown))} for recorder {recorder!r} "
                         f"(known: {', '.join(sorted(template))})", path)
    out = dict(template)
    for key, raw in params.items():
        try:
            out[key] = coerce(key, raw, template[key])
        except InputError as exc:
            raise InputError(exc.problem, path) from None
    return out


# unit of a parameter from the last part of its name (``sigma_range_m`` → m)
UNIT_SUFFIXES = {
    "m": "m", "km": "km", "m2": "m²", "s": "s", "deg": "deg", "deg2": "deg²", "rad": "rad",
    "radps": "rad/s", "mps": "m/s", "mps2": "m/s²", "hz": "Hz", "db": "dB", "wavelengths": "λ",
    "samples": "samples", "scans": "scans", "m2ps3": "m²/s³", "degps": "deg/s",
}

# units of parameters whose name does not state theirs (or states only a part of it: the q of a
# white-noise acceleration model is a spectral density, deg²/s³, not deg²)
NAMED_UNITS = {
    "q_deg2": "deg²/s³", "process_noise_q_deg2": "deg²/s³",
    "process_noise_variance": "m²/s⁴", "cv_process_noise": "m²/s⁴", "kf_process_noise": "m²/s⁴",
    "ca_transition_process_noise": "m²/s⁶", "ca_steady_process_noise": "m²/s⁶",
    "initial_variance": "SI²",            # P₀ = v·I over [p, v, a]: m², (m/s)², (m/s²)²
    "noise_variance": "power",            # sensor noise power, the reference of every SNR
    "clutter_alpha": "1/amplitude", "amplitude_threshold": "amplitude", "peak_threshold": "amplitude",
    "step_tolerance_sigma": "σ",          # a multiple of a standard deviation
    "imm_transition": "probability",      # a matrix of transition probabilities
    "emitter": "preset", "pairs": "pair list",
    "initial_targets_mean": "count", "turning_fraction": "fraction",
    # flags and choices (their value's type is not known from the name alone)
    "startup_gains": "flag", "gcc_phat": "flag", "amplitude_tracking": "flag", "stationary_emitter": "flag",
    "trajectory": "choice", "geometry": "choice", "pair": "choice", "track_start": "choice",
    "initial_guess": "choice", "subspace_tracker": "choice", "source_count_criterion": "choice",
    "snapshot_dtype": "choice",
}

# what kind of number a dimensionless parameter is, from the shape of its name (first match)
KIND_PATTERNS = (
    (re.compile(r"^n_|_count$|_per_scan$|^iterations$|^max_\w*tracks$"), "count"),
    (re.compile(r"_per_gate$"), "count/gate"),
    (re.compile(r"_probability$"), "probability"),
    (re.compile(r"_(first|last)_sample$"), "sample index"),
    (re.compile(r"^alpha(_|$)|_pole$"), "coefficient"),
    (re.compile(r"_forgetting(_factor)?$|_scales?$"), "factor"),
    (re.compile(r"_gain$|_ratio$|_relative_mse$"), "ratio"),
    (re.compile(r"_amplitude_(mean|std)$|_strength$"), "amplitude"),
)


def parameter_unit(name: str, value=None) -> str | None:
    """The unit of a scenario parameter, or None when nothing names one.

    In this order:

    1. :data:`NAMED_UNITS`, by the whole name: parameters whose name does not state their unit
       (``cv_process_noise`` → m²/s⁴, ``clutter_alpha`` → 1/amplitude), or states only a part of it
       (``q_deg2`` → deg²/s³), and the flags and choices of the bundled scenarios;
    2. a ``_X_per_Y`` ending with two units of :data:`UNIT_SUFFIXES` (``approach_rate_deg_per_s``
       → deg/s);
    3. the suffix of the name, :data:`UNIT_SUFFIXES` (``_m``, ``_s``, ``_deg``, ``_mps``,
       ``_mps2``, ``_hz``, ``_db``, ``_rad``, ``_samples``, ``_scans``, ...);
    4. for a dimensionless parameter, what kind of number it is, from the shape of its name
       (:data:`KIND_PATTERNS`): ``count`` (``n_…``, ``…_count``, ``…_per_scan``, ``iterations``),
       ``count/gate`` (an expected count per gate, ``…_per_gate``), ``probability``
       (``…_probability``), ``sample index``, ``coefficient`` (AR coefficients ``alpha…``, poles),
       ``factor`` (forgetting factors, scales), ``ratio`` (gains, ratios), ``amplitude``
       (correlator amplitude units);
    5. from ``value`` when given: ``flag`` for a bool, ``choice`` for a string (for a parameter
       none of the above knows; ``replay scenarios`` passes the name only).

    A unit written in the parameter's comment is not read: the unit comes from the name, so the
    same parameter shows the same unit in every scenario file.
    """
    if name in NAMED_UNITS:
        return NAMED_UNITS[name]
    parts = name.split("_")
    if len(parts) >= 3 and parts[-2] == "per" and parts[-3] in UNIT_SUFFIXES and parts[-1] in UNIT_SUFFIXES:
        return f"{UNIT_SUFFIXES[parts[-3]]}/{UNIT_SUFFIXES[parts[-1]]}"
    if len(parts) > 1 and parts[-1] in UNIT_SUFFIXES:
        return UNIT_SUFFIXES[parts[-1]]
    for pattern, kind in KIND_PATTERNS:
        if pattern.search(name):
            return kind
    if isinstance(value, bool):
        return "flag"
    if isinstance(value, str):
        return "choice"
    return None


_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*=(.*)$")
# a comment line that only heads a group of parameters: "# ---- filter design ----", "# === ..."
_HEADING = re.compile(r"^(-{2,}|={2,}|\*{2,})")


def _trailing_comment(value: str) -> str:
    """The comment after a TOML value on its line ('#' outside a string), or ''."""
    quote = None
    i = 0
    while i < len(value):
        c = value[i]
        if quote:
            if c == "\\" and quote == '"':
                i += 1
            elif c == quote:
                quote = None
        elif c in "\"'":
            quote = c
        elif c == "#":
            return value[i + 1:].strip()
        i += 1
    return ""


def parameter_docs(path) -> dict[str, str]:
    """``name → meaning`` of a scenario file's parameters in ``[params]``.

    A parameter's meaning is the comment after it on its line::

        sigma_range_m = 100.0          # plot noise, range

    or, when it has none, the comment lines directly above it (a contiguous block of ``#``
    lines, joined into one text)::

        # The paper's truth is constant velocity; with truth process noise > 0 the target
        # wanders by kilometres over the run.
        truth_process_noise_mps2 = 0.0

    The comment on the line wins over the lines above. A blank line, a value, a table header
    or a heading line (a comment starting with ``--``, ``==`` or ``**``, such as
    ``# ---- filter design ----``) ends a block, so a comment that introduces a group of
    parameters is kept from the first of them by a blank line or by writing it as a heading.
    Parameters without either are left out.
    """
    docs: dict[str, str] = {}
    section = None
    above: list[str] = []  # comment lines directly above the current line
    try:
        lines = Path(path).read_text().splitlines()
    except OSError:
        return docs
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("#"):
            text = stripped.lstrip("#").strip()
            if _HEADING.match(text):
                above = []
            elif text:
                above.append(text)
            continue
        comment_above = " ".join(above)
        above = []
        if stripped.startswith("[") and not line[:1].isspace() and "=" not in stripped:
            section = stripped.strip("[]").strip()
            continue
        if section != "params":
            continue
        m = _KEY.match(line)
        if m:
            comment = _trailing_comment(m.group(2)) or comment_above
            if comment:
                docs[m.group(1)] = comment
    return docs
