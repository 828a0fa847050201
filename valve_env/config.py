"""Environment configuration: parameters + scenario + control, from keyword
arguments and YAML files (``configs/*.yaml``).

A YAML file may hold any of the sections ``valve``, ``bulb``, ``tank``,
``scenario``, ``control``, ``sensors``, each a mapping of field names to values. Keyword
arguments to ``gym.make`` override the file: ``gym.make("ThermoValve-v0",
config="configs/cold_supply.yaml", tapping_profile="L", valve={"F_hmax": 2.0})``.
Top-level keywords that name a field of ScenarioParams or ControlParams are
accepted directly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from valve_env.effects import Effects, parse_effects
from valve_env.params import BulbParams, ConfigError, TankParams, ValveParams, _from_mapping
from valve_env.scenario import ScenarioParams


@dataclass(frozen=True)
class ControlParams:
    """Control loop, targets and reward weights.

    | field | unit | meaning (default, source) |
    |---|---|---|
    | dt_s | s | control step; 30 (SPEC section 5) |
    | n_sub | - | physics sub-steps per control step; 3 (10 s, well under the bulb's 40 s and the tank's ~500 s) |
    | horizon_h | h | episode length; 24 (SPEC) |
    | T_target_C | degC | outlet target; 60 (SPEC) |
    | T_floor_C | degC | hygiene and comfort floor; 55 (SPEC) |
    | setting_min_C, setting_max_C | degC | range of the valve's temperature setting (action); 40 .. 80 |
    | setting_C | degC | the setting when the agent does not set it (ThermoValvePressure-v0); 62 |
    | dp_min_mbar, dp_max_mbar | mbar | range of the pump's differential pressure (action); 0 .. 300 |
    | w_track | 1/K^2 | reward weight of the squared tracking error; 0.04 (= (e / 5 K)^2) |
    | w_floor | 1/K | reward weight of the shortfall below the floor; 1.0 |
    | w_energy | 1/kW | reward weight of the mean primary heat plus 2.5 x pump power (primary energy factor); 0.02 |
    """

    dt_s: float = 30.0
    n_sub: int = 3
    horizon_h: float = 24.0
    T_target_C: float = 60.0
    T_floor_C: float = 55.0
    setting_min_C: float = 40.0
    setting_max_C: float = 80.0
    setting_C: float = 62.0
    dp_min_mbar: float = 0.0
    dp_max_mbar: float = 300.0
    w_track: float = 0.04
    w_floor: float = 1.0
    w_energy: float = 0.02

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(v):
                raise ConfigError(f"ControlParams.{f.name} must be finite, got {v!r}")
        if self.dt_s <= 0:
            raise ConfigError(f"ControlParams.dt_s must be > 0, got {self.dt_s!r}")
        if int(self.n_sub) != self.n_sub or self.n_sub < 1:
            raise ConfigError(f"ControlParams.n_sub must be an integer >= 1, got {self.n_sub!r}")
        object.__setattr__(self, "n_sub", int(self.n_sub))
        if self.horizon_h * 3600.0 < self.dt_s:
            raise ConfigError(f"ControlParams.horizon_h must cover at least one step, got {self.horizon_h!r}")
        if not self.setting_min_C < self.setting_max_C:
            raise ConfigError("ControlParams.setting_min_C must be < setting_max_C")
        if not self.setting_min_C <= self.setting_C <= self.setting_max_C:
            raise ConfigError(
                f"ControlParams.setting_C must be within [setting_min_C, setting_max_C], got {self.setting_C}"
            )
        if not 0 <= self.dp_min_mbar < self.dp_max_mbar:
            raise ConfigError("ControlParams.dp_min_mbar must be >= 0 and < dp_max_mbar")
        for name in ("w_track", "w_floor", "w_energy"):
            if getattr(self, name) < 0:
                raise ConfigError(f"ControlParams.{name} must be >= 0, got {getattr(self, name)!r}")

    @property
    def n_steps(self) -> int:
        return int(round(self.horizon_h * 3600.0 / self.dt_s))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> ControlParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class SensorParams:
    """Measurement imperfections, applied by wrappers (valve_env.wrappers), never in the physics.

    | field | unit | meaning (default) |
    |---|---|---|
    | noise_K | K | white noise on every observed temperature; 0 (paper Table 1: 0.05 K uncertainty) |
    | flow_noise_rel | - | relative white noise on observed flow and dp; 0 (paper Table 1: 0.015) |
    | dead_time_steps | steps | the observation reaches the agent this many control steps late; 0 |
    """

    noise_K: float = 0.0
    flow_noise_rel: float = 0.0
    dead_time_steps: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(v) or v < 0:
                raise ConfigError(f"SensorParams.{f.name} must be finite and >= 0, got {v!r}")
        if int(self.dead_time_steps) != self.dead_time_steps:
            raise ConfigError(f"SensorParams.dead_time_steps must be an integer, got {self.dead_time_steps!r}")
        object.__setattr__(self, "dead_time_steps", int(self.dead_time_steps))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> SensorParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines an environment instance besides the seed."""

    valve: ValveParams = field(default_factory=ValveParams)
    bulb: BulbParams = field(default_factory=BulbParams)
    tank: TankParams = field(default_factory=TankParams)
    scenario: ScenarioParams = field(default_factory=ScenarioParams)
    control: ControlParams = field(default_factory=ControlParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    #: the valve's named effects (the ``effects:`` mapping of the ``valve:`` section; valve_env.effects)
    effects: Effects = field(default_factory=Effects)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        out = {name: getattr(self, name).to_dict() for name in SECTIONS}
        if self.effects:
            out["valve"]["effects"] = self.effects.as_dict()
        return out

    def replace(self, **changes: Any) -> EnvConfig:
        return dataclasses.replace(self, **changes)


SECTIONS: dict[str, Any] = {
    "valve": ValveParams,
    "bulb": BulbParams,
    "tank": TankParams,
    "scenario": ScenarioParams,
    "control": ControlParams,
    "sensors": SensorParams,
}


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a config YAML file; errors name the file and the problem."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file {str(p)!r} does not exist")
    try:
        data = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {str(p)!r} is not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"config file {str(p)!r} must hold a mapping of sections {sorted(SECTIONS)}")
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"config file {str(p)!r}: unknown section(s) {unknown}; known: {sorted(SECTIONS)}")
    return data


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = {k: dict(v) if isinstance(v, Mapping) else v for k, v in base.items()}
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k].update(v)
        else:
            out[k] = v
    return out


