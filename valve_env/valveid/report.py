"""The human reports of the valve's identification: markdown with PNG figures (matplotlib, Agg backend).
:func:`write_report` writes either:

* a diagnosis (``thermovalve diagnose``), written for a valve engineer who has two minutes: the verdict
  first (the cause and its evidence), then the misfit before, the candidates, the extended model's
  parameters with their uncertainties, the gain, and the residuals after;
* a fit (``thermovalve fit --report DIR``), like the seed paper: Table 4, Fig. 5-7, the correlation of
  the estimates and the whiteness of the residuals, every number that of the one reported fit.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from valve_env.effects import REGISTRY as EFFECTS
from valve_env.ident.mle import MLEstimator
from valve_env.ident.tests import residual_report
from valve_env.valveid.bootstrap import conditional_std
from valve_env.valveid.diagnose import Diagnosis
from valve_env.valveid.diagnostics import paper_figure, phase_diagram, whiteness_figure
from valve_env.valveid.fit import PAPER_TABLE4, VALVE_FIELDS, fit_summary
from valve_env.valveid.fitting import BASE_PARAMS, NOISE_PARAMS, Model, RunData
from valve_env.valveid.preprocess import describe

#: the fit report's parameter labels and units
_LABELS = {"sigma": ("sigma", "N/K"), "F_hmax": ("F_h,max", "N"), "p_bset": ("p_b,set", "MPa"),
           "s_F": ("s_F (friction diffusion)", "N/sqrt(s)"), "s_x": ("s_x (observation sd)", "mm")}
#: each output-error parameter's unit, as the fit and the effects' registry declare it
UNITS: dict[str, str] = {**{q.name: q.unit for q in (*BASE_PARAMS, *NOISE_PARAMS)},
                         **{p.name: p.unit for e in EFFECTS.values() for p in e.parameters}}
MEANING = {"sigma": "Dahl stiffness", "F_hmax": "maximum friction force", "p_bset": "bellows pressure at the set point",
           "s_w": "measurement noise sd", "s_e": "model error sd (Ornstein-Uhlenbeck)",
           "tau_e": "model error time constant", "tau_s": "bulb time constant", "beta": "medium temperature weight",
           "band_mm": "stick band of the stem", "rate_MPa_per_h": "set-pressure drift"}


def _fmt(v: float) -> str:
    if v is None or not math.isfinite(v):
        return "n/a"
    if v == 0:
        return "0"
    a = abs(v)
    return f"{v:.4g}" if 1e-3 <= a < 1e5 else f"{v:.3e}"


def _series(model: Model, data: RunData,
            params: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, str]:
    """(simulated opening, gas temperature, standardised one-step errors, residual, residual label).

    The residual is measured minus simulated; for a model with stiction, whose open-loop staircase
    drifts out of step with the measured one, it is the one-step prediction error instead."""
    xs, Tg, _ = model.simulate(data, params)
    nu, S = model.prediction_errors(data, params)
    if any(EFFECTS[e].variance_gain for e in model.effects):
        return xs, Tg, nu / np.sqrt(S), nu, "one-step prediction error"
    return xs, Tg, nu / np.sqrt(S), data.x - xs, "measured - simulated"


def write_figures(d: Diagnosis, out_dir: Path, stem: str) -> list[tuple[str, str]]:
    """Write the PNG figures; returns (file name, caption) pairs."""
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    data = d.valid if d.valid_range[0] > 0 else d.train
    a, b = d.valid_range if d.valid_range[0] > 0 else (len(data), len(data))
    base_m = Model((), d.valve)
    fin_m = Model(d.final.effects, d.valve)
    xb, Tgb, zb, rb, lb = _series(base_m, data, d.base.params)
    xf, Tgf, zf, rf, lf = _series(fin_m, data, d.final.params)
    th = (data.t - data.t[0]) / 3600.0
    figs: list[tuple[str, str]] = []

    def save(fig: Any, suffix: str, caption: str) -> None:
        fig.tight_layout()
        figs.append((save_figure(fig, out_dir / f"{stem}_{suffix}.png", dpi=90).name, caption))
    label_f = "+".join(d.final.effects) or "base"

    fig, ax = plt.subplots(3, 1, figsize=(11, 8.5), sharex=True, gridspec_kw={"height_ratios": [2, 1.3, 1]})
    ax[0].plot(th, data.x, ".", ms=1.5, color="0.5", label="measured x_mm")
    ax[0].plot(th, xb, lw=1.0, color="tab:red", label="base model (simulated)")
    if d.final.effects:
        ax[0].plot(th, xf, lw=1.0, color="tab:blue", label=f"{label_f} (simulated)")
    ax[0].set_ylabel("opening, mm")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(th, rb * 1e3, lw=0.6, color="tab:red", label=f"base: {lb}")
    if d.final.effects:
        ax[1].plot(th, rf * 1e3, lw=0.6, color="tab:blue", label=f"{label_f}: {lf}")
    ax[1].set_ylabel("residual, um")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[2].plot(th, data.T_raw, lw=0.6, label="T_tank_C")
    ax[2].plot(th, data.M_raw, lw=0.6, label="T_med_C")
    ax[2].set_ylabel("degC")
    ax[2].set_xlabel("time, h")
    ax[2].legend(loc="upper right", fontsize=8)
    for axx in ax:
        if b > a:
            axx.axvspan(th[a], th[b - 1], color="0.9", zorder=0)
    ax[0].set_title("Opening: measured and simulated (shaded: held out for validation)", fontsize=10)
    save(fig, "fit", "The run, the base model's and the extended model's simulation, and the residuals.")

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    rising = data.vT > 0
    for axx, xs_, Tg_, r_, title in ((ax[0], xb, Tgb, rb, "base model"), (ax[1], xf, Tgf, rf, label_f)):
        r = r_ * 1e3
        lim = max(float(np.percentile(np.abs(r), 99)), 1e-3)
        sc = axx.scatter(Tg_, data.x, c=r, s=2, cmap="coolwarm", vmin=-lim, vmax=lim)
        axx.plot(Tg_[rising], xs_[rising], ",", color="k", alpha=0.3)
        axx.set_xlabel("gas temperature T_g (model), degC")
        axx.set_title(f"phase diagram, colour = residual ({title})", fontsize=10)
        fig.colorbar(sc, ax=axx, label="um")
    ax[0].set_ylabel("measured opening, mm")
    save(fig, "phase", "Where in the phase diagram the misfit lies (colour: measured minus simulated).")

    fig, ax = plt.subplots(1, 2, figsize=(11, 3.6))
    lags = np.arange(1, 31)
    for z, lab, c in ((zb, "base", "tab:red"), (zf, label_f, "tab:blue")):
        acf = [float(np.corrcoef(z[:-k], z[k:])[0, 1]) for k in lags]
        ax[0].plot(lags, acf, "o-", ms=3, color=c, label=lab)
    ci = 1.96 / math.sqrt(len(zb))
    ax[0].axhspan(-ci, ci, color="0.85")
    ax[0].set_xlabel("lag, samples")
    ax[0].set_ylabel("autocorrelation")
    ax[0].set_title("one-step prediction errors (standardised)", fontsize=10)
    ax[0].legend(fontsize=8)
    win = 3600.0
    edges = np.arange(0, data.t[-1] - data.t[0] + win, win)
    for rr, lab, c in ((rb, "base", "tab:red"), (rf, label_f, "tab:blue")):
        vals = [np.sqrt(np.mean(rr[(data.t - data.t[0] >= e0) & (data.t - data.t[0] < e1)] ** 2)) * 1e3
                if ((data.t - data.t[0] >= e0) & (data.t - data.t[0] < e1)).any() else np.nan
                for e0, e1 in zip(edges[:-1], edges[1:], strict=True)]
        ax[1].step(edges[:-1] / 3600, vals, where="post", color=c, label=lab)
    ax[1].set_xlabel("time, h")
    ax[1].set_ylabel("RMS per hour, um")
    ax[1].set_title("where in time the misfit lies", fontsize=10)
    ax[1].legend(fontsize=8)
    save(fig, "residuals", "Residual whiteness before and after, and the misfit hour by hour.")
    return figs


def render_markdown(d: Diagnosis, figures: list[tuple[str, str]], title: str = "run") -> str:
    j = d.to_json()
    diag = d.diagnostics
    L: list[str] = [f"# Valve diagnosis: {title}", ""]
    g = j["gain"]
    if d.cause == "none":
        best = d.findings[0] if d.findings else None
        L += ["**Cause: none.** The calibrated base model (docs/reference.md s. 1) is not improved by any named effect "
              "in a way that is both statistically significant and real on held-out data.", ""]
        if best is not None:
            L += [f"Closest candidate: `{best.effect}` (LR = {best.lr_stat:.1f}, p = {best.p_value:.2g}, "
                  f"delta BIC = {best.delta_bic:.1f}; validation RMS {best.validation_rms_before_mm * 1e3:.2f} -> "
                  f"{best.validation_rms_after_mm * 1e3:.2f} um, held-out log-likelihood gain "
                  f"{best.validation_loglik_gain:.1f})."
                  + "".join(f" Not named because {w}." for w in ["; ".join(d.not_named_because(best))] if w), ""]
    else:
        f = d.findings[0]
        eff = EFFECTS[d.cause]
        pars = ", ".join(f"{k} = {_fmt(v)} ± {_fmt(f.fit.std.get(k, float('nan')))} {UNITS.get(k, '')}"
                         for k, v in f.fit.effect_params.items())
        L += [f"**Cause: `{d.cause}`** ({eff.title}): {pars}.", ""]
        u = f.uncertainty or {}
        if u:
            ci = "; ".join(f"{k} {_fmt(a)} .. {_fmt(b)}" for k, (a, b) in u.get("interval_95", {}).items())
            corr = u.get("bias_corrected", {})
            bias = ", ".join(f"{k} {_fmt(v)}{' (corrected)' if corr.get(k) else ''}"
                             for k, v in u.get("bias", {}).items())
            hess = ", ".join(f"{k} {_fmt(v)}" for k, v in u.get("hessian_std", {}).items())
            L += [f"*Uncertainty ({f.std_method}):* the ± is one sd from re-estimating the model on "
                  f"{u.get('replicates', 0)} runs simulated from the fit (the run's own residuals resampled in "
                  f"blocks as the opening's noise, white resting noise with stiction; temperature smoothing "
                  f"included), or the inverse-Hessian/HAC sd where that is larger; bias of the re-estimates "
                  f"{bias}; basic bootstrap 95 % interval {ci}; inverse-Hessian/HAC sd {hess}.", ""]
            pre = u.get("preprocessing") or {}
            if pre:
                both = ", ".join(f"{k} {_fmt(pre['irw'][k])} (IRW-RTS) / {_fmt(v)} (TV)" for k, v in pre["tv"].items())
                L += [f"*Pre-processing:* refitted on TV-denoised temperatures (the estimate above), half the "
                      f"difference added to the sd (errors in variables, docs/uncertainty.md): {both}.", ""]
        else:
            L += [f"*Uncertainty:* {f.std_method}.", ""]
        bends = (f"; the likelihood ratio and the held-out gain are taken {f.bends_left_out()}"
                 if f.rounding_bends else "")
        L += [f"*Physics:* {eff.physics}", "",
              f"*Evidence:* likelihood ratio {f.lr_stat:.1f} (p = {f.p_value:.2g}), delta AIC = "
              f"{f.delta_aic:.1f}, delta BIC = {f.delta_bic:.1f}; on data not used for fitting "
              f"({d.settings['validation']}) the one-step RMS goes from {f.validation_rms_before_mm * 1e3:.2f} "
              f"to {f.validation_rms_after_mm * 1e3:.2f} um and the log-likelihood rises by "
              f"{f.validation_loglik_gain:.1f}{bends}.", ""]
        if len(d.selected) > 1:
            L += [f"*Forward selection* found {len(d.selected)} effects, in this order: "
                  + " -> ".join(f"`{e}`" for e in d.selected) + ".", ""]
    L += [f"*Gain:* validation one-step RMS {g['validation_rms_before_mm'] * 1e3:.2f} -> "
          f"{g['validation_rms_after_mm'] * 1e3:.2f} um ({g['validation_rms_reduction']:.0%} less); simulation RMS "
          f"on the fitting data {g['rms_before_mm'] * 1e3:.2f} -> {g['rms_after_mm'] * 1e3:.2f} um.", ""]
    sc = d.simulation_check
    if sc:
        L += [f"*Simulation check* ({sc['model']} model): the held-out opening simulated from the temperatures "
              f"alone is {sc['held_out_simulation_rms_mm'] * 1e3:.2f} um RMS off, {sc['ratio']:.1f} times the "
              f"opening's noise ({sc['opening_noise_sd_mm'] * 1e3:.2f} um); "
              + ("within" if sc["passed"] else "**beyond**") + f" the {sc['limit']:g} a model that explains the record "
              "stays within (docs/diagnosis.md, \"The JSON\").", ""]
    if "stiction_band_mm" in (d.sensitivity or {}):
        b = d.sensitivity["stiction_band_mm"]
        L += ["*What this record can see:* " + (
            f"its slips would show a stick band of {b * 1e3:.1f} um or more; a smaller band may go unnamed"
            if b is not None else "its slips would show no stick band up to 100 um")
              + " (its noise, sampling and length decide this, not the valve; docs/diagnosis.md, "
              "\"What a `none` cannot see\").", ""]

    pre = {k: v for k, v in (d.preprocessing or {}).items() if v}
    if pre:

        L += ["## Pre-processing: the record as measured", ""]
        for which, notes in pre.items():
            L += [f"- {which}: {line}" for line in describe(notes)]
        L += [""]
    if d.notes:
        L += ["## Notes", ""] + [f"- {n}" for n in d.notes] + [""]
    L += ["## 1. What the calibrated model gets wrong", ""]
    L += [f"- Simulation RMS {diag['rms_mm'] * 1e3:.2f} um against a measurement noise of "
          f"{diag['noise_sd_mm'] * 1e3:.2f} um; slowly varying model error {diag['model_error_sd_mm'] * 1e3:.2f} um "
          f"(time constant {diag['model_error_time_constant_s']:.0f} s).",
          f"- Ljung-Box test of the one-step errors (lag {diag['ljung_box_lag']}): p = {diag['ljung_box_p']:.2g} "
          + ("(not white: information is left in the residuals)." if diag["ljung_box_p"] < 0.01 else "(white)."),
          f"- Mean residual while the temperature rises {diag['mean_mm']['rising'] * 1e3:+.2f} um, falls "
          f"{diag['mean_mm']['falling'] * 1e3:+.2f} um, rests {diag['mean_mm']['still'] * 1e3:+.2f} um "
          "(a lag shows as opposite signs for rising and falling).",
          "- Worst hours: " + ", ".join(f"{w['from_h']:.0f}-{w['to_h']:.0f} h ({w['rms_mm'] * 1e3:.1f} um)"
                                        for w in diag["worst_hours"]) + ".",
          "- Correlation of the residual with the effects' signatures: "
          + ", ".join(f"{k} {v:+.2f}" for k, v in diag["signature_correlation"].items())
          + " (correlation with the rate of T_tank, with T_med - T_tank and with time; for stiction the share "
          "of steps in which the model moves by more than 3 noise sd while the measured opening rests).", ""]
    for name, cap in figures:
        L += [f"![{cap}]({name})", "", f"*{cap}*", ""]

    L += ["## 2. Candidates (best first)", "",
          "| effect | parameters | LR | p | dAIC | dBIC | RMS before/after, um | validation RMS before/after, um | "
          "validation dlogL | size, um | named |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for f in d.findings:
        pars = ", ".join(f"{k}={_fmt(v)}±{_fmt(f.fit.std.get(k, float('nan')))}"
                         for k, v in f.fit.effect_params.items())
        L.append(f"| {f.effect} | {pars} | {f.lr_stat:.1f} | {f.p_value:.2g} | {f.delta_aic:.1f} | {f.delta_bic:.1f} | "
                 f"{f.rms_before_mm * 1e3:.2f}/{f.rms_after_mm * 1e3:.2f} | "
                 f"{f.validation_rms_before_mm * 1e3:.2f}/{f.validation_rms_after_mm * 1e3:.2f} | "
                 f"{f.validation_loglik_gain:.1f} | {f.effect_size_mm * 1e3:.2f} | {'yes' if f.accepted else 'no'} |")
    L += ["", f"A cause is named when p < {d.settings['alpha']:g} and delta BIC < 0 (significant), the effect "
          f"moves the simulated opening by at least {d.settings['min_effect_size_noise_sd']:g} noise sd RMS "
          "(relevant; column 'size'), and, on the validation data, the log-likelihood rises by more than "
          f"{d.settings['min_validation_gain']:g} and the one-step RMS does not rise (real; stiction, which "
          "improves the predicted variance rather than the mean, is exempt from the RMS condition).", ""]
    for i, step in enumerate(d.steps[1:], start=2):
        L += [f"Forward selection, step {i} (on top of {', '.join(step[0].reference)}): "
              + "; ".join(f"{f.effect}: LR {f.lr_stat:.1f}, p {f.p_value:.2g}, validation dlogL "
                          f"{f.validation_loglik_gain:.1f}{' (added)' if f.accepted and f is step[0] else ''}"
                          for f in step), ""]

    L += ["## 3. Parameters", "", "| parameter | meaning | base model | " + (
        f"{'+'.join(d.final.effects)} |" if d.final.effects else "|"), "|---|---|---|" + ("---|" if d.final.effects
                                                                                        else "")]
    names = list(d.final.params) if d.final.effects else list(d.base.params)
    for k in names:
        bv = (f"{_fmt(d.base.params[k])} ± {_fmt(d.base.std.get(k, float('nan')))}" if k in d.base.params else "-")
        row = f"| {k} ({UNITS.get(k, '')}) | {MEANING.get(k, '')} | {bv} |"
        if d.final.effects:
            row += f" {_fmt(d.final.params[k])} ± {_fmt(d.final.std.get(k, float('nan')))} |"
        L.append(row)
    withheld = list(conditional_std(d.final))
    if d.final.effects and withheld:
        L += ["", f"n/a beside {', '.join(withheld)} in the {'+'.join(d.final.effects)} column: sd withheld. With the "
              "band held at the slips' median, their inverse-Hessian sd is conditional on it and read off a likelihood "
              "with kinks (too small by one to two orders of magnitude on generated sticky runs); the JSON keeps it as "
              "`uncertainty.conditional_std` (docs/diagnosis.md, \"Known limits\")."]
    L += ["", f"Paper Table 4: sigma 6.41 ± 0.589 N/K, F_hmax 1.31 ± 0.067 N, p_bset 0.0776 ± 0.000892 MPa. "
          f"Fitted on {d.settings['n_train']} samples; validated on {d.settings['n_validation']} "
          f"({d.settings['validation']}). Diagnosis time {d.seconds:.1f} s.", ""]
    L += ["## How to read this report", "",
          "The base model is the seed paper's force balance with Dahl friction, fitted by maximum likelihood. "
          "Each named effect is a physical extension with its own parameters. Section 1 shows where the base "
          "model fails; section 2 how much each effect explains (a likelihood-ratio test, information criteria) "
          "and whether the gain holds on data the fit never saw. Parameters carry one standard deviation. See "
          "docs/diagnosis.md.", ""]
    return "\n".join(L)


#: the figures :func:`write_report` writes beside a diagnosis' ``<stem>.md``
FIGURE_SUFFIXES: tuple[str, ...] = ("_fit.png", "_phase.png", "_residuals.png")
#: the files :func:`write_report` writes into a fit's report directory (``validation.png`` too with validation data)
FIT_REPORT_FILES: tuple[str, ...] = ("report.md", "fit.png", "phase.png", "whiteness.png")


def write_report(result: Diagnosis | MLEstimator, path: str | Path, *, data: pd.DataFrame | None = None,
                 summary: dict[str, Any] | None = None, validation: pd.DataFrame | None = None,
                 name: str = "run") -> Path:
    """The report of ``result``; returns the markdown file's path.

    A :class:`Diagnosis`: ``path`` is the markdown file, its figures go beside it (:data:`FIGURE_SUFFIXES`).
    A fitted :class:`MLEstimator` of the base valve model: ``path`` is a directory (:data:`FIT_REPORT_FILES`),
    ``data`` the run it was fitted to, ``summary`` the ``thermovalve fit`` JSON (default :func:`fit_summary`),
    ``validation`` an independent run (paper Fig. 7), ``name`` the run's name in the titles."""
    if not isinstance(result, Diagnosis):
        if data is None:
            raise ValueError("the report of a fit needs the run it was fitted to (data=...)")
        return _write_fit_report(result, data, path, summary, validation, name)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figs = write_figures(result, path.parent, path.stem)
    path.write_text(render_markdown(result, figs, result.train.name))
    return path


