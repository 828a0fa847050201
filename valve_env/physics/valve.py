"""Physics of the self-acting thermostatic valve (docs/reference.md, section 1, the seed paper).

Everything here is a pure function of floats (or NumPy arrays of floats) and
of a packed parameter vector ``vp`` (see :class:`valve_env.params.ValveParams`
and :meth:`~valve_env.params.ValveParams.to_array`). The same source is used
three ways: as plain NumPy by the estimator and by users, and compiled by
numba inside the simulator's block kernel, which calls them in loops over
envs, for the single and the batched environments alike. There is one model
of the valve.

Units inside the model: mm, N, MPa (= N/mm^2), degC, s. Differential
pressures enter in mbar at the public functions and are converted here
(1 mbar = 1e-4 MPa).
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from valve_env.params import (
    I_A_B,
    I_A_K,
    I_A_S,
    I_ANT_A,
    I_ANT_B,
    I_ANT_C,
    I_C_B,
    I_C_I,
    I_C_V,
    I_DP_K_SP,
    I_DP_S_SP,
    I_F_HMAX,
    I_K_F,
    I_KVS,
    I_LEAK,
    I_SIGMA,
    I_STROKE,
)

MBAR_TO_MPA = 1.0e-4
BAR_TO_MPA = 0.1
KELVIN = 273.15
LN10 = 2.302585092994046  # 10**y = exp(LN10 y), cheaper than pow


@register_jitable
def vapour_pressure(T_C, vp):
    """Bellows charge pressure p_b(T) in MPa (Antoine: log10(p/bar) = A - B/(T/K + C))."""
    return BAR_TO_MPA * np.exp(LN10 * (vp[I_ANT_A] - vp[I_ANT_B] / (T_C + KELVIN + vp[I_ANT_C])))


@register_jitable
def vapour_pressure_slope(T_C, vp):
    """d p_b / dT in MPa/K."""
    Tk = T_C + KELVIN + vp[I_ANT_C]
    return vapour_pressure(T_C, vp) * np.log(10.0) * vp[I_ANT_B] / (Tk * Tk)


@register_jitable
def saturation_temperature(p_MPa, vp):
    """Inverse of :func:`vapour_pressure`: the temperature (degC) at which p_b = p."""
    return vp[I_ANT_B] / (vp[I_ANT_A] - np.log10(p_MPa / BAR_TO_MPA)) - vp[I_ANT_C] - KELVIN


@register_jitable
def stiffness(dp_k_mbar, vp):
    """Denominator of the force balance, C_v + C_i + C_b + K_f dp_k, in N/mm."""
    return vp[I_C_V] + vp[I_C_I] + vp[I_C_B] + vp[I_K_F] * dp_k_mbar * MBAR_TO_MPA


@register_jitable
def demanded_opening(T_g_C, F_h_N, dp_k_mbar, ps_bar, p_bset_MPa, vp):
    """Unclipped opening of the force balance (paper eq. 11/16), mm.

    ``ps_bar`` is the static pressure difference dp_s = p_1 - p_0 in bar.
    """
    return opening_at_pressure(vapour_pressure(T_g_C, vp), F_h_N, dp_k_mbar, ps_bar, p_bset_MPa, vp)


@register_jitable
def opening_at_pressure(p_b_MPa, F_h_N, dp_k_mbar, ps_bar, p_bset_MPa, vp):
    """:func:`demanded_opening` with the bellows' charge pressure ``p_b_MPa`` (:func:`vapour_pressure` of the
    gas temperature) given: a simulation that keeps the pressure along a path evaluates only this."""
    num = (
        vp[I_A_K] * (dp_k_mbar * MBAR_TO_MPA - vp[I_DP_K_SP])
        + vp[I_A_S] * (ps_bar * BAR_TO_MPA - vp[I_DP_S_SP])
        - vp[I_A_B] * (p_b_MPa - p_bset_MPa)
        + F_h_N
    )
    return num / stiffness(dp_k_mbar, vp)


@register_jitable
def opening(T_g_C, F_h_N, dp_k_mbar, ps_bar, p_bset_MPa, vp):
    """Valve opening x in mm, limited to the stroke (0 = seated, closed)."""
    x = demanded_opening(T_g_C, F_h_N, dp_k_mbar, ps_bar, p_bset_MPa, vp)
    return np.minimum(np.maximum(x, 0.0), vp[I_STROKE])


@register_jitable
def dahl_update(F_h_N, dT_K, vp):
    """Exact noise-free Dahl step (alpha = 1) for a monotone increment dT of T_g.

    F <- s F_hmax + (F - s F_hmax) exp(-sigma |dT| / F_hmax),  s = sgn(dT).
    For dT = 0 the force is unchanged. |F| <= F_hmax is preserved.
    """
    s = np.sign(dT_K)
    return dahl_relax(F_h_N, s, np.exp(-vp[I_SIGMA] * np.abs(dT_K) / vp[I_F_HMAX]), vp)


@register_jitable
def dahl_relax(F_h_N, s, decay, vp):
    """The Dahl force relaxing towards ``s F_hmax`` by the factor ``decay``:
    F <- s F_hmax + (F - s F_hmax) decay. :func:`dahl_update` with s = sgn(dT) and
    decay = exp(-sigma |dT| / F_hmax); the estimator's filter (estimation.valve_model) with a
    smooth sign and the decay it also propagates the variance with."""
    Fm = vp[I_F_HMAX]
    return s * Fm + (F_h_N - s * Fm) * decay


@register_jitable
def dahl_rate(F_h_N, v_K_per_s, vp):
    """Dahl drift dF_h/dt = v sigma (1 - F_h/F_hmax sgn(v)) in N/s (paper eq. 14)."""
    return v_K_per_s * vp[I_SIGMA] * (1.0 - F_h_N / vp[I_F_HMAX] * np.sign(v_K_per_s))


@register_jitable
def kv(x_mm, vp):
    """Linear valve characteristic Kv(x) = Kvs (l + (1 - l) x / stroke), m^3/h."""
    leak = vp[I_LEAK]
    return vp[I_KVS] * (leak + (1.0 - leak) * x_mm / vp[I_STROKE])


@register_jitable
def flow_kgh(x_mm, dp_mbar, vp):
    """Mass flow through the valve, kg/h: q = 31.62 Kv sqrt(dp / mbar) (water, 1000 kg/m^3)."""
    return 31.62 * kv(x_mm, vp) * np.sqrt(np.maximum(dp_mbar, 0.0))


@register_jitable
def opening_from_flow(q_kgh, dp_mbar, vp):
    """Invert the valve characteristic: the opening (mm) that passes q at dp.

    Used where a measured run has no x_mm column (docs/reference.md, section 2). The result is
    limited to [0, stroke].
    """
    kv_ = q_kgh / (31.62 * np.sqrt(np.maximum(dp_mbar, 1e-12)))
    leak = vp[I_LEAK]
    x = (kv_ / vp[I_KVS] - leak) / (1.0 - leak) * vp[I_STROKE]
    return np.minimum(np.maximum(x, 0.0), vp[I_STROKE])


@register_jitable
def setpoint_pressure(T_set_C, vp):
    """The bellows set pressure p_b,set (MPa) for a temperature setting T_set (degC).

    The setting spring moves the fix point so that the valve seats (x = 0) at
    T_g = T_set under the calibration pressures with no friction.
    """
    return vapour_pressure(T_set_C, vp)


@register_jitable
def setpoint_temperature(p_bset_MPa, vp):
    """The temperature setting (degC) that corresponds to p_b,set."""
    return saturation_temperature(p_bset_MPa, vp)


@register_jitable
def gain_mm_per_K(T_C, dp_k_mbar, vp):
    """Static gain -dx/dT_g of the unclipped force balance, mm/K."""
    return vp[I_A_B] * vapour_pressure_slope(T_C, vp) / stiffness(dp_k_mbar, vp)


@register_jitable
def friction_band_K(T_C, vp):
    """Half-width of the hysteresis band in temperature, F_hmax / (A_b dp_b/dT), K."""
    return vp[I_F_HMAX] / (vp[I_A_B] * vapour_pressure_slope(T_C, vp))