def make_config(config: str | Path | EnvConfig | Mapping[str, Any] | None = None, **overrides: Any) -> EnvConfig:
    """Build an EnvConfig from a YAML path, a mapping or an EnvConfig, then
    apply keyword overrides: a section name with a mapping or a dataclass
    (``valve={"sigma": 5.0}``), or a single field of ScenarioParams or
    ControlParams by its name (``tapping_profile="L"``)."""
    if isinstance(config, EnvConfig):
        base: dict[str, Any] = {}
        start = config
    else:
        start = EnvConfig()
        if config is None:
            base = {}
        elif isinstance(config, (str, Path)):
            base = load_yaml(config)
        elif isinstance(config, Mapping):
            base = dict(config)
        else:
            raise ConfigError(f"config must be a YAML path, a mapping or an EnvConfig, got {type(config).__name__}")
    sections: dict[str, Any] = {}
    for k, v in base.items():
        if k not in SECTIONS:
            raise ConfigError(f"unknown config section {k!r}; known: {sorted(SECTIONS)}")
        sections[k] = v
    scen_fields = {f.name for f in fields(ScenarioParams)}
    ctrl_fields = {f.name for f in fields(ControlParams)}
    for k, v in overrides.items():
        if k in SECTIONS:
            if dataclasses.is_dataclass(v) and not isinstance(v, type):
                v = dataclasses.asdict(v)
            if not isinstance(v, Mapping):
                raise ConfigError(f"{k}= must be a mapping of field names or a {SECTIONS[k].__name__}")
            sections = _merge(sections, {k: v})
        elif k in scen_fields:
            sections = _merge(sections, {"scenario": {k: v}})
        elif k in ctrl_fields:
            sections = _merge(sections, {"control": {k: v}})
        else:
            raise ConfigError(
                f"unknown environment option {k!r}; use a section ({sorted(SECTIONS)}) or a scenario/control field"
            )
    built: dict[str, Any] = {"effects": start.effects}
    if "valve" in sections and isinstance(sections["valve"], Mapping) and "effects" in sections["valve"]:
        # the valve's named effects (docs/reference.md, "The valve file"), checked against the registry
        sections["valve"] = dict(sections["valve"])
        built["effects"] = parse_effects(sections["valve"].pop("effects"))
    for name, cls in SECTIONS.items():
        current = getattr(start, name)
        if name in sections:
            merged = {**current.to_dict(), **dict(sections[name])}
            built[name] = cls.from_dict(merged)
        else:
            built[name] = current
    return EnvConfig(**built)
