"""The PI tuning procedure (step test, model fit, SIMC) reproduces the gains
stored in valve_env/data/controllers.yaml."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from valve_env.controllers.process import ModelFit, StepResponse, fit_fopdt, fit_ipdt, fopdt_response, simc_pi
from valve_env.controllers.tuning import GAINS_PATH, load_gains, tune

# The stored gains are rounded to 6 significant digits; the fit is
# deterministic, so agreement is to the fit's tolerance.
RTOL = 1e-3


@pytest.fixture(scope="module")
def fresh() -> dict:
    return tune()


@pytest.mark.parametrize("env_id", ["ThermoValve-v0", "ThermoValvePressure-v0", "ThermoValveDual-v0"])
def test_tuning_reproduces_the_stored_gains(fresh: dict, env_id: str) -> None:
    stored = load_gains(env_id)
    for key in ("Kp", "Ti_s", "tau_c_s"):
        assert fresh[env_id]["pi"][key] == pytest.approx(stored["pi"][key], rel=RTOL), (env_id, key)
    for key in ("K", "theta_s"):
        assert fresh[env_id]["model"][key] == pytest.approx(stored["model"][key], rel=RTOL, abs=1e-3), (env_id, key)
    assert fresh[env_id]["procedure"] == stored["procedure"]
    assert stored["model"]["rms_K"] < 0.05  # the process model fits the step test


def test_gains_file_is_where_the_controllers_look() -> None:
    """Package data beside valve_env/data/__init__.py, not a file of the repository around the package."""
    import valve_env.data

    assert GAINS_PATH.name == "controllers.yaml" and GAINS_PATH.is_file()
    assert str(GAINS_PATH) == str(Path(valve_env.data.__file__).parent / "controllers.yaml")


def test_fopdt_fit_recovers_a_known_model() -> None:
    t = 30.0 * np.arange(1, 400)
    y = fopdt_response(t, 1.3, 700.0, 45.0, 2.0, 60.0)
    fit = fit_fopdt(StepResponse(t_s=t, y=y, y0=60.0, dt_s=30.0), 2.0)
    assert (fit.K, fit.tau_s, fit.theta_s) == pytest.approx((1.3, 700.0, 45.0), rel=1e-4)


def test_ipdt_fit_recovers_a_known_model() -> None:
    t = 30.0 * np.arange(1, 60)
    y = 2e-5 * 10.0 * np.maximum(t - 40.0, 0.0)
    fit = fit_ipdt(StepResponse(t_s=t, y=y, y0=0.0, dt_s=30.0), 10.0)
    assert (fit.K, fit.theta_s) == pytest.approx((2e-5, 40.0), rel=1e-4)


def test_simc_rules_by_hand() -> None:
    # FOPDT K=2, tau=600 s, theta=45 s, dt=30 s -> theta_eff = 60 s; tau_c = 60 s:
    # Kc = 600 / (2 * 120) = 2.5, Ti = min(600, 480) = 480 s
    g = simc_pi(ModelFit("fopdt", 2.0, 600.0, 45.0, 0.0), None, 30.0)
    assert (g.Kp, g.Ti_s, g.tau_c_s) == pytest.approx((2.5, 480.0, 60.0))
    # IPDT k=1e-4 K/s per unit, theta=0 -> theta_eff=15 s, tau_c=585 s: Kc = 1/(1e-4*600) = 16.67, Ti = 2400 s
    g = simc_pi(ModelFit("ipdt", 1e-4, math.nan, 0.0, 0.0), 585.0, 30.0)
    assert (g.Kp, g.Ti_s) == pytest.approx((1.0 / 0.06, 2400.0))


def test_a_zero_delay_is_reported_as_zero() -> None:
    """A step response with no dead time: the fit's delay sits on its bound and is 0, not a float residue
    (``thermovalve tune`` printed and stored ``theta_s=1.5e-17`` for the pressure loop)."""
    t = 30.0 * np.arange(1, 60)
    fit = fit_ipdt(StepResponse(t_s=t, y=2e-5 * 10.0 * t, y0=0.0, dt_s=30.0), 10.0)
    assert fit.theta_s == 0.0 and fit.K == pytest.approx(2e-5, rel=1e-6)
    fit = fit_fopdt(StepResponse(t_s=t, y=fopdt_response(t, 1.3, 700.0, 0.0, 2.0, 60.0), y0=60.0, dt_s=30.0), 2.0)
    assert fit.theta_s == 0.0 and fit.tau_s == pytest.approx(700.0, rel=1e-4)
