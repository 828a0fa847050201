"""Tests of valve_env.diagnosis.fitting: the maximum-likelihood fit of the base model and its effects."""

from __future__ import annotations

from valve_env.diagnosis.diagnose import check_run, prepare
from valve_env.diagnosis.fitting import Model
from valve_env.experiment import simulate_experiment


def test_a_warm_start_is_kept_by_the_grid_scan_and_the_refit_does_not_lose() -> None:
    """The effect's grid scan keeps a start value that beats every grid point (73 s is on no grid),
    and a fit started from a fit ends with at least its likelihood (the scan once dropped the start:
    a refit from a good estimate ended 6 log-likelihood units lower)."""
    df = simulate_experiment(seed=31, duration_h=8.0, dt_s=20.0, effects={"sensor_lag": {"tau_s": 73.0}},
                             T_noise_C=0.005, x_noise_mm=2.0e-3)
    d = prepare(check_run(df))
    m = Model(("sensor_lag",))
    fit = m.fit(d, with_std=False)
    assert abs(fit.params["tau_s"] - 73.0) < 5.0
    p = next(q for q in m.eff_params if q.name == "tau_s")
    assert m._scan(d, fit.params, p, keep_start=True) == fit.params["tau_s"]
    again = m.fit(d, start=fit.params, with_std=False)
    assert again.loglik >= fit.loglik - 1e-6
