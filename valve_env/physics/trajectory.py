"""The valve's trajectory physics with its named effects: one definition for every consumer.

Pure ``register_jitable`` functions (plain Python/NumPy when called from Python, compiled inline
by numba) for one step of the valve's trajectory: the sensed temperature (medium-temperature
mixing), the bulb lag, the Dahl friction (:func:`valve_env.physics.valve.dahl_update`), the
drifted set pressure, the force balance's opening and the stick-slip of the stem
(:func:`valve_env.physics.stickslip.stick_slip_step`). The simulator kernel (single and
batched environments, :mod:`valve_env.simulator`), the data generator
(:mod:`valve_env.experiment`) and the diagnosis's simulation
(:mod:`valve_env.valveid.oe`) call these; none keeps a copy. The effects and their
parameters are declared in :mod:`valve_env.effects` (docs/reference.md, "Named effects").

Units: degC, s, mm, N, MPa; differential pressure in mbar, static pressure in bar.
"""

from __future__ import annotations

import math

from numba.extending import register_jitable

from valve_env.params import I_F_HMAX, I_STROKE
from valve_env.physics.stickslip import initial_state as stick_initial_state
from valve_env.physics.stickslip import stick_slip_step
from valve_env.physics.valve import dahl_update, demanded_opening

#: number of variables of :func:`valve_step`'s state (T_g, F_h, x, then the stick-slip state
#: u_prev, du_prev, u_s, stuck, d of :mod:`valve_env.physics.stickslip`)
N_VALVE_STATE = 8


@register_jitable
def sensed_temperature(T_tank_C, T_med_C, beta):
    """medium_temperature: the bulb senses T_env = T_tank + beta (T_med - T_tank), degC (beta = 0: T_tank)."""
    return T_tank_C + beta * (T_med_C - T_tank_C)


@register_jitable
def bulb_coefficients(h_s, tau_s):
    """``(a, b)`` of :func:`bulb_lag` for a step of ``h_s`` and a bulb time constant ``tau_s``:
    ``a = exp(-h / tau)``, ``b = tau / h (1 - a)``; ``(0, 0)`` for ``tau_s <= 0`` (no lag)."""
    if tau_s <= 0.0:
        return 0.0, 0.0
    a = math.exp(-h_s / tau_s)
    return a, tau_s / h_s * (1.0 - a)


@register_jitable
def bulb_lag(T_g, u0, u1, a, b):
    """sensor_lag: tau dT_g/dt = u - T_g over one step, exact for an input moving linearly from ``u0``
    to ``u1`` (``a``, ``b`` from :func:`bulb_coefficients`)."""
    return u1 + (T_g - u0) * a - (u1 - u0) * b


@register_jitable
def bulb_lag_hold(T_g, u, a):
    """:func:`bulb_lag` for an input held at ``u`` over the step (zero-order hold: the environments'
    bulb sees the pocket's temperature of the start of each sub-step)."""
    return u + (T_g - u) * a


@register_jitable
def drifted_set_pressure(p_bset_MPa, rate_MPa_per_h, t_s):
    """setpoint_drift: p_b,set(t) = p_b,set + rate t, with t in s from the start (rate in MPa/h)."""
    return p_bset_MPa + rate_MPa_per_h * (t_s / 3600.0)


@register_jitable
def friction_step(F_h, dT_g, F_noise_dW, vp):
    """Dahl friction over an increment ``dT_g`` of the gas temperature (exact, valve.dahl_update),
    plus an optional process-noise increment (paper eq. 15's dw), kept within +-F_hmax."""
    F = dahl_update(F_h, dT_g, vp)
    if F_noise_dW != 0.0:
        Fm = vp[I_F_HMAX]
        F = min(max(F + F_noise_dW, -Fm), Fm)
    return F


@register_jitable
def valve_initial_state(T_env0, dp_mbar, ps_bar, p_set_MPa, S, J, stiction, vp):
    """A valve at rest: the bulb at its sensed temperature, no friction force, the stem where the force
    balance puts it (with stiction: at rest there after a motion upwards). Returns the
    :data:`N_VALVE_STATE` state ``(T_g, F_h, x, u_prev, du_prev, u_s, stuck, d)``."""
    stroke = vp[I_STROKE]
    xd = min(max(demanded_opening(T_env0, 0.0, dp_mbar, ps_bar, p_set_MPa, vp), 0.0), stroke)
    if stiction:
        y, u_prev, du_prev, u_s, stuck, d = stick_initial_state(xd, S, J, 0.0, stroke)
        return T_env0, 0.0, y, u_prev, du_prev, u_s, stuck, d
    return T_env0, 0.0, xd, xd, 0.0, xd, 1.0, 1.0


