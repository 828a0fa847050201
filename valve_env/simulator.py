"""The plant simulator: valve + sensor bulb + stratified tank, one control step.

``plant_step`` advances a block of environments (the columns of an array ``Z``,
see "the block" below) by one control step. It is compiled by numba from the
pure physics functions in :mod:`valve_env.physics` (cached on disk), so the
single env, the batched env and the estimator share one model of the valve;
its loops over envs are vectorised by the compiler (docs/speed.md).
``env_step`` is the single env's whole step (action checks, ``apply_action``,
``plant_step`` on a block of one column, ``fill_obs``) in one call;
``env_step_batch`` runs the same functions over the N columns of the batched
env's block (valve_env.envs.vector).

Packed arrays (float64):

* valve vector ``vp``: :meth:`ValveParams.to_array` (indices ``params.I_*``)
* plant vector ``pp``: :func:`pack_plant` (indices ``P_*`` below, then the clock table)
* state ``s``: layer temperatures (bottom .. top), then T_g, F_h, x, direction, the stem's
  stick-slip state (physics.stickslip: u_prev, du_prev, u_s, stuck, d), the time since the
  reset (s) and the demanded opening (mm)
* accumulators ``acc``: KPI integrals and the energy account (``A_*``)
* step outputs ``out``: what the env turns into observations and info (``O_*``)
* scenario row: draw power W, draw temperature degC, tap flow kg/s, supply degC, dp mbar
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, prange
from numba.extending import register_jitable

from valve_env.config import EnvConfig
from valve_env.effects import ENGINE_INDEX
from valve_env.physics import valve as _valve

# The physics functions are ``register_jitable``: plain NumPy when called from
# Python, compiled inline here. One source, one model.
from valve_env.physics.tank import (  # noqa: E402
    advection_heat,
    buoyancy_mix,
    circulation_heat,
    coil_heat,
    columns,
    draw_flow,
    loss_heat,
    pump_power_W,
)
from valve_env.physics.trajectory import (  # noqa: E402
    bulb_lag_hold,
    drifted_set_pressure,
    sensed_temperature,
    valve_initial_state,
    valve_step,
)
from valve_env.physics.valve import dahl_update, flow_kgh, opening, setpoint_pressure  # noqa: E402

# plant vector
(P_NL, P_NC, P_M, P_UA_COIL, P_UA_LOSS, P_T_AMB, P_T_COLD, P_CP, P_PUMP_EFF, P_DP_CIRC, P_Q_REF,
 P_BULB_A, P_BULB_LAYER, P_DT, P_NSUB, P_T_TARGET, P_T_FLOOR, P_W_TRACK, P_W_FLOOR, P_W_ENERGY,
 P_PS, P_CLOCK_N, P_DRAW_MAX,
 # the valve's named effects (valve_env.effects; docs/reference.md): any on (1.0/0.0), medium_temperature's
 # beta, stiction's band and jump (mm; stiction is on when either is > 0), setpoint_drift's rate (MPa/h).
 # sensor_lag sets the bulb's time constant (P_BULB_A)
 P_EFFECTS, P_BETA, P_STICK_S, P_STICK_J, P_DRIFT,
 # the hot-water circulation loop (physics.tank.circulation_heat): flow kg/s (0: none), pipes' UA W/K,
 # the return's layer
 P_CIRC_M, P_CIRC_UA, P_CIRC_LAYER,
 # the tracking term's free band above the target, K (control.free_band_K; 0: symmetric)
 P_FREE_BAND) = range(32)
N_PLANT = 32  # then, if P_CLOCK_N > 0, the clock table: (sin, cos) of each step of a day
# state offsets after the layers: gas temperature, friction force, stem position, direction of the last
# motion; the stem's stick-slip state (valve_env.physics.stickslip); time since reset (s); demanded opening
S_TG, S_FH, S_X, S_DIR, S_UPREV, S_DUPREV, S_US, S_STUCK, S_D, S_AGE, S_XD = range(11)
N_STATE_EXTRA = 11
# accumulators
(A_SQ, A_ABS, A_TDIS, A_UNMET, A_HEAT, A_PUMP, A_RET, A_MASS, A_TRAVEL, A_REV, A_LOSS, A_DRAW,
 A_TIME, A_DELIVERED, A_DEMAND) = range(15)
N_ACC = 15
# step outputs
(O_T_TOP, O_T_POCKET, O_T_BOTTOM, O_T_SUP, O_T_RET, O_Q_KGH, O_DP, O_DRAW_LMIN, O_HEAT_W, O_PUMP_W,
 O_X, O_FH, O_TG, O_T_SET) = range(14)
N_OUT = 14
N_SCEN = 5
PRIMARY_ENERGY_FACTOR_ELECTRICITY = 2.5


def pack_plant(cfg: EnvConfig) -> np.ndarray:
    """The plant vector for ``plant_step`` from an EnvConfig."""
    t, b, c, sc = cfg.tank, cfg.bulb, cfg.control, cfg.scenario
    dt_sub = c.dt_s / c.n_sub
    bulb_layer = min(t.n_layers - 1, int(b.height * t.n_layers))
    pp = np.zeros(N_PLANT)
    pp[P_NL] = t.n_layers
    pp[P_NC] = t.coil_layers
    pp[P_M] = t.layer_mass_kg
    pp[P_UA_COIL] = t.UA_coil
    pp[P_UA_LOSS] = t.UA_loss
    pp[P_T_AMB] = t.T_ambient
    pp[P_T_COLD] = t.T_cold
    pp[P_CP] = t.cp
    pp[P_PUMP_EFF] = t.pump_eff
    pp[P_DP_CIRC] = t.dp_circuit_mbar
    pp[P_Q_REF] = t.q_ref_kgh
    eff = cfg.effects
    tau = eff.get("sensor_lag", "tau_s", b.tau_s) if "sensor_lag" in eff else b.tau_s
    pp[P_BULB_A] = np.exp(-dt_sub / tau) if tau > 0 else 0.0
    ev = eff.vector()
    pp[P_EFFECTS] = 1.0 if eff else 0.0
    pp[P_BETA] = ev[ENGINE_INDEX["beta"]]
    pp[P_STICK_S] = ev[ENGINE_INDEX["band_mm"]]
    pp[P_STICK_J] = ev[ENGINE_INDEX["jump_mm"]]
    pp[P_DRIFT] = ev[ENGINE_INDEX["rate_MPa_per_h"]]
    pp[P_BULB_LAYER] = bulb_layer
    pp[P_DT] = c.dt_s
    pp[P_NSUB] = c.n_sub
    pp[P_T_TARGET] = c.T_target_C
    pp[P_T_FLOOR] = c.T_floor_C
    pp[P_W_TRACK] = c.w_track
    pp[P_W_FLOOR] = c.w_floor
    pp[P_W_ENERGY] = c.w_energy
    pp[P_PS] = sc.ps_bar
    pp[P_DRAW_MAX] = cfg.draw_max_kgs()
    pp[P_CIRC_M] = t.circ_kgh / 3600.0
    pp[P_CIRC_UA] = t.circ_UA
    pp[P_CIRC_LAYER] = t.circ_layer
    pp[P_FREE_BAND] = c.free_band_K
    # the time-of-day features of the observation, tabulated when a day is a whole
    # number of steps (two libm calls per env-step otherwise)
    per_day = 86400.0 / c.dt_s
    if per_day == round(per_day) and per_day <= 100_000:
        n = int(per_day)
        ang = np.arange(n) * (2.0 * np.pi / n)
        table = np.column_stack([np.sin(ang), np.cos(ang)]).ravel()
        pp = np.concatenate([pp, table])
        pp[P_CLOCK_N] = n
    return pp


def initial_state(cfg: EnvConfig, T0: float, T_supply0: float | None = None) -> np.ndarray:
    """A settled start: the whole tank at T0, the bulb at its sensed temperature (T0, or mixed with the
    supply ``T_supply0`` under medium_temperature), no friction force, the stem at rest where the force
    balance puts it (physics.trajectory.valve_initial_state)."""
    n = cfg.tank.n_layers
    s = np.zeros(n + N_STATE_EXTRA)
    s[:n] = T0
    vp = cfg.valve.to_array()
    ev = cfg.effects.vector()
    S, J = ev[ENGINE_INDEX["band_mm"]], ev[ENGINE_INDEX["jump_mm"]]
    T_env = T0 if T_supply0 is None else float(sensed_temperature(T0, T_supply0, ev[ENGINE_INDEX["beta"]]))
    st = valve_initial_state(T_env, cfg.scenario.dp_mbar, cfg.scenario.ps_bar,
                             _valve.setpoint_pressure(cfg.control.setting_C, vp), S, J, S > 0 or J > 0, vp)
    for q, v in zip((S_TG, S_FH, S_X, S_UPREV, S_DUPREV, S_US, S_STUCK, S_D), st, strict=True):
        s[n + q] = float(v)
    s[n + S_AGE] = 0.0
    s[n + S_XD] = s[n + S_UPREV]
    return s


# -- the block: envs as columns ------------------------------------------------------
# ``plant_step`` works on a block ``Z`` of shape (block_rows(n_layers), n_envs), one
# column per env (structure of arrays), from top to bottom:
#   the state ``s`` (n_layers + N_STATE_EXTRA rows),
#   the rows ``Z_*`` below (N_Z: the step's inputs, its reward, its sums, scratch),
#   the heat flows Q (n_layers rows),
#   the accumulators ``acc`` (N_ACC rows, from ``acc_row(n_layers)``),
#   the step outputs ``out`` (N_OUT rows, from ``out_row(n_layers)``).
# Every physics function runs as a loop over the block's envs, which the compiler
# vectorises. The batched env keeps all its envs in one block; a single env is a block
# of one column.
(Z_DRAW_W, Z_DRAW_T, Z_TAP_M, Z_T_SUP, Z_T_SET, Z_DP,  # inputs of the step
 Z_REWARD,  # output
 # sums over the step's sub-steps
 Z_TRAVEL, Z_REV, Z_DRAWN, Z_DELIVERED, Z_UNMET, Z_LOSS, Z_SQ, Z_ABS, Z_SHORT, Z_HEAT, Z_PUMP, Z_RET, Z_MASS,
 Z_DRAW_MASS,
 # scratch of a sub-step
 Z_PB, Z_M, Z_X_NEW, Z_T_RET, Z_EPS, Z_M_DRAW, Z_Q_DELIV, Z_Q_LOSS, Z_FLAG) = range(30)
N_Z = 30


@register_jitable
def acc_row(n_layers: int) -> int:
    """The first accumulator row of a block (``A_*`` are offsets from it)."""
    return 2 * n_layers + N_STATE_EXTRA + N_Z


@register_jitable
def out_row(n_layers: int) -> int:
    """The first step-output row of a block (``O_*`` are offsets from it)."""
    return acc_row(n_layers) + N_ACC


@register_jitable
def block_rows(n_layers: int) -> int:
    """Rows of a block ``Z`` for a tank of ``n_layers`` layers."""
    return out_row(n_layers) + N_OUT


@njit(cache=True, error_model="numpy")
def plant_step(Z, lo, hi, vp, pp):
    """Advance the envs in columns ``lo .. hi - 1`` of the block ``Z`` by one control step.

    Before the call each column holds an env's state, accumulators and step
    inputs (the scenario row's draw power, draw temperature, tap flow and
    supply temperature, the setting in force and the differential pressure);
    after it, the new state, the step's sums (``Z_TRAVEL`` .. ``Z_DRAW_MASS``)
    added to the accumulators, the step outputs and the reward (``Z_REWARD``).

    Compiled with NumPy's error model (a division by zero gives inf or NaN
    instead of raising): the raising checks are branches that stop the
    compiler from vectorising the loops over envs, and no division here can be
    by zero.
    """
    nl = int(pp[P_NL])
    nc = int(pp[P_NC])
    b0 = nl + N_STATE_EXTRA
    c0, c1 = columns(lo, hi, Z.shape[1])
    nsub = int(pp[P_NSUB])
    dt = pp[P_DT] / nsub
    cp = pp[P_CP]
    dt_Mcp = dt / (pp[P_M] * cp)
    T_cold = pp[P_T_COLD]
    T_target = pp[P_T_TARGET]
    T_floor = pp[P_T_FLOOR]
    free_band = pp[P_FREE_BAND]
    a_b = pp[P_BULB_A]
    ps = pp[P_PS]
    T = Z[:nl]
    Tb = Z[int(pp[P_BULB_LAYER])]
    T_top = Z[nl - 1]
    T_g = Z[nl + S_TG]
    F_h = Z[nl + S_FH]
    X = Z[nl + S_X]
    direction = Z[nl + S_DIR]
    draw_W = Z[b0 + Z_DRAW_W]
    draw_T = Z[b0 + Z_DRAW_T]
    tap_m = Z[b0 + Z_TAP_M]
    T_sup = Z[b0 + Z_T_SUP]
    T_set = Z[b0 + Z_T_SET]
    dp = Z[b0 + Z_DP]
    travel = Z[b0 + Z_TRAVEL]
    rev = Z[b0 + Z_REV]
    drawn = Z[b0 + Z_DRAWN]
    deliv = Z[b0 + Z_DELIVERED]
    unmet = Z[b0 + Z_UNMET]
    loss = Z[b0 + Z_LOSS]
    e2 = Z[b0 + Z_SQ]
    eabs = Z[b0 + Z_ABS]
    short = Z[b0 + Z_SHORT]
    heat = Z[b0 + Z_HEAT]
    pump = Z[b0 + Z_PUMP]
    ret = Z[b0 + Z_RET]
    mass = Z[b0 + Z_MASS]
    draw_mass = Z[b0 + Z_DRAW_MASS]
    p_bset = Z[b0 + Z_PB]
    m = Z[b0 + Z_M]
    x_new = Z[b0 + Z_X_NEW]
    T_ret = Z[b0 + Z_T_RET]
    eps = Z[b0 + Z_EPS]
    m_draw = Z[b0 + Z_M_DRAW]
    q_deliv = Z[b0 + Z_Q_DELIV]
    q_loss = Z[b0 + Z_Q_LOSS]
    flag = Z[b0 + Z_FLAG]
    Q = Z[b0 + N_Z:b0 + N_Z + nl]
    w = int(c1 - c0)
    mix_S = np.empty((nl + 1, w))
    mix_R = np.empty((nl, w))
    mix_M = np.empty(w)
    for r in range(Z_TRAVEL, Z_DRAW_MASS + 1):
        for i in range(c0, c1):
            Z[b0 + r, i] = 0.0
    for i in range(c0, c1):
        p_bset[i] = setpoint_pressure(T_set[i], vp)
    effects = pp[P_EFFECTS] != 0.0
    circ = pp[P_CIRC_M] > 0.0
    circ_layer = int(pp[P_CIRC_LAYER])
    for _ in range(nsub):
        if effects:
            _valve_effects_substep(Z, nl, c0, c1, Tb, T_sup, dp, ps, p_bset, x_new, m, a_b, dt, vp, pp)
        else:
            # sensor bulb: exact first-order lag towards the pocket's layer; Dahl friction;
            # the force balance's opening; the flow it passes
            for i in range(c0, c1):
                Tg1 = bulb_lag_hold(T_g[i], Tb[i], a_b)
                F = dahl_update(F_h[i], Tg1 - T_g[i], vp)
                T_g[i] = Tg1
                F_h[i] = F
                x = opening(Tg1, F, dp[i], ps, p_bset[i], vp)
                x_new[i] = x
                m[i] = flow_kgh(x, dp[i], vp) / 3600.0
        # stem travel and reversals
        for i in range(c0, c1):
            dx = x_new[i] - X[i]
            moved = dx > 1e-9 or dx < -1e-9
            d = 1.0 if dx > 0 else -1.0
            travel[i] += abs(dx) if moved else 0.0
            rev[i] += 1.0 if moved and direction[i] != 0.0 and d != direction[i] else 0.0
            direction[i] = d if moved else direction[i]
            X[i] = x_new[i]
        coil_heat(T, nc, m, T_sup, pp[P_UA_COIL], cp, Q, T_ret, eps, lo, hi)
        draw_flow(draw_W, draw_T, tap_m, T_top, T_cold, cp, m_draw, q_deliv, lo, hi, pp[P_DRAW_MAX])
        for i in range(c0, c1):
            drawn[i] += m_draw[i] * cp * (T_top[i] - T_cold) * dt
            deliv[i] += q_deliv[i] * dt
            unmet[i] += (draw_W[i] - q_deliv[i]) * dt if draw_W[i] > 0.0 else 0.0
        advection_heat(T, m_draw, T_cold, cp, Q, lo, hi)
        loss_heat(T, pp[P_UA_LOSS], pp[P_T_AMB], Q, q_loss, lo, hi)
        if circ:
            circulation_heat(T, pp[P_CIRC_M], pp[P_CIRC_UA], pp[P_T_AMB], circ_layer, cp, Q, q_loss, lo, hi)
        for j in range(nl):
            for i in range(c0, c1):
                T[j, i] += Q[j, i] * dt_Mcp
        buoyancy_mix(T, mix_S, mix_R, mix_M, flag, lo, hi)
        for i in range(c0, c1):
            mi = m[i]
            loss[i] += q_loss[i] * dt
            heat[i] += mi * cp * (T_sup[i] - T_ret[i]) * dt
            pump[i] += pump_power_W(mi, dp[i], pp[P_DP_CIRC], pp[P_Q_REF], pp[P_PUMP_EFF]) * dt
            ret[i] += mi * T_ret[i] * dt
            mass[i] += mi * dt
            draw_mass[i] += m_draw[i] * dt
            # the tracking error: the top's distance from the band [T_target, T_target + free_band]
            # (a store behind a mixing valve, docs/tasks.md "ThermoValveDistrictHeating-v1"); with no
            # band it is T_top - T_target exactly (e - 0.0 == e)
            e = T_top[i] - T_target
            e = e - free_band if e > free_band else (0.0 if e > 0.0 else e)
            e2[i] += e * e
            eabs[i] += abs(e)
            sh = T_floor - T_top[i]
            short[i] += sh if sh > 0.0 else 0.0
    step = pp[P_DT]
    reward = Z[b0 + Z_REWARD]
    for i in range(c0, c1):
        p_kw = (heat[i] + PRIMARY_ENERGY_FACTOR_ELECTRICITY * pump[i]) / step / 1000.0
        reward[i] = -(pp[P_W_TRACK] * e2[i] / nsub + pp[P_W_FLOOR] * short[i] / nsub + pp[P_W_ENERGY] * p_kw)
    # the step's sums into the accumulators
    a0 = acc_row(nl)
    _add_row(Z[a0 + A_TRAVEL], travel, 1.0, lo, hi)
    _add_row(Z[a0 + A_REV], rev, 1.0, lo, hi)
    _add_row(Z[a0 + A_DRAW], drawn, 1.0, lo, hi)
    _add_row(Z[a0 + A_DELIVERED], deliv, 1.0, lo, hi)
    _add_row(Z[a0 + A_DEMAND], draw_W, step, lo, hi)
    _add_row(Z[a0 + A_UNMET], unmet, 1.0, lo, hi)
    _add_row(Z[a0 + A_LOSS], loss, 1.0, lo, hi)
    _add_row(Z[a0 + A_SQ], e2, dt, lo, hi)
    _add_row(Z[a0 + A_ABS], eabs, dt, lo, hi)
    _add_row(Z[a0 + A_TDIS], short, dt, lo, hi)
    _add_row(Z[a0 + A_HEAT], heat, 1.0, lo, hi)
    _add_row(Z[a0 + A_PUMP], pump, 1.0, lo, hi)
    _add_row(Z[a0 + A_RET], ret, 1.0, lo, hi)
    _add_row(Z[a0 + A_MASS], mass, 1.0, lo, hi)
    time_acc = Z[a0 + A_TIME]
    for i in range(c0, c1):
        time_acc[i] += step
    # the step outputs
    o0 = out_row(nl)
    _copy_row(Z[o0 + O_T_TOP], T_top, 1.0, lo, hi)
    _copy_row(Z[o0 + O_T_POCKET], Tb, 1.0, lo, hi)
    _copy_row(Z[o0 + O_T_BOTTOM], Z[0], 1.0, lo, hi)
    _copy_row(Z[o0 + O_T_SUP], T_sup, 1.0, lo, hi)
    _copy_row(Z[o0 + O_Q_KGH], mass, 3600.0 / step, lo, hi)
    _copy_row(Z[o0 + O_DP], dp, 1.0, lo, hi)
    _copy_row(Z[o0 + O_DRAW_LMIN], draw_mass, 60.0 / step, lo, hi)
    _copy_row(Z[o0 + O_HEAT_W], heat, 1.0 / step, lo, hi)
    _copy_row(Z[o0 + O_PUMP_W], pump, 1.0 / step, lo, hi)
    _copy_row(Z[o0 + O_X], X, 1.0, lo, hi)
    _copy_row(Z[o0 + O_FH], F_h, 1.0, lo, hi)
    _copy_row(Z[o0 + O_TG], T_g, 1.0, lo, hi)
    _copy_row(Z[o0 + O_T_SET], T_set, 1.0, lo, hi)
    T_ret_out = Z[o0 + O_T_RET]
    for i in range(c0, c1):
        T_ret_out[i] = ret[i] / mass[i] if mass[i] > 1e-12 else Z[0, i]


@register_jitable
def _valve_effects_substep(Z, nl, c0, c1, Tb, T_sup, dp, ps, p_bset, x_new, m, a_b, dt, vp, pp):
    """The valve's sub-step with its named effects (physics.trajectory.valve_step): the bulb lags the
    sensed temperature (the pocket mixed with the supply water through the valve, medium_temperature), the
    set pressure drifts with the time since the reset (setpoint_drift), the stem sticks and slips
    (stiction). Writes the new stem position to ``x_new`` (the caller counts travel and reversals) and
    the flow to ``m``."""
    beta = pp[P_BETA]
    S = pp[P_STICK_S]
    J = pp[P_STICK_J]
    rate = pp[P_DRIFT]
    stiction = S > 0.0 or J > 0.0
    T_g = Z[nl + S_TG]
    F_h = Z[nl + S_FH]
    X = Z[nl + S_X]
    UP = Z[nl + S_UPREV]
    DUP = Z[nl + S_DUPREV]
    US = Z[nl + S_US]
    ST = Z[nl + S_STUCK]
    D = Z[nl + S_D]
    AGE = Z[nl + S_AGE]
    XD = Z[nl + S_XD]
    for i in range(c0, c1):
        env = sensed_temperature(Tb[i], T_sup[i], beta)
        AGE[i] += dt
        Tg, F, x, UP[i], DUP[i], US[i], ST[i], D[i], XD[i] = valve_step(
            T_g[i], F_h[i], X[i], UP[i], DUP[i], US[i], ST[i], D[i], bulb_lag_hold(T_g[i], env, a_b), 0.0, dp[i],
            ps, drifted_set_pressure(p_bset[i], rate, AGE[i]), S, J, stiction, vp)
        T_g[i] = Tg
        F_h[i] = F
        x_new[i] = x
        m[i] = flow_kgh(x, dp[i], vp) / 3600.0


@register_jitable
def _add_row(dst, src, scale, lo, hi):
    c0, c1 = columns(lo, hi, dst.shape[0])
    for i in range(c0, c1):
        dst[i] += src[i] * scale


@register_jitable
def _copy_row(dst, src, scale, lo, hi):
    c0, c1 = columns(lo, hi, dst.shape[0])
    for i in range(c0, c1):
        dst[i] = src[i] * scale


# -- the environments' step: action -> plant_step -> observation --------------
# Shared by the single env (``env_step``) and the batched env
# (``env_step_batch``): both call the same ``apply_action``, ``plant_step`` and
# ``clock``. The batched step writes each env's observation row with the same
# copies as ``fill_obs`` does, element by element (a view of a column of the
# shared block per env would update its reference count atomically from every
# thread); tests/envs/test_vector.py holds the two bit-identical.

MODE_SETTING, MODE_PRESSURE, MODE_DUAL = 0, 1, 2
MODE_CODES: dict[str, int] = {"setting": MODE_SETTING, "pressure": MODE_PRESSURE, "dual": MODE_DUAL}
# the observation (valve_env.envs.thermovalve.OBS_NAMES) from the step outputs
OBS_FROM_OUT = (O_T_TOP, O_T_POCKET, O_T_BOTTOM, O_T_SUP, O_T_RET, O_Q_KGH, O_DP, O_DRAW_LMIN)
N_OBS = 12
# the info columns of the batched step (INFO rows 0-4; row 5 is the time), from the step outputs
INFO_FROM_OUT = (O_X, O_FH, O_TG, O_HEAT_W, O_PUMP_W)
# the env's action memory ``sd``: the setting in force (degC), the dp in force (mbar)
SD_SET, SD_DP = 0, 1


@register_jitable
def clock(k, pp):
    """The time-of-day features (sin, cos) of step index ``k`` (from the plant vector's table if it has one)."""
    n = int(pp[P_CLOCK_N])
    if n > 0:
        j = N_PLANT + 2 * (k % n)
        return pp[j], pp[j + 1]
    ang = k * (2.0 * np.pi * pp[P_DT] / 86400.0)
    return np.sin(ang), np.cos(ang)


@njit(cache=True)
def fill_obs(obs, out, pp, k, T_set):
    """Write the float32 observation of step index ``k`` from the step outputs."""
    for j in range(8):
        obs[j] = out[OBS_FROM_OUT[j]]
    obs[8], obs[9] = clock(k, pp)
    obs[10] = T_set
    obs[11] = pp[P_T_TARGET]


@register_jitable
def apply_action(mode, a0, a1, scen_dp, setting, dp):
    """The (setting degC, dp mbar) in force after a (validated, clipped) action
    ``(a0, a1)`` (``a1`` is read in dual mode only), from the scenario's dp
    ``scen_dp`` and the (setting, dp) in force before.

    setting mode: the setting is the action, dp the scenario's; pressure mode:
    dp is the action, the setting stays; dual: both. Scalars in and out: called
    once per env in the batched step, where a call with array arguments cost
    35 ns per env-step in reference counting (docs/speed.md)."""
    if mode == MODE_SETTING:
        return a0, scen_dp
    if mode == MODE_PRESSURE:
        return setting, a0
    return a0, a1


@njit(cache=True)
def env_step(s, acc, out, obs, vp, pp, scen, k, a, bounds, mode, sd, work):
    """One step of one env from its raw action: validate, clip, act, simulate, observe.

    ``scen`` is the episode's (n_steps, 5) scenario, ``k`` the step index,
    ``a`` the action (float64, overwritten by its clipped value), ``bounds``
    (2, act_dim) the action box, ``sd`` the action memory (setting, dp),
    ``work`` a block of one column (``block_rows(n_layers)``, 1) that
    :func:`plant_step` steps. Returns (reward, status): status -1 if the action is not finite (nothing
    is changed), 1 if it was clipped, else 0.
    """
    na = a.shape[0]
    for j in range(na):
        if not np.isfinite(a[j]):
            return 0.0, -1
    status = 0
    for j in range(na):
        if a[j] < bounds[0, j]:
            a[j] = bounds[0, j]
            status = 1
        elif a[j] > bounds[1, j]:
            a[j] = bounds[1, j]
            status = 1
    row = scen[k]
    sd[SD_SET], sd[SD_DP] = apply_action(mode, a[0], a[na - 1], row[4], sd[SD_SET], sd[SD_DP])
    ns = s.shape[0]
    nl = int(pp[P_NL])
    a0 = acc_row(nl)
    o0 = out_row(nl)
    for q in range(ns):
        work[q, 0] = s[q]
    for q in range(N_ACC):
        work[a0 + q, 0] = acc[q]
    # typed column indices, as the batched kernels pass them: constants would be compile-time literals and
    # compile load_inputs and plant_step (the whole plant, ~14 s) a second time in a process that uses both
    load_inputs(work, np.uint64(0), ns, row, sd[SD_SET], sd[SD_DP])
    plant_step(work, np.int64(0), np.int64(1), vp, pp)
    for q in range(ns):
        s[q] = work[q, 0]
    for q in range(N_ACC):
        acc[q] = work[a0 + q, 0]
    for q in range(N_OUT):
        out[q] = work[o0 + q, 0]
    fill_obs(obs, out, pp, k + 1, sd[SD_SET])
    return work[ns + Z_REWARD, 0], status


@njit(cache=True)
def load_inputs(Z, i, ns, row, T_set, dp):
    """Column ``i``'s step inputs: the scenario row (draw power, draw
    temperature, tap flow, supply temperature), the setting and dp in force."""
    Z[ns + Z_DRAW_W, i] = row[0]
    Z[ns + Z_DRAW_T, i] = row[1]
    Z[ns + Z_TAP_M, i] = row[2]
    Z[ns + Z_T_SUP, i] = row[3]
    Z[ns + Z_T_SET, i] = T_set
    Z[ns + Z_DP, i] = dp


@njit(cache=True)
def _next_run(i, k, RK, RV, CUR, NRUN, ROW, NEXT):
    """Env ``i`` at step ``k`` has reached ``NEXT[i]``: move ``CUR[i]`` to the run in
    force, copy its scenario row into ``ROW[i]`` and set ``NEXT[i]`` to the step
    where the following run starts (the largest int64 after the last run)."""
    cur = CUR[i]
    while cur + 1 < NRUN[i] and RK[i, cur + 1] <= k:
        cur += 1
    CUR[i] = cur
    for q in range(ROW.shape[1]):
        ROW[i, q] = RV[i, cur, q]
    NEXT[i] = RK[i, cur + 1] if cur + 1 < NRUN[i] else np.iinfo(np.int64).max


@register_jitable
def _hold_columns(Z, kept, STEP, c0, c1, restore):
    """Copy the columns of the envs that do not step (``STEP[i]`` false) into the rows of
    ``kept``, or back into ``Z`` with ``restore``."""
    c = 0
    for i in range(c0, c1):
        if not STEP[i]:
            for q in range(Z.shape[0]):
                if restore:
                    Z[q, i] = kept[c, q]
                else:
                    kept[c, q] = Z[q, i]
            c += 1


@njit(cache=True)
def _step_block(lo, hi, Z, OBS, INFO, vp, pp, RK, RV, CUR, NRUN, ROW, NEXT, K, A, mode, SD, STEP):
    """``apply_action``, ``plant_step`` and the observation for the envs in
    columns ``lo .. hi - 1`` of the batched env's block ``Z`` (observations in
    the rows of ``OBS``). Envs with ``STEP[i]`` false are left exactly as
    they were."""
    nl = int(pp[P_NL])
    ns = nl + N_STATE_EXTRA
    o0 = out_row(nl)
    c0, c1 = columns(lo, hi, Z.shape[1])
    row = np.empty(RV.shape[2])
    na = A.shape[1]
    held = 0
    for i in range(c0, c1):
        if STEP[i]:
            k = K[i]
            if k >= NEXT[i]:  # a new run of the scenario starts (every ~30 steps)
                _next_run(i, k, RK, RV, CUR, NRUN, ROW, NEXT)
            for q in range(row.shape[0]):
                row[q] = ROW[i, q]
            T_set, dp = apply_action(mode, A[i, 0], A[i, na - 1], row[4], SD[i, SD_SET], SD[i, SD_DP])
            SD[i, SD_SET] = T_set
            SD[i, SD_DP] = dp
            load_inputs(Z, i, ns, row, T_set, dp)
        else:
            held += 1
    # the block is stepped whole (vectorised); envs that do not step are put back
    kept = np.empty((held, Z.shape[0]))
    if held > 0:
        _hold_columns(Z, kept, STEP, c0, c1, False)
    plant_step(Z, lo, hi, vp, pp)
    if held > 0:
        _hold_columns(Z, kept, STEP, c0, c1, True)
    for i in range(c0, c1):
        K[i] += 1 if STEP[i] else 0
    # the observations, env by env (a row of ``OBS`` each, as the agent gets them)
    for i in range(c0, c1):
        if STEP[i]:
            for j in range(8):
                OBS[i, j] = Z[o0 + OBS_FROM_OUT[j], i]
            OBS[i, 8], OBS[i, 9] = clock(K[i], pp)
            OBS[i, 10] = Z[o0 + O_T_SET, i]
            OBS[i, 11] = pp[P_T_TARGET]
    # the info rows row by row: loops over envs that the compiler vectorises
    for j in range(5):
        _copy_row(INFO[j], Z[o0 + INFO_FROM_OUT[j]], 1.0, lo, hi)
    _copy_row(INFO[5], K, pp[P_DT], lo, hi)


@njit(cache=True)
def check_actions(A_IN, bounds, A, CLIPPED, STEP):
    """Validate and clip the batched actions (as ``env_step`` does for one env).

    If a stepping env's action ``A_IN[i]`` is not finite, nothing changes and
    ``i`` is returned. Otherwise the actions are clipped into ``A``,
    ``CLIPPED[i]`` is set for a stepping env whose action was outside
    ``bounds``, and -2 is returned if some action was clipped, else -1.
    """
    n = A_IN.shape[0]
    na = A_IN.shape[1]
    for i in range(n):
        if STEP[i]:
            for j in range(na):
                if not np.isfinite(A_IN[i, j]):
                    return i
    any_clip = False
    for i in range(n):
        c = False
        for j in range(na):
            v = A_IN[i, j]
            if v < bounds[0, j]:
                v = bounds[0, j]
                c = True
            elif v > bounds[1, j]:
                v = bounds[1, j]
                c = True
            A[i, j] = v
        c = c and STEP[i]
        CLIPPED[i] = c
        any_clip = any_clip or c
    return -2 if any_clip else -1


@njit(cache=True, parallel=True)
def env_step_batch(Z, OBS, INFO, vp, pp, RK, RV, CUR, NRUN, ROW, NEXT, K, A_IN, bounds, A, CLIPPED, mode, SD, STEP,
                   block):
    """``env_step`` over the N envs in the columns of the block ``Z`` for the
    envs with ``STEP[i]``, on numba's threads.

    The actions (row i for env i) go through :func:`check_actions` (its
    return value is returned; nothing is stepped if an action is not finite);
    then the envs, cut into contiguous column ranges of ``block`` envs (the
    last may be shorter), each take
    :func:`_step_block` (``apply_action``, ``plant_step`` and the observation,
    as the single env's ``env_step``). Observations go to the rows of
    ``OBS`` (N, N_OBS), the env's observation array; ``INFO`` (6, N) receives the info columns x, F_h,
    T_g, heat, pump and the time (s).

    Each env's scenario is run-length encoded: rows ``RV[i, :NRUN[i]]`` start
    at step indices ``RK[i, :NRUN[i]]`` (``RK[i, 0] == 0``); ``CUR[i]`` is the
    run in force, which only moves forward within an episode, ``ROW[i]`` its
    row and ``NEXT[i]`` the step index where the next run starts (0 after a
    reset, so the first step loads run 0).
    """
    status = check_actions(A_IN, bounds, A, CLIPPED, STEP)
    if status >= 0:
        return status
    n = Z.shape[1]
    for b in prange((n + block - 1) // block):
        _step_block(b * block, min(n, (b + 1) * block), Z, OBS, INFO, vp, pp, RK, RV, CUR, NRUN, ROW, NEXT, K, A,
                    mode, SD, STEP)
    return status


@njit(cache=True)
def env_step_batch_serial(Z, OBS, INFO, vp, pp, RK, RV, CUR, NRUN, ROW, NEXT, K, A_IN, bounds, A, CLIPPED, mode, SD,
                          STEP, block):
    """:func:`env_step_batch` in one serial loop (no thread pool: for small N),
    over column ranges of at most ``block`` envs (a range's rows stay in cache
    while its sub-steps pass over them)."""
    status = check_actions(A_IN, bounds, A, CLIPPED, STEP)
    if status >= 0:
        return status
    n = Z.shape[1]
    for lo in range(0, n, block):
        _step_block(lo, min(n, lo + block), Z, OBS, INFO, vp, pp, RK, RV, CUR, NRUN, ROW, NEXT, K, A, mode, SD,
                    STEP)
    return status


def reset_outputs(out: np.ndarray, s: np.ndarray, pp: np.ndarray, scen0: np.ndarray, setting: float, dp: float) -> None:
    """The step outputs at the start of an episode (no flow history yet)."""
    nl = int(pp[P_NL])
    out[:] = 0.0
    out[O_T_TOP] = s[nl - 1]
    out[O_T_POCKET] = s[int(pp[P_BULB_LAYER])]
    out[O_T_BOTTOM] = s[0]
    out[O_T_SUP] = scen0[3]
    out[O_T_RET] = s[0]
    out[O_DP] = dp
    out[O_X] = s[nl + S_X]
    out[O_TG] = s[nl + S_TG]
    out[O_T_SET] = setting


def effect_info(s: np.ndarray, nl: int, pp: np.ndarray, vp: np.ndarray, setting: np.ndarray | float) -> dict[str, Any]:
    """The hidden states of the valve's named effects from a state vector ``s`` (or the rows of the
    batched env's states, ``(N, ns)``) and the setting(s) in force: ``x_demand_mm`` (the force
    balance's opening, before stiction), ``stuck`` (1.0 while the stem sticks; with stiction),
    ``p_set_MPa`` (the bellows set pressure in force, drifted by setpoint_drift). Empty without effects."""
    if pp[P_EFFECTS] == 0.0:
        return {}
    out: dict[str, Any] = {
        "x_demand_mm": s[..., nl + S_XD].copy(),
        "p_set_MPa": _valve.setpoint_pressure(np.asarray(setting, dtype=float), vp)
        + pp[P_DRIFT] * s[..., nl + S_AGE] / 3600.0,
    }
    if pp[P_STICK_S] > 0.0 or pp[P_STICK_J] > 0.0:
        out["stuck"] = s[..., nl + S_STUCK].copy()
    return out


def kpis_from_acc(acc: np.ndarray) -> dict[str, float]:
    """The docs/reference.md, section 5 KPIs from an accumulator vector."""
    T = max(acc[A_TIME], 1e-12)
    return {
        "rmse_K": float(np.sqrt(acc[A_SQ] / T)),
        "iae_Kh": float(acc[A_ABS] / 3600.0),
        "tdis_Kh": float(acc[A_TDIS] / 3600.0),
        "unmet_kWh": float(acc[A_UNMET] / 3.6e6),
        "heat_kWh": float(acc[A_HEAT] / 3.6e6),
        "pump_kWh": float(acc[A_PUMP] / 3.6e6),
        "return_C": float(acc[A_RET] / acc[A_MASS]) if acc[A_MASS] > 1e-12 else float("nan"),
        "travel_mm": float(acc[A_TRAVEL]),
        "reversals": float(acc[A_REV]),
    }


KPI_NAMES: tuple[str, ...] = (
    "rmse_K", "iae_Kh", "tdis_Kh", "unmet_kWh", "heat_kWh", "pump_kWh", "return_C", "travel_mm", "reversals",
)
