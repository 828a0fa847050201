"""Environment configuration: parameters + scenario + control, from keyword
arguments and YAML files (the packaged ``valve_env/data/scenarios/*.yaml`` or a user's own).

A YAML file may hold any of the sections ``valve``, ``bulb``, ``tank``,
``scenario``, ``control``, ``sensors``, each a mapping of field names to values. Keyword
arguments to ``gym.make`` override the file: ``gym.make("ThermoValve-v0",
config="configs/scenarios/cold_supply.yaml", tapping_profile="L", valve={"F_hmax": 2.0})``; a packaged
scenario also loads by its name, ``config="cold_supply"`` (:mod:`valve_env.data`).
Top-level keywords that name a field of ScenarioParams or ControlParams are
accepted directly.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from importlib.resources.abc import Traversable
from pathlib import Path, PurePath
from typing import Any, ClassVar

import yaml

from valve_env.data import packaged_scenario, scenario_files
from valve_env.effects import REGISTRY as EFFECTS
from valve_env.effects import Effects, parse_effects
from valve_env.params import (
    DP_MAX_MBAR,
    DRAW_MAX_L_MIN,
    BulbParams,
    ConfigError,
    TankParams,
    ValveParams,
    _from_mapping,
    check_fields,
    param,
)
from valve_env.scenario import ScenarioParams, largest_tap_l_min

#: the largest fraction of a layer's heat capacity that the coil and the losses may exchange in a
#: sub-step (EnvConfig.layer_exchange): the rest is left for the draw, so that every layer's update
#: is a mixture of the temperatures around it (docs/configuration.md)
MAX_LAYER_EXCHANGE = 0.5
#: the longest episode in control steps: its scenario takes 80 MB (5 float64 a step); a year at 16 s
MAX_EPISODE_STEPS = 2_000_000


@dataclass(frozen=True)
class ControlParams:
    """Control loop, targets and reward weights.

    | field | unit | meaning (default, source) | range (why) |
    |---|---|---|---|
    | dt_s | s | control step; 30 (docs/reference.md, section 5) | [1, 3600] (a fast controller .. an hourly schedule) |
    | n_sub | - | physics sub-steps per control step; 3 (10 s, well under the bulb's 40 s and the tank's ~500 s) | [1, 1000] (integer; bounds a step's cost) |
    | horizon_h | h | episode length; 24 (docs/reference.md, section 5) | (0, 8784] (up to a leap year; at most 2 000 000 steps) |
    | T_target_C | degC | outlet target; 60 (docs/reference.md, section 5) | [10, 100] (hot water at ambient pressure) |
    | T_floor_C | degC | hygiene and comfort floor; 55 (docs/reference.md, section 5) | [0, 100] (hot water at ambient pressure) |
    | setting_min_C, setting_max_C | degC | range of the valve's temperature setting (action); 40 .. 80 | [10, 120] (thermostat scales) |
    | setting_C | degC | the setting when the agent does not set it (ThermoValvePressure-v0); 62 | [10, 120], within the setting range |
    | dp_min_mbar, dp_max_mbar | mbar | range of the pump's differential pressure (action); 0 .. 300 | [0, 2000] (0 .. 2 bar, DP_MAX_MBAR) |
    | w_track | 1/K^2 | reward weight of the squared tracking error; 0.04 (= (e / 5 K)^2) | [0, 100] (a weight) |
    | free_band_K | K | no tracking error from T_target_C up to this much above it (a store behind a thermostatic mixing valve, EN 15092: the tap gets the target from a hotter store; docs/tasks.md, "ThermoValveDistrictHeating-v1"); 0: the error is T_top - T_target both ways | [0, 50] (up to a 110 degC store over a 60 degC target) |
    | w_floor | 1/K | reward weight of the shortfall below the floor; 1.0 | [0, 100] (a weight) |
    | w_energy | 1/kW | reward weight of the mean primary heat plus 2.5 x pump power (primary energy factor); 0.02 | [0, 100] (a weight) |
    """  # noqa: E501

    SECTION: ClassVar[str] = "control"

    dt_s: float = param(30.0, 1.0, 3600.0, "s", "a fast controller .. an hourly schedule")
    n_sub: int = param(3, 1, 1000, "-", "bounds the cost of a step", kind="int")
    horizon_h: float = param(24.0, 0.0, 8784.0, "h", "up to a leap year", lo_open=True)
    T_target_C: float = param(60.0, 10.0, 100.0, "degC", "hot water at ambient pressure")
    T_floor_C: float = param(55.0, 0.0, 100.0, "degC", "hot water at ambient pressure")
    setting_min_C: float = param(40.0, 10.0, 120.0, "degC", "thermostat scales")
    setting_max_C: float = param(80.0, 10.0, 120.0, "degC", "thermostat scales")
    setting_C: float = param(62.0, 10.0, 120.0, "degC", "thermostat scales")
    dp_min_mbar: float = param(0.0, 0.0, DP_MAX_MBAR, "mbar", "0 .. 2 bar")
    dp_max_mbar: float = param(300.0, 0.0, DP_MAX_MBAR, "mbar", "0 .. 2 bar")
    w_track: float = param(0.04, 0.0, 100.0, "1/K^2", "a weight")
    free_band_K: float = param(0.0, 0.0, 50.0, "K", "up to a 110 degC store over a 60 degC target")
    w_floor: float = param(1.0, 0.0, 100.0, "1/K", "a weight")
    w_energy: float = param(0.02, 0.0, 100.0, "1/kW", "a weight")

    def __post_init__(self) -> None:
        check_fields(self)
        steps = self.horizon_h * 3600.0 / self.dt_s
        if not 1 <= round(steps) <= MAX_EPISODE_STEPS:
            raise ConfigError(
                f"control.horizon_h must give 1 .. {MAX_EPISODE_STEPS} steps of control.dt_s = {self.dt_s:g} s, "
                f"got {self.horizon_h!r} h ({steps:.4g} steps)"
            )
        if not self.setting_min_C < self.setting_max_C:
            raise ConfigError(
                f"control.setting_min_C must be < control.setting_max_C, got {self.setting_min_C!r} >= "
                f"{self.setting_max_C!r}"
            )
        if not self.setting_min_C <= self.setting_C <= self.setting_max_C:
            raise ConfigError(
                f"control.setting_C must be within [setting_min_C, setting_max_C] = "
                f"[{self.setting_min_C:g}, {self.setting_max_C:g}], got {self.setting_C!r}"
            )
        if not self.dp_min_mbar < self.dp_max_mbar:
            raise ConfigError(
                f"control.dp_min_mbar must be < control.dp_max_mbar, got {self.dp_min_mbar!r} >= {self.dp_max_mbar!r}"
            )

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

    | field | unit | meaning (default) | range (why) |
    |---|---|---|---|
    | noise_K | K | white noise on every observed temperature; 0 (paper Table 1: 0.05 K uncertainty) | [0, 10] (a precise .. a poor sensor) |
    | flow_noise_rel | - | relative white noise on observed flow and dp; 0 (paper Table 1: 0.015) | [0, 1] (up to 100 %) |
    | dead_time_steps | steps | the observation reaches the agent this many control steps late; 0 | [0, 1000] (integer; a delay line's memory) |
    """  # noqa: E501

    SECTION: ClassVar[str] = "sensors"

    noise_K: float = param(0.0, 0.0, 10.0, "K", "a precise .. a poor sensor")
    flow_noise_rel: float = param(0.0, 0.0, 1.0, "-", "up to 100 %")
    dead_time_steps: int = param(0, 0, 1000, "steps", "a delay line's memory", kind="int")

    def __post_init__(self) -> None:
        check_fields(self)

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

    def __post_init__(self) -> None:
        for name, cls in SECTIONS.items():
            got = getattr(self, name)
            if not isinstance(got, cls):
                raise ConfigError(f"EnvConfig.{name} must be a {cls.__name__}, got {type(got).__name__}")
        need = self.min_n_sub()
        if self.control.n_sub < need:
            tap = largest_tap_l_min(self.scenario.tapping_profile)
            raise ConfigError(
                f"control.n_sub = {self.control.n_sub} is too few for this tank: in a sub-step of "
                f"{self.sub_step_s:g} s the explicit update of a {self.tank.layer_mass_kg:.3g} kg layer exchanges "
                f"{self.layer_exchange():.3g} of its heat capacity through the coil and the losses (at most "
                f"{MAX_LAYER_EXCHANGE:g}) and passes at most {60.0 * self.draw_max_kgs():.3g} l/min of draw (the "
                f"tapping cycle's largest tap: {tap:g} l/min); use control.n_sub >= {need}, a larger "
                "tank.volume_l or fewer tank.n_layers"
            )

    @property
    def sub_step_s(self) -> float:
        """The physics sub-step, control.dt_s / control.n_sub, s."""
        return self.control.dt_s / self.control.n_sub

    def layer_exchange(self) -> float:
        """The largest fraction of a layer's heat capacity that the coil and the standing
        loss can exchange in one sub-step, (UA_coil / coil_layers + UA_loss / n_layers)
        dt_sub / (m_layer cp) (docs/configuration.md: the explicit layer update)."""
        t = self.tank
        return (t.UA_coil / t.coil_layers + t.UA_loss / t.n_layers) * self.sub_step_s / (t.layer_mass_kg * t.cp)

    def draw_max_kgs(self) -> float:
        """The tank's largest hot-water outflow, kg/s: DRAW_MAX_L_MIN, and no more than the
        layer mass the explicit update can still move in a sub-step besides the coil and the
        losses, (1 - layer_exchange) m_layer / dt_sub, less the circulation loop's flow
        (physics.tank.draw_flow's limit)."""
        numerical = max(0.0, 1.0 - self.layer_exchange()) * self.tank.layer_mass_kg / self.sub_step_s
        if self.tank.circ_kgh > 0.0:
            numerical = max(0.0, numerical - self.tank.circ_kgh / 3600.0)
        return min(DRAW_MAX_L_MIN / 60.0, numerical)

    def min_n_sub(self) -> int:
        """The fewest sub-steps per control step that keep the explicit layer update a
        mixture of the temperatures around each layer: layer_exchange <= MAX_LAYER_EXCHANGE,
        with room left for the tapping cycle's largest tap flow and the circulation loop's flow
        (docs/configuration.md).

        With e the exchange at one sub-step and f the largest tap (kg/s), n sub-steps
        exchange e / n and pass (n - e) m_layer / dt_s: n >= max(e / MAX_LAYER_EXCHANGE,
        e + f dt_s / m_layer)."""
        t = self.tank
        e1 = self.layer_exchange() * self.control.n_sub
        tap = largest_tap_l_min(self.scenario.tapping_profile) / 60.0 + t.circ_kgh / 3600.0
        need = max(e1 / MAX_LAYER_EXCHANGE, e1 + tap * self.control.dt_s / t.layer_mass_kg)
        return max(1, math.ceil(need * (1.0 - 1e-12)))

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


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that names a key twice (PyYAML keeps the last one
    silently: ``sigma: 6.41`` then ``sigma: 7`` in one valve section gave 7 without a word)."""


def _unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> Any:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node, deep=True)
        try:
            dup = key in seen
            seen.add(key)
        except TypeError:  # an unhashable key: the safe loader's own error follows
            continue
        if dup:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def load_yaml(path: str | Path | Traversable) -> dict[str, Any]:
    """Read a config YAML file; errors name the file and the problem in one line (a key given twice
    in one mapping is an error). A name of a packaged scenario (``"cold_supply"``, or
    ``configs/scenarios/cold_supply.yaml`` where no such file exists) reads the packaged file
    (:func:`valve_env.data.packaged_scenario`)."""
    p: Path | Traversable = path if not isinstance(path, (str, PurePath)) else Path(path)
    if isinstance(path, (str, PurePath)):
        p = packaged_scenario(path) or p
    if p.is_dir():
        raise ConfigError(f"config file {str(p)!r} is a directory, not a YAML file")
    if not p.is_file():
        if isinstance(path, (str, PurePath)) and len(PurePath(path).parts) == 1 and not PurePath(path).suffix:
            raise ConfigError(f"config {str(path)!r} is neither a file nor a packaged scenario; packaged: "
                              f"{', '.join(scenario_files())}")
        raise ConfigError(f"config file {str(p)!r} does not exist")
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"config file {str(p)!r} is not UTF-8 text (byte {exc.start}): is it a YAML file?") from exc
    except OSError as exc:
        raise ConfigError(f"config file {str(p)!r} cannot be read: {exc.strerror or exc}") from exc
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader) or {}  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {str(p)!r} is not valid YAML: {' '.join(str(exc).split())}") from exc
    if not isinstance(data, dict):
        raise ConfigError(
            f"config file {str(p)!r} must hold a mapping of sections {sorted(SECTIONS)}, got {type(data).__name__}"
        )
    unknown = sorted(str(k) for k in data if k not in SECTIONS)
    if unknown:
        raise ConfigError(f"config file {str(p)!r}: unknown section(s) {unknown}; known: {sorted(SECTIONS)}")
    return data


def _section(name: str, value: Any) -> Mapping[str, Any]:
    """A config section's mapping of field names to values, or a one-line error naming the section."""
    if value is None:
        raise ConfigError(
            f"config section {name!r} is empty (a YAML '{name}:' with nothing under it): give it fields or remove it"
        )
    if not isinstance(value, Mapping):
        raise ConfigError(
            f"config section {name!r} must be a mapping of field names to values, got {type(value).__name__} {value!r}"
        )
    bad = [k for k in value if not isinstance(k, str)]
    if bad:
        raise ConfigError(f"config section {name!r}: field names must be text, got {bad[0]!r}")
    return value


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = {k: dict(v) if isinstance(v, Mapping) else v for k, v in base.items()}
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k].update(v)
        else:
            out[k] = v
    return out


