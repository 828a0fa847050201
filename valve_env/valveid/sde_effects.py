"""The named effects as continuous-discrete SDE models for the estimator (its extension hooks).

:func:`effect_model` builds a subclass of
:class:`valve_env.valveid.valve_model.ValveModel` with any combination of
the effects of docs/reference.md, section 3, so that ``MLEstimator(effect_model(["sensor_lag"]))``
fits it with the estimator's extended Kalman filter and the likelihood-ratio
statistic against the base model is ``2 (fit_ext.loglik_ - fit_base.loglik_)``.
One set of numba hooks serves every combination: the positions of the effect
parameters and of the added states are passed to the hooks in the constants
vector (``-1`` where an effect is off).

| effect | added parameter | added state | hook |
|---|---|---|---|
| sensor_lag | ``tau_s`` (s) | ``T_g``: dT_g = (T_env - T_g) / tau dt | T_g = state, rate (T_env - T_g) / tau |
| medium_temperature | ``beta`` (-) | | T_env = T + beta (T_med - T); Dahl driver v + beta (v_med - v) |
| setpoint_drift | ``rate_MPa_per_h`` | | p_b,set(t) = p_bset + rate t / 3600 (t = time_s) |
| stiction | ``band_mm`` (mm) | ``x_s``: dx_s = (d - band tanh(d / band)) / tau_slip, d = x_d - x_s | opening = x_s |

The stiction state is the filter-friendly, smooth (differentiable) counterpart
of stick-slip: inside the band the stem hardly moves, outside it it follows
the demand within ``tau_slip`` (5 s; fit with ``n_sub`` >= 4 at 10 s sampling). It captures the dead band and the delay
of a sticking stem but not the saw-tooth of stick-slip itself; the diagnosis
uses the exact stick-slip with a decision-directed filter instead
(:func:`valve_env.valveid.oe.stick_loglik`). The temperatures and their
rates are the estimator's smoothed inputs (``tank_temperature(t, u)``,
``medium_temperature(t, u)``, ``u[U_V]``, ``u[U_V_MED]``).
"""

from __future__ import annotations

from typing import Any

import numba as nb
import numpy as np

from valve_env.effects import REGISTRY, check_effects
from valve_env.ident.sde import Parameter
from valve_env.physics.trajectory import sensed_temperature
from valve_env.valveid.valve_model import (
    N_BASE_CONSTANTS,
    N_BASE_PARAMS,
    N_BASE_STATES,
    P_P_BSET,
    U_T,
    U_V,
    U_V_MED,
    ValveModel,
    hook_opening,
    medium_temperature,
    tank_temperature,
)

# positions in the constants vector (after the base constants)
C_TAU, C_BETA, C_BAND, C_RATE, C_XTG, C_XSTEM, C_TSLIP = (N_BASE_CONSTANTS + i for i in range(7))
TAU_SLIP_S = 5.0


@nb.njit(cache=True)
def _par(p: np.ndarray, c: np.ndarray, where: int, default: float) -> float:
    i = int(c[where])
    return p[i] if i >= 0 else default


