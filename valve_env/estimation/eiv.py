"""Errors in variables for the base valve fit: the temperature-noise part of the standard errors.

The base model (:class:`~valve_env.estimation.valve_model.ValveModel`) takes the
total-variation-denoised tank temperature as an exact input, so the inverse
Hessian of its likelihood measures only what the noise on the opening does to
the estimates. The noise on the sensed temperature (docs/reference.md, section 2: white,
0.001-0.05 degC) moves the estimates as well: through the denoised level (the
force balance, hence ``p_bset``) and, above all, through where the denoised
temperature reverses (the Dahl friction's reversals, hence ``sigma`` and
``F_hmax``). A latent-temperature state inside the EKF was tried and failed
(docs/estimation.md: the filtered rate jitters and the Dahl force, which reacts
to every reversal, collapses), so the temperature noise is propagated by a
**conditional parametric bootstrap of the whole pipeline** instead
(docs/uncertainty.md):

1. take the denoised temperatures of the fitted run as the best estimate of the
   true ones, and the noise sd of each temperature channel from its second
   differences (:func:`~valve_env.estimation.valve_model.noise_sd`), or a given sd;
2. ``B`` times: add fresh white noise of that sd to them, keep every other
   column (the measured opening included), and re-run the whole fit, denoising
   included, warm-started at the estimate (one start, no Hessian);
3. the spread of the replicate estimates is the temperature-noise part of the
   covariance, ``G_T Sigma_T G_T'`` to first order; the inverse Hessian is the
   opening-noise part ``G_x Sigma_x G_x'`` (the two noises are independent), so

       var = var_Hessian + var_bootstrap(temperature) (1 + 1/B),

   taken on the optimiser's (log) scale and mapped to the natural scale with the
   delta method, like the Hessian's (the 1/B term is the Monte-Carlo error of the
   bias estimate below);
4. the mean shift of the replicates from the estimate is the pipeline's bias
   under temperature noise (the denoising shaves or shifts the temperature's
   reversals, and sigma reacts: about -4 % at 0.01 degC on the independent
   simulator's smooth ramps, docs/uncertainty.md); ``params`` is the
   bias-corrected estimate ``2 theta_hat - mean(theta*)`` on the log scale
   (Efron & Tibshirani 1993, section 10.6). ``params_raw`` keeps the ML estimate.

It reduces to the plain ML fit when the temperature carries no noise (the
bootstrap spread is then zero), so on models without a temperature input (the
ctsmTMB Ornstein references) the estimator is unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from valve_env.estimation.fit import MLEstimator
from valve_env.estimation.valve_model import ValveModel, noise_sd

#: the fitted parameters the bootstrap reports on (docs/reference.md, section 7's params, and the noise parameters)
REPORTED: tuple[str, ...] = ("sigma", "F_hmax", "p_bset", "s_F", "s_x")
_PREPARED = ("T_tank_s", "v_tank", "T_med_s", "v_med", "t_in")


@dataclass(frozen=True)
class EIVResult:
    """Standard errors with the temperature noise accounted for.

    ``params``: the bias-corrected estimates; ``params_raw``: the ML estimates;
    ``std``: combined (inverse Hessian plus temperature bootstrap), natural scale;
    ``std_hessian``: the plain ML standard errors; ``std_temperature``: the bootstrap part
    alone; ``bias``: mean replicate minus estimate (the pipeline's bias under temperature noise,
    reported, not subtracted); ``replicates``: the B x k replicate estimates (natural scale);
    ``T_noise_C``, ``T_med_noise_C``: the noise sds used; ``B``, ``failed``: replicates run and
    failed."""

    params: dict[str, float]
    params_raw: dict[str, float]
    std: dict[str, float]
    std_hessian: dict[str, float]
    std_temperature: dict[str, float]
    bias: dict[str, float]
    replicates: pd.DataFrame
    T_noise_C: float
    T_med_noise_C: float
    B: int
    failed: int

    def to_dict(self) -> dict[str, Any]:
        return {"params": dict(self.params), "params_raw": dict(self.params_raw), "std": dict(self.std),
                "std_hessian": dict(self.std_hessian),
                "std_temperature": dict(self.std_temperature), "bias": dict(self.bias),
                "T_noise_C": self.T_noise_C, "T_med_noise_C": self.T_med_noise_C, "B": self.B,
                "failed": self.failed, "method": "inverse Hessian + conditional temperature-noise bootstrap "
                                                  "(valve_env.estimation.eiv)"}


def temperature_bootstrap(est: MLEstimator, data: pd.DataFrame, *, B: int = 16, seed: int = 0,
                          T_noise_C: float | None = None, T_med_noise_C: float | None = None) -> EIVResult:
    """Errors-in-variables standard errors of a fitted base valve model (see the module doc).

    ``est`` a fitted :class:`MLEstimator` of a :class:`ValveModel`; ``data`` the run it was
    fitted to (docs/reference.md, section 2 columns); ``B`` bootstrap replicates (each one fit without a
    Hessian, warm-started); ``T_noise_C`` / ``T_med_noise_C`` the temperature noise sds (default:
    estimated from the data's second differences)."""
    if not hasattr(est, "params_"):
        raise ValueError("temperature_bootstrap needs a fitted estimator")
    model = est.model
    if not isinstance(model, ValveModel):
        raise TypeError(f"temperature_bootstrap works on a ValveModel fit, got {type(model).__name__}")
    if B < 2:
        raise ValueError(f"B must be at least 2, got {B}")
    raw = data.drop(columns=[c for c in _PREPARED if c in data.columns])
    prep = model.prepare(raw)
    T_s = prep["T_tank_s"].to_numpy(dtype=float)
    M_s = prep["T_med_s"].to_numpy(dtype=float)
    sT = noise_sd(raw["T_tank_C"].to_numpy(dtype=float)) if T_noise_C is None else float(T_noise_C)
    sM = noise_sd(raw["T_med_C"].to_numpy(dtype=float)) if T_med_noise_C is None else float(T_med_noise_C)
    free = [n for n in REPORTED if n in est.free_]
    rng = np.random.default_rng(seed)
    init = {k: float(v) for k, v in est.params_.items()}
    fixed = {k: est.params_[k] for k in est.fixed}
    rows: list[dict[str, float]] = []
    failed = 0
    for _ in range(B):
        d = raw.copy()
        d["T_tank_C"] = T_s + sT * rng.standard_normal(len(d))
        d["T_med_C"] = M_s + sM * rng.standard_normal(len(d))
        m = ValveModel(model.valve, init=init, clip_width_mm=model.clip_width_mm, sign_eps=model.sign_eps,
                       tv_factor=model.tv_factor)
        try:
            r = MLEstimator(m, n_starts=1, seed=None, fixed=fixed, hessian=False, method=est.method,
                            n_sub=est.n_sub, foh=est.foh).fit(d)
        except (ValueError, np.linalg.LinAlgError):
            failed += 1
            continue
        if not np.isfinite(r.nll_):
            failed += 1
            continue
        rows.append({k: r.params_[k] for k in free})
    reps = pd.DataFrame(rows, columns=free)
    qs = {q.name: q for q in model.parameters}
    std_h = {k: float(est.std_.get(k, np.nan)) for k in free}
    std_t: dict[str, float] = {}
    std: dict[str, float] = {}
    bias: dict[str, float] = {}
    params: dict[str, float] = {}
    for k in free:
        v = reps[k].to_numpy(dtype=float)
        est_k = float(est.params_[k])
        bias[k] = float(np.mean(v) - est_k) if len(v) else float("nan")
        if len(v) < 2:
            params[k] = est_k
            std_t[k] = std[k] = float("nan")
            continue
        mc = 1.0 + 1.0 / len(v)
        if qs[k].transform == "log":  # on the optimiser's scale, then the delta method
            lv = np.log(v)
            pk = float(np.exp(2.0 * np.log(est_k) - np.mean(lv)))
            sd_w = float(np.std(lv, ddof=1))
            sd_hw = float(est.std_work_.get(k, np.nan))
            std_t[k] = sd_w * pk
            std[k] = float(np.sqrt(sd_hw**2 + mc * sd_w**2) * pk) if np.isfinite(sd_hw) else float("nan")
        else:
            pk = float(2.0 * est_k - np.mean(v))
            std_t[k] = float(np.std(v, ddof=1))
            std[k] = float(np.sqrt(std_h[k] ** 2 + mc * std_t[k] ** 2))
        params[k] = pk
    return EIVResult(params=params, params_raw={k: float(est.params_[k]) for k in free}, std=std,
                     std_hessian=std_h, std_temperature=std_t, bias=bias, replicates=reps,
                     T_noise_C=sT, T_med_noise_C=sM, B=B, failed=failed)


__all__ = ["EIVResult", "temperature_bootstrap", "REPORTED"]
