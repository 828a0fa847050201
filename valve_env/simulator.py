"""The plant simulator: valve + sensor bulb + stratified tank, one control step.

``plant_step`` advances one environment by one control step. It is compiled by numba from the
pure physics functions in :mod:`valve_env.physics` (cached on disk), so the
single env, the batched env and the estimator share one model of the valve.
``env_step`` is the single env's whole step (action checks, ``apply_action``,
``plant_step``, ``fill_obs``) in one call; ``env_step_batch`` runs the same
functions over N envs for the batched env (valve_env.envs.vector).

Packed arrays (float64):

* valve vector ``vp``: :meth:`ValveParams.to_array` (indices ``params.I_*``)
* plant vector ``pp``: :func:`pack_plant` (indices ``P_*`` below)
* state ``s``: layer temperatures (bottom .. top), then T_g, F_h, x, direction
* accumulators ``acc``: KPI integrals and the energy account (``A_*``)
* step outputs ``out``: what the env turns into observations and info (``O_*``)
* scenario row: draw power W, draw temperature degC, tap flow kg/s, supply degC, dp mbar
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from valve_env.config import EnvConfig
from valve_env.physics import valve as _valve

# The physics functions are ``register_jitable``: plain NumPy when called from
# Python, compiled inline here. One source, one model.
from valve_env.physics.tank import (  # noqa: E402
    advection_heat,
    buoyancy_mix,
    coil_heat,
    draw_flow,
    loss_heat,
    pump_power_W,
)
from valve_env.physics.valve import dahl_update, flow_kgh, opening, setpoint_pressure  # noqa: E402

# plant vector
(P_NL, P_NC, P_M, P_UA_COIL, P_UA_LOSS, P_T_AMB, P_T_COLD, P_CP, P_PUMP_EFF, P_DP_CIRC, P_Q_REF,
 P_BULB_A, P_BULB_LAYER, P_DT, P_NSUB, P_T_TARGET, P_T_FLOOR, P_W_TRACK, P_W_FLOOR, P_W_ENERGY,
 P_PS) = range(21)
N_PLANT = 21
# state offsets after the layers
S_TG, S_FH, S_X, S_DIR = 0, 1, 2, 3
N_STATE_EXTRA = 4
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
    pp[P_BULB_A] = np.exp(-dt_sub / b.tau_s)
    pp[P_BULB_LAYER] = bulb_layer
    pp[P_DT] = c.dt_s
    pp[P_NSUB] = c.n_sub
    pp[P_T_TARGET] = c.T_target_C
    pp[P_T_FLOOR] = c.T_floor_C
    pp[P_W_TRACK] = c.w_track
    pp[P_W_FLOOR] = c.w_floor
    pp[P_W_ENERGY] = c.w_energy
    pp[P_PS] = sc.ps_bar
    return pp


def initial_state(cfg: EnvConfig, T0: float) -> np.ndarray:
    """A settled start: the whole tank at T0, bulb at T0, no friction force."""
    n = cfg.tank.n_layers
    s = np.zeros(n + N_STATE_EXTRA)
    s[:n] = T0
    s[n + S_TG] = T0
    s[n + S_FH] = 0.0
    s[n + S_X] = float(
        _valve.opening(T0, 0.0, cfg.scenario.dp_mbar, cfg.scenario.ps_bar,
                       _valve.setpoint_pressure(cfg.control.setting_C, cfg.valve.to_array()), cfg.valve.to_array())
    )
    return s


@njit(cache=True)
def plant_step(s, acc, out, vp, pp, scen, T_set, dp, work):
    """Advance one environment by one control step; returns the reward.

    ``s``, ``acc`` and ``out`` are updated in place. ``scen`` is this step's
    scenario row, ``T_set`` the valve's temperature setting (degC), ``dp`` the
    differential pressure across the valve (mbar), ``work`` a (3, n_layers)
    scratch array.
    """
    nl = int(pp[P_NL])
    nc = int(pp[P_NC])
    nsub = int(pp[P_NSUB])
    dt = pp[P_DT] / nsub
    cp = pp[P_CP]
    Mcp = pp[P_M] * cp
    T_cold = pp[P_T_COLD]
    bl = int(pp[P_BULB_LAYER])
    a_b = pp[P_BULB_A]
    T = s[:nl]
    Q = work[0]
    wsum = work[1]
    wcnt = work[2]
    p_bset = setpoint_pressure(T_set, vp)
    draw_W = scen[0]
    draw_T = scen[1]
    draw_m = scen[2]
    T_sup = scen[3]
    ps = pp[P_PS]
    T_g = s[nl + S_TG]
    F_h = s[nl + S_FH]
    x = s[nl + S_X]
    direction = s[nl + S_DIR]
    dt_Mcp = dt / Mcp
    e2 = 0.0
    eabs = 0.0
    short = 0.0
    heat_J = 0.0
    travel = 0.0
    reversals = 0.0
    drawn_J = 0.0
    delivered_J = 0.0
    unmet_J = 0.0
    loss_J = 0.0
    pump_J = 0.0
    ret_mass = 0.0
    mass = 0.0
    draw_mass = 0.0
    for _ in range(nsub):
        # sensor bulb: exact first-order lag towards the pocket's layer
        T_g_new = T[bl] + (T_g - T[bl]) * a_b
        F_h = dahl_update(F_h, T_g_new - T_g, vp)
        T_g = T_g_new
        x_new = opening(T_g, F_h, dp, ps, p_bset, vp)
        dx = x_new - x
        if dx > 1e-9 or dx < -1e-9:
            travel += abs(dx)
            d = 1.0 if dx > 0 else -1.0
            if direction != 0.0 and d != direction:
                reversals += 1.0
            direction = d
        x = x_new
        m = flow_kgh(x, dp, vp) / 3600.0
        T_ret = coil_heat(T, nc, m, T_sup, pp[P_UA_COIL], cp, Q)
        q_coil = m * cp * (T_sup - T_ret)
        m_draw, delivered = draw_flow(draw_W, draw_T, draw_m, T[nl - 1], T_cold, cp)
        drawn_J += m_draw * cp * (T[nl - 1] - T_cold) * dt
        delivered_J += delivered * dt
        if draw_W > 0.0:
            unmet_J += (draw_W - delivered) * dt
        advection_heat(T, m_draw, T_cold, cp, Q)
        loss_J += loss_heat(T, pp[P_UA_LOSS], pp[P_T_AMB], Q) * dt
        for j in range(nl):
            T[j] += Q[j] * dt_Mcp
        buoyancy_mix(T, wsum, wcnt)
        p_w = pump_power_W(m, dp, pp[P_DP_CIRC], pp[P_Q_REF], pp[P_PUMP_EFF])
        heat_J += q_coil * dt
        pump_J += p_w * dt
        ret_mass += m * T_ret * dt
        mass += m * dt
        draw_mass += m_draw * dt
        e = T[nl - 1] - pp[P_T_TARGET]
        e2 += e * e
        eabs += abs(e)
        sh = pp[P_T_FLOOR] - T[nl - 1]
        if sh > 0.0:
            short += sh
    s[nl + S_TG] = T_g
    s[nl + S_FH] = F_h
    s[nl + S_X] = x
    s[nl + S_DIR] = direction
    step = pp[P_DT]
    acc[A_TRAVEL] += travel
    acc[A_REV] += reversals
    acc[A_DRAW] += drawn_J
    acc[A_DELIVERED] += delivered_J
    acc[A_DEMAND] += draw_W * step
    acc[A_UNMET] += unmet_J
    acc[A_LOSS] += loss_J
    acc[A_SQ] += e2 * dt
    acc[A_ABS] += eabs * dt
    acc[A_TDIS] += short * dt
    acc[A_HEAT] += heat_J
    acc[A_PUMP] += pump_J
    acc[A_RET] += ret_mass
    acc[A_MASS] += mass
    acc[A_TIME] += step
    out[O_T_TOP] = T[nl - 1]
    out[O_T_POCKET] = T[bl]
    out[O_T_BOTTOM] = T[0]
    out[O_T_SUP] = T_sup
    out[O_T_RET] = ret_mass / mass if mass > 1e-12 else T[0]
    out[O_Q_KGH] = mass / step * 3600.0
    out[O_DP] = dp
    out[O_DRAW_LMIN] = draw_mass / step * 60.0
    out[O_HEAT_W] = heat_J / step
    out[O_PUMP_W] = pump_J / step
    out[O_X] = x
    out[O_FH] = F_h
    out[O_TG] = T_g
    out[O_T_SET] = T_set
    p_kw = (heat_J + PRIMARY_ENERGY_FACTOR_ELECTRICITY * pump_J) / step / 1000.0
    return -(pp[P_W_TRACK] * e2 / nsub + pp[P_W_FLOOR] * short / nsub + pp[P_W_ENERGY] * p_kw)


# -- the environments' step: action -> plant_step -> observation --------------
# Shared by the single env (``env_step``) and the batched env
# (``env_step_batch``): both call the same ``apply_action``, ``plant_step`` and
# ``fill_obs``, so the two cannot drift apart.

MODE_SETTING, MODE_PRESSURE, MODE_DUAL = 0, 1, 2
MODE_CODES: dict[str, int] = {"setting": MODE_SETTING, "pressure": MODE_PRESSURE, "dual": MODE_DUAL}
# the observation (valve_env.envs.thermovalve.OBS_NAMES) from the step outputs
OBS_FROM_OUT = (O_T_TOP, O_T_POCKET, O_T_BOTTOM, O_T_SUP, O_T_RET, O_Q_KGH, O_DP, O_DRAW_LMIN)
N_OBS = 12
# the env's action memory ``sd``: the setting in force (degC), the dp in force (mbar)
SD_SET, SD_DP = 0, 1


@njit(cache=True)
def fill_obs(obs, out, pp, k, T_set):
    """Write the float32 observation of step index ``k`` from the step outputs."""
    for j in range(8):
        obs[j] = out[OBS_FROM_OUT[j]]
    ang = k * (2.0 * np.pi * pp[P_DT] / 86400.0)
    obs[8] = np.sin(ang)
    obs[9] = np.cos(ang)
    obs[10] = T_set
    obs[11] = pp[P_T_TARGET]


@njit(cache=True)
def apply_action(a, mode, scen, sd):
    """Put a (validated, clipped) action in force: ``sd`` <- (setting, dp).

    setting mode: the setting is the action, dp the scenario's; pressure mode:
    dp is the action, the setting stays; dual: both."""
    if mode == MODE_SETTING:
        sd[SD_SET] = a[0]
        sd[SD_DP] = scen[4]
    elif mode == MODE_PRESSURE:
        sd[SD_DP] = a[0]
    else:
        sd[SD_SET] = a[0]
        sd[SD_DP] = a[1]


@njit(cache=True)
def env_step(s, acc, out, obs, vp, pp, scen, k, a, bounds, mode, sd, work):
    """One step of one env from its raw action: validate, clip, act, simulate, observe.

    ``scen`` is the episode's (n_steps, 5) scenario, ``k`` the step index,
    ``a`` the action (float64, overwritten by its clipped value), ``bounds``
    (2, act_dim) the action box, ``sd`` the action memory (setting, dp).
    Returns (reward, status): status -1 if the action is not finite (nothing
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
    apply_action(a, mode, row, sd)
    r = plant_step(s, acc, out, vp, pp, row, sd[SD_SET], sd[SD_DP], work)
    fill_obs(obs, out, pp, k + 1, sd[SD_SET])
    return r, status


@njit(cache=True)
def _step_block(lo, hi, S, ACC, OUT, OBS, R, INFO, vp, pp, RK, RV, CUR, NRUN, K, A, mode, SD, STEP):
    """``apply_action``, ``plant_step`` and ``fill_obs`` for envs ``lo .. hi - 1``
    of the batched step, on local copies of each env's rows."""
    s = np.empty(S.shape[1])
    acc = np.empty(ACC.shape[1])
    out = np.empty(OUT.shape[1])
    obs = np.empty(OBS.shape[1], np.float32)
    row = np.empty(RV.shape[2])
    a = np.empty(A.shape[1])
    sd = np.empty(2)
    work = np.empty((3, int(pp[P_NL])))
    for i in range(lo, hi):
        if STEP[i]:
            k = K[i]
            c = CUR[i]
            while c + 1 < NRUN[i] and RK[i, c + 1] <= k:
                c += 1
            CUR[i] = c
            s[:] = S[i]
            acc[:] = ACC[i]
            row[:] = RV[i, c]
            a[:] = A[i]
            sd[SD_SET] = SD[i, SD_SET]
            sd[SD_DP] = SD[i, SD_DP]
            apply_action(a, mode, row, sd)
            R[i] = plant_step(s, acc, out, vp, pp, row, sd[SD_SET], sd[SD_DP], work)
            K[i] = k + 1
            fill_obs(obs, out, pp, k + 1, sd[SD_SET])
            S[i] = s
            ACC[i] = acc
            OUT[i] = out
            OBS[i] = obs
            SD[i, SD_SET] = sd[SD_SET]
            SD[i, SD_DP] = sd[SD_DP]
        INFO[0, i] = OUT[i, O_X]
        INFO[1, i] = OUT[i, O_FH]
        INFO[2, i] = OUT[i, O_TG]
        INFO[3, i] = OUT[i, O_HEAT_W]
        INFO[4, i] = OUT[i, O_PUMP_W]
        INFO[5, i] = K[i] * pp[P_DT]


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
def env_step_batch(S, ACC, OUT, OBS, R, INFO, vp, pp, RK, RV, CUR, NRUN, K, A_IN, bounds, A, CLIPPED, mode, SD, STEP,
                   nblocks):
    """``env_step`` over N envs (row i of every array is env i) for the envs
    with ``STEP[i]``, on numba's threads.

    The actions go through :func:`check_actions` (its return value is
    returned; nothing is stepped if an action is not finite); then the envs,
    cut into ``nblocks`` contiguous blocks, each take :func:`_step_block`
    (``apply_action``, ``plant_step`` and ``fill_obs``, exactly as the single
    env's ``env_step``). ``INFO`` (6, N) receives the info columns x, F_h, T_g,
    heat, pump and the time (s).

    Each env's scenario is run-length encoded: rows ``RV[i, :NRUN[i]]`` start
    at step indices ``RK[i, :NRUN[i]]`` (``RK[i, 0] == 0``); ``CUR[i]`` is the
    run in force, which only moves forward within an episode.

    A block works on its own copies of each env's rows: views of the shared
    arrays taken per env update the shared arrays' reference counts atomically
    from every thread, which cost more than the physics (threads gave 1.0x).
    """
    status = check_actions(A_IN, bounds, A, CLIPPED, STEP)
    if status >= 0:
        return status
    n = S.shape[0]
    block = (n + nblocks - 1) // nblocks
    for b in prange(nblocks):
        _step_block(b * block, min(n, (b + 1) * block), S, ACC, OUT, OBS, R, INFO, vp, pp, RK, RV, CUR, NRUN, K, A,
                    mode, SD, STEP)
    return status


@njit(cache=True)
def env_step_batch_serial(S, ACC, OUT, OBS, R, INFO, vp, pp, RK, RV, CUR, NRUN, K, A_IN, bounds, A, CLIPPED, mode, SD,
                          STEP):
    """:func:`env_step_batch` in one serial loop (no thread pool: for small N)."""
    status = check_actions(A_IN, bounds, A, CLIPPED, STEP)
    if status >= 0:
        return status
    _step_block(0, S.shape[0], S, ACC, OUT, OBS, R, INFO, vp, pp, RK, RV, CUR, NRUN, K, A, mode, SD, STEP)
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


def kpis_from_acc(acc: np.ndarray) -> dict[str, float]:
    """The SPEC section 5 KPIs from an accumulator vector."""
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
