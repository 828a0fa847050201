"""The registry of the valve's named effects (docs/reference.md, "Named effects").

Each effect of the base valve model is declared here once: its name, its parameters with
units, bounds and defaults, its physics and the source of its defaults. Everything that
knows an effect reads it from :data:`REGISTRY`:

* the data generator (:mod:`valve_env.experiment`: validation of ``effects=``, the random
  sizes of the diagnosis studies),
* the valve's identification (:mod:`valve_env.valveid`: the output-error engine's effect vector
  :data:`ENGINE_INDEX`, the estimator's SDE models in :mod:`valve_env.valveid.sde_effects`, the
  diagnosis' candidates, checked by :func:`check_effects`). The likelihood-ratio test of an effect
  whose null value lies on the edge of its parameter space (``boundary``: tau = 0, beta = 0,
  band = 0) takes the 50:50 mixture of chi-square(0) and chi-square(1) (Self and Liang 1987);
  the diagnosis fits an effect's ``parameters``, not its ``extra`` ones (stiction's slip jump
  is held at the band, J = S),
* the environments (the ``valve: effects:`` mapping of a config, :func:`parse_effects`,
  packed for the simulator kernel by :mod:`valve_env.simulator`),
* the valve file (:mod:`valve_env.valvefile`).

The trajectory physics of each effect is a pure function in :mod:`valve_env.physics.trajectory`
(and :mod:`valve_env.physics.stickslip`); a new effect is one :class:`Effect` here plus its
physics function (``tests/test_effects.py`` walks the registry and checks that every consumer
supports every effect).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from valve_env.params import ConfigError, Spec


@dataclass(frozen=True)
class EffectParameter:
    """One parameter of an effect.

    ``lower``/``upper``: the physically valid range (what a config, a valve file and the
    generator accept); ``default``: the value when a config names the effect without it
    (``None``: see the effect's docstring, e.g. stiction's ``jump_mm`` = its ``band_mm``);
    ``null``: the value that switches the effect off.

    For the diagnosis: ``fit_lower``/``fit_upper`` the search range, ``scale`` the typical size
    (the optimiser works on value / scale), ``starts`` the starting values, ``log_grid`` a
    profile over a log grid (for a likelihood that is rough in this parameter). For the
    estimator's SDE models: ``sde_init``, ``sde_lower``, ``sde_upper``, ``transform``. For the
    randomised diagnosis studies: ``draw`` = (kind, lo, hi) with kind ``"log"`` (log-uniform),
    ``"uniform"`` or ``"signed"`` (a random sign times a uniform size)."""

    name: str
    unit: str
    lower: float
    upper: float
    default: float | None
    doc: str
    null: float = 0.0
    fit_lower: float = 0.0
    fit_upper: float = 1.0
    scale: float = 1.0
    starts: tuple[float, ...] = ()
    log_grid: bool = False
    sde_init: float = 0.0
    sde_lower: float = 0.0
    sde_upper: float = 1.0
    transform: str = "none"
    draw: tuple[str, float, float] | None = None

    @property
    def spec(self) -> Spec:
        """The values a config may give: a finite number in ``[lower, upper]`` (the one checker of a
        configured number, :class:`valve_env.params.Spec`)."""
        return Spec(lo=self.lower, hi=self.upper, unit=self.unit)


@dataclass(frozen=True)
class Effect:
    """A named effect (docs/reference.md, "Named effects").

    ``parameters`` are the effect's identified parameters (the diagnosis fits them);
    ``extra`` optional parameters with a default that the diagnosis holds at it (e.g.
    stiction's slip jump)."""

    name: str
    title: str
    physics: str
    source: str
    signature: str
    parameters: tuple[EffectParameter, ...]
    boundary: bool  # the null value is on the edge of the parameter space
    #: the effect improves predictions mainly through their variance (when the opening will not move),
    #: not their mean; its held-out one-step RMS need not fall (see diagnosis/diagnose.py)
    variance_gain: bool = False
    extra: tuple[EffectParameter, ...] = ()

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def all_parameters(self) -> tuple[EffectParameter, ...]:
        return self.parameters + self.extra

    def parameter(self, name: str) -> EffectParameter:
        for p in self.all_parameters:
            if p.name == name:
                return p
        raise KeyError(name)


REGISTRY: dict[str, Effect] = {
    "sensor_lag": Effect(
        name="sensor_lag",
        title="sensor (bulb) lag",
        physics="The bulb and its charge are a heat capacity behind a heat-transfer film, so the gas temperature "
        "follows the water around the bulb with a first-order lag: tau dT_g/dt = T_env - T_g (exact for an input "
        "linear over a step: physics.trajectory.bulb_lag). Grows with fouling of the bulb, a dry pocket or still "
        "water. In the environments the bulb already lags the pocket (bulb.tau_s, 40 s); the effect sets that "
        "time constant to tau_s.",
        source="EN 215 / EN 14597 test practice for thermostatic heads: time constants of 20 s to several minutes "
        "(liquid- and vapour-filled bulbs in water); the default 90 s is the example in docs/reference.md s. 8",
        signature="the misfit grows with the speed of the temperature ramps and changes sign with their direction: "
        "the measured valve reacts later than the simulated one (residual correlated with dT/dt)",
        parameters=(
            EffectParameter("tau_s", "s", 0.0, 3600.0, 90.0, "time constant of the bulb, s",
                            fit_lower=0.0, fit_upper=1800.0, scale=100.0, starts=(30.0, 150.0),
                            sde_init=60.0, sde_lower=0.5, sde_upper=3600.0, transform="log",
                            draw=("log", 20.0, 180.0)),
        ),
        boundary=True,
    ),
    "medium_temperature": Effect(
        name="medium_temperature",
        title="heating of the sensor by the medium",
        physics="The water flowing through the valve body heats the bulb, capillary or the valve's thermostat "
        "head by conduction: the sensed temperature is a mix T_env = T_tank + beta (T_med - T_tank) "
        "(physics.trajectory.sensed_temperature). Paper section 4 assumes beta = 0. In the environments the medium "
        "is the primary supply water through the valve.",
        source="the seed paper's section 4 (the effect it neglects); default 0.12, the example in "
        "docs/reference.md s. 8",
        signature="the misfit follows the difference T_med - T_tank, independent of the tank temperature's motion",
        parameters=(
            EffectParameter("beta", "-", 0.0, 1.0, 0.12, "weight of the medium temperature in the sensed temperature",
                            fit_lower=0.0, fit_upper=0.95, scale=0.1, starts=(0.05, 0.25),
                            sde_init=0.05, sde_lower=0.0, sde_upper=0.95, transform="logit",
                            draw=("uniform", 0.03, 0.25)),
        ),
        boundary=True,
    ),
    "stiction": Effect(
        name="stiction",
        title="stiction (static friction) of the stem",
        physics="Static friction in the stem seal exceeds the sliding friction: a resting stem sticks until the "
        "demanded opening (the force balance's) has moved band_mm away, then slips and follows the demand until the "
        "demand stops or reverses, where it sticks again. The two-parameter (S, J) model of Choudhury et al. (2005) "
        "in stem millimetres, S = band_mm (deadband plus stickband), J = jump_mm (the slip jump; default J = S: the "
        "stem slips onto the demand without offset), with Kano et al.'s (2004) direction memory "
        "(physics.stickslip.stick_slip_step). A stuck stem pushed on in its last direction breaks away after J, "
        "pushed back after S.",
        source="Choudhury, Thornhill & Shah (2005), Control Eng. Practice 13:641-658; Kano et al. (2004), IFAC "
        "DYCOPS. Stiction of 0.5-5 % of travel is what the control-valve literature reports for industrial valves "
        "(Choudhury et al. 2005; Jelali & Huang 2010, Detection and Diagnosis of Stiction in Control Loops, "
        "Springer): on a 2 mm stroke 0.01-0.1 mm; default 0.04 mm = 2 % (also the example in docs/reference.md s. 8)",
        signature="the measured opening stays flat after each reversal of the demand and then jumps: a dead zone "
        "of width band_mm at every turn of the hysteresis loop",
        parameters=(
            EffectParameter("band_mm", "mm", 0.0, 1.0, 0.04, "stick band S of the stem (deadband plus stickband), mm",
                            fit_lower=0.0, fit_upper=0.5, scale=0.01, starts=(0.01,), log_grid=True,
                            sde_init=0.01, sde_lower=1e-4, sde_upper=0.5, transform="log",
                            draw=("uniform", 0.01, 0.04)),
        ),
        extra=(
            EffectParameter("jump_mm", "mm", 0.0, 1.0, None,
                            "slip jump J, mm (default: band_mm, no offset; J < S undershoots, J > S overshoots, "
                            "J = 0 is a pure deadband)"),
        ),
        boundary=True,
        variance_gain=True,
    ),
    "setpoint_drift": Effect(
        name="setpoint_drift",
        title="drift of the set point",
        physics="The charge of the bulb ages (a slow leak or non-condensable gas), so the bellows pressure at the "
        "set point drifts: p_b,set(t) = p_b,set + rate t, t in h from the start of the record or episode "
        "(physics.trajectory.drifted_set_pressure).",
        source="charge ageing of vapour-filled thermostats; default 1e-4 MPa/h, the example in docs/reference.md s. 8 "
        "(about 0.03 K/h of set point at 58 degC)",
        signature="the misfit is an offset that grows steadily over the record, the same for both directions of "
        "motion",
        parameters=(
            EffectParameter("rate_MPa_per_h", "MPa/h", -0.01, 0.01, 1.0e-4, "drift rate of the bellows set pressure, "
                            "MPa/h", fit_lower=-0.01, fit_upper=0.01, scale=1.0e-5, starts=(0.0,),
                            sde_init=0.0, sde_lower=-0.01, sde_upper=0.01, transform="none",
                            draw=("signed", 1.5e-5, 6e-5)),
        ),
        boundary=False,
    ),
}

#: Parameter name -> index into the effect vector of the diagnosis engine and of the simulator
#: (registry order: each effect's parameters, then its extra ones)
ENGINE_INDEX: dict[str, int] = {
    p.name: i for i, p in enumerate(q for e in REGISTRY.values() for q in e.all_parameters)
}
N_EFFECT_PARAMS = len(ENGINE_INDEX)


def effect_names() -> list[str]:
    return list(REGISTRY)


def check_effects(names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Validate effect names (ValueError naming an unknown one); duplicates dropped, order kept."""
    out = []
    for name in names:
        if name not in REGISTRY:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(REGISTRY)}")
        if name not in out:
            out.append(name)
    return tuple(out)


def check_parameters(name: str, pars: Any, where: str = "effects", fill_defaults: bool = True) -> dict[str, float]:
    """The checked parameters of effect ``name`` from a mapping (ConfigError naming an unknown effect or
    parameter, a missing mapping, a value that is None, NaN, a bool, not a number or out of range).
    With ``fill_defaults`` the parameters not given take their defaults (stiction's ``jump_mm`` is left
    out: it then equals ``band_mm``)."""
    if name not in REGISTRY:
        raise ConfigError(f"{where}: unknown effect {name!r}; known effects: {', '.join(REGISTRY)}")
    eff = REGISTRY[name]
    if pars is None:
        pars = {}
    if not isinstance(pars, Mapping):
        raise ConfigError(f"{where}.{name} must be a mapping of parameters "
                          f"({', '.join(p.name for p in eff.all_parameters)}), got {pars!r}")
    known = {p.name for p in eff.all_parameters}
    unknown = sorted(str(k) for k in pars if k not in known)
    if unknown:
        raise ConfigError(f"{where}.{name}: unknown parameter(s) {unknown}; expected {sorted(known)}")
    out: dict[str, float] = {}
    for p in eff.all_parameters:
        if p.name not in pars:
            if not fill_defaults:
                if p.default is not None:
                    raise ConfigError(f"{where}.{name}: missing parameter {p.name!r}")
                continue
            if p.default is None:
                continue
            out[p.name] = float(p.default)
            continue
        out[p.name] = float(p.spec.check(f"{where}.{name}.{p.name}", pars[p.name]))
    return out


@dataclass(frozen=True)
class Effects:
    """A checked set of effects with their parameters (immutable, hashable, picklable).

    Built by :func:`parse_effects`; ``items`` holds ``(name, ((param, value), ...))`` in registry
    order. ``Effects()`` is the base valve."""

    items: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.items)

    def __contains__(self, name: object) -> bool:
        return any(n == name for n, _ in self.items)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.items)

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {n: dict(p) for n, p in self.items}

    def get(self, name: str, param: str, default: float = 0.0) -> float:
        for n, pars in self.items:
            if n == name:
                for k, v in pars:
                    if k == param:
                        return v
        return default

    def vector(self) -> np.ndarray:
        """The effect vector (:data:`ENGINE_INDEX` order) with every absent effect at its null value;
        stiction's jump_mm is its band_mm unless given."""
        e = np.array([p.null for eff in REGISTRY.values() for p in eff.all_parameters], dtype=float)
        for _name, pars in self.items:
            for k, v in pars:
                e[ENGINE_INDEX[k]] = v
        if "stiction" in self and not any(k == "jump_mm" for k, _ in dict(self.items)["stiction"]):
            e[ENGINE_INDEX["jump_mm"]] = e[ENGINE_INDEX["band_mm"]]
        return e


def parse_effects(data: Any, where: str = "valve.effects") -> Effects:
    """Check an ``effects:`` mapping (name -> parameters) against the registry; ConfigError naming the
    problem. ``None`` or an :class:`Effects` pass through."""
    if isinstance(data, Effects):
        return data
    if data is None:
        return Effects()
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where} must be a mapping of effect names ({', '.join(REGISTRY)}) to parameters, "
                          f"got {data!r}")
    unknown = sorted(str(k) for k in data if k not in REGISTRY)
    if unknown:
        raise ConfigError(f"{where}: unknown effect(s) {unknown}; known effects: {', '.join(REGISTRY)}")
    items = []
    for name in REGISTRY:
        if name in data:
            if data[name] is None:
                raise ConfigError(f"{where}.{name} is empty (None); give its parameters, e.g. "
                                  f"{{{REGISTRY[name].parameters[0].name}: {REGISTRY[name].parameters[0].default}}}")
            pars = check_parameters(name, data[name], where)
            items.append((name, tuple(pars.items())))
    return Effects(tuple(items))


def draw(name: str, rng: np.random.Generator) -> dict[str, float]:
    """A random size of effect ``name`` as the diagnosis studies draw it (the ``draw`` of its parameters)."""
    out: dict[str, float] = {}
    for p in REGISTRY[name].parameters:
        if p.draw is None:
            continue
        kind, lo, hi = p.draw
        if kind == "log":
            out[p.name] = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        elif kind == "uniform":
            out[p.name] = float(rng.uniform(lo, hi))
        elif kind == "signed":
            out[p.name] = float(rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi))
        else:  # pragma: no cover - a declaration error
            raise ValueError(f"unknown draw kind {kind!r}")
    return out


__all__ = ["Effect", "EffectParameter", "Effects", "REGISTRY", "ENGINE_INDEX", "N_EFFECT_PARAMS", "check_effects",
           "effect_names",
           "check_parameters", "parse_effects", "draw"]
