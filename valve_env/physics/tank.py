"""Physics of the stratified hot-water tank heated by an internal coil.

Pure functions over a block of tanks: layer temperatures ``T`` of shape
(n_layers, n_envs), row 0 the bottom layer, row ``n_layers - 1`` the top layer
(the outlet), one column per environment; per-environment quantities are
vectors of length n_envs. A single tank is the block with one column
(``T[:, None]``). ``lo`` and ``hi`` select the columns ``lo .. hi - 1`` to work
on (default: all). NumPy and numba compatible.

The block layout is for speed: every function is a loop over layers around a
loop over environments, which the compiler vectorises (4 envs per instruction
with AVX2). Every heat flow is computed once and applied once, so the first
law closes to rounding:

    heat from the coil = stored + standing losses + draws (+ 0 from mixing)

Units: degC, W, J, kg, kg/s, s.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from valve_env.physics.fexp import fexp


@register_jitable
def columns(lo, hi, n):
    """The column range ``lo .. hi - 1`` (``hi < 0``: to the last of ``n``) as unsigned
    integers: indices the compiler knows are not negative need no wrap-around
    code, which would keep it from vectorising the loops."""
    return np.uint64(lo), np.uint64(n if hi < 0 else hi)


@register_jitable
def coil_heat(T, coil_layers, m_dot, T_sup, UA_coil, cp, Q_out, T_ret_out, eps_out, lo=0, hi=-1):
    """Heat the coil gives each layer (W, written into ``Q_out``, shape of ``T``).

    The coil spans the lowest ``coil_layers`` layers; primary water enters at
    the top of the coil and leaves at its bottom. Each coil segment exchanges
    heat with its layer by effectiveness-NTU with a uniform layer temperature
    (C_min = the primary flow's capacity rate C = m cp):
    eps = 1 - exp(-UA_seg / C), Q = eps C (T_in - T_layer), T_out = T_in - eps (T_in - T_layer).

    ``m_dot`` and ``T_sup`` are per env; writes the primary return temperature
    into ``T_ret_out`` and the segments' effectiveness into ``eps_out``. With
    no flow (C <= 1e-12) the coil gives no heat and returns ``T_sup``.
    """
    n = T.shape[0]
    c0, c1 = columns(lo, hi, T.shape[1])
    UA_seg = UA_coil / coil_layers
    for i in range(c0, c1):
        C = m_dot[i] * cp
        eps_out[i] = 1.0 - fexp(-UA_seg / C) if C > 1e-12 else 0.0
        T_ret_out[i] = T_sup[i]
    for j in range(coil_layers - 1, -1, -1):
        for i in range(c0, c1):
            d = T_ret_out[i] - T[j, i]
            Q_out[j, i] = eps_out[i] * (m_dot[i] * cp) * d
            T_ret_out[i] -= eps_out[i] * d
    for j in range(coil_layers, n):
        for i in range(c0, c1):
            Q_out[j, i] = 0.0


@register_jitable
def draw_flow(P_demand_W, T_draw_C, m_tap_max, T_top, T_cold, cp, m_out, delivered_out, lo=0, hi=-1):
    """Tank outflow (kg/s, into ``m_out``) and delivered power (W, into
    ``delivered_out``) for a hot-water draw, per env.

    A thermostatic mixer blends tank water with cold water to reach T_draw.
    If the tank's top is hot enough the whole demand is delivered with
    m = P / (cp (T_top - T_cold)); otherwise the tap runs at its full flow
    ``m_tap_max`` straight from the tank and delivers only
    m cp (T_top - T_cold) (nothing if the top is no warmer than the cold
    water). No demand, no flow.
    """
    c0, c1 = columns(lo, hi, T_top.shape[0])
    for i in range(c0, c1):
        P = P_demand_W[i]
        dT_top = T_top[i] - T_cold
        warm = dT_top > 1e-9
        hot = warm and T_top[i] >= T_draw_C[i]
        m_hot = P / (cp * dT_top) if warm else 0.0
        m = m_hot if hot else m_tap_max[i]
        q = P if hot else (m_tap_max[i] * cp * dT_top if warm else 0.0)
        m_out[i] = m if P > 0.0 else 0.0
        delivered_out[i] = q if P > 0.0 else 0.0


@register_jitable
def advection_heat(T, m_dot, T_cold, cp, Q_out, lo=0, hi=-1):
    """Heat each layer gains (W, added into ``Q_out``) from the plug flow of a
    draw ``m_dot`` (per env): cold water enters the bottom, each layer is
    displaced upwards, the top layer leaves through the outlet.
    Sum over layers = m cp (T_cold - T_top)."""
    n = T.shape[0]
    c0, c1 = columns(lo, hi, T.shape[1])
    for i in range(c0, c1):
        Q_out[0, i] += m_dot[i] * cp * (T_cold - T[0, i])
    for j in range(1, n):
        for i in range(c0, c1):
            Q_out[j, i] += m_dot[i] * cp * (T[j - 1, i] - T[j, i])


@register_jitable
def loss_heat(T, UA_loss, T_amb, Q_out, total_out, lo=0, hi=-1):
    """Standing losses to ambient, spread evenly over the layers (W, subtracted
    from ``Q_out``); writes each tank's total loss (W) into ``total_out``."""
    n = T.shape[0]
    c0, c1 = columns(lo, hi, T.shape[1])
    UA_l = UA_loss / n
    for i in range(c0, c1):
        total_out[i] = 0.0
    for j in range(n):
        for i in range(c0, c1):
            q = UA_l * (T[j, i] - T_amb)
            Q_out[j, i] -= q
            total_out[i] += q


@register_jitable
def stratification_breaks(T, flag_out, lo=0, hi=-1):
    """``flag_out[i]`` = 1.0 where tank ``i`` has a layer warmer than the one above it, else 0.0."""
    n = T.shape[0]
    c0, c1 = columns(lo, hi, T.shape[1])
    for i in range(c0, c1):
        flag_out[i] = 0.0
    for j in range(n - 1):
        for i in range(c0, c1):
            flag_out[i] = 1.0 if T[j, i] > T[j + 1, i] else flag_out[i]


@register_jitable
def buoyancy_mix(T, work_sum, work_cnt, flag, lo=0, hi=-1):
    """Mix any layer that is warmer than the one above it (buoyancy).

    Equal-mass layers are pooled into blocks with their mean temperature by the
    pool-adjacent-violators algorithm: the result is the closest stably
    stratified profile (non-decreasing upwards) and conserves the energy of
    every mixed block exactly. ``work_sum``/``work_cnt`` are scratch vectors of
    length n_layers, ``flag`` one of length n_envs (see
    :func:`stratification_breaks`: only the tanks it flags are visited).
    Returns the number of layers that were mixed, over all tanks.
    """
    n = T.shape[0]
    c0, c1 = columns(lo, hi, T.shape[1])
    stratification_breaks(T, flag, lo, hi)
    mixed = 0
    for i in range(c0, c1):
        if flag[i] == 0.0:
            continue
        j0 = 0  # the lowest inversion; below it the profile is already stable
        while T[j0, i] <= T[j0 + 1, i]:
            j0 += 1
        for j in range(j0):
            work_sum[j] = T[j, i]
            work_cnt[j] = 1.0
        nb = j0
        for j in range(j0, n):
            work_sum[nb] = T[j, i]
            work_cnt[nb] = 1.0
            nb += 1
            # block means compared by cross-multiplication (sum_a / n_a > sum_b / n_b)
            while nb > 1 and work_sum[nb - 2] * work_cnt[nb - 1] > work_sum[nb - 1] * work_cnt[nb - 2]:
                work_sum[nb - 2] += work_sum[nb - 1]
                work_cnt[nb - 2] += work_cnt[nb - 1]
                nb -= 1
        j = 0
        for b in range(nb):
            c = int(work_cnt[b])
            mean = work_sum[b] / work_cnt[b]
            for _ in range(c):
                T[j, i] = mean
                j += 1
        mixed += n - nb
    return mixed


@register_jitable
def pump_power_W(m_dot, dp_valve_mbar, dp_circuit_mbar, q_ref_kgh, eff, rho_kg_m3=1000.0):
    """Electric power of the primary pump: V (dp_valve + dp_circuit (q/q_ref)^2) / eta."""
    q_kgh = m_dot * 3600.0
    dp_pa = (dp_valve_mbar + dp_circuit_mbar * (q_kgh / q_ref_kgh) ** 2) * 100.0
    return (m_dot / rho_kg_m3) * dp_pa / eff
