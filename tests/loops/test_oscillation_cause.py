"""The cause of an oscillation that is not named stiction (docs/loops.md, "Oscillation causes"):
``aggressive_tuning`` only when the fitted linear process, closed by the controller identified from the record,
rings at the observed period; a loop-internal oscillation that the linear loop damps is ``nonlinear_oscillation``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from valve_env.loops.diagnose import closed_loop, diagnose, rings
from valve_env.loops.envloop import record_env_loop
from valve_env.loops.io import LoopData

DT = 10.0
TAU_S = 80.0
DELAY = 3  # samples
TI_S = 200.0


def _pi_loop(kc: float, n: int = 720, seed: int = 0, noise: float = 0.05, load: float = 0.002,
             exact: bool = False) -> LoopData:
    """A linear loop: first-order process (gain 1, tau 80 s, 3 samples' delay), a velocity-form PI acting on the
    previous sample's error (as ``record_env_loop`` records it), a slow load random walk and white PV noise.
    ``exact``: no noise or load, a unit step into the process state at sample 10 (the free response)."""
    rng = np.random.default_rng(seed)
    a = math.exp(-DT / TAU_S)
    op = np.full(n, 50.0)
    w = np.zeros(n)
    pv = np.zeros(n)
    drift = 0.0
    for k in range(1, n):
        drift += 0.0 if exact else load * rng.standard_normal()
        u = op[k - DELAY] if k >= DELAY else op[0]
        w[k] = a * w[k - 1] + (1 - a) * (u - 50.0)
        if exact and k == 10:
            w[k] += 1.0  # a step into the process state: the loop then rings freely
        pv[k] = w[k] + drift + (0.0 if exact else noise * rng.standard_normal())
        if k >= 2:
            op[k] = op[k - 1] + kc * ((pv[k - 2] - pv[k - 1]) + DT / TI_S * -pv[k - 1])
    return LoopData(time_s=np.arange(n) * DT, sp=np.zeros(n), pv=pv, op=op, tag="pi-synthetic", source="test")


def test_aggressive_pi_rings_and_is_named() -> None:
    kc = 3.5
    loop = _pi_loop(kc)
    d = diagnose(loop)
    assert d.cause == "aggressive_tuning"
    cl = d.result["oscillation"]["closed_loop"]
    # the controller is identified from the record: dOP[k] = Kc (1 + dt/Ti) e[k-1] - Kc e[k-2]
    assert cl["controller_fit_r2"] > 0.99
    np.testing.assert_allclose(cl["controller_coefs"], [0.0, kc * (1 + DT / TI_S), -kc], atol=0.05 * kc)
    # the closed loop's free response, simulated without noise, rings with the identified mode's period
    free = _pi_loop(kc, n=400, exact=True).pv[10:]
    ups = np.flatnonzero((free[:-1] < 0) & (free[1:] >= 0))
    period = float(np.mean(np.diff(ups))) * DT
    mode = cl["modes"][0]
    assert mode["period_s"] == pytest.approx(period, rel=0.15)
    assert mode["decay_per_cycle"] >= 0.3
    assert rings(cl, d.result["oscillation"]["period_s"])


def test_calm_pi_does_not_ring() -> None:
    """A gentle PI on the same process: the identified closed loop's modes decay fast."""
    loop = _pi_loop(0.8)
    cl = closed_loop(loop, diagnose(loop).fits["linear"].process)
    assert cl["controller_fit_r2"] > 0.99
    assert not rings(cl, 130.0)


def test_env_sticky_stem_is_not_called_aggressive_tuning() -> None:
    """Development seed 6 of the mid-stroke task (Kp 5, Ti 1500 s): the sticky stem's cycle is not named
    stiction (weak likelihood evidence, docs/loops.md) and used to be called aggressive_tuning; the identified
    linear loop damps its 43 min cycle (decay per cycle about 0.04), so it is a nonlinear oscillation."""
    loop = record_env_loop(0.1, seed=6, env_id="ThermoValveStickyCirculation-v0", Kp=5.0, Ti_s=1500.0)
    d = diagnose(loop)
    assert d.result["oscillation"]["oscillating"]
    assert d.cause == "nonlinear_oscillation"
    assert d.result["oscillation"]["closed_loop"]["controller_fit_r2"] > 0.99


def test_process_transfer_is_the_simulated_process() -> None:
    """``ProcessFit.transfer`` (what closed_loop closes the controller around) is the recursion the model simulates:
    filtered by scipy from rest, a path that starts at rest gives model.simulate's output exactly, fractional delay
    included."""
    from scipy.signal import lfilter

    from valve_env.loops.model import ProcessFit, simulate

    rng = np.random.default_rng(3)
    x = np.concatenate([np.zeros(5), np.cumsum(rng.standard_normal(400))])
    for a, delay in ((0.9, 2.25), (0.6, 1.0), (0.95, 3.75)):
        pf = ProcessFit(a, delay, False, 1.7, np.zeros(1), np.zeros((x.size, 1)), (0.0, 0.0), 0.0, x.size, 3)
        num, den = pf.transfer()
        np.testing.assert_allclose(lfilter(num, den, x), simulate(x, pf), rtol=1e-12, atol=1e-12)
