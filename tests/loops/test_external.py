"""External oscillation (docs/loops.md, "Tenth session: external oscillation"): a stiction finding on an oscillating
record must also hold when every valve candidate carries a sinusoidal load at the oscillation's period, so an
external sinusoid is not read as a sticky valve, while a sticky valve under the same kind of load is still named."""

from __future__ import annotations

import math

import numpy as np

from valve_env.loops.diagnose import diagnose
from valve_env.loops.model import disturbance_basis, dominant_period
from valve_env.loops.sim import simulate_loop


def test_dominant_period_and_basis() -> None:
    rng = np.random.default_rng(0)
    n, dt = 720, 10.0
    t = np.arange(n) * dt
    r = 0.8 * np.sin(2 * np.pi * t / 617.0 + 0.4) + 0.002 * t + rng.normal(0.0, 0.3, n)
    p = dominant_period(r, dt, near_s=500.0)
    assert abs(p - 617.0) / 617.0 < 0.01
    plain = disturbance_basis(n, dt, 1200.0)
    periodic = disturbance_basis(n, dt, 1200.0, p)
    assert periodic.shape == (n, plain.shape[1] + 2)
    np.testing.assert_array_equal(periodic[:, :-2], plain)
    # a sinusoid of that period lies in the basis's span
    coef, *_ = np.linalg.lstsq(periodic, np.cos(2 * np.pi * t / p - 1.0), rcond=None)
    assert np.max(np.abs(periodic @ coef - np.cos(2 * np.pi * t / p - 1.0))) < 1e-9


def test_external_sinusoid_is_not_stiction_and_sticky_still_is() -> None:
    # the smooth twin of benchmark seed 6607 (a level loop) under a 600 s sinusoid: the ninth session's false alarm
    smooth, _ = simulate_loop("level", S=0.0, seed=16607, external_amp=1.0, external_period_s=600.0)
    d = diagnose(smooth)
    assert d.cause != "stiction"
    # the fourth condition ran, so the plain comparison justified stiction (the unchanged decision's false alarm),
    # and the periodic load withdrew it
    pl = d.result["decision"]["periodic_load"]
    assert not pl["justified"] and abs(pl["period_s"] - 600.0) < 12.0
    # benchmark seed 6611's sticky level loop under its external-set sinusoid (593 s, 0.92 %)
    sticky, truth = simulate_loop("level", S=2.8324845918016637, J=2.428601752728236, seed=6611,
                                  external_amp=0.9229448089289031, external_period_s=593.0360684141019)
    d = diagnose(sticky)
    assert d.cause == "stiction" and d.result["decision"]["periodic_load"]["justified"]
    assert math.isclose(d.result["stiction"]["band_pct"], truth.S, rel_tol=0.2)
