"""Fitting a measured run with the base valve model and reporting it like the seed paper
(Table 4, Fig. 5-7). Used by ``thermovalve fit``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from valve_env.ident.mle import MLEstimator
from valve_env.ident.tests import residual_report
from valve_env.params import ValveParams
from valve_env.valveid.diagnostics import paper_figure, phase_diagram, whiteness_figure
from valve_env.valveid.preprocess import describe
from valve_env.valveid.robust import misspecification_check, robust_std
from valve_env.valveid.valve_model import ValveModel

#: The parameters handed to the environment (ValveParams fields).
VALVE_FIELDS: tuple[str, ...] = ("sigma", "F_hmax", "p_bset")
#: The paper's Table 4 (estimate, std).
PAPER_TABLE4: dict[str, tuple[float, float]] = {"sigma": (6.41, 0.589), "F_hmax": (1.31, 0.067),
                                                "p_bset": (0.0776, 0.000892)}
_LABELS = {"sigma": ("sigma", "N/K"), "F_hmax": ("F_h,max", "N"), "p_bset": ("p_b,set", "MPa"),
           "s_F": ("s_F (friction diffusion)", "N/sqrt(s)"), "s_x": ("s_x (observation sd)", "mm")}


def fit_run(data: pd.DataFrame, *, valve: ValveParams | None = None, n_starts: int = 3, seed: int = 0,
            fixed: dict[str, float] | None = None) -> MLEstimator:
    """Fit the base valve model (docs/reference.md, section 1) to a validated run."""
    model = ValveModel(valve)
    return MLEstimator(model, n_starts=n_starts, seed=seed, fixed=fixed).fit(data)


def _f(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def fit_summary(est: MLEstimator, data: pd.DataFrame, validation: pd.DataFrame | None = None) -> dict[str, Any]:
    """The ``thermovalve fit`` JSON: docs/reference.md, section 7 keys first (params holds ValveParams fields only,
    so it can be passed to ``gym.make("ThermoValve-v0", valve=params)``), then extras."""
    sim = est.simulate(data)
    meas = data["x_mm"].to_numpy(dtype=float)
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
            "rms_sim_mm": float(np.sqrt(np.nanmean((validation["x_mm"].to_numpy(dtype=float) - vsim) ** 2))),
            "loglik": float(-est.nll(data=validation)),
        }
    return out


def uncertainty_summary(est: MLEstimator) -> dict[str, Any]:
    """The robust standard errors and the misspecification check of a fit, for the JSON:
    ``std_hessian`` (inverse Hessian), ``std_robust`` (the HAC sandwich of
    :func:`valve_env.valveid.robust.robust_std`), ``robust_lags``, ``std_method`` (which of them
    ``std`` holds) and ``misspecification`` (:func:`~valve_env.valveid.robust.misspecification_check`,
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


def table4_markdown(est: MLEstimator) -> str:
    """A parameter table like the paper's Table 4, with the paper's values beside ours."""
    lines = ["| variable | estimate | std.dev. | t | unit | paper estimate | paper std.dev. |",
             "|---|---|---|---|---|---|---|"]
    for k in (*VALVE_FIELDS, "s_F", "s_x"):
        label, unit = _LABELS[k]
        sd = est.std_.get(k, float("nan"))
        t = est.tstat_.get(k, float("nan"))
        pe, ps = PAPER_TABLE4.get(k, (float("nan"), float("nan")))
        lines.append(f"| {label} | {est.params_[k]:.4g} | {_fmt(sd)} | {_fmt(t, '.1f')} | {unit} | "
                     f"{_fmt(pe)} | {_fmt(ps)} |")
    return "\n".join(lines)


def _fmt(v: float, spec: str = ".3g") -> str:
    return "-" if not math.isfinite(v) else format(v, spec)


def reported_table(summary: dict[str, Any]) -> str:
    """The reported fit's parameters (``summary``, the ``thermovalve fit`` JSON) beside the paper's
    Table 4: the same numbers the console and the JSON give."""
    lines = ["| variable | estimate | std.dev. | t = estimate / std.dev. | unit | paper estimate | paper std.dev. |",
             "|---|---|---|---|---|---|---|"]
    rows = [(k, summary["params"][k], summary["std"].get(k)) for k in VALVE_FIELDS]
    rows += [(k, summary["noise_params"][k], summary.get("noise_std", {}).get(k)) for k in ("s_F", "s_x")]
    for k, v, sd in rows:
        label, unit = _LABELS[k]
        if k in ("s_F", "s_x") and "errors in variables" in summary.get("model", ""):
            label += ", of the ML fit the errors-in-variables fit starts from"
        sdv = float(sd) if sd is not None else float("nan")
        t = v / sdv if math.isfinite(sdv) and sdv > 0 else float("nan")
        pe, ps = PAPER_TABLE4.get(k, (float("nan"), float("nan")))
        lines.append(f"| {label} | {v:.4g} | {_fmt(sdv)} | {_fmt(t, '.1f')} | {unit} | {_fmt(pe)} | {_fmt(ps)} |")
    return "\n".join(lines)


def _at_reported(est: MLEstimator, summary: dict[str, Any]) -> MLEstimator:
    """``est`` moved to the reported parameters (the errors-in-variables estimate differs from the ML
    point estimate it starts from), so that every figure shows the fit the report reports."""
    import copy

    moved = copy.copy(est)
    values = {**est.params_, **{k: float(v) for k, v in summary["params"].items()}}
    moved.p_ = est.model.param_vector(values)
    moved.params_ = values
    return moved


def write_report(est: MLEstimator, data: pd.DataFrame, outdir: str | Path, summary: dict[str, Any] | None = None,
                 validation: pd.DataFrame | None = None, name: str = "run") -> Path:
    """Figures (paper Fig. 5-7 style, whiteness checks) and a markdown report in ``outdir``, rendered
    from ``summary`` (the ``thermovalve fit`` JSON, :func:`fit_summary` or :func:`eiv_summary`):
    the parameters, their sd, the verdicts and the figures are those of the one reported fit."""
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    summary = summary or fit_summary(est, data, validation)
    fit_label = summary["model"]
    rep_est = _at_reported(est, summary)
    d = est.model.prepare(data)
    pred = rep_est.predict(d)
    sim = rep_est.simulate(d)
    res = rep_est.residuals(d, standardised=False)["x_mm"].to_numpy()
    t = d["time_s"].to_numpy()
    short = "errors-in-variables fit" if "errors in variables" in fit_label else "ML fit"
    paper_figure(t, d["x_mm"].to_numpy(), pred["x_mm"].to_numpy(), sim["x_mm"].to_numpy(), res,
                 out / "fit.png", title=f"{name}: estimation (paper Fig. 6), {short}")
    phase_diagram(d["T_tank_s"].to_numpy(), d["x_mm"].to_numpy(), out / "phase.png",
                  simulated=sim["x_mm"].to_numpy(), title=f"{name}: opening vs temperature (paper Fig. 5), {short}")
    inputs = d[["T_tank_C", "T_med_C", "dp_mbar", "ps_bar"]]
    rep = residual_report(res, inputs)
    whiteness_figure(rep, out / "whiteness.png", title=f"{name}: residual whiteness, {short}")
    mis = summary.get("misspecification") or {}
    parts = [f"# Valve fit: {name}", "",
             f"**The fit:** {fit_label}. **Standard deviations:** {summary['std_method']}. Every number and "
             f"figure below is of this fit (the `fit` JSON holds the same).", "",
             "## Parameters (cf. the paper's Table 4)", "", reported_table(summary), "",
             f"log-likelihood {summary['loglik']:.2f}, n = {summary['n']}, "
             f"one-step RMS {summary['rms_mm']:.3g} mm, simulation RMS {summary['rms_sim_mm']:.3g} mm "
             "(the paper: residual sd 2.4e-3 mm).", ""]
    pre = summary.get("preprocessing") or []
    if pre:

        parts += ["## Pre-processing: the record as measured", ""] + [f"- {x}" for x in describe(pre)] + [""]
    if summary.get("identifiability"):
        parts += ["**Identifiability:**", ""] + [f"- {m}" for m in summary["identifiability"]] + [""]
    parts += ["## Correlation of the estimates (ML point estimate, inverse Hessian)", "", _corr_md(est), "",
              "## Residual diagnostics", "",
              f"**Misspecification check** (the verdict the JSON gives, `misspecification`): "
              f"{'misspecified' if mis.get('misspecified') else 'not misspecified'}"
              + (f": {mis['message']}" if mis.get("message") else "") + ".", "",
              "The whiteness statistics of the one-step residuals (5 % level), for reading the figure; the "
              "misspecification verdict above weighs them against the noise model:", "",
              _diag_md(rep), "",
              "![fit](fit.png)", "", "![phase](phase.png)", "", "![whiteness](whiteness.png)", ""]
    if validation is not None:
        dv = est.model.prepare(validation)
        pv = rep_est.predict(dv)
        sv = rep_est.simulate(dv)
        rv = rep_est.residuals(dv, standardised=False)["x_mm"].to_numpy()
        paper_figure(dv["time_s"].to_numpy(), dv["x_mm"].to_numpy(), pv["x_mm"].to_numpy(), sv["x_mm"].to_numpy(),
                     rv, out / "validation.png", title=f"{name}: cross-validation (paper Fig. 7), {short}")
        v = summary.get("validation", {})
        parts += ["## Cross-validation (paper Fig. 7)", "",
                  f"one-step RMS {v.get('rms_mm', float('nan')):.3g} mm, simulation RMS "
                  f"{v.get('rms_sim_mm', float('nan')):.3g} mm on {v.get('n', 0)} samples.", "",
                  "![validation](validation.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(parts))
    return path


def _corr_md(est: MLEstimator) -> str:
    names = list(est.corr_.columns)
    lines = ["| | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for i, r in enumerate(names):
        row = " | ".join(_fmt(float(est.corr_.to_numpy()[i, j]), ".2f") for j in range(len(names)))
        lines.append(f"| {r} | {row} |")
    return "\n".join(lines)


def _diag_md(rep: Any) -> str:
    s = rep.summary()
    return (f"- autocorrelation: {s['acf_outside_band']} of {s['acf_lags']} lags outside the 95 % band\n"
            f"- Ljung-Box (lag {s['ljung_box_lag']}): Q = {s['ljung_box_stat']:.1f}, p = {s['ljung_box_pvalue']:.3g}\n"
            f"- cumulated periodogram: max deviation {s['cpgram_max_dev']:.3f} (95 % KS band {s['cpgram_band']:.3f})\n"
            f"- all three within their 5 % bands: {'yes' if s['white'] else 'no'}")


__all__ = ["fit_run", "fit_summary", "eiv_summary", "uncertainty_summary",
            "table4_markdown", "reported_table", "write_report", "VALVE_FIELDS", "PAPER_TABLE4"]
