"""Errors in variables for the base fit (valve_env.valveid.eiv): the temperature-noise
bootstrap adds to the Hessian's variance, vanishes without temperature noise, reports its bias."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from valve_env.experiment import simulate_experiment
from valve_env.ident.mle import MLEstimator
from valve_env.valveid.eiv import temperature_bootstrap
from valve_env.valveid.valve_model import ValveModel

NAMES = ("sigma", "F_hmax", "p_bset")


@pytest.fixture(scope="module")
def fitted() -> tuple[MLEstimator, object]:
    df = simulate_experiment(seed=41, duration_h=3.0, dt_s=10.0, T_noise_C=0.01)
    data = df[["time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm"]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = MLEstimator(ValveModel(), n_starts=1, seed=0).fit(data)
    return est, data


def test_bootstrap_adds_the_temperature_noise(fitted: tuple[MLEstimator, object]) -> None:
    est, data = fitted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = temperature_bootstrap(est, data, B=3, seed=1)
    assert r.B == 3 and r.failed == 0 and len(r.replicates) == 3
    assert r.T_noise_C == pytest.approx(0.01, rel=0.3)  # estimated from the data's second differences
    for k in NAMES:
        assert r.std_temperature[k] > 0.0
        assert r.std[k] > r.std_hessian[k]  # var = Hessian + bootstrap (1 + 1/B)
        lw = r.std[k] / r.params[k]
        want = np.sqrt((r.std_hessian[k] / est.params_[k]) ** 2
                       + (1 + 1 / 3) * np.std(np.log(r.replicates[k]), ddof=1) ** 2)
        assert lw == pytest.approx(want, rel=1e-9)
        # bias-corrected estimate: 2 log(theta_hat) - mean log(theta*)
        assert np.log(r.params[k]) == pytest.approx(2 * np.log(est.params_[k]) - np.mean(np.log(r.replicates[k])))
    js = r.to_dict()
    assert set(js["std"]) >= set(NAMES) and "method" in js


def test_no_temperature_noise_no_extra_spread(fitted: tuple[MLEstimator, object]) -> None:
    est, data = fitted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = temperature_bootstrap(est, data, B=2, seed=1, T_noise_C=0.0, T_med_noise_C=0.0)
    # the same input every replicate: every refit lands where the fit did (to the optimiser's tolerance)
    for k in NAMES:
        assert r.std_temperature[k] < 0.05 * r.std_hessian[k]
        assert r.std[k] == pytest.approx(r.std_hessian[k], rel=0.01)


def test_bad_use() -> None:
    with pytest.raises(ValueError, match="fitted"):
        temperature_bootstrap(MLEstimator(ValveModel()), None, B=4)  # type: ignore[arg-type]
