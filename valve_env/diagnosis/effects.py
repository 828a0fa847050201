"""The effect library: what the calibrated valve simulation can get wrong (SPEC section 3).

Each effect is a physically meaningful extension of the base valve model of
SPEC section 1 with its own parameters. The base model is recovered when the
effect's parameters take their *null* value; for sensor_lag, medium_temperature
and stiction the null value lies on the edge of the parameter space (tau = 0,
beta = 0, band = 0), which the likelihood-ratio test accounts for (a 50:50
mixture of chi-square(0) and chi-square(1), Self and Liang 1987).

| name | physics | parameter | null |
|---|---|---|---|
| sensor_lag | bulb heat capacity behind a film: tau dT_g/dt = T_env - T_g | tau_s, s | 0 (T_g = T_env) |
| medium_temperature | the water through the valve heats the bulb: T_env = T_tank + beta (T_med - T_tank) | beta | 0 |
| stiction | static friction: the resting stem sticks until the demand is band_mm away, then slips | band_mm | 0 |
| setpoint_drift | charge ageing: p_b,set(t) = p_b,set + rate t (t in h from the start) | rate_MPa_per_h | 0 (2-sided) |

Stiction's likelihood is that of a stick-slip filter
(:func:`valve_env.diagnosis.engine.stick_loglik`); it is rough in ``band_mm``,
so the band itself is measured from the jumps of the opening
(:mod:`valve_env.diagnosis.stiction`) and the likelihood serves the test. The same
effects are available as continuous-discrete SDE models for the estimator in
:mod:`valve_env.diagnosis.sde_effects`.

More effects may be added to :data:`EFFECTS`; each needs a term in
:func:`valve_env.diagnosis.engine.simulate_valve`.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EffectParameter:
    """One parameter of an effect.

    ``lower``/``upper`` bound it; ``scale`` is its typical size (the optimiser
    works on value / scale); ``null`` switches the effect off; ``starts`` are
    the starting values tried; ``log_grid`` asks for a profile over a log grid
    (for a likelihood that is rough in this parameter)."""

    name: str
    unit: str
    lower: float
    upper: float
    scale: float
    null: float
    starts: tuple[float, ...]
    doc: str
    log_grid: bool = False


@dataclass(frozen=True)
class Effect:
    """A named effect (SPEC section 3)."""

    name: str
    title: str
    physics: str
    signature: str
    parameters: tuple[EffectParameter, ...]
    boundary: bool  # the null value is on the edge of the parameter space
    #: the effect improves predictions mainly through their variance (when the opening will not move),
    #: not their mean; its held-out one-step RMS need not fall (see diagnose.py)
    variance_gain: bool = False

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)


EFFECTS: dict[str, Effect] = {
    "sensor_lag": Effect(
        name="sensor_lag",
        title="sensor (bulb) lag",
        physics="The bulb and its charge are a heat capacity behind a heat-transfer film, so the gas temperature "
        "follows the water around the bulb with a first-order lag: tau dT_g/dt = T_tank - T_g. Grows with "
        "fouling of the bulb, a dry pocket or still water.",
        signature="the misfit grows with the speed of the temperature ramps and changes sign with their direction: "
        "the measured valve reacts later than the simulated one (residual correlated with dT/dt)",
        parameters=(
            EffectParameter("tau_s", "s", 0.0, 1800.0, 100.0, 0.0, (30.0, 150.0),
                            "time constant of the bulb, s"),
        ),
        boundary=True,
    ),
    "medium_temperature": Effect(
        name="medium_temperature",
        title="heating of the sensor by the medium",
        physics="The water flowing through the valve body heats the bulb, capillary or the valve's thermostat "
        "head by conduction: the sensed temperature is a mix T_env = T_tank + beta (T_med - T_tank). Paper "
        "section 4 assumes beta = 0.",
        signature="the misfit follows the difference T_med - T_tank, independent of the tank temperature's motion",
        parameters=(
            EffectParameter("beta", "-", 0.0, 0.95, 0.1, 0.0, (0.05, 0.25),
                            "weight of the medium temperature in the sensed temperature"),
        ),
        boundary=True,
    ),
    "stiction": Effect(
        name="stiction",
        title="stiction (static friction) of the stem",
        physics="Static friction in the stem seal exceeds the sliding friction: a resting stem sticks until the "
        "force balance demands a motion larger than the band, then slips to the demanded opening. Typical of a "
        "dry or worn gland; the opening moves in steps.",
        signature="the measured opening moves in steps and stays flat while the simulated one moves smoothly: a "
        "saw-tooth residual during slow ramps",
        parameters=(
            EffectParameter("band_mm", "mm", 0.0, 0.5, 0.01, 0.0, (0.01,), "stick band of the stem, mm",
                            log_grid=True),
        ),
        boundary=True,
        variance_gain=True,
    ),
    "setpoint_drift": Effect(
        name="setpoint_drift",
        title="drift of the set point",
        physics="The charge of the bulb ages (a slow leak or non-condensable gas), so the bellows pressure at the "
        "set point drifts: p_b,set(t) = p_b,set + rate t.",
        signature="the misfit is an offset that grows steadily over the record, the same for both directions of "
        "motion",
        parameters=(
            EffectParameter("rate_MPa_per_h", "MPa/h", -0.01, 0.01, 1.0e-5, 0.0, (0.0,),
                            "drift rate of the bellows set pressure, MPa/h"),
        ),
        boundary=False,
    ),
}

#: Parameter name -> index into the engine's effect vector (tau_s, beta, band_mm, rate_MPa_per_h).
ENGINE_INDEX: dict[str, int] = {"tau_s": 0, "beta": 1, "band_mm": 2, "rate_MPa_per_h": 3}


def effect_names() -> list[str]:
    return list(EFFECTS)


def check_effects(names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Validate candidate effect names (ValueError naming an unknown one)."""
    out = []
    for name in names:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        if name not in out:
            out.append(name)
    return tuple(out)


__all__ = ["Effect", "EffectParameter", "EFFECTS", "ENGINE_INDEX", "effect_names", "check_effects"]
