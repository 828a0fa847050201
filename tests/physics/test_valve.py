"""The valve's physics against the paper's numbers and against physics."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from valve_env.params import ConfigError, ValveParams
from valve_env.physics import valve as v

VP = ValveParams().to_array()


def test_set_point_is_57_9_degC_at_calibration():
    T_sp = v.setpoint_temperature(ValveParams().p_bset, VP)
    assert T_sp == pytest.approx(57.9, abs=0.05)
    # x = 0 there, at the calibration pressures with no friction
    assert v.demanded_opening(T_sp, 0.0, 100.0, 2.0, ValveParams().p_bset, VP) == pytest.approx(0.0, abs=1e-9)


def test_gain_is_0_167_mm_per_K():
    assert v.gain_mm_per_K(57.9, 100.0, VP) == pytest.approx(0.167, abs=0.001)
    # and it is the slope of the force balance itself
    p = ValveParams().p_bset
    slope = (v.demanded_opening(57.4, 0.0, 100.0, 2.0, p, VP) - v.demanded_opening(58.4, 0.0, 100.0, 2.0, p, VP)) / 1.0
    assert slope == pytest.approx(0.167, abs=0.002)


def test_vapour_pressure_is_methanol_antoine():
    # NIST: methanol boils at 64.7 degC at 1 atm
    assert v.vapour_pressure(64.7, VP) == pytest.approx(0.101325, rel=0.01)
    assert v.saturation_temperature(v.vapour_pressure(42.0, VP), VP) == pytest.approx(42.0, abs=1e-9)


def _quasi_static_loop(T_lo: float, T_hi: float, n: int = 4000):
    """Heat slowly from T_lo to T_hi and cool back; returns branches (T, x)."""
    p = ValveParams().p_bset
    up = np.linspace(T_lo, T_hi, n)
    down = up[::-1]
    F = 0.0
    xs_up, xs_down = [], []
    Tprev = T_lo
    for T in up:
        F = v.dahl_update(F, T - Tprev, VP)
        Tprev = T
        xs_up.append(v.opening(T, F, 100.0, 2.0, p, VP))
    for T in down:
        F = v.dahl_update(F, T - Tprev, VP)
        Tprev = T
        xs_down.append(v.opening(T, F, 100.0, 2.0, p, VP))
    return up, np.array(xs_up), down, np.array(xs_down)


def test_quasi_static_sweep_draws_a_loop_0_8_K_wide():
    up, x_up, down, x_down = _quasi_static_loop(40.0, 70.0)
    # temperature at which each branch passes x = 0.2 mm, near the set point
    # (both branches decrease with T); the band scales with 1 / (dp_b/dT)
    T_heat = np.interp(0.2, x_up[::-1], up[::-1])
    T_cool = np.interp(0.2, x_down, down)
    width = T_heat - T_cool
    expected = 2 * ValveParams().F_hmax / (ValveParams().A_b * v.vapour_pressure_slope(0.5 * (T_heat + T_cool), VP))
    assert expected == pytest.approx(0.8, abs=0.05)  # "about 0.8 K" (docs/reference.md); 0.796 K exactly at 57.9 degC
    assert width == pytest.approx(expected, rel=0.02)
    # while heating the friction holds the closing valve more open
    assert T_heat > T_cool
    assert v.friction_band_K(57.9, VP) == pytest.approx(0.40, abs=0.01)


@settings(max_examples=200, deadline=None)
@given(
    F0=st.floats(-1.31, 1.31),
    path=st.lists(st.floats(-30.0, 30.0, allow_nan=False), min_size=1, max_size=60),
)
def test_friction_never_exceeds_F_hmax(F0, path):
    F = F0
    for dT in path:
        F = v.dahl_update(F, dT, VP)
        assert abs(F) <= ValveParams().F_hmax * (1 + 1e-12)


def test_dahl_update_is_the_exact_solution_of_the_ode():
    # integrate dF/dt = v sigma (1 - F/Fmax sgn v) with small Euler steps; v = 0.01 K/s for 200 s
    F_exact = v.dahl_update(-0.5, 2.0, VP)
    F = -0.5
    dt = 0.001
    for _ in range(200_000):
        F += dt * v.dahl_rate(F, 0.01, VP)
    assert F == pytest.approx(F_exact, abs=1e-4)


def test_opening_respects_stroke_and_flow_follows_kv():
    p = ValveParams().p_bset
    assert v.opening(0.0, 0.0, 100.0, 2.0, p, VP) == pytest.approx(2.0)
    assert v.opening(90.0, 0.0, 100.0, 2.0, p, VP) == 0.0
    # Kv definition: q = 31.62 Kv sqrt(dp/mbar); fully open at 100 mbar: 31.62 * 1.9 * 10
    assert v.flow_kgh(2.0, 100.0, VP) == pytest.approx(600.78)
    # leakage when seated
    assert v.flow_kgh(0.0, 100.0, VP) == pytest.approx(600.78 * 0.0002)
    x = np.linspace(0, 2, 11)
    assert np.allclose(v.opening_from_flow(v.flow_kgh(x, 80.0, VP), 80.0, VP), x)


@pytest.mark.parametrize(
    "field,value",
    [("sigma", -1.0), ("F_hmax", 0.0), ("A_b", float("nan")), ("leakage", 1.5), ("stroke", float("inf"))],
)
def test_invalid_valve_parameters_are_refused(field, value):
    with pytest.raises(ConfigError, match=field):
        ValveParams(**{field: value})
