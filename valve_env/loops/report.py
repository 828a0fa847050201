"""The loop-diagnosis report: OP-PV phase plot, the fitted loop's simulation against the data,
residual diagnostics (statsmodels ACF and Ljung-Box), the band's profile likelihood
(docs/loops.md, "Report")."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from valve_env.loops.diagnose import Diagnosis
from valve_env.loops.model import residuals, simulate
from valve_env.outputs import OutputSet

FIGURES = ("phase.png", "simulation.png", "residuals.png", "profile.png")


def write_report(diag: Diagnosis, outs: OutputSet, directory: Path) -> list[Path]:
    """Stage ``report.md`` and the figures in ``directory`` (declared in ``outs`` by the caller)."""
    from valve_env.plotting import headless

    headless()
    import matplotlib.pyplot as plt
    from statsmodels.stats.diagnostic import acorr_ljungbox
    from statsmodels.tsa.stattools import acf

    loop, s, R = diag.loop, diag.settings, diag.result
    best = R["stiction"]["model"] if R["cause"] == "stiction" else "linear"
    fit = diag.fits[best]
    lin = diag.fits["linear"]
    t_min = loop.time_s / 60.0
    paths = {name: directory / name for name in (*FIGURES, "report.md")}

    fig, ax = plt.subplots(figsize=(5, 4.5))
    ax.plot(loop.op, loop.pv, lw=0.5, color="C0")
    ax.set_xlabel("OP, %")
    ax.set_ylabel("PV")
    ax.set_title(f"{loop.tag}: OP-PV phase plot")
    fig.tight_layout()
    outs.stage(paths["phase.png"], lambda p: fig.savefig(p, dpi=90, format="png"))
    plt.close(fig)

    fig, axs = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    axs[0].plot(t_min, loop.op, lw=0.7, label="OP (data)")
    if best != "linear":
        axs[0].plot(t_min, fit.path(loop.op), lw=0.9, label=f"valve position ({best}, S = {fit.S:.3g} %)")
    if loop.mv is not None:
        axs[0].plot(t_min, loop.mv, lw=0.7, ls=":", label="MV (measured)")
    axs[0].set_ylabel("%")
    axs[0].legend(fontsize=7)
    axs[1].plot(t_min, loop.pv, lw=0.5, color="0.5", label="PV (data)")
    axs[1].plot(t_min, loop.sp, lw=0.8, color="k", label="SP")
    axs[1].plot(t_min, simulate(loop.op, lin.process), lw=0.9, label="linear valve, simulated")
    if best != "linear":
        axs[1].plot(t_min, simulate(fit.path(loop.op), fit.process), lw=0.9, label=f"{best} valve, simulated")
    axs[1].set_xlabel("time, min")
    axs[1].legend(fontsize=7)
    fig.tight_layout()
    outs.stage(paths["simulation.png"], lambda p: fig.savefig(p, dpi=90, format="png"))
    plt.close(fig)

    e = residuals(loop.pv, fit.path(loop.op), fit.process, s.k0)
    nl = min(40, e.size // 4)
    r = acf(e, nlags=nl, fft=True)
    lb = acorr_ljungbox(e, lags=[10, 20], return_df=True)
    fig, axs = plt.subplots(1, 2, figsize=(9, 3.2))
    axs[0].bar(np.arange(1, nl + 1), r[1:], width=0.6)
    axs[0].axhline(1.96 / np.sqrt(e.size), ls="--", color="k", lw=0.7)
    axs[0].axhline(-1.96 / np.sqrt(e.size), ls="--", color="k", lw=0.7)
    axs[0].set_title("residual ACF")
    axs[0].set_xlabel("lag, samples")
    axs[1].hist(e, bins=40, color="C0")
    axs[1].set_title("residual histogram")
    fig.tight_layout()
    outs.stage(paths["residuals.png"], lambda p: fig.savefig(p, dpi=90, format="png"))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for name in ("backlash", "stiction"):
        prof = np.array(diag.fits[name].profile)
        ax.semilogx(prof[:, 0], diag.neff_factor * 2 * (prof[:, 1] - lin.loglik), ".-", label=name)
    ax.axhline(0.0, color="k", lw=0.7)
    ax.set_xlabel("band S, % of OP")
    ax.set_ylabel("adjusted LR vs linear")
    ax.legend(fontsize=7)
    fig.tight_layout()
    outs.stage(paths["profile.png"], lambda p: fig.savefig(p, dpi=90, format="png"))
    plt.close(fig)

    lines = [f"# Loop diagnosis: {loop.tag}", "", f"Source: `{loop.source}`, {loop.n} samples at {loop.dt:g} s.", "",
             f"**Cause: {R['cause']}**", ""]
    if "stiction" in R:
        st = R["stiction"]
        lines += [f"Band S = {st['band_pct']:.3g} % of OP (sd {st['std_pct']:.2g} %, 95 % interval "
                  f"{st['ci95_pct'][0]:.3g}-{st['ci95_pct'][1]:.3g} %), slip jump J = {st['jump_pct']:.3g} %, "
                  f"{st['kind']}.", ""]
        if not st["band_resolved"] and st["band_fitted_pct"] < st["sampling_offset_pct"]:
            lines += [f"The fitted band ({st['band_fitted_pct']:.3g} %) is below one sample's OP move "
                      f"({st['sampling_offset_pct']:.3g} %): the record does not resolve it (the limit cycle is "
                      "about as fast as the sampling), so the band is a rough figure; its sd says so.", ""]
        elif not st["band_resolved"]:
            lines += ["The fitted valve never crosses its band back in this record (it only moves on in its first "
                      "direction): the record shows the slip jump and that the band exceeds every push back, not the "
                      "band itself, so the band is a rough figure.", ""]
    for note in R["notes"]:
        lines.append(f"- note: {note}")
    lines += ["", "| candidate | loglik | params | LR | LR adjusted | p | delta BIC | S % | J % | process |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for f in R["findings"]:
        lines.append(f"| {f['candidate']} | {f['loglik']:.1f} | {f['n_params']} | {f['lr_stat']:.1f} | "
                     f"{f['lr_stat_adjusted']:.1f} | {f['p_value']:.3g} | {f['delta_bic']:.1f} | {f['S_pct']:.3g} | "
                     f"{f['J_pct']:.3g} | {f['process']} |")
    d = R["decision"]
    sh = d["shape"]
    basis = "justifies stiction" if d["by_likelihood"] else "does not justify stiction"
    lines += ["", f"n_eff/n of the linear residuals: {d['neff_factor']:.3f}; held-out log-likelihood gain of "
              f"{d['best_nonlinear']} over linear: {d['heldout_loglik_gain']:.1f}.", "",
              f"The likelihood comparison {basis}. OP-{'dPV' if sh['integrating'] else 'PV'} cross-correlation (Horch, "
              "reported, not part of the decision): "
              f"signed phase {sh['phase_signed_deg']:.0f} deg (tau_r {sh['tau_r']:.1f}, tau_l {sh['tau_l']:.1f} "
              f"samples), |r(0)|/max|r| = {sh['ratio']:.2f}.", "",
              f"Oscillation: {R['oscillation']}", "",
              "Ljung-Box on the residuals of the chosen model: " + ", ".join(
                  f"lag {int(k)}: Q = {row.lb_stat:.1f}, p = {row.lb_pvalue:.2g}" for k, row in lb.iterrows()), "",
              "![phase](phase.png)", "", "![simulation](simulation.png)", "", "![residuals](residuals.png)", "",
              "![profile](profile.png)", ""]
    outs.write_text(paths["report.md"], "\n".join(lines))
    return list(paths.values())


__all__ = ["write_report", "FIGURES"]
