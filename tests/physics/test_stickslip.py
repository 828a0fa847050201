"""The (S, J) stick-slip model (valve_env.physics.stickslip) against its defining cases
(Choudhury et al. 2005, Kano et al. 2004)."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from valve_env.physics import stickslip as ss


def _ramp_up_down() -> np.ndarray:
    return np.concatenate([np.linspace(0, 10, 101), np.linspace(9.9, 0, 100)])


def test_no_friction_is_the_identity() -> None:
    u = np.sin(np.linspace(0, 20, 500)) * 5
    assert np.array_equal(ss.simulate(u, 0.0, 0.0), u)


def test_pure_stick_slip_breaks_away_after_S_and_then_tracks() -> None:
    u = _ramp_up_down()
    y = ss.simulate(u, 3.0)  # J = S: no offset
    k = np.flatnonzero(y > 0)[0]
    assert u[k] > 3.0 and u[k - 1] <= 3.0 + 1e-12  # stuck until the input moved S away
    assert np.allclose(y[k:101], u[k:101])  # then it follows the input exactly
    # at the reversal it sticks and holds until the input has come back S
    top = y[100]
    back = np.flatnonzero(y[101:] < top)[0] + 101
    assert top - u[back] > 3.0 and top - u[back - 1] <= 3.0 + 1e-12


def test_deadband_lags_by_half_the_band() -> None:
    u = _ramp_up_down()
    y = ss.simulate(u, 2.0, 0.0)  # J = 0: backlash of width S
    assert np.allclose(y[50:100], u[50:100] - 1.0)
    assert np.allclose(y[-50:], u[-50:] + 1.0)


def test_same_direction_restart_needs_J_reversal_needs_S() -> None:
    # up, pause (sticks), up again: breaks away after J; then down: needs S
    u = np.concatenate([np.linspace(0, 5, 51), np.full(10, 5.0), np.linspace(5.1, 8, 30)])
    y = ss.simulate(u, 3.0, 1.0)
    i = 60 + np.flatnonzero(np.diff(y[60:]) > 0)[0] + 1
    assert u[i] - 5.0 > 1.0 and u[i - 1] - 5.0 <= 1.0 + 1e-12


def test_compiled_equals_python_and_end_stops_hold() -> None:
    rng = np.random.default_rng(0)
    u = np.cumsum(rng.normal(0, 0.3, 2000)) + 1.0
    py = ss.simulate(u, 0.5, 0.2, 0.0, 2.0)
    jit = njit(ss.stick_slip_path)(np.ascontiguousarray(u), 0.5, 0.2, 0.0, 2.0, np.empty_like(u))
    assert np.array_equal(py, jit)
    assert py.min() >= 0.0 and py.max() <= 2.0


def test_rest_after_a_downward_motion_is_the_mirror_image() -> None:
    # d0 = -1 (at rest after a motion downwards) on -u is the d0 = +1 path of u, mirrored
    rng = np.random.default_rng(1)
    u = np.ascontiguousarray(np.cumsum(rng.normal(0, 0.3, 2000)))
    path = njit(ss.stick_slip_path)
    up = path(u, 0.5, 0.2, -np.inf, np.inf, np.empty_like(u), 1.0)
    down = path(-u, 0.5, 0.2, -np.inf, np.inf, np.empty_like(u), -1.0)
    assert np.array_equal(down, -up)
    assert np.array_equal(up, path(u, 0.5, 0.2, -np.inf, np.inf, np.empty_like(u)))  # +1 is the default
    assert ss.initial_state(1.0, 0.5, 0.2, -np.inf, np.inf, -1.0)[0] == pytest.approx(1.15)


def test_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="S must be"):
        ss.simulate(np.zeros(3), float("nan"))
    with pytest.raises(ValueError, match="J must be"):
        ss.simulate(np.zeros(3), 1.0, -1.0)
