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

    heat from the coil = stored + standing losses + circulation + draws (+ 0 from mixing)

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
def draw_flow(P_demand_W, T_draw_C, m_tap_max, T_top, T_cold, cp, m_out, delivered_out, lo=0, hi=-1,
              m_max=np.inf):
    """Tank outflow (kg/s, into ``m_out``) and delivered power (W, into
    ``delivered_out``) for a hot-water draw, per env.

    A thermostatic mixer blends tank water with cold water to reach T_draw.
    If the tank's top is hot enough the whole demand is delivered with
    m = P / (cp (T_top - T_cold)); otherwise the tap runs at its full flow
    ``m_tap_max`` straight from the tank and delivers only
    m cp (T_top - T_cold) (nothing if the top is no warmer than the cold
    water). No demand, no flow.

    The outflow is limited to ``m_max`` (kg/s; the simulator passes
    ``EnvConfig.draw_max_kgs()``: the outlet's capacity, and what the explicit
    layer update can move in a sub-step), the delivered power in proportion.
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
        over = m > m_max
        q = q * (m_max / m) if over else q
        m = m_max if over else m
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
def circulation_return_factor(m_circ, UA_pipe, cp):
    """The fraction of its excess over the pipes' ambient that the hot-water circulation keeps round its
    loop, exp(-UA_pipe / (m cp)): a pipe at a uniform ambient cools the water exponentially along its
    length (docs/tasks.md, "ThermoValveStickyCirculation-v0"). 1 with no pipe loss; 0 with no flow."""
    return np.exp(-UA_pipe / (m_circ * cp)) if m_circ > 0.0 else 0.0


@register_jitable
def circulation_heat(T, m_circ, UA_pipe, T_amb, layer, cp, Q_out, total_out, lo=0, hi=-1):
    """The heat a hot-water circulation loop takes from the tank (W: the layers' gains added into
    ``Q_out``, each tank's loop loss added into ``total_out``).

    A circulation pump draws ``m_circ`` (kg/s, the same in every env) from the top layer (the outlet)
    round the building's pipes, heat-loss coefficient ``UA_pipe`` (W/K: the loop's length times the
    pipes' loss per metre and kelvin) to ``T_amb``; the water returns at

        T_ret = T_amb + (T_top - T_amb) exp(-UA_pipe / (m cp))

    into layer ``layer`` and displaces the layers above it upwards (the plug flow of
    :func:`advection_heat`, entering at ``layer`` instead of the bottom). A return warmer than its
    layer is left to :func:`buoyancy_mix`. Sum over layers = -m cp (T_top - T_ret), the loop's loss.
    """
    n = T.shape[0]
    c0, c1 = columns(lo, hi, T.shape[1])
    C = m_circ * cp
    a = circulation_return_factor(m_circ, UA_pipe, cp)
    for i in range(c0, c1):
        T_ret = T_amb + (T[n - 1, i] - T_amb) * a
        Q_out[layer, i] += C * (T_ret - T[layer, i])
        total_out[i] += C * (T[n - 1, i] - T_ret)
    for j in range(layer + 1, n):
        for i in range(c0, c1):
            Q_out[j, i] += C * (T[j - 1, i] - T[j, i])


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
def buoyancy_mix(T, S, R, M, flag, lo=0, hi=-1):
    """Mix any layer that is warmer than the one above it (buoyancy); returns
    the number of tanks that were mixed.

    Equal-mass layers are pooled into blocks with their mean temperature: the
    result is the closest stably stratified profile (non-decreasing upwards,
    the isotonic regression of the layers), which conserves the energy of every
    mixed block. It is computed in its min-max form,

        T_j <- max_{a <= j} min_{b >= j} mean(T_a .. T_b),

    with the block means from prefix sums: for each lowest layer ``a`` a running
    minimum over the top layer ``b`` (from the top down) updates every layer
    ``b`` at once, n (n + 1) / 2 passes over the envs that the compiler
    vectorises (the pool-adjacent-violators algorithm gives the same profile,
    but one tank at a time with branches that cannot be vectorised). Only the
    tanks that :func:`stratification_breaks` flags are written, so a stable
    tank is left exactly as it was; a block of stable tanks costs one pass.

    ``S`` (n_layers + 1, w), ``R`` (n_layers, w) and ``M`` (w,) are scratch with
    ``w >= hi - lo``; ``flag`` (n_envs,) receives the flags.
    """
    n = T.shape[0]
    c0, c1 = columns(lo, hi, T.shape[1])
    stratification_breaks(T, flag, lo, hi)
    k = 0
    for i in range(c0, c1):
        k += 1 if flag[i] != 0.0 else 0
    if k == 0:
        return 0
    for i in range(c0, c1):
        S[0, i - c0] = 0.0
        M[i - c0] = 0.0
    for j in range(n):
        for i in range(c0, c1):  # the running sum in M: rows j and j + 1 of S would look dependent
            M[i - c0] += T[j, i]
            S[j + 1, i - c0] = M[i - c0]
            R[j, i - c0] = -np.inf
    for a in range(n):
        for i in range(c0, c1):
            M[i - c0] = np.inf
        for b in range(n - 1, a, -1):
            w = 1.0 / (b - a + 1)
            for i in range(c0, c1):  # (comparisons, not min/max: numba's min/max do not vectorise)
                mean = (S[b + 1, i - c0] - S[a, i - c0]) * w
                m = mean if mean < M[i - c0] else M[i - c0]
                M[i - c0] = m
                r = R[b, i - c0]
                R[b, i - c0] = m if m > r else r
        for i in range(c0, c1):  # the block of layer a alone: its own temperature, exactly
            t = T[a, i]
            m = t if t < M[i - c0] else M[i - c0]
            r = R[a, i - c0]
            R[a, i - c0] = m if m > r else r
    for j in range(n):
        for i in range(c0, c1):
            t = T[j, i]
            T[j, i] = R[j, i - c0] if flag[i] != 0.0 else t
    return k


@register_jitable
def pump_power_W(m_dot, dp_valve_mbar, dp_circuit_mbar, q_ref_kgh, eff, rho_kg_m3=1000.0):
    """Electric power of the primary pump: V (dp_valve + dp_circuit (q/q_ref)^2) / eta."""
    q_kgh = m_dot * 3600.0
    dp_pa = (dp_valve_mbar + dp_circuit_mbar * (q_kgh / q_ref_kgh) ** 2) * 100.0
    return (m_dot / rho_kg_m3) * dp_pa / eff
