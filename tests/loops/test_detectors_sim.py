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


def test_historian_rounds_and_compresses() -> None:
    """The historian's rounding keeps values on its grid; store-on-change keeps the first and last values and stays
    within its dead band of the signal in between (linear interpolation between the values kept)."""
    from valve_env.loops.sim import Historian

    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(size=500))
    r = Historian.record(x, 0.25, 0.0)
    assert np.allclose(r / 0.25, np.round(r / 0.25)) and np.max(np.abs(r - x)) <= 0.125 + 1e-12
    c = Historian.record(x, 0.0, 1.0)
    assert c[0] == x[0] and c[-1] == x[-1]
    assert np.max(np.abs(c - x)) < 3.5 and np.mean(np.abs(np.diff(c, 2)) < 1e-9) > 0.3  # straight stretches


@pytest.mark.parametrize("shape", ["sine", "square", "triangle", "narrowband"])
def test_external_oscillation_shapes(shape: str) -> None:
    """Every shape of external oscillation has the period asked for and an amplitude of about one."""
    from valve_env.loops.sim import _external

    x = _external(shape, 36000, 600.0, 1.0, np.random.default_rng(4))
    p = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(x.size)
    assert abs(1.0 / f[1 + np.argmax(p[1:])] - 600.0) < 60.0
    assert 0.5 < np.sqrt(2.0) * x.std() < 1.8


def test_the_plants_habits_are_off_by_default_and_change_the_record_when_on() -> None:
    """The default loop does not depend on the new options; a cascade's set point moves at every sample, the
    historian's rounding puts the PV on its grid, and a timid gain makes OP smoother."""
    base, _ = simulate_loop("flow", S=2.0, seed=5, hours=0.5)
    same, _ = simulate_loop("flow", S=2.0, seed=5, hours=0.5, kc_factor=1.0, external_shape="square")
    assert np.array_equal(base.pv, same.pv) and np.array_equal(base.op, same.op)
    from valve_env.loops.sim import Historian

    casc, _ = simulate_loop("flow", S=2.0, seed=5, hours=0.5, sp_walk_sd=0.5, historian=Historian(pv_step=0.05))
    assert np.mean(np.diff(casc.sp) != 0) > 0.5
    assert np.allclose(casc.pv / 0.05, np.round(casc.pv / 0.05))
    timid, _ = simulate_loop("flow", S=0.0, seed=5, hours=0.5, kc_factor=0.1)
    smooth, _ = simulate_loop("flow", S=0.0, seed=5, hours=0.5)
    assert np.std(np.diff(timid.op)) < np.std(np.diff(smooth.op))


def test_random_case_with_the_plants_habits_and_the_stictions_visibility() -> None:
    """``plant=True`` draws the plant's habits (the first population has none of them); its loops are valid records;
    the visibility of stiction is NaN for a valve without a band and the control error's variance ratio to the
    smooth twin for a sticky one (above 1 for a band of 4 % that limit-cycles)."""
    import math

    from valve_env.loops.sim import random_case, simulate_case, simulate_loop, stiction_visibility

    first, plant = random_case(11, kind="stiction"), random_case(11, kind="stiction", plant=True)
    assert "historian" not in first and "noise_ar" not in first
    assert {"historian", "noise_ar", "slow_load_sd", "sp_walk_sd", "kc_factor"} <= set(plant)
    loop, _ = simulate_case(plant)
    assert all(np.isfinite(v).all() for v in (loop.pv, loop.op, loop.sp)) and loop.n >= 240
    assert math.isnan(stiction_visibility(random_case(11, kind="smooth", plant=True)))
    case = {**first, "process": PROCESSES["flow"], "S": 4.0, "J": 2.0, "hours": 1.0, "dt": 10.0}
    sticky, _ = simulate_case(case)
    twin, _ = simulate_loop("flow", S=0.0, seed=case["seed"], hours=1.0, dt=10.0, tau_c_s=case["tau_c_s"],
                            sp_steps=case["sp_steps"], op0=case["op0"], ti_factor=case["ti_factor"],
                            load_tau_s=case["load_tau_s"])
    v = stiction_visibility(case, sticky)
    assert v == pytest.approx(np.var(sticky.sp - sticky.pv) / np.var(twin.sp - twin.pv)) and v > 1.0
