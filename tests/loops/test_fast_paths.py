"""The loop model's fast paths compute what they define: the candidates' output-error fits from lagged moments
against the alternating least squares written plainly, one pass over the record per iteration (``_record_pass_fit``),
and the LR scan's Schur-complement solve and whole-delay moments against least squares on the delayed lag output."""

from __future__ import annotations

import math

import numpy as np
import pytest

from valve_env.loops import model
from valve_env.loops.model import Settings, scan_paths, valve_path
from valve_env.loops.sim import simulate_loop


def _record_pass_fit(pv: np.ndarray, w: np.ndarray, basis: np.ndarray, k0: int, k1: int, p: int,
                     n_iter: int) -> tuple[float, np.ndarray, float, float]:
    """The output-error fit of ``pv ~ K w + basis weights`` with AR(p <= 2) noise over samples ``k0..k1-1``:
    (K, weights) by least squares on the AR-filtered terms (with the kernels' ridge), alternated ``n_iter`` times
    with the AR filter by least squares on the residual. Returns (rss, theta, rho1, rho2)."""
    rho = np.zeros(2)
    X = np.column_stack([w, basis])
    ks = np.arange(k0, k1)
    for _ in range(1 if p == 0 else n_iter):
        Xf = X[ks] - rho[0] * X[ks - 1] - rho[1] * X[ks - 2]
        z = pv[ks] - rho[0] * pv[ks - 1] - rho[1] * pv[ks - 2]
        A = Xf.T @ Xf
        A += np.diag(1e-9 * np.diag(A) + 1e-12)
        theta = np.linalg.solve(A, Xf.T @ z)
        r = pv - X @ theta
        if p > 0:
            lags = np.column_stack([r[ks - 1], r[ks - 2]])[:, :p]
            G = lags.T @ lags + 1e-12 * np.eye(p)
            rho = np.zeros(2)
            rho[:p] = np.linalg.solve(G, lags.T @ r[ks])
    e = r[ks] - rho[0] * r[ks - 1] - rho[1] * r[ks - 2]
    return float(e @ e), theta, float(rho[0]), float(rho[1])


@pytest.fixture(scope="module")
def loop():  # type: ignore[no-untyped-def]
    lp, _ = simulate_loop("temperature", S=2.5, J=1.5, seed=31)
    return lp


@pytest.mark.parametrize("p", [0, 1, 2])
@pytest.mark.parametrize("knot_s", [1200.0, math.inf])
def test_moment_fit_is_the_record_pass_fit(loop, p: int, knot_s: float) -> None:  # type: ignore[no-untyped-def]
    s = Settings(dt=loop.dt, noise_order=p, disturbance_knot_s=knot_s)
    basis, idx, val = model._settings_basis(loop.n, s)
    x = valve_path(loop.op, 2.0, 1.0, 1.0)
    for k0, k1 in ((s.k0, loop.n), (s.k0, loop.n // 2), (loop.n // 2 + s.k0, loop.n)):
        PB, BB = model._fixed_moments(loop.pv, idx, val, basis.shape[1], k0, k1)
        for a, d, integ in ((s.alist()[2], 1.0, False), (s.alist()[5], 2.25, False), (1.0, 7.0, True)):
            w = model._filtered(x, a, d, integ)
            rss, theta, r1, r2 = _record_pass_fit(loop.pv, w, basis, k0, k1, p, s.n_iter)
            rss_m, theta_m, r1_m, r2_m = model._oe_fit_moments(loop.pv, w, idx, val, PB, BB, k0, k1, p, s.n_iter,
                                                               np.zeros(loop.n))
            assert rss_m == pytest.approx(rss, rel=1e-7)
            assert theta_m[0] == pytest.approx(theta[0], rel=1e-6)
            assert (r1_m, r2_m) == pytest.approx((r1, r2), rel=1e-6, abs=1e-9)


def _scan_reference(pv: np.ndarray, x: np.ndarray, basis: np.ndarray, s: Settings) -> float:
    """The scan's RSS of one path by least squares on the delayed lag output, dense (the whole-sample delays' best,
    then the sub-sample ones of its gain's sign; the normal equations with the kernels' ridge), as ``_scan_rss``
    defines it."""
    k0, n = s.k0, pv.size
    best, sign = math.inf, 0.0
    for sub in (False, True):
        best_k = 0.0
        lags = [(a, False) for a in s.alist()] + ([(1.0, True)] if s.allow_integrating else [])
        for a, integ in lags:
            w = np.empty(n)
            w[0] = 0.0 if integ else x[0]
            for k in range(1, n):
                w[k] = w[k - 1] + (x[k] - x.mean()) if integ else a * w[k - 1] + (1.0 - a) * x[k]
            for dly in s.delays():
                if (dly < 1.0) != sub:
                    continue
                d = int(math.floor(dly))
                f = dly - d
                wk = (1.0 - f) * w[k0 - d:n - d] + f * w[k0 - d - 1:n - d - 1]
                X = np.column_stack([wk, basis[k0:]])
                A, b = X.T @ X, X.T @ pv[k0:]
                A += np.diag(1e-9 * np.diag(A) + 1e-12)  # the kernels' ridge (a slow lag is nearly in the basis)
                theta = np.linalg.solve(A, b)
                if sub and theta[0] * sign <= 0.0:
                    continue
                rss = float(pv[k0:] @ pv[k0:] - theta @ b)
                if rss < best:
                    best, best_k = rss, theta[0]
        if not sub:
            sign = best_k
    return best


@pytest.mark.parametrize("s", [Settings(), Settings(disturbance_knot_s=math.inf), Settings(min_delay=0.25)])
def test_scan_is_least_squares_on_the_delayed_lag(loop, s: Settings) -> None:  # type: ignore[no-untyped-def]
    s = Settings(**{**s.__dict__, "dt": loop.dt})
    xs, _ = scan_paths(loop.op, 1)
    xs = xs[[0, 1, 40, 101, 144]]
    rss = model._scan_rss_paths(loop.pv, xs, s)
    basis = model._settings_basis(loop.n, s)[0]
    ref = [_scan_reference(loop.pv, x, basis, s) for x in xs]
    np.testing.assert_allclose(rss, ref, rtol=1e-6)
