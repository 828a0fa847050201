"""Fitting a measured run with the base valve model (``thermovalve fit``): the fit and its JSON summary;
the report, like the seed paper's Table 4 and Fig. 5-7, is :func:`valve_env.valveid.report.write_report`'s."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from valve_env.data_io import censored_opening
from valve_env.ident.mle import MLEstimator
from valve_env.ident.tests import misspecification_check
from valve_env.ident.uncertainty import robust_std
from valve_env.params import ValveParams
from valve_env.valveid.valve_model import ValveModel

#: The parameters handed to the environment (ValveParams fields).
VALVE_FIELDS: tuple[str, ...] = ("sigma", "F_hmax", "p_bset")
#: The paper's Table 4 (estimate, std).
PAPER_TABLE4: dict[str, tuple[float, float]] = {"sigma": (6.41, 0.589), "F_hmax": (1.31, 0.067),
                                                "p_bset": (0.0776, 0.000892)}


def fit_run(data: pd.DataFrame, *, valve: ValveParams | None = None, n_starts: int = 3, seed: int = 0,
            fixed: dict[str, float] | None = None) -> MLEstimator:
    """Fit the base valve model (docs/reference.md, section 1) to a validated run."""
    model = ValveModel(valve)
    return MLEstimator(model, n_starts=n_starts, seed=seed, fixed=fixed).fit(data)


def measured_opening(data: pd.DataFrame) -> np.ndarray:
    """x_mm, NaN where it is not measured: derived from a flow read as 0 under a meter's low-flow cut-off
    (:func:`valve_env.data_io.censored_opening`)."""
    x = data["x_mm"].to_numpy(dtype=float)
    censored = censored_opening(data)
    return x if censored is None else np.where(censored, np.nan, x)


def _f(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def fit_summary(est: MLEstimator, data: pd.DataFrame, validation: pd.DataFrame | None = None) -> dict[str, Any]:
    """The ``thermovalve fit`` JSON: docs/reference.md, section 7 keys first (params holds ValveParams fields only,
    so it can be passed to ``gym.make("ThermoValve-v0", valve=params)``), then extras."""
    sim = est.simulate(data)
    meas = measured_opening(data)
    out: dict[str, Any] = {
        "params": {k: float(est.params_[k]) for k in VALVE_FIELDS},
        "std": {k: _f(est.std_.get(k, float("nan"))) for k in VALVE_FIELDS},
        "loglik": float(est.loglik_),
        "rms_mm": float(est.rms_["x_mm"]),
        "n": int(est.n_samples_),
        "noise_params": {k: float(est.params_[k]) for k in ("s_F", "s_x")},
        "noise_std": {k: _f(est.std_.get(k, float("nan"))) for k in ("s_F", "s_x")},
        "tstat": {k: _f(v) for k, v in est.tstat_.items()},
        "corr": {r: {c: _f(float(est.corr_.to_numpy()[i, j])) for j, c in enumerate(est.corr_.columns)}
                 for i, r in enumerate(est.corr_.index)},
        "rms_sim_mm": float(np.sqrt(np.nanmean((meas - sim["x_mm"].to_numpy()) ** 2))),
        "n_obs": int(est.n_obs_),
        "aic": float(est.aic_),
        "bic": float(est.bic_),
        "converged": bool(est.converged_),
        "identifiability": list(est.identifiability_),
        "fit_time_s": float(est.fit_time_s_),
        "model": "base valve model, docs/reference.md, section 1 (valve_env.valveid.valve_model.ValveModel)",
    }
    out.update(uncertainty_summary(est))
    if validation is not None:
        res = est.residuals(validation, standardised=False)["x_mm"].to_numpy()
        vsim = est.simulate(validation)["x_mm"].to_numpy()
        out["validation"] = {
            "n": len(validation),
            "rms_mm": float(np.sqrt(np.nanmean(res**2))),
            "rms_sim_mm": float(np.sqrt(np.nanmean((measured_opening(validation) - vsim) ** 2))),
            "loglik": float(-est.nll(data=validation)),
        }
    return out


def uncertainty_summary(est: MLEstimator) -> dict[str, Any]:
    """The robust standard errors and the misspecification check of a fit, for the JSON:
    ``std_hessian`` (inverse Hessian), ``std_robust`` (the HAC sandwich of
    :func:`valve_env.ident.uncertainty.robust_std`), ``robust_lags``, ``std_method`` (which of them
    ``std`` holds) and ``misspecification`` (:func:`~valve_env.ident.tests.misspecification_check`,
    which also warns)."""

    rob = robust_std(est)
    return {"std_hessian": {k: _f(est.std_.get(k, float("nan"))) for k in VALVE_FIELDS},
            "std_robust": {k: _f(rob.std.get(k, float("nan"))) for k in VALVE_FIELDS},
            "robust_lags": rob.lags, "std_method": "inverse Hessian (ML)",
            "misspecification": misspecification_check(est)}


def eiv_summary(fit: Any, data: pd.DataFrame, validation: pd.DataFrame | None = None) -> dict[str, Any]:
    """The ``thermovalve fit --eiv`` JSON: :func:`fit_summary` of the relaxed-denoiser fit with
    ``params`` and ``std`` replaced by the errors-in-variables result
    (:class:`valve_env.valveid.eiv.EIVFit`) and its details under ``eiv``."""
    out = fit_summary(fit.estimator, data, validation)
    out["params"] = {k: float(fit.params[k]) for k in VALVE_FIELDS}
    out["std"] = {k: _f(fit.std[k]) for k in VALVE_FIELDS}
    out["std_method"] = "errors in variables (valve_env.valveid.eiv.fit_eiv, docs/uncertainty.md)"
    out["eiv"] = fit.to_dict()
    out["fit_time_s"] = float(fit.fit_time_s)
    out["model"] = f"{fit.model} valve model with errors in variables (valve_env.valveid.eiv.fit_eiv)"
    return out


__all__ = ["fit_run", "fit_summary", "eiv_summary", "uncertainty_summary", "VALVE_FIELDS", "PAPER_TABLE4"]
