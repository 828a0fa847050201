"""The tank's physics: energy conservation and stable stratification.

The functions work on a block of tanks, layers x envs; a single tank is a block of
one column (``T[:, None]``).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from valve_env.physics import tank


def _mix(T: np.ndarray) -> int:
    n, w = T.shape
    return int(tank.buoyancy_mix(T, np.zeros((n + 1, w)), np.zeros((n, w)), np.zeros(w), np.zeros(w)))


def _pool_adjacent_violators(t: np.ndarray) -> np.ndarray:
    """The isotonic regression of one tank's layers by pool-adjacent-violators (test oracle)."""
    blocks: list[list[float]] = []  # [sum, count]
    for v in t:
        blocks.append([float(v), 1.0])
        while len(blocks) > 1 and blocks[-2][0] / blocks[-2][1] > blocks[-1][0] / blocks[-1][1]:
            s, c = blocks.pop()
            blocks[-1][0] += s
            blocks[-1][1] += c
    return np.concatenate([np.full(int(c), s / c) for s, c in blocks])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 100.0, allow_nan=False), min_size=6, max_size=12))
def test_buoyancy_mixing_is_the_pool_adjacent_violators_profile(temps):
    T = np.array(temps)[:, None]
    expected = _pool_adjacent_violators(T[:, 0])
    _mix(T)
    np.testing.assert_allclose(T[:, 0], expected, rtol=1e-12, atol=1e-10)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 100.0, allow_nan=False), min_size=6, max_size=12))
def test_buoyancy_mixing_conserves_energy_and_stratifies(temps):
    T = np.array(temps)[:, None]
    E0 = T.sum()
    _mix(T)
    assert T.sum() == pytest.approx(E0, rel=1e-12, abs=1e-9)
    assert np.all(np.diff(T[:, 0]) >= -1e-9)


def test_buoyancy_mixing_leaves_a_stable_tank_alone():
    T = np.linspace(20, 60, 8)[:, None]
    T0 = T.copy()
    assert _mix(T) == 0
    assert np.array_equal(T, T0)


def test_a_block_of_tanks_equals_the_tanks_one_by_one():
    rng = np.random.default_rng(3)
    T = rng.uniform(10, 70, (8, 5))
    T[:, 1] = np.sort(T[:, 1])  # one stable tank among unstable ones
    m = rng.uniform(0.0, 0.2, 5)
    m[2] = 0.0  # no flow
    T_sup = rng.uniform(60, 80, 5)
    Qb, Tr, eps = np.zeros((8, 5)), np.zeros(5), np.zeros(5)
    tank.coil_heat(T, 4, m, T_sup, 800.0, 4180.0, Qb, Tr, eps)
    tank.advection_heat(T, m, 10.0, 4180.0, Qb)
    Tb = T.copy()
    _mix(Tb)
    for i in range(5):
        Q1, tr1, e1 = np.zeros((8, 1)), np.zeros(1), np.zeros(1)
        tank.coil_heat(T[:, i:i + 1], 4, m[i:i + 1], T_sup[i:i + 1], 800.0, 4180.0, Q1, tr1, e1)
        tank.advection_heat(T[:, i:i + 1], m[i:i + 1], 10.0, 4180.0, Q1)
        assert np.array_equal(Q1[:, 0], Qb[:, i]) and tr1[0] == Tr[i]
        T1 = T[:, i:i + 1].copy()
        _mix(T1)
        assert np.array_equal(T1[:, 0], Tb[:, i])


def _coil(T: np.ndarray, m: float, T_sup: float = 70.0) -> tuple[float, np.ndarray]:
    Q, T_ret, eps = np.zeros((T.size, 1)), np.zeros(1), np.zeros(1)
    tank.coil_heat(T[:, None], 4, np.array([m]), np.array([T_sup]), 800.0, 4180.0, Q, T_ret, eps)
    return float(T_ret[0]), Q[:, 0]


def test_coil_heat_balances_the_primary_side():
    T = np.linspace(20, 60, 8)
    m, cp = 0.1, 4180.0
    T_ret, Q = _coil(T, m)
    assert Q.sum() == pytest.approx(m * cp * (70.0 - T_ret), rel=1e-12)
    assert np.all(Q[:4] > 0) and np.all(Q[4:] == 0)
    assert T[0] < T_ret < 70.0
    # an infinitely slow flow returns at the coldest layer it passes, a fast one near supply
    assert _coil(T, 1e-6)[0] == pytest.approx(T[0], abs=1e-6)
    assert _coil(T, 100.0)[0] > 69.0
    # no flow: no heat, the return is the supply
    T_ret, Q = _coil(T, 0.0)
    assert T_ret == 70.0 and np.all(Q == 0.0)


def _draw(P: float, T_top: float) -> tuple[float, float]:
    m, q = np.zeros(1), np.zeros(1)
    tank.draw_flow(np.array([P]), np.array([40.0]), np.array([0.1]), np.array([T_top]), 10.0, 4180.0, m, q)
    return float(m[0]), float(q[0])


def test_draw_flow_mixes_down_and_reports_shortfall():
    cp, Tc = 4180.0, 10.0
    P = 0.1 * cp * (40 - Tc)  # 6 l/min at 40 degC
    m, delivered = _draw(P, 60.0)
    assert delivered == pytest.approx(P)
    assert m == pytest.approx(P / (cp * (60 - Tc)))
    m, delivered = _draw(P, 30.0)
    assert m == pytest.approx(0.1)
    assert delivered == pytest.approx(0.1 * cp * 20.0)
    # a tank no warmer than the cold water runs the tap at full flow and delivers nothing
    assert _draw(P, 10.0) == (0.1, 0.0)
    assert _draw(0.0, 60.0) == (0.0, 0.0)


def test_advection_and_losses_move_heat_out():
    T = np.linspace(20, 60, 8)[:, None]
    Q = np.zeros((8, 1))
    tank.advection_heat(T, np.array([0.1]), 10.0, 4180.0, Q)
    assert Q.sum() == pytest.approx(0.1 * 4180.0 * (10.0 - 60.0))
    Q = np.zeros((8, 1))
    total = np.zeros(1)
    tank.loss_heat(T, 2.0, 20.0, Q, total)
    assert total[0] == pytest.approx(2.0 * (T.mean() - 20.0)) and Q.sum() == pytest.approx(-total[0])
