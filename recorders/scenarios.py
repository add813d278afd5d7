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
noise, range``, read by :func:`parameter_docs`), its unit the suffix of its name
(:func:`parameter_unit`); ``replay scenarios NAME`` shows both.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.errors import InputError


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
    from recorders import RECORDERS

    if recorder not in RECORDERS:
        raise InputError(f"unknown recorder {recorder!r} (known: {', '.join(sorted(RECORDERS))})", path)
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
    "samples": "samples",
}


def parameter_unit(name: str) -> str | None:
    """The unit a parameter's name states by its suffix (``_m``, ``_s``, ``_deg``, ``_mps``,
    ``_mps2``, ``_hz``, ``_db``, ``_rad``, ...), or None (a count, a ratio, a choice)."""
    if "_" not in name:
        return None
    return UNIT_SUFFIXES.get(name.rsplit("_", 1)[1])


_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*=(.*)$")


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
    """``name → meaning`` of a scenario file's parameters: the comment after each one on its
    line in ``[params]`` (parameters without one are left out)."""
    docs: dict[str, str] = {}
    section = None
    try:
        lines = Path(path).read_text().splitlines()
    except OSError:
        return docs
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("[") and not line[:1].isspace() and "=" not in stripped:
            section = stripped.strip("[]").strip()
            continue
        if section != "params":
            continue
        m = _KEY.match(line)
        if m:
            comment = _trailing_comment(m.group(2))
            if comment:
                docs[m.group(1)] = comment
    return docs
