"""Configuration of the correction engine (keyframes, term strengths, drift, solver, rules).

The documented defaults live in ``default_config.toml`` beside this module; that file
is the reference for every key, its unit and why its default is what it is.
``CorrectionConfig()`` equals that file; ``CorrectionConfig.load(path)`` overlays a user
file on it.  Unknown sections or keys and wrongly typed values are refused with a
``ConfigError`` naming the file, line and field.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from posefix.core.rules import MAX_MOVE_LIMIT_M, MIN_MOVE_LIMIT_M, EditRules

DEFAULT_CONFIG_PATH = Path(__file__).with_name("default_config.toml")


class ConfigError(ValueError):
    """A configuration file or value that cannot be used."""

    def __init__(self, file: str, line: int | None, field_name: str, message: str):
        self.file, self.line, self.field, self.message = file, line, field_name, message
        where = f"{file}:{line}" if line else file
        super().__init__(f"{where}: field '{field_name}': {message}")


@dataclass(frozen=True)
class KeyframeConfig:
    every_s: float = 1.0
    every_m: float = 0.0
    images: bool = True


@dataclass(frozen=True)
class LocationConfig:
    sigma_h_m: float = 3.0
    sigma_v_m: float = 6.0
    loss: str = "cauchy"
    loss_scale: float = 1.0


@dataclass(frozen=True)
class UserConfig:
    sigma_h_m: float = 0.5
    sigma_v_m: float = 0.5


@dataclass(frozen=True)
class RelativeConfig:
    sigma_t_floor_m: float = 0.02
    sigma_t_per_sqrt_s_m: float = 0.2
    sigma_t_per_m: float = 0.002
    max_lateral_speed_mps: float = 0.5
    edit_bend_chi2: float = 9.21
    transient_short_s: float = 5.0
    transient_long_s: float = 60.0
    sigma_r_floor_rad: float = 0.00001
    sigma_r_per_sqrt_s_rad: float = 0.00003


@dataclass(frozen=True)
class GravityConfig:
    sigma: float = 0.01


@dataclass(frozen=True)
class DriftConfig:
    enabled: bool = True
    bias_sigma_m: float = 5.0
    bias_tau_s: float = 60.0
    min_edits_for_estimate: int = 3


@dataclass(frozen=True)
class CalibrationConfig:
    model: str = "auto"


@dataclass(frozen=True)
class PropagationConfig:
    mode: str = "distance"


@dataclass(frozen=True)
class SolverConfig:
    method: str = "banded"
    max_iterations: int = 100
    ftol: float = 1e-10


_CHOICES = {
    ("location", "loss"): ("cauchy", "huber", "soft_l1", "none"),
    ("propagation", "mode"): ("distance", "time"),
    ("calibration", "model"): ("auto", "gnss", "plain", "relative", "naive"),
    ("solver", "method"): ("banded", "scipy"),
    ("rules", "lock_direction"): ("forward", "both"),
    ("rules", "order_rule"): ("refuse", "flag"),
    ("rules", "deleted"): ("remove", "flag"),
}
_RANGES = {("rules", "max_move_m"): (MIN_MOVE_LIMIT_M, MAX_MOVE_LIMIT_M)}
_POSITIVE = {
    ("location", "sigma_h_m"), ("location", "sigma_v_m"), ("location", "loss_scale"),
    ("user", "sigma_h_m"), ("user", "sigma_v_m"), ("gravity", "sigma"),
    ("relative", "sigma_t_floor_m"), ("relative", "sigma_r_floor_rad"),
    ("relative", "transient_short_s"), ("relative", "transient_long_s"), ("solver", "max_iterations"),
    ("solver", "ftol"), ("rules", "every_n"), ("drift", "bias_sigma_m"), ("drift", "bias_tau_s"),
}


@dataclass(frozen=True)
class CorrectionConfig:
    """All engine settings; see ``default_config.toml`` for units and reasons."""

    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    location: LocationConfig = field(default_factory=LocationConfig)
    user: UserConfig = field(default_factory=UserConfig)
    relative: RelativeConfig = field(default_factory=RelativeConfig)
    gravity: GravityConfig = field(default_factory=GravityConfig)
    drift: DriftConfig = field(default_factory=DriftConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    propagation: PropagationConfig = field(default_factory=PropagationConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    rules: EditRules = field(default_factory=EditRules)

    @classmethod
    def load(cls, path: str | Path) -> "CorrectionConfig":
        """Defaults overlaid with the TOML file at ``path``."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(str(path), None, "-", f"cannot read: {exc.strerror}") from None
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(str(path), getattr(exc, "lineno", None), "-", f"not valid TOML: {exc}") from None
        return cls.from_dict(data, source=str(path), text=text)

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<config>", text: str = "") -> "CorrectionConfig":
        """Defaults overlaid with ``{section: {key: value}}``; validates every value."""
        base = cls()
        sections = {}
        for section, values in data.items():
            if section not in {f.name for f in dataclasses.fields(cls)}:
                raise ConfigError(source, _line_of(text, f"[{section}]"), section, "unknown section")
            if not isinstance(values, dict):
                raise ConfigError(source, _line_of(text, section), section, "must be a table")
            current = getattr(base, section)
            known = {f.name: f for f in dataclasses.fields(current)}
            updates = {}
            for key, value in values.items():
                if key not in known:
                    raise ConfigError(source, _line_of(text, key), f"{section}.{key}", "unknown key")
                updates[key] = _check_value(section, key, value, getattr(current, key), source, text)
            sections[section] = dataclasses.replace(current, **updates)
        return dataclasses.replace(base, **sections)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Plain nested dict (TOML/JSON friendly)."""
        return {f.name: dataclasses.asdict(getattr(self, f.name)) for f in dataclasses.fields(self)}


def _check_value(section: str, key: str, value: Any, default: Any, source: str, text: str) -> Any:
    name = f"{section}.{key}"
    line = _line_of(text, key)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(source, line, name, f"must be true or false, got {value!r}")
    elif isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(source, line, name, f"must be an integer, got {value!r}")
    elif isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(source, line, name, f"must be a number, got {value!r}")
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            raise ConfigError(source, line, name, "must be finite")
    elif isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(source, line, name, f"must be a string, got {value!r}")
    choices = _CHOICES.get((section, key))
    if choices and value not in choices:
        raise ConfigError(source, line, name, f"must be one of {', '.join(choices)}; got {value!r}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        bounds = _RANGES.get((section, key))
        if bounds and not bounds[0] <= value <= bounds[1]:
            raise ConfigError(source, line, name, f"must be between {bounds[0]:g} and {bounds[1]:g}, got {value}")
        if (section, key) in _POSITIVE and value <= 0:
            raise ConfigError(source, line, name, f"must be > 0, got {value}")
        if value < 0:
            raise ConfigError(source, line, name, f"must be >= 0, got {value}")
    return value


def _line_of(text: str, needle: str) -> int | None:
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped.startswith(needle) and (needle.startswith("[") or stripped[len(needle):].lstrip().startswith("=")):
            return number
    return None
