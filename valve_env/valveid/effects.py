"""The effect library of the diagnosis: what the calibrated valve simulation can get wrong.

The effects, their parameters, bounds and physics are declared once, in the registry
:mod:`valve_env.effects` (docs/reference.md, "Named effects"); this module is the diagnosis's
view of it. Each effect is a physically meaningful extension of the base valve model with its
own parameters. The base model is recovered when the effect's parameters take their *null*
value; for sensor_lag, medium_temperature and stiction the null value lies on the edge of the
parameter space (tau = 0, beta = 0, band = 0), which the likelihood-ratio test accounts for (a
50:50 mixture of chi-square(0) and chi-square(1), Self and Liang 1987).

The diagnosis fits each effect's ``parameters`` (not its ``extra`` ones: stiction's slip jump is
held at the band, J = S). Stiction's likelihood is that of a stick-slip filter
(:func:`valve_env.valveid.oe.stick_loglik`); it is rough in ``band_mm``, so the band
itself is measured from the jumps of the opening (:mod:`valve_env.valveid.stiction`) and the
likelihood serves the test. The same effects are available as continuous-discrete SDE models
for the estimator in :mod:`valve_env.valveid.sde_effects`.

A new effect is a declaration in the registry plus its term in
:func:`valve_env.valveid.oe.simulate_valve` (through :mod:`valve_env.physics.trajectory`).
"""

from __future__ import annotations

from valve_env.effects import ENGINE_INDEX, N_EFFECT_PARAMS, REGISTRY, Effect, EffectParameter, effect_names

#: the registry, as the diagnosis names it
EFFECTS: dict[str, Effect] = REGISTRY


def check_effects(names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Validate candidate effect names (ValueError naming an unknown one)."""
    out = []
    for name in names:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        if name not in out:
            out.append(name)
    return tuple(out)


__all__ = ["Effect", "EffectParameter", "EFFECTS", "ENGINE_INDEX", "N_EFFECT_PARAMS", "effect_names",
           "check_effects"]
