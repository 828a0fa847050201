"""The tank's physics: energy conservation and stable stratification."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from valve_env.physics import tank


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 100.0, allow_nan=False), min_size=6, max_size=12))
def test_buoyancy_mixing_conserves_energy_and_stratifies(temps):
    T = np.array(temps)
    E0 = T.sum()
    n = T.size
    tank.buoyancy_mix(T, np.zeros(n), np.zeros(n))
    assert T.sum() == pytest.approx(E0, rel=1e-12, abs=1e-9)
    assert np.all(np.diff(T) >= -1e-9)


def test_buoyancy_mixing_leaves_a_stable_tank_alone():
    T = np.linspace(20, 60, 8)
    T0 = T.copy()
    assert tank.buoyancy_mix(T, np.zeros(8), np.zeros(8)) == 0
    assert np.array_equal(T, T0)


def test_coil_heat_balances_the_primary_side():
    T = np.linspace(20, 60, 8)
    Q = np.zeros(8)
    m, cp = 0.1, 4180.0
    T_ret = tank.coil_heat(T, 4, m, 70.0, 800.0, cp, Q)
    assert Q.sum() == pytest.approx(m * cp * (70.0 - T_ret), rel=1e-12)
    assert np.all(Q[:4] > 0) and np.all(Q[4:] == 0)
    assert T[0] < T_ret < 70.0
    # an infinitely slow flow returns at the coldest layer it passes, a fast one near supply
    assert tank.coil_heat(T, 4, 1e-6, 70.0, 800.0, cp, Q) == pytest.approx(T[0], abs=1e-6)
    assert tank.coil_heat(T, 4, 100.0, 70.0, 800.0, cp, Q) > 69.0


def test_draw_flow_mixes_down_and_reports_shortfall():
    cp, Tc = 4180.0, 10.0
    P = 0.1 * cp * (40 - Tc)  # 6 l/min at 40 degC
    m, delivered = tank.draw_flow(P, 40.0, 0.1, 60.0, Tc, cp)
    assert delivered == pytest.approx(P)
    assert m == pytest.approx(P / (cp * (60 - Tc)))
    m, delivered = tank.draw_flow(P, 40.0, 0.1, 30.0, Tc, cp)
    assert m == pytest.approx(0.1)
    assert delivered == pytest.approx(0.1 * cp * 20.0)


def test_advection_moves_heat_out_of_the_top():
    T = np.linspace(20, 60, 8)
    Q = np.zeros(8)
    tank.advection_heat(T, 0.1, 10.0, 4180.0, Q)
    assert Q.sum() == pytest.approx(0.1 * 4180.0 * (10.0 - 60.0))