class EffectOverrideWarning(UserWarning):
    """A config file or mapping names a valve effect that the configuration it is laid on already has,
    with other parameters: the file's parameters win (docs/tasks.md, "A valve file on a task")."""


#: the overrides already told: each once per process, not once per env built from the same file (an
#: evaluation builds one per episode, and gymnasium's make resets the warnings module's own registries)
_TOLD: set[str] = set()


def combine_effects(
    current: Effects, given: Any, where: str = "valve.effects", origins: dict[str, str] | None = None,
    source: str | None = None, warn: bool = False,
) -> Effects:
    """The named effects ``current`` with the ``effects:`` mapping ``given`` laid on them, by name:
    ``current``'s effects stay, ``given``'s are added, an effect both name takes ``given``'s parameters,
    and an effect given as ``None`` (YAML ``null``) is removed (a ConfigError if ``current`` has none
    of that name: the ``stiction:`` with nothing under it is a mistake there). ``given`` ``None`` or
    ``{}`` changes nothing. With ``warn``, an override with other parameters raises an
    :class:`EffectOverrideWarning` naming the effect, both parameter sets, ``source`` (where ``given``
    comes from) and the overridden effect's origin (``origins``: effect name -> where it came from,
    updated in place). docs/tasks.md, "A valve file on a task"."""
    if given is None:
        return current
    if isinstance(given, Effects):
        given = given.as_dict()
    if not isinstance(given, Mapping):
        return parse_effects(given, where)  # the one-line error of a malformed mapping
    unknown = sorted(str(k) for k in given if k not in EFFECTS)
    if unknown:
        raise ConfigError(f"{where}: unknown effect(s) {unknown}; known effects: {', '.join(EFFECTS)}")
    have = current.as_dict()
    origins = origins if origins is not None else {}
    for name in [n for n, v in given.items() if v is None]:
        if name not in have:
            first = EFFECTS[name].parameters[0]
            raise ConfigError(f"{where}.{name} is empty (None); give its parameters, e.g. {{{first.name}: "
                              f"{first.default}}} (null removes an effect, and there is no {name} to remove)")
        del have[name]
        origins.pop(name, None)
    added = parse_effects({n: v for n, v in given.items() if v is not None}, where).as_dict()
    for name, pars in added.items():
        if warn and name in have and have[name] != pars:
            msg = (f"{source or where}: valve effect {name} {pars} overrides {name} {have[name]} of "
                   f"{origins.get(name, 'the configuration')} (the file's parameters win; docs/tasks.md, "
                   "'A valve file on a task')")
            if msg not in _TOLD:
                _TOLD.add(msg)
                warnings.warn(msg, EffectOverrideWarning, stacklevel=5)
        have[name] = pars
        origins[name] = source or where
    return parse_effects(have, where)


