"""``fexp``, the physics' vectorisable exponential, against the C library's exp."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from valve_env.physics.fexp import fexp


@njit(error_model="numpy")
def _fexp_loop(x: np.ndarray, out: np.ndarray) -> None:
    for i in range(x.shape[0]):
        out[i] = fexp(x[i])


def _ulps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a - b) / np.spacing(np.abs(b))


def test_fexp_is_within_one_ulp_of_libm_over_the_range() -> None:
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-708, 709, 200_000), rng.uniform(-1, 1, 100_000), [0.0, 1.0, -1.0, 1e-300]])
    y = np.empty_like(x)
    _fexp_loop(x, y)
    ref = np.array([math.exp(v) for v in x])
    assert _ulps(y, ref).max() <= 1.0
    assert y[-4] == 1.0 and y[-1] == 1.0


def test_compiled_and_interpreted_fexp_agree_bit_for_bit() -> None:
    x = np.random.default_rng(1).uniform(-50, 50, 5000)
    y = np.empty_like(x)
    _fexp_loop(x, y)
    assert np.array_equal(y, fexp(x))  # NumPy arrays, interpreted
    assert all(float(fexp(float(v))) == w for v, w in zip(x[:200], y[:200], strict=True))  # Python floats


def test_fexp_clamps_and_propagates_nan() -> None:
    x = np.array([-1e6, 1e6, np.nan])
    y = np.empty(3)
    _fexp_loop(x, y)
    assert y[0] == fexp(-708.0) and 0.0 < y[0] < 1e-307
    assert y[1] == fexp(709.0) and np.isfinite(y[1])
    assert np.isnan(y[2]) and np.isnan(fexp(np.array([np.nan]))[0])