def _fmt_spec(v: float, spec: str = ".3g") -> str:
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
        lines.append(f"| {label} | {v:.4g} | {_fmt_spec(sdv)} | {_fmt_spec(t, '.1f')} | {unit} | {_fmt_spec(pe)} "
                     f"| {_fmt_spec(ps)} |")
    return "\n".join(lines)


def quantisation_note(summary: dict[str, Any]) -> str | None:
    """One line on the quantised tank temperature's bracket (docs/uncertainty.md, "Errors in variables",
    item 4), from the ``thermovalve fit`` JSON, or None where the record is not quantised."""
    corr = (summary.get("eiv") or {}).get("bias_correction")
    if not corr:
        return None
    shifts = ", ".join(f"{k} {100.0 * (math.sqrt(1.0 + c) - 1.0):+.1f} %" for k, c in corr.items())
    return ("the tank temperature is quantised (its noise lies below its step): the estimates are the middle of "
            "the ML fit and its bias-corrected value by the temperature bootstrap, and the sd carries the "
            f"bracket ({shifts})")


def _at_reported(est: MLEstimator, summary: dict[str, Any]) -> MLEstimator:
    """``est`` moved to the reported parameters (the errors-in-variables estimate differs from the ML
    point estimate it starts from), so that every figure shows the fit the report reports."""
    import copy

    moved = copy.copy(est)
    values = {**est.params_, **{k: float(v) for k, v in summary["params"].items()}}
    moved.p_ = est.model.param_vector(values)
    moved.params_ = values
    return moved


def _write_fit_report(est: MLEstimator, data: pd.DataFrame, outdir: str | Path, summary: dict[str, Any] | None = None,
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
    qnote = quantisation_note(summary)
    if qnote:
        parts += [f"**Quantised record:** {qnote}.", ""]
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
        row = " | ".join(_fmt_spec(float(est.corr_.to_numpy()[i, j]), ".2f") for j in range(len(names)))
        lines.append(f"| {r} | {row} |")
    return "\n".join(lines)


def _diag_md(rep: Any) -> str:
    s = rep.summary()
    return (f"- autocorrelation: {s['acf_outside_band']} of {s['acf_lags']} lags outside the 95 % band\n"
            f"- Ljung-Box (lag {s['ljung_box_lag']}): Q = {s['ljung_box_stat']:.1f}, p = {s['ljung_box_pvalue']:.3g}\n"
            f"- cumulated periodogram: max deviation {s['cpgram_max_dev']:.3f} (95 % KS band {s['cpgram_band']:.3f})\n"
            f"- all three within their 5 % bands: {'yes' if s['white'] else 'no'}")


__all__ = ["write_report", "write_figures", "render_markdown", "reported_table", "quantisation_note",
           "FIGURE_SUFFIXES", "FIT_REPORT_FILES"]
