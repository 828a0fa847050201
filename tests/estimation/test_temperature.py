"""The IRW-RTS temperature smoother recovers the measurement noise (docs/estimation.md, "Temperature
pre-processing")."""

from __future__ import annotations

import numpy as np
import pytest

from valve_env.valveid.temperature import smooth_temperature

NOISE = 0.002  # K, the generated channel's white measurement noise


def _heated_tank(dt: float = 20.0, hours: float = 8.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tank heated 20 min in each hour (first-order towards 75 degC, time constant 30 min) and cooling
    towards 45 degC (60 min) otherwise: the rate jumps at every switch (a kink of the temperature). Exact
    first-order solution on a 1 s grid, sampled every ``dt``; returns (t, true T, measured T)."""
    fine = np.arange(0.0, hours * 3600.0 + dt, 1.0)
    on = (fine % 3600.0) < 1200.0
    target = np.where(on, 75.0, 45.0)
    decay = np.where(on, np.exp(-1.0 / 1800.0), np.exp(-1.0 / 3600.0))
    x = np.empty_like(fine)
    x[0] = 50.0
    for k in range(1, len(fine)):
        x[k] = target[k] + (x[k - 1] - target[k]) * decay[k]
    t = np.arange(0.0, hours * 3600.0, dt)
    true = np.interp(t, fine, x)
    return t, true, true + NOISE * np.random.default_rng(seed).standard_normal(len(t))


@pytest.mark.parametrize("seed", [0, 1])
def test_smoother_recovers_the_noise_sd_and_does_not_collapse(seed: int) -> None:
    # the former smoother (reweighted Gaussian passes, q and r by Nelder-Mead) returned s ~ 1e-11 K here: the raw
    # reading as the "smoothed" temperature
    t, true, y = _heated_tank(seed=seed)
    level, rate, s, _ = smooth_temperature(t, y)
    assert 0.7 * NOISE < s < 1.3 * NOISE
    assert np.std(y - level) > 0.5 * NOISE  # not the raw reading
    assert np.sqrt(np.mean((level - true) ** 2)) < 0.6 * NOISE  # and closer to the truth than the reading


def test_smoother_keeps_the_heating_kink() -> None:
    # no spurious lead: just before the heater switches on, the smoothed rate is still the cooling rate (a
    # Gaussian random walk of the rate would round the kink and start rising early)
    t, true, y = _heated_tank(dt=10.0)
    _, rate, _, _ = smooth_temperature(t, y)
    true_rate = np.gradient(true, t)
    heat = np.flatnonzero((t % 3600.0 == 0.0) & (t > 0))
    before = heat - 2
    jump = true_rate[heat + 2] - true_rate[before]
    assert np.all(np.abs(rate[before] - true_rate[before]) < 0.1 * jump)


def test_the_compiled_em_sums_as_numpy_does() -> None:
    """The smoother's EM runs compiled; its one sum (the M-step's q) is NumPy's pairwise summation, so its figures
    are those of the NumPy loop it replaced to the last digit. A plain running sum differs in the last bits on most
    of these arrays, which a long EM carries into the smoothed temperatures."""
    from valve_env.valveid.temperature import _pairwise_sum

    rng = np.random.default_rng(7)
    lengths = [0, 1, 7, 8, 9, 127, 128, 129, 255, 256, 1000, 8639, 8640, 86399, 200001]
    plain_differs = 0
    for n in lengths:
        a = rng.standard_normal(n) * np.exp(3.0 * rng.standard_normal(n))
        assert _pairwise_sum(a, 0, n) == np.sum(a), n
        plain_differs += float(np.cumsum(a)[-1]) != float(np.sum(a)) if n else 0
        if n > 10:  # a part of an array, as the M-step sums e[1:]
            assert _pairwise_sum(a, 1, n - 1) == np.sum(a[1:]), n
    assert plain_differs > 0  # the order matters on these arrays