def make_config(config: str | Path | EnvConfig | Mapping[str, Any] | None = None, **overrides: Any) -> EnvConfig:
    """Build an EnvConfig from a YAML path, a mapping or an EnvConfig, then
    apply keyword overrides: a section name with a mapping or a dataclass
    (``valve={"sigma": 5.0}``), or a single field of ScenarioParams or
    ControlParams by its name (``tapping_profile="L"``). A bad value read from a
    file raises a ConfigError that names the file. The valve's named effects
    (``valve: {effects: ...}``) combine by name (:func:`combine_effects`)."""
    return layer_config(config, overrides)


def layer_config(
    config: str | Path | EnvConfig | Mapping[str, Any] | None, overrides: Mapping[str, Any],
    owner: str = "the configuration", source: str | None = None,
) -> EnvConfig:
    """:func:`make_config` with the effects' origins named: ``owner`` names where an EnvConfig
    ``config``'s effects come from (e.g. "task ThermoValveStickyValve-v0"); with ``source`` the
    ``overrides`` are a config file or mapping laid on it (``source`` names it), and an effect they
    override with other parameters warns (:class:`EffectOverrideWarning`)."""
    try:
        return _make_config(config, overrides, owner, source)
    except ConfigError as exc:
        if isinstance(config, (str, Path)) and str(config) not in str(exc):
            raise ConfigError(f"config file {str(config)!r}: {exc}") from None
        raise


