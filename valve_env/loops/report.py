"""The loop-diagnosis report (docs/loops.md, "Report"): one story, one band and one model name in the headline, the
table and the figures; the OP-PV phase plot, the fitted loop's simulation against the data, the residual diagnostics
(statsmodels ACF and Ljung-Box) and the band's profile likelihood."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from valve_env.loops.diagnose import MODEL, LoopDiagnosis, sd_text
from valve_env.loops.model import ValveFit, fit_valve, residuals, simulate
from valve_env.outputs import OutputSet

FIGURES = ("phase.png", "simulation.png", "residuals.png", "profile.png")

#: the detectors' lines in the report: name, the result's key, the statistic's description
_DETECTORS = (("Horch (OP-PV cross-correlation phase, deg)", "horch"),
              ("Horch, integrating variant (OP-dPV, deg)", "horch_dpv"),
              ("He et al. (stiction index of OP)", "he"),
              ("Kano et al. (stuck-time share)", "kano"),
              ("Choudhury et al. (peak squared bicoherence)", "bicoherence"),
              ("OP-PV ellipse (normalised area)", "ellipse"))


def _headline(R: dict[str, Any]) -> str:
    if R["cause"] == "insufficient_data":
        return f"**Cause: insufficient_data** ({R['reason']})"
    line = f"**Cause: {R['cause']}** (detection by {decision(R['detection'])})"
    if "stiction" in R:
        line += f"; {band_text(R['stiction'])}"
    return line


#: said beside a band the detection did not ask for (``--quantify``), wherever the band is given
ON_REQUEST = "fitted on request; stiction not detected"


def band_text(st: dict[str, Any]) -> str:
    """The band's one label (``st``: the result's ``stiction`` block), with :data:`ON_REQUEST` where the detection
    did not ask for it: as the headline and ``loop-diagnose``'s line on stdout give it."""
    return st["label"] + ("" if st["detected"] else f" ({ON_REQUEST})")


def decision(det: dict[str, Any]) -> str:
    """The detection as the rule that decided it reads: Horch's phase for the default rule, the probability and its
    threshold for the learned one; then its verdict."""
    verdict = "stiction" if det["stiction"] else "no stiction"
    if det.get("rule", {}).get("name") == "learned":
        return (f"the learned rule: probability of stiction {det['probability']:.2f}, threshold "
                f"{det['threshold']:.2f}: {verdict}")
    h = det["detectors"]["horch"]
    return f"Horch's test: OP-PV phase {h['statistic']:.0f} deg: {verdict}"


def _model_fit(diag: LoopDiagnosis) -> tuple[str, ValveFit]:
    """The model the figures show: the stick-slip fit when a band was fitted, else the linear valve (fitted here if
    the diagnosis did not need it)."""
    if MODEL in diag.fits:
        return diag.result["stiction"]["label"], diag.fits[MODEL]
    lin = diag.fits.get("linear") or fit_valve(diag.loop.op, diag.loop.pv, "linear", diag.settings)
    return "linear valve", lin


def _text_figure(plt: Any, text: str) -> Any:
    fig, ax = plt.subplots(figsize=(5, 1.2))
    ax.axis("off")
    ax.text(0.5, 0.5, text, ha="center", va="center", fontsize=9)
    return fig


