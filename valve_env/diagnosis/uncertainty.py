"""Honest uncertainty of a named effect's parameters: a parametric bootstrap of the whole chain.

Why not the Hessian: the output-error likelihood of :mod:`valve_env.diagnosis.fitting`
conditions on the *smoothed* temperatures as if they were exact. Their smoothing error is an
error in the input (errors in variables) that moves the estimates coherently over the record;
the likelihood cannot see it, and neither can a HAC sandwich of its scores. For stiction the
likelihood is not even smooth in the band. The coverage study
(``benchmarks/diagnosis_coverage.py``) measured fewer than half of the estimates within one
reported (Hessian/HAC) sd.

The bootstrap repeats what produced the estimate, in a world where the fitted model is the
truth (Efron and Tibshirani 1993, ch. 6; for grey-box models e.g. Ljung 1999, sec. 9.7):

1. the latent temperatures as smoothed from the run are the true temperatures; the valve is
   simulated from them with the fitted parameters on a fine grid (``truth_step_s``, finer
   than the estimator's sub-steps, so the estimator's discretisation counts too);
2. a replicate run: white noise of the measured sd on both temperature channels, the fitted
   noise model (white ``s_w`` plus the Ornstein-Uhlenbeck model error ``s_e``, ``tau_e``) on
   the opening (with stiction: white noise of the sd measured on the resting steps, see
   :func:`replicate_run`);
3. the replicate is prepared exactly as a measured run (temperatures smoothed again) and the
   model re-estimated the way the estimate was made: maximum likelihood from the estimate,
   stiction's band from the jumps of the replicate's opening;
4. the bias is the mean of the re-estimates minus the estimate. Where it is clear (more than
   ``bias_z`` standard errors of that mean) the estimate is corrected by it (the bootstrap
   bias correction) and the sd is the spread of the re-estimates plus the uncertainty of the
   correction; otherwise the sd is their root-mean-square error about the estimate (spread
   and bias together). The bias, the spread and a basic bootstrap 95 % interval are reported
   beside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from valve_env.diagnosis.effects import EFFECTS
from valve_env.diagnosis.fitting import FitResult, Model, RunData
from valve_env.diagnosis.stiction import jump_band, noise_sd

#: Name of the method, as written into the JSON.
METHOD = "parametric bootstrap"


@dataclass
class BootstrapResult:
    """Replicate estimates of the effect parameters and their summary."""

    names: list[str]
    replicates: np.ndarray  # (B, k)
    estimate: dict[str, float]
    std: dict[str, float]
    bias: dict[str, float]
    interval_95: dict[str, tuple[float, float]]
    B: int = 0
    corrected: dict[str, float] = field(default_factory=dict)
    bias_corrected: dict[str, bool] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        return {"method": METHOD, "replicates": int(self.B),
                "bias": {k: float(v) for k, v in self.bias.items()},
                "bias_corrected": {k: bool(v) for k, v in self.bias_corrected.items()},
                "uncorrected_estimate": {k: float(v) for k, v in self.estimate.items()},
                "spread": {k: float(v) for k, v in zip(self.names, self.replicates.std(axis=0, ddof=1), strict=True)},
                "interval_95": {k: [float(a), float(b)] for k, (a, b) in self.interval_95.items()}}


def _ou_path(t: np.ndarray, s_e: float, tau_e: float, rng: np.random.Generator) -> np.ndarray:
    n = t.shape[0]
    out = np.empty(n)
    z = np.asarray(rng.standard_normal(n), dtype=float)
    out[0] = s_e * z[0]
    phi = np.asarray(np.exp(-np.diff(t) / tau_e), dtype=float)
    sd = np.asarray(s_e * np.sqrt(1.0 - phi * phi), dtype=float)
    for k in range(1, n):
        out[k] = phi[k - 1] * out[k - 1] + sd[k - 1] * z[k]
    return out


def replicate_run(model: Model, data: RunData, values: dict[str, float], rng: np.random.Generator,
                  truth_step_s: float = 1.0) -> RunData:
    """One parametric-bootstrap replicate of ``data`` under ``values`` (see the module docstring)."""
    fine = Model(model.effects, model.valve, max_step_s=min(truth_step_s, model.max_step_s))
    x_true, _, _ = fine.simulate(data, values)
    n = len(data)
    if "stiction" in model.effects:
        # the band is measured from the steps of the opening: their noise is measured directly on the
        # resting steps (the filter's s_w and s_e also absorb its misfit and would overstate it)
        y = x_true + noise_sd(data.x) * rng.standard_normal(n)
    else:
        y = x_true + values["s_w"] * rng.standard_normal(n) + _ou_path(data.t, values["s_e"], values["tau_e"], rng)
    T = data.T + data.s_T * rng.standard_normal(n)
    M = data.M + data.s_M * rng.standard_normal(n)
    return RunData.from_arrays(data.t, T, M, y, data.dp, data.ps, name=f"{data.name} (bootstrap)")


def _refit(model: Model, rep: RunData, values: dict[str, float]) -> dict[str, float]:
    """Re-estimate on a replicate, as :meth:`Model.fit` estimates: stiction's band from the jumps of
    the opening (:func:`valve_env.diagnosis.stiction.jump_band`, no valve model needed), the smooth
    parameters by L-BFGS-B from the truth of the bootstrap world (with the band fixed)."""
    out = dict(values)
    fixed: dict[str, float] = {}
    for p in model.eff_params:
        if p.name == "band_mm":
            b, _ = jump_band(rep.x, float(model.valve.stroke))
            fixed[p.name] = out[p.name] = b if math.isfinite(b) else float(values[p.name])
    if len(fixed) < len(model.eff_params):
        out = model._fit_smooth(rep, out, fixed, 200, False).params
    return out


def bootstrap(model: Model, data: RunData, fit: FitResult, B: int = 16, seed: int = 0,
              truth_step_s: float = 1.0, bias_z: float = 2.0) -> BootstrapResult:
    """Parametric bootstrap of the effect parameters of ``fit`` (a fit of ``model`` to ``data``)."""
    rng = np.random.default_rng(seed)
    names = [p.name for e in model.effects for p in EFFECTS[e].parameters]
    reps = np.empty((B, len(names)))
    for b in range(B):
        rep = replicate_run(model, data, fit.params, rng, truth_step_s)
        pr = _refit(model, rep, fit.params)
        reps[b] = [pr[k] for k in names]
    est = {k: float(fit.params[k]) for k in names}
    mean = reps.mean(axis=0)
    sd = reps.std(axis=0, ddof=1)
    bias, std, ci, corrected, flag = {}, {}, {}, {}, {}
    for i, k in enumerate(names):
        bias[k] = float(mean[i] - est[k])
        se = float(sd[i] / math.sqrt(B))
        flag[k] = bool(se > 0 and abs(bias[k]) > bias_z * se)
        if flag[k]:
            # a bias the replicates show clearly (e.g. the band's jumps overshoot a little): corrected,
            # and the sd includes the uncertainty of the correction (the mean of B replicates)
            corrected[k] = est[k] - bias[k]
            std[k] = float(math.sqrt(sd[i] ** 2 + se**2))
        else:
            # no clear bias: root-mean-square error about the estimate (spread and bias together)
            corrected[k] = est[k]
            std[k] = float(math.sqrt(sd[i] ** 2 + bias[k] ** 2))
        lo, hi = np.percentile(reps[:, i], [2.5, 97.5])
        # basic bootstrap interval (reflected about the estimate)
        ci[k] = (float(2 * est[k] - hi), float(2 * est[k] - lo))
    return BootstrapResult(names, reps, est, std, bias, ci, B, corrected, flag)
