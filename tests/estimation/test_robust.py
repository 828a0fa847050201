"""The EKF estimator's sandwich standard errors and misspecification check (valve_env.ident.uncertainty,
valve_env.ident.tests)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from valve_env.ident.examples import Ornstein2D
from valve_env.ident.mle import IdentifiabilityWarning, MLEstimator
from valve_env.ident.tests import MisspecificationWarning, misspecification_check
from valve_env.ident.uncertainty import newey_west_lags, robust_std, score_contributions, step_nll


def _ornstein_data(seed: int, n: int = 1500, ar: float = 0.0) -> pd.DataFrame:
    """Ornstein2D (examples.py) simulated on a fine Euler grid; observation noise white, or AR(1)
    with coefficient ``ar`` (a misspecified model then)."""
    rng = np.random.default_rng(seed)
    dt, sub = 0.1, 20
    h = dt / sub
    theta, mu, alpha, s1, s2, sy = 2.0, 1.0, 0.7, 0.5, 0.3, 0.1
    u = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=n // 50 + 1), 50)[:n]
    x = np.array([1.0, 1.0])
    X = np.empty((n, 2))
    for k in range(n):
        X[k] = x
        for _ in range(sub):
            dx = np.array([theta * (mu + u[k] - x[0]), alpha * (x[0] - x[1])]) * h
            x = x + dx + np.array([s1, s2]) * np.sqrt(h) * rng.standard_normal(2)
    e = rng.standard_normal((n, 2)) * sy
    if ar:
        for k in range(1, n):
            e[k] = ar * e[k - 1] + np.sqrt(1 - ar**2) * e[k]
    return pd.DataFrame({"time_s": np.arange(n) * dt, "u": u, "y1": X[:, 0] + e[:, 0], "y2": X[:, 1] + e[:, 1]})


def _fit(d: pd.DataFrame) -> MLEstimator:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        return MLEstimator(Ornstein2D(x0=(1.0, 1.0)), n_starts=1, seed=0, method="lkf").fit(d)


@pytest.fixture(scope="module")
def white_fit() -> MLEstimator:
    return _fit(_ornstein_data(5))


def test_step_terms_sum_to_the_nll(white_fit: MLEstimator) -> None:
    assert step_nll(white_fit.filter_).sum() == pytest.approx(white_fit.nll_, rel=1e-10)


def test_sandwich_equals_hessian_when_the_model_is_right(white_fit: MLEstimator) -> None:
    G = score_contributions(white_fit)
    assert np.abs(G.sum().to_numpy()).max() < 0.05 * np.sqrt((G**2).sum().to_numpy()).max()  # score ~ 0 at the ML
    for lags in (0, None):
        r = robust_std(white_fit, lags=lags, scores=G)
        for k in ("theta", "mu", "alpha"):
            assert 0.75 < r.ratio[k] < 1.33, (k, lags, r.ratio[k])
    assert robust_std(white_fit, scores=G).lags == newey_west_lags(len(G))
    with warnings.catch_warnings():
        warnings.simplefilter("error", MisspecificationWarning)
        chk = misspecification_check(white_fit)
    assert chk["misspecified"] is False and chk["message"] == ""
    assert set(chk["outputs"]) == {"y1", "y2"}


@pytest.mark.slow  # the flag also fires in the default suite's diagnoses (MisspecificationWarning)
def test_correlated_noise_is_flagged() -> None:
    est = _fit(_ornstein_data(6, ar=0.8))
    with pytest.warns(MisspecificationWarning, match="not white"):
        chk = misspecification_check(est)
    assert chk["misspecified"] is True
    assert not chk["outputs"]["y1"]["white"] or not chk["outputs"]["y2"]["white"]
    bad = [k for k, v in chk["outputs"].items() if not v["white"]]
    assert all(chk["outputs"][k]["ljung_box_p"] <= 0.01 or
               chk["outputs"][k]["cpgram_max_dev"] >= chk["outputs"][k]["cpgram_band"] for k in bad)
    assert chk["message"].startswith("the one-step residuals of " + bad[0])
