"""Physics of the stratified hot-water tank heated by an internal coil.

Pure functions over arrays of layer temperatures (index 0 = bottom layer,
``n - 1`` = top layer, the outlet), NumPy and numba compatible. Every heat
flow is computed once and applied once, so the first law closes to rounding:

    heat from the coil = stored + standing losses + draws (+ 0 from mixing)

Units: degC, W, J, kg, kg/s, s.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable


@register_jitable
def coil_heat(T, coil_layers, m_dot, T_sup, UA_coil, cp, Q_out):
    """Heat the coil gives each layer (W, written into ``Q_out``); returns the
    primary return temperature.

    The coil spans the lowest ``coil_layers`` layers; primary water enters at
    the top of the coil and leaves at its bottom. Each coil segment exchanges
    heat with its layer by effectiveness-NTU with a uniform layer temperature
    (C_min = the primary flow's capacity rate):
    eps = 1 - exp(-UA_seg / (m cp)), Q = eps m cp (T_in - T_layer).
    """
    n = T.shape[0]
    for j in range(n):
        Q_out[j] = 0.0
    Tp = T_sup
    C = m_dot * cp
    if C <= 1e-12:
        return Tp
    UA_seg = UA_coil / coil_layers
    eps = 1.0 - np.exp(-UA_seg / C)
    for j in range(coil_layers - 1, -1, -1):
        Q = eps * C * (Tp - T[j])
        Q_out[j] = Q
        Tp = Tp - Q / C
    return Tp


@register_jitable
def draw_flow(P_demand_W, T_draw_C, m_tap_max, T_top, T_cold, cp):
    """Tank outflow (kg/s) and delivered power (W) for a hot-water draw.

    A thermostatic mixer blends tank water with cold water to reach T_draw.
    If the tank's top is hot enough the whole demand is delivered with
    m = P / (cp (T_top - T_cold)); otherwise the tap runs at its full flow
    ``m_tap_max`` straight from the tank and delivers only
    m cp (T_top - T_cold). Returns (m_tank, delivered_W).
    """
    if P_demand_W <= 0.0:
        return 0.0, 0.0
    dT_top = T_top - T_cold
    if dT_top <= 1e-9:
        return m_tap_max, 0.0
    if T_top >= T_draw_C:
        m = P_demand_W / (cp * dT_top)
        return m, P_demand_W
    return m_tap_max, m_tap_max * cp * dT_top


@register_jitable
def advection_heat(T, m_dot, T_cold, cp, Q_out):
    """Heat each layer gains (W, added into ``Q_out``) from the plug flow of a
    draw: cold water enters the bottom, each layer is displaced upwards, the
    top layer leaves through the outlet. Sum = m cp (T_cold - T_top)."""
    n = T.shape[0]
    T_below = T_cold
    for j in range(n):
        Q_out[j] += m_dot * cp * (T_below - T[j])
        T_below = T[j]


@register_jitable
def loss_heat(T, UA_loss, T_amb, Q_out):
    """Standing losses to ambient, spread evenly over the layers (W, subtracted
    from ``Q_out``); returns the total loss in W."""
    n = T.shape[0]
    UA_l = UA_loss / n
    total = 0.0
    for j in range(n):
        q = UA_l * (T[j] - T_amb)
        Q_out[j] -= q
        total += q
    return total


@register_jitable
def buoyancy_mix(T, work_sum, work_cnt):
    """Mix any layer that is warmer than the one above it (buoyancy).

    Equal-mass layers are pooled into blocks with their mean temperature by the
    pool-adjacent-violators algorithm: the result is the closest stably
    stratified profile (non-decreasing upwards) and conserves the energy of
    every mixed block exactly. ``work_sum``/``work_cnt`` are scratch arrays of
    the same length as ``T``. Returns the number of layers that were mixed.
    """
    n = T.shape[0]
    j0 = -1  # the lowest inversion; below it the profile is already stable
    for j in range(n - 1):
        if T[j] > T[j + 1]:
            j0 = j
            break
    if j0 < 0:
        return 0
    for j in range(j0):
        work_sum[j] = T[j]
        work_cnt[j] = 1.0
    nb = j0
    for j in range(j0, n):
        work_sum[nb] = T[j]
        work_cnt[nb] = 1.0
        nb += 1
        # block means compared by cross-multiplication (sum_a / n_a > sum_b / n_b)
        while nb > 1 and work_sum[nb - 2] * work_cnt[nb - 1] > work_sum[nb - 1] * work_cnt[nb - 2]:
            work_sum[nb - 2] += work_sum[nb - 1]
            work_cnt[nb - 2] += work_cnt[nb - 1]
            nb -= 1
    if nb == n:
        return 0
    j = 0
    for b in range(nb):
        c = int(work_cnt[b])
        mean = work_sum[b] / work_cnt[b]
        for _ in range(c):
            T[j] = mean
            j += 1
    return n - nb


@register_jitable
def pump_power_W(m_dot, dp_valve_mbar, dp_circuit_mbar, q_ref_kgh, eff, rho_kg_m3=1000.0):
    """Electric power of the primary pump: V (dp_valve + dp_circuit (q/q_ref)^2) / eta."""
    q_kgh = m_dot * 3600.0
    dp_pa = (dp_valve_mbar + dp_circuit_mbar * (q_kgh / q_ref_kgh) ** 2) * 100.0
    return (m_dot / rho_kg_m3) * dp_pa / eff