def _make_config(
    config: str | Path | EnvConfig | Mapping[str, Any] | None, overrides: Mapping[str, Any],
    owner: str = "the configuration", source: str | None = None,
) -> EnvConfig:
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
    # the valve's named effects, layer by layer (the start's, the file's, then the keywords'), combined by name
    effect_layers: list[tuple[Any, str, bool]] = []

    def take_effects(section: Mapping[str, Any], label: str, warn: bool) -> Mapping[str, Any]:
        if "effects" not in section:
            return section
        rest = dict(section)
        effect_layers.append((rest.pop("effects"), label, warn))
        return rest

    sections: dict[str, Any] = {}
    for k, v in base.items():
        if k not in SECTIONS:
            raise ConfigError(f"unknown config section {k!r}; known: {sorted(SECTIONS)}")
        sections[k] = _section(k, v)
    if "valve" in sections:
        sections["valve"] = take_effects(sections["valve"], str(config) if isinstance(config, (str, Path))
                                         else "the config", False)
    scen_fields = {f.name for f in fields(ScenarioParams)}
    ctrl_fields = {f.name for f in fields(ControlParams)}
    for k, v in overrides.items():
        if k in SECTIONS:
            if dataclasses.is_dataclass(v) and not isinstance(v, type):
                v = dataclasses.asdict(v)
            if not isinstance(v, Mapping):
                raise ConfigError(
                    f"{k}= must be a mapping of field names or a {SECTIONS[k].__name__}, got "
                    + ("None" if v is None else f"{type(v).__name__} {v!r}")
                )
            v = _section(k, v)
            if k == "valve":
                v = take_effects(v, source or "the valve= keyword", source is not None)
            sections = _merge(sections, {k: v})
        elif k in scen_fields:
            sections = _merge(sections, {"scenario": {k: v}})
        elif k in ctrl_fields:
            sections = _merge(sections, {"control": {k: v}})
        else:
            raise ConfigError(
                f"unknown environment option {k!r}; use a section ({sorted(SECTIONS)}) or a scenario/control field"
            )
    # the valve's named effects (docs/reference.md, "The valve file"), checked against the registry
    effects = start.effects
    origins = dict.fromkeys(effects.names, owner)
    for given, label, warn in effect_layers:
        effects = combine_effects(effects, given, "valve.effects", origins, label, warn)
    built: dict[str, Any] = {"effects": effects}
    for name, cls in SECTIONS.items():
        current = getattr(start, name)
        if name in sections:
            merged = {**current.to_dict(), **dict(sections[name])}
            built[name] = cls.from_dict(merged)
        else:
            built[name] = current
    return EnvConfig(**built)


def ranges_table() -> str:
    """The accepted values of every config field as a Markdown table (docs/configuration.md
    holds its output; tests/envs/test_config_validation.py keeps the two equal)."""
    lines = ["| field | unit | range | default | why |", "|---|---|---|---|---|"]
    for section, cls in SECTIONS.items():
        for f in fields(cls):
            spec = f.metadata["spec"]
            unit = spec.unit if spec.kind in ("float", "int") else "-"
            kind = " (integer)" if spec.kind == "int" else ""
            lines.append(f"| {section}.{f.name} | {unit} | {spec.describe()}{kind} | {f.default} | {spec.why} |")
    return "\n".join(lines) + "\n"