@nb.njit(cache=True)
def _env(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    return sensed_temperature(tank_temperature(t, u), medium_temperature(t, u), _par(p, c, C_BETA, 0.0))


@nb.njit(cache=True)
def fx_gas_temperature(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    """T_g: the bulb state with sensor_lag, else the sensed environment T_env."""
    i = int(c[C_XTG])
    return x[i] if i >= 0 else _env(t, x, u, p, c)


@nb.njit(cache=True)
def fx_gas_rate(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    """dT_g/dt, the Dahl driver."""
    i = int(c[C_XTG])
    if i >= 0:
        return (_env(t, x, u, p, c) - x[i]) / max(_par(p, c, C_TAU, 1.0), 1e-6)
    beta = _par(p, c, C_BETA, 0.0)
    return u[U_V] + beta * (u[U_V_MED] - u[U_V])


@nb.njit(cache=True)
def fx_set_pressure(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    """p_b,set(t) = p_bset + rate t / 3600."""
    return p[P_P_BSET] + _par(p, c, C_RATE, 0.0) * t / 3600.0


@nb.njit(cache=True)
def fx_opening(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray, T_g: float,
               p_set: float) -> float:
    """The stem state with stiction, else the force balance."""
    i = int(c[C_XSTEM])
    if i >= 0:
        return x[i]
    return hook_opening(t, x, u, p, c, T_g, p_set)


@nb.njit(cache=True)
def fx_extra_drift(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> np.ndarray:
    out = np.zeros(x.shape[0] - N_BASE_STATES)
    i = int(c[C_XTG])
    if i >= 0:
        out[i - N_BASE_STATES] = fx_gas_rate(t, x, u, p, c)  # the bulb state's drift is the Dahl driver
    j = int(c[C_XSTEM])
    if j >= 0:
        Tg = fx_gas_temperature(t, x, u, p, c)
        xd = hook_opening(t, x, u, p, c, Tg, fx_set_pressure(t, x, u, p, c))
        band = max(_par(p, c, C_BAND, 0.0), 1e-9)
        d = xd - x[j]
        out[j - N_BASE_STATES] = (d - band * np.tanh(d / band)) / c[C_TSLIP]
    return out


#: each effect's parameter for the estimator, from the registry (valve_env.effects: start, bounds, transform)
_PARAMS: dict[str, Parameter] = {
    name: Parameter(p.name, p.sde_init, p.sde_lower, p.sde_upper, p.transform,  # type: ignore[arg-type]
                    unit=p.unit, doc=p.doc)
    for name, eff in REGISTRY.items() for p in eff.parameters
}
#: the SDE hooks above, by effect: the extra state each adds (None: none) and its constants slot
HOOKS: dict[str, tuple[str | None, int]] = {
    "sensor_lag": ("T_g", C_TAU),
    "medium_temperature": (None, C_BETA),
    "stiction": ("x_s", C_BAND),
    "setpoint_drift": (None, C_RATE),
}


def effect_model(effects: list[str] | tuple[str, ...], **options: Any) -> ValveModel:
    """The base valve model extended by ``effects`` (names of docs/reference.md, section 3), for the estimator.

    ``options`` go to :class:`ValveModel` (``valve``, ``fixed``, ``init``, ``clip_width_mm``)."""
    names = check_effects(list(effects))
    order = [e for e in REGISTRY if e in names]
    extra_params = tuple(_PARAMS[e] for e in order)
    extra_states = [state for state, _ in (HOOKS[e] for e in order) if state is not None]
    n_base_params = N_BASE_PARAMS
    idx = {q.name: n_base_params + k for k, q in enumerate(extra_params)}
    consts = np.array([
        idx.get("tau_s", -1), idx.get("beta", -1), idx.get("band_mm", -1), idx.get("rate_MPa_per_h", -1),
        N_BASE_STATES + extra_states.index("T_g") if "T_g" in extra_states else -1,
        N_BASE_STATES + extra_states.index("x_s") if "x_s" in extra_states else -1,
        TAU_SLIP_S,
    ], dtype=float)

    def extra_constants(self: ValveModel) -> np.ndarray:
        return consts

    def extra_initial_state(self: ValveModel, p: np.ndarray, y0: np.ndarray,
                            u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m, v = [], []
        if "T_g" in extra_states:
            m.append(float(u0[U_T]))
            v.append(0.05**2)
        if "x_s" in extra_states:
            m.append(float(y0[0]) if np.isfinite(y0[0]) else 0.5)
            v.append(0.01**2)
        return np.array(m), np.array(v)

    cls = type(
        "ValveModel_" + "_".join(order),
        (ValveModel,),
        {
            "name": "valve+" + "+".join(order) if order else "valve",
            "extra_states": tuple(extra_states),
            "extra_parameters": extra_params,
            "gas_temperature_hook": fx_gas_temperature,
            "gas_rate_hook": fx_gas_rate,
            "set_pressure_hook": fx_set_pressure,
            "opening_hook": fx_opening,
            "extra_drift_hook": fx_extra_drift,
            "extra_constants": extra_constants,
            "extra_initial_state": extra_initial_state,
        },
    )
    return cls(**options)


__all__ = ["effect_model"]
