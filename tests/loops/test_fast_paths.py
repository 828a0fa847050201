"""The loop model's fast paths compute what the paths they replaced computed: the
candidates' output-error fits from lagged moments against the record-pass fit (``_oe_fit``), the LR
scan's Schur-complement solve and whole-delay moments against least squares on the delayed lag output, and the fit
memo against fitting afresh."""

from __future__ import annotations

import math

import numpy as np
import pytest

from valve_env.loops import model
from valve_env.loops.model import Settings, fit_valve, scan_paths, valve_path
from valve_env.loops.sim import simulate_loop


@pytest.fixture(scope="module")
def loop():  # type: ignore[no-untyped-def]
    lp, _ = simulate_loop("temperature", S=2.5, J=1.5, seed=31)
    return lp


@pytest.mark.parametrize("p", [0, 1, 2])
@pytest.mark.parametrize("period", [math.inf, 700.0])
def test_moment_fit_is_the_record_pass_fit(loop, p: int, period: float) -> None:  # type: ignore[no-untyped-def]
    s = Settings(dt=loop.dt, noise_order=p, load_period_s=period)
    basis, idx, val = model._settings_basis(loop.n, s)
    x = valve_path(loop.op, 2.0, 1.0, 1.0)
    for k0, k1 in ((s.k0, loop.n), (s.k0, loop.n // 2), (loop.n // 2 + s.k0, loop.n)):
        PB, BB = model._fixed_moments(loop.pv, idx, val, basis.shape[1], k0, k1)
        for a, d, integ in ((s.alist()[2], 1.0, False), (s.alist()[5], 2.25, False), (1.0, 7.0, True)):
            w = model._filtered(x, a, d, integ)
            rss, theta, r1, r2 = model._oe_fit(loop.pv, w, basis, k0, k1, p, s.n_iter)
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


@pytest.mark.parametrize("s", [Settings(), Settings(load_period_s=900.0), Settings(min_delay=0.25)])
def test_scan_is_least_squares_on_the_delayed_lag(loop, s: Settings) -> None:  # type: ignore[no-untyped-def]
    s = Settings(**{**s.__dict__, "dt": loop.dt})
    xs, _ = scan_paths(loop.op, 1, float(np.quantile(loop.op, 0.2)))
    xs = xs[[0, 1, 40, 101, 144]]
    rss = model._scan_rss_paths(loop.pv, xs, s)
    basis = model._settings_basis(loop.n, s)[0]
    ref = [_scan_reference(loop.pv, x, basis, s) for x in xs]
    np.testing.assert_allclose(rss, ref, rtol=1e-6)


def test_fit_memo_gives_the_same_fits(loop, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    s = Settings(dt=loop.dt, n_grid=6)
    calls = []
    fit = model.fit_process
    monkeypatch.setattr(model, "fit_process", lambda *a, **k: calls.append(1) or fit(*a, **k))
    memo: model.FitMemo = {}
    shared = [fit_valve(loop.op, loop.pv, v, s, memo=memo) for v in ("backlash", "stiction")]
    n_shared = len(calls)
    alone = [fit_valve(loop.op, loop.pv, v, s) for v in ("backlash", "stiction")]
    n_alone = len(calls)
    for a, b in zip(shared, alone, strict=True):
        assert (a.S, a.J, a.direction, a.loglik, a.profile) == (b.S, b.J, b.direction, b.loglik, b.profile)
    # the stiction grid's J = 0 paths (6 bands, 2 directions; and the refinement's where it starts alike) were the
    # backlash valve's: looked up, not fitted again
    assert n_shared <= len(calls) - n_shared - 2 * s.n_grid
    again = fit_valve(loop.op, loop.pv, "stiction", s, memo=memo)
    assert again.process is shared[1].process and len(calls) == n_alone
