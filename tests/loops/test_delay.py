"""The process model's fractional delay (docs/loops.md, "Model"): a first order plus dead time whose delay is not a
whole number of samples is identified, the integer-delay model is nested in it, and a delay below one sample is
admitted only with the process gain's sign (the controller's own same-sample relation has the opposite sign)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from valve_env.loops.model import Settings, fit_process


def _foptd(x: np.ndarray, gain: float, tau_s: float, delay: float, dt: float = 10.0) -> np.ndarray:
    """A first-order lag with a delay of ``delay`` samples (a fraction too), the input between its samples
    taken on the straight line (an interval-mean record's view of a delay), written independently of the model."""
    d = int(math.floor(delay))
    f = delay - d
    xd = np.concatenate([np.full(d + 1, x[0]), x])[: x.size + 1]  # xd[k + 1] = x[k - d]
    u = (1.0 - f) * xd[1:] + f * xd[:-1]
    a = math.exp(-dt / tau_s)
    return gain * lfilter([1.0 - a], [1.0, -a], u, zi=[a * u[0]])[0]


def _steps(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(20.0, 80.0, n // 7 + 1), 7)[:n]


@pytest.mark.parametrize("delay", [1.5, 2.25, 0.5])
def test_fractional_delay_is_identified_and_nests_the_integer_model(delay: float) -> None:
    x = _steps(720, 3)
    rng = np.random.default_rng(4)
    pv = _foptd(x, 0.8, 40.0, delay) + rng.normal(0.0, 0.05, x.size)
    fine = Settings(min_delay=0.25, fine_step=0.25, noise_order=0, disturbance_knot_s=math.inf)
    whole = Settings(min_delay=1.0, fine_step=1.0, noise_order=0, disturbance_knot_s=math.inf)
    assert set(whole.delays()) <= set(fine.delays())  # nested: the integer grid is part of the fractional one
    pf = fit_process(pv, x, fine)
    pi = fit_process(pv, x, whole)
    assert pf.delay == pytest.approx(delay)
    assert pf.tau_s(10.0) == pytest.approx(40.0, rel=1e-6) and pf.K == pytest.approx(0.8, rel=0.02)
    assert pi.delay == float(round(pi.delay)) and pi.delay >= 1.0
    # same samples, a nested grid: the fractional fit is at least as likely, here clearly more
    assert pf.n == pi.n and pf.loglik > pi.loglik + 20.0


def test_sub_sample_delay_needs_the_process_gain_sign() -> None:
    """A loop closed by a controller that reacts to the same sample's PV (op[k] = r[k] - kc pv[k], a process of
    delay 2 samples, driven mostly by measurement noise): the same-sample relation fits the PV better than the
    process, with a negative gain; the fit with sub-sample delays allowed still finds the process."""
    from valve_env.loops import model

    n, kc, a = 720, 1.5, math.exp(-10.0 / 40.0)
    rng = np.random.default_rng(6)
    r = 50.0 + np.repeat(rng.uniform(-0.3, 0.3, n // 30 + 1), 30)[:n]
    op = np.full(n, 50.0)
    pv = np.zeros(n)
    w = 0.0
    for k in range(n):
        w = a * w + (1.0 - a) * 0.8 * ((op[k - 2] if k >= 2 else 50.0) - 50.0)
        pv[k] = w + rng.normal(0.0, 0.3)
        op[k] = r[k] - kc * pv[k]
    fine = Settings(min_delay=0.25, fine_step=0.25, noise_order=0, disturbance_knot_s=math.inf)
    pf = fit_process(pv, op, fine)
    assert pf.delay == 2.0 and pf.K == pytest.approx(0.8, rel=0.1)
    # without the sign rule a delay of a quarter sample wins, with a negative gain: the controller
    k0 = fine.k0
    fits = []
    for aa in fine.alist():
        X = np.column_stack([model._filtered(op, aa, 0.25, False)[k0:], np.ones(n - k0)])
        theta, *_ = np.linalg.lstsq(X, pv[k0:], rcond=None)
        fits.append((float(np.sum((pv[k0:] - X @ theta) ** 2)), theta))
    rss, theta = min(fits, key=lambda t: t[0])
    assert theta[0] < 0.0 and rss < 0.5 * pf.rss