@register_jitable
def stem_step(x_demand, x, u_prev, du_prev, u_s, stuck, d, S, J, stroke):
    """stiction: the stem's (S, J) stick-slip (physics.stickslip) on the demanded opening ``x_demand``
    (mm, the force balance's, clipped to the stroke), where the end stops win: a demand at an end stop
    (the bellows pressing the cone onto its seat, or the stem against its upper stop) puts the stem
    there, at rest after a motion towards that stop, whatever the band, so a sticky valve still
    closes; leaving the stop then takes a breakaway of ``S``. Returns the new stick-slip state
    ``(x, u_prev, du_prev, u_s, stuck, d)``."""
    if x_demand <= 0.0 or x_demand >= stroke:
        u = min(max(x_demand, 0.0), stroke)
        return u, u, du_prev, u, 1.0, (-1.0 if u <= 0.0 else 1.0)
    return stick_slip_step(x_demand, x, u_prev, du_prev, u_s, stuck, d, S, J, 0.0, stroke)


@register_jitable
def valve_step(T_g, F_h, x, u_prev, du_prev, u_s, stuck, d, T_g_new, F_noise_dW, dp_mbar, ps_bar, p_set_MPa,
               S, J, stiction, vp):
    """One step of the valve from the new gas temperature ``T_g_new`` (the caller's bulb lag): Dahl
    friction, the force balance's opening clipped to the stroke (the demand), and with ``stiction`` the
    stick-slip of the stem (band ``S``, jump ``J``, mm). Returns the new state as
    :func:`valve_initial_state` and the demanded opening ``x_demand`` (mm) as a ninth value."""
    F = friction_step(F_h, T_g_new - T_g, F_noise_dW, vp)
    stroke = vp[I_STROKE]
    xd = min(max(demanded_opening(T_g_new, F, dp_mbar, ps_bar, p_set_MPa, vp), 0.0), stroke)
    if stiction:
        x, u_prev, du_prev, u_s, stuck, d = stem_step(xd, x, u_prev, du_prev, u_s, stuck, d, S, J, stroke)
    else:
        x = xd
    return T_g_new, F, x, u_prev, du_prev, u_s, stuck, d, xd


# positions of the effect parameters in the effect vector ``e`` (valve_env.effects.ENGINE_INDEX; checked
# against the registry by tests/test_effects.py)
E_TAU, E_BETA, E_BAND, E_JUMP, E_RATE = 0, 1, 2, 3, 4


@register_jitable
def valve_path(t, T_tank, T_med, dp, ps, p_bset_MPa, e, vp, hold, F_noise, dW, out):
    """The valve's trajectory with its effects over a grid ``t`` (s), from the inputs at the grid points
    (tank and medium temperatures degC, dp mbar, ps bar), the base set pressure (MPa), the effect vector
    ``e`` (tau_s, beta, band_mm, jump_mm, rate_MPa_per_h; zeros: the base valve) and the packed valve
    vector ``vp``.

    ``hold``: the sensed temperature over each interval is its start's (zero-order hold, as the
    environments' sub-steps see the pocket); else it moves linearly over the interval (the generator's
    fine grid; the bulb lag is exact for either). ``F_noise * dW[i]`` is added to the friction force in
    step i (0: none). Writes ``out`` (5, n): gas temperature, friction force, stem position, demanded
    opening, stuck flag (1.0 stuck, 0.0 moving; 1.0 throughout without stiction)."""
    n = t.shape[0]
    tau = e[E_TAU]
    beta = e[E_BETA]
    S = e[E_BAND]
    J = e[E_JUMP]
    rate = e[E_RATE]
    stiction = S > 0.0 or J > 0.0
    t0 = t[0]
    env0 = sensed_temperature(T_tank[0], T_med[0], beta)
    Tg, F, x, u_prev, du_prev, u_s, stuck, d = valve_initial_state(
        env0, dp[0], ps[0], drifted_set_pressure(p_bset_MPa, rate, 0.0), S, J, stiction, vp)
    out[0, 0] = Tg
    out[1, 0] = F
    out[2, 0] = x
    out[3, 0] = u_prev
    out[4, 0] = stuck
    env_prev = env0
    for i in range(1, n):
        h = t[i] - t[i - 1]
        env = sensed_temperature(T_tank[i], T_med[i], beta)
        a, b = bulb_coefficients(h, tau)
        if hold:
            Tg_new = bulb_lag_hold(Tg, env_prev, a)
        else:
            Tg_new = bulb_lag(Tg, env_prev, env, a, b)
        env_prev = env
        j = i - 1 if hold else i
        Tg, F, x, u_prev, du_prev, u_s, stuck, d, xd = valve_step(
            Tg, F, x, u_prev, du_prev, u_s, stuck, d, Tg_new, F_noise * dW[i], dp[j], ps[j],
            drifted_set_pressure(p_bset_MPa, rate, t[i] - t0), S, J, stiction, vp)
        out[0, i] = Tg
        out[1, i] = F
        out[2, i] = x
        out[3, i] = xd
        out[4, i] = stuck
    return out


__all__ = ["N_VALVE_STATE", "E_TAU", "E_BETA", "E_BAND", "E_JUMP", "E_RATE", "sensed_temperature",
           "bulb_coefficients", "bulb_lag", "bulb_lag_hold", "drifted_set_pressure", "friction_step",
           "valve_initial_state", "stem_step", "valve_step", "valve_path"]
