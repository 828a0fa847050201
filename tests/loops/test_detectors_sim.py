"""The classical detectors on shapes they were designed for, and the simulated-loop generator."""

from __future__ import annotations

import numpy as np
import pytest

from valve_env.loops.detectors import he_curve_fit, horch, kano
from valve_env.loops.io import LoopData
from valve_env.loops.sim import PROCESSES, simulate_loop


def _loop(op: np.ndarray, pv: np.ndarray) -> LoopData:
    n = op.size
    return LoopData(time_s=np.arange(n) * 10.0, sp=np.zeros(n), pv=pv, op=op)


def test_he_tells_triangle_from_sine() -> None:
    t = np.arange(720)
    tri = 2 * np.abs((t / 40.0) % 2 - 1) - 1
    sine = np.sin(np.pi * t / 40.0)
    assert he_curve_fit(_loop(50 + 3 * tri, sine))["statistic"] > 0.6
    assert he_curve_fit(_loop(50 + 3 * sine, sine))["statistic"] < 0.4


def test_horch_even_vs_odd_cross_correlation() -> None:
    t = np.arange(720)
    op = np.sin(2 * np.pi * t / 80.0)
    in_phase = horch(_loop(op, -op))        # extremum at lag 0: not stiction
    quarter = horch(_loop(op, np.cos(2 * np.pi * t / 80.0)))  # odd: stiction
    assert not in_phase["stiction"] and in_phase["statistic"] < 60 and in_phase["ratio"] > 0.95
    assert quarter["stiction"] and quarter["statistic"] > 120 and quarter["ratio"] < 0.2
    # an integrating process: PV is the integral of OP (a quarter period behind) - odd on PV, even on its increments
    level = np.cumsum(op)
    assert horch(_loop(op, level))["stiction"]
    assert not horch(_loop(op, level), integrating=True)["stiction"]
    # white noise fed back with one sample's delay: no resolved cycle, no verdict of stiction
    rng = np.random.default_rng(1)
    noise = rng.normal(size=720)
    assert not horch(_loop(-np.roll(noise, 1), noise))["stiction"]


def test_kano_sees_a_stuck_valve() -> None:
    rng = np.random.default_rng(0)
    op = 50 + 3 * np.sin(2 * np.pi * np.arange(720) / 120.0)
    pv_stuck = np.repeat(op[::30], 30)[:720] + rng.normal(0, 0.01, 720)   # PV holds while OP moves
    pv_free = op + rng.normal(0, 0.01, 720)
    assert kano(_loop(op, pv_stuck))["stiction"]
    assert not kano(_loop(op, pv_free))["stiction"]


@pytest.mark.parametrize("process", sorted(PROCESSES))
def test_generator_sticky_valve_holds_while_op_moves(process: str) -> None:
    loop, truth = simulate_loop(process, S=3.0, J=1.5, seed=7)
    assert loop.n == 720 and loop.dt == 10.0
    assert truth.label == "stiction" and truth.S == 3.0
    assert loop.mv is not None
    # the recorded valve position moves less often than the controller output
    assert np.mean(np.abs(np.diff(loop.mv)) < 1e-9) > np.mean(np.abs(np.diff(loop.op)) < 1e-9)
    smooth, t0 = simulate_loop(process, S=0.0, seed=7)
    np.testing.assert_allclose(smooth.mv, smooth.op)
    assert t0.label == "none"
