"""A named effect's misspecification-robust sd and its misspecification check
(valve_env.valveid.robust.robust_finding; docs/uncertainty.md, "Sandwich standard errors and the
misspecification check")."""

from __future__ import annotations

import warnings

import pytest

from valve_env.experiment import simulate_experiment
from valve_env.ident.tests import MisspecificationWarning
from valve_env.valveid.diagnose import check_run, prepare
from valve_env.valveid.fitting import Model
from valve_env.valveid.robust import robust_finding


@pytest.fixture(scope="module")
def lag_run():  # type: ignore[no-untyped-def]
    df = simulate_experiment(seed=71, duration_h=8.0, dt_s=10.0, effects={"sensor_lag": {"tau_s": 120.0}},
                             T_noise_C=0.005, x_noise_mm=2.4e-3)
    return prepare(check_run(df))


def test_right_model_sandwich_beside_hessian_and_white_residuals(lag_run) -> None:  # type: ignore[no-untyped-def]
    """On the model that generated the run: the sandwich and the inverse Hessian agree (a correctly
    specified likelihood), the fit's own sd is the larger of the two (one implementation,
    estimation.covariance), and the check stays quiet."""
    m = Model(("sensor_lag",))
    fit = m.fit(lag_run)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MisspecificationWarning)
        r = robust_finding(m, lag_run, fit)
    h, s = r["std_hessian"]["tau_s"], r["std_robust"]["tau_s"]
    assert 0.6 < s / h < 1.6, (h, s)
    assert fit.std["tau_s"] == pytest.approx(max(h, s), rel=1e-6)
    assert abs(fit.params["tau_s"] / 120.0 - 1.0) < 5 * max(h, s) / 120.0
    assert r["robust_lags"] > 0
    assert r["misspecification"]["misspecified"] is False


def test_wrong_model_is_flagged(lag_run) -> None:  # type: ignore[no-untyped-def]
    """A model without the run's lag leaves correlated one-step errors: the check warns."""
    m = Model(("medium_temperature",))
    fit = m.fit(lag_run)
    with pytest.warns(MisspecificationWarning, match="medium_temperature valve model"):
        r = robust_finding(m, lag_run, fit)
    assert r["misspecification"]["misspecified"] is True
    assert r["misspecification"]["outputs"]["x_mm"]["ljung_box_p"] < 0.01
