"""Errors in variables inside the likelihood (valve_env.valveid.eiv_model): the input-error model
reduces to ctsmTMB's Ornstein2D references (tests/data/ctsmtmb_ornstein, GPL-3) when its error state is
off, the valve version's fast kernel agrees with the generic EKF, and it reduces to the base valve model."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import norm

from valve_env.ident.examples import Ornstein2D
from valve_env.ident.kalman import run_filter, to_arrays
from valve_env.ident.mle import IdentifiabilityWarning, MLEstimator, negloglik
from valve_env.valveid.eiv_model import InputErrorModel, ValveEIVModel, denoising_error, valve_eiv_model
from valve_env.valveid.valve_model import ValveModel


def _ornstein(ornstein_dir: Path) -> tuple[pd.DataFrame, dict]:
    d = pd.read_csv(ornstein_dir / "Ornstein2D.csv").iloc[:50].rename(columns={"t": "time_s"})
    ref = json.loads((ornstein_dir / "estimate_reference_ornstein2d_first50.json").read_text())["fits"]
    return d, ref


def _natural(par: dict[str, float]) -> dict[str, float]:
    return {k.removeprefix("log"): (float(np.exp(v)) if k.startswith("log") else float(v)) for k, v in par.items()}


def test_error_state_off_reproduces_ctsmtmb_nll(ornstein_dir: Path) -> None:
    """s_d = 0: the input's error state stays at 0; the input's measurement is an independent Gaussian
    channel, so nll(EIV) = ctsmTMB's nll + that channel's nll."""
    d, ref = _ornstein(ornstein_dir)
    rng = np.random.default_rng(3)
    d["u_meas"] = d["u"] + 0.05 * rng.standard_normal(len(d))
    m = InputErrorModel(Ornstein2D(), "u", "u_meas", fixed={"s_d": 0.0, "tau_d": 1.0, "s_e": 0.05})
    params = _natural(ref["ekf"]["par_fixed"])
    value = negloglik(m, params, d, compiled=False)
    channel = -float(norm.logpdf(d["u_meas"] - d["u"], scale=0.05).sum())
    assert value - channel == pytest.approx(ref["ekf"]["nll"], abs=1e-6)
    # without a measured column the model is the base model
    m0 = InputErrorModel(Ornstein2D(), "u", fixed={"s_d": 0.0, "tau_d": 1.0})
    assert negloglik(m0, params, d, compiled=False) == pytest.approx(4.83956779, abs=1e-6)


def test_error_state_on_changes_the_likelihood(ornstein_dir: Path) -> None:
    d, ref = _ornstein(ornstein_dir)
    params = _natural(ref["ekf"]["par_fixed"])
    on = InputErrorModel(Ornstein2D(), "u", fixed={"s_d": 0.3, "tau_d": 0.5})
    # the input's uncertainty widens the predictions: a different (here larger) nll at the same parameters
    assert negloglik(on, params, d, compiled=False) != pytest.approx(ref["ekf"]["nll"], abs=1e-3)
    res = run_filter(on, on.param_vector(params), to_arrays(on, d), compiled=False)
    v = res.P_pred[:, 2, 2]
    assert v[0] == pytest.approx(0.09)  # starts at the stationary variance s_d^2
    assert np.all(v > 0.0) and np.all(v <= 0.09 + 1e-9)  # the outputs only ever inform it


@pytest.mark.slow  # about 2-3 min: the generic Python model functions behind the LKF
def test_fit_with_error_state_off_lands_on_ctsmtmb_estimates(ornstein_dir: Path) -> None:
    """The linear Kalman filter (the EIV model of a linear model is linear): ctsmTMB's LKF fit."""
    d, ref = _ornstein(ornstein_dir)
    r = ref["lkf"]
    m = InputErrorModel(Ornstein2D(), "u", fixed={"s_d": 0.0, "tau_d": 1.0})
    assert m.linear
    assert negloglik(m, _natural(r["par_fixed"]), d, method="lkf") == pytest.approx(r["nll"], abs=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)  # sigma_y1 -> 0, as in ctsmTMB
        est = MLEstimator(m, n_starts=2, seed=1, method="lkf").fit(d)
    assert est.loglik_ == pytest.approx(-r["nll"], abs=1e-5)
    for key, value in r["par_fixed"].items():
        name = key.removeprefix("log")
        if name == "sigma_y1":
            continue
        ours = est.params_work_[name] if key.startswith("log") else est.params_[name]
        assert abs(ours - value) < 0.05 * r["sd_fixed"][key], name
        assert est.std_work_[name] == pytest.approx(r["sd_fixed"][key], rel=0.05), name


@pytest.fixture(scope="module")
def valve_run() -> pd.DataFrame:
    from valve_env.experiment import simulate_experiment

    df = simulate_experiment(seed=31, duration_h=3.0, dt_s=10.0, T_noise_C=0.01)
    return df[["time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm"]]


def test_valve_eiv_fast_kernel_matches_generic_ekf(valve_run: pd.DataFrame) -> None:
    for measured in (None, "T_tank_C"):
        m = ValveEIVModel(measured=measured, fixed={"s_d": 0.006, "tau_d": 30.0})
        p = m.param_vector({"s_x": 2.4e-3})
        arr = to_arrays(m, valve_run.iloc[:60])
        fast = run_filter(m, p, arr)
        generic = run_filter(m, p, arr, fast=False, compiled=False, n_sub=8)
        assert fast.y_pred.shape == generic.y_pred.shape
        assert abs(fast.nll - generic.nll) < 2e-3 * abs(fast.nll)
        np.testing.assert_allclose(fast.y_pred[:, 0], generic.y_pred[:, 0], atol=3e-4)  # mm
        if measured:  # degC; exact discrete steps against RK4 of the linearised coupling
            np.testing.assert_allclose(fast.y_pred[:, 1], generic.y_pred[:, 1], atol=2e-3)
        # exact discrete steps against RK4 of the linearised coupling: the error's variance to 15 %
        np.testing.assert_allclose(fast.P_filt[:, 1, 1], generic.P_filt[:, 1, 1], rtol=0.15)


def test_valve_eiv_reduces_to_the_base_model(valve_run: pd.DataFrame) -> None:
    base = ValveModel()
    m = ValveEIVModel(fixed={"s_d": 0.0, "tau_d": 30.0})
    vals = {"s_x": 2.4e-3, "sigma": 6.0}
    a = negloglik(base, vals, valve_run)
    b = negloglik(m, vals, valve_run)
    assert b == pytest.approx(a, abs=1e-8)
    on = negloglik(ValveEIVModel(fixed={"s_d": 0.01, "tau_d": 30.0}), vals, valve_run)
    assert on != pytest.approx(a, abs=1.0)


def test_denoising_error_calibration(valve_run: pd.DataFrame) -> None:
    t = valve_run["time_s"].to_numpy()
    s_d, tau_d, s_n = denoising_error(valve_run["T_tank_C"].to_numpy(), t, B=2)
    assert s_n == pytest.approx(0.01, rel=0.3)
    assert 0.0 < s_d < s_n  # the denoised temperature is closer to the truth than the raw one
    assert tau_d > 0.0
    assert denoising_error(np.linspace(50, 60, len(t)), t)[0] == 0.0  # no noise, no error
    m = valve_eiv_model(valve_run)
    assert m.parameter("s_d").fixed and m.parameter("s_d").init == pytest.approx(s_d, rel=0.2)