def write_loop_report(diag: LoopDiagnosis, outs: OutputSet, directory: Path) -> list[Path]:
    """Stage ``report.md`` and the figures in ``directory`` (declared in ``outs`` by the caller)."""
    from valve_env.plotting import headless

    headless()
    import matplotlib.pyplot as plt

    from valve_env.ident.tests import residual_report

    loop, s, R = diag.loop, diag.settings, diag.result
    paths = {name: directory / name for name in (*FIGURES, "report.md")}

    def save(name: str, fig: Any) -> None:
        outs.stage(paths[name], lambda p: fig.savefig(p, dpi=90, format="png"))
        plt.close(fig)

    lines = [f"# Loop diagnosis: {loop.tag}", "", f"Source: `{loop.source}`, {loop.n} samples at {loop.dt:g} s.", "",
             _headline(R), ""]
    for note in R["notes"]:
        lines.append(f"- note: {note}")
    if R["notes"]:
        lines.append("")

    fig, ax = plt.subplots(figsize=(5, 4.5))
    ax.plot(loop.op, loop.pv, lw=0.5, color="C0")
    ax.set_xlabel("OP, %" + (" of its observed range" if loop.op_scaled_from else ""))
    ax.set_ylabel("PV")
    ax.set_title(f"{loop.tag}: OP-PV phase plot", fontsize=9)
    fig.tight_layout()
    save("phase.png", fig)

    if R["cause"] == "insufficient_data":
        for name in ("simulation.png", "residuals.png", "profile.png"):
            save(name, _text_figure(plt, f"not computed: {R['reason']}"))
        lines += ["![phase](phase.png)", ""]
        outs.write_text(paths["report.md"], "\n".join(lines))
        return list(paths.values())

    label, fit = _model_fit(diag)
    lin = diag.fits.get("linear") or (fit if fit.valve == "linear" else None)
    t_min = loop.time_s / 60.0
    fig, axs = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    axs[0].plot(t_min, loop.op, lw=0.7, label="OP (data)")
    if fit.valve != "linear":
        axs[0].plot(t_min, fit.path(loop.op), lw=0.9, label=f"valve position: {label}")
    if loop.mv is not None:
        axs[0].plot(t_min, loop.mv, lw=0.7, ls=":", label="MV (measured)")
    axs[0].set_ylabel("%")
    axs[0].legend(fontsize=7)
    axs[1].plot(t_min, loop.pv, lw=0.5, color="0.5", label="PV (data)")
    axs[1].plot(t_min, loop.sp, lw=0.8, color="k", label="SP")
    if lin is not None and fit.valve != "linear":
        axs[1].plot(t_min, simulate(loop.op, lin.process), lw=0.8, ls="--", label="linear valve, simulated")
    axs[1].plot(t_min, simulate(fit.path(loop.op), fit.process), lw=0.9, label=f"{label}, simulated")
    axs[1].set_xlabel("time, min")
    axs[1].legend(fontsize=7)
    fig.tight_layout()
    save("simulation.png", fig)

    e = residuals(loop.pv, fit.path(loop.op), fit.process, s.k0)
    white = residual_report(e, nlags=min(40, e.size // 4))  # the core's whiteness checks: ACF, Ljung-Box
    lb = white.ljung_box.loc[[10, 20]]
    fig, axs = plt.subplots(1, 2, figsize=(9, 3.2))
    axs[0].bar(white.lags[1:], white.acf[1:], width=0.6)
    axs[0].axhline(white.acf_band, ls="--", color="k", lw=0.7)
    axs[0].axhline(-white.acf_band, ls="--", color="k", lw=0.7)
    axs[0].set_title(f"residual ACF: {label}", fontsize=8)
    axs[0].set_xlabel("lag, samples")
    axs[1].hist(e, bins=40, color="C0")
    axs[1].set_title("residual histogram", fontsize=8)
    fig.tight_layout()
    save("residuals.png", fig)

    if fit.valve != "linear" and fit.profile:
        prof = np.array(fit.profile)
        fig, ax = plt.subplots(figsize=(5, 3.5))
        ax.semilogx(prof[:, 0], 2 * (prof[:, 1] - prof[:, 1].max()), ".-")
        st = R["stiction"]
        ax.axvline(st["band_fitted_pct"], color="C1", lw=0.8, label=f"fitted S {st['band_fitted_pct']:.3g} % "
                   f"(+ sampling offset {st['sampling_offset_pct']:.2g} % = band {st['band_pct']:.3g} %)")
        ax.axhline(-3.84, color="k", lw=0.7, ls="--")
        ax.set_xlabel("band S, % of OP")
        ax.set_ylabel("2 (ln L(S) - max ln L)")
        ax.set_title(label, fontsize=8)
        ax.legend(fontsize=7)
        fig.tight_layout()
        save("profile.png", fig)
    else:
        save("profile.png", _text_figure(plt, "no band fitted (stiction not detected; --quantify fits it)"))

    det = R["detection"]
    rule = det.get("rule", {})
    lines += ["## Detection", "",
              f"The decision: {rule.get('kind', '')} (`--rule {rule.get('name', '')}`): "
              f"{'stiction' if det['stiction'] else 'no stiction'}. The learned rule (a logistic regression fitted "
              f"on simulated loops only) gives a probability of stiction of {det['probability']:.2f} against its "
              f"threshold {det['threshold']:.2f}.", "",
              "| detector | statistic | its own verdict |", "|---|---|---|"]
    for name, key in _DETECTORS:
        d = det["detectors"][key]
        verdict = d.get("verdict", "stiction" if d.get("stiction") else "no stiction")
        if key == "ellipse":
            verdict = "(no published threshold)"
        lines.append(f"| {name} | {d['statistic']:.3g} | {verdict} |")
    osc = R["oscillation"]
    lines += ["", "Oscillation of the control error (Thornhill et al.): " + (
        f"regular, period {osc['period_s']:.0f} s (regularity {osc['regularity']:.2g})" if osc["oscillating"]
        else "none detected") + (f"; the linear loop model from OP explains {100 * osc['linear_sim_r2']:.0f} % of the "
                                 "PV's variance" if osc.get("linear_sim_r2") is not None else "") + ".", ""]
    if "stiction" in R:
        st = R["stiction"]
        lines += ["## Band (grey-box model)", "",
                  f"Model: {st['label']}.", "",
                  "| quantity | value |", "|---|---|",
                  f"| model | {st['label']} |",
                  f"| band S, % of OP | {st['band_pct']:.3g} |",
                  f"| sd of S, % | {sd_text(st['std_pct'])} |",
                  f"| 95 % interval of S, % | {st['ci95_pct'][0]:.3g} to {st['ci95_pct'][1]:.3g} |",
                  f"| slip jump J, % of OP | {st['jump_pct']:.3g} |",
                  f"| fitted S before the sampling offset, % | {st['band_fitted_pct']:.3g} |",
                  f"| sampling offset (one sample's OP move), % | {st['sampling_offset_pct']:.2g} |",
                  f"| controller's output jitter within a sample driving the valve (sd), % | "
                  f"{st['op_jitter_pct']:.2g} |" if st.get("op_jitter_pct") else
                  "| controller's output jitter within a sample driving the valve | none (the smooth sub-sample OP) |",
                  f"| band read on the record's first and second half, % | {st['halves_band_pct'][0]:.3g}, "
                  f"{st['halves_band_pct'][1]:.3g} |",
                  "| band read by each valve that could have moved between the samples, % | "
                  + ", ".join(f"{k} {v:.3g}" for k, v in st["valves_band_pct"].items()) + " |",
                  f"| band resolved by the record | {'yes' if st['band_resolved'] else 'no'} |",
                  f"| detected by the shape tests | {'yes' if st['detected'] else 'no (fitted on request)'} |", ""]
    if R["findings"]:
        lines += ["Likelihood of each model fitted (reported; the decision is the detection's):", "",
                  "| model | log-likelihood | parameters | LR vs linear | p | delta BIC | process |",
                  "|---|---|---|---|---|---|---|"]
        for f in R["findings"]:
            name = R["stiction"]["label"] if f["candidate"] == MODEL else "linear valve"
            lines.append(f"| {name} | {f['loglik']:.1f} | {f['n_params']} | {f['lr_stat']:.1f} | {f['p_value']:.3g} | "
                         f"{f['delta_bic']:.1f} | {f['process']} |")
        lines.append("")
    lines += [f"Residuals of the {label}: Ljung-Box " + ", ".join(
        f"lag {k}: Q = {q:.1f}, p = {p:.2g}"
        for k, q, p in zip(lb.index.to_numpy(dtype=int), lb["lb_stat"], lb["lb_pvalue"], strict=True)) + ".", "",
        "![phase](phase.png)", "", "![simulation](simulation.png)", "", "![residuals](residuals.png)", "",
        "![profile](profile.png)", ""]
    outs.write_text(paths["report.md"], "\n".join(lines))
    return list(paths.values())


__all__ = ["write_loop_report", "FIGURES"]
