"""The fit's figures (the seed paper's Fig. 5-7): measured, predicted and simulated opening, the phase
diagram and the whiteness of the residuals (the statistics are :mod:`valve_env.ident.tests`'). Figures use
matplotlib's Agg backend.
"""

from __future__ import annotations

from pathlib import Path

from valve_env.plotting import headless, save_figure

headless()

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from valve_env.ident.tests import ResidualReport, residual_report  # noqa: E402


# --------------------------------------------------------------------------- figures
def paper_figure(time_s: np.ndarray, measured: np.ndarray, predicted: np.ndarray, simulated: np.ndarray,
                 residuals: np.ndarray, path: str | Path, title: str = "", nlags: int = 40,
                 ylabel: str = "x [mm]") -> Path:
    """The paper's Fig. 6/7: measured, predicted and simulated output; residuals; residual ACF
    (:func:`valve_env.ident.tests.residual_report`'s, with its 95 % band)."""
    th = np.asarray(time_s, dtype=float) / 3600.0
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), constrained_layout=True)
    ax[0].plot(th, measured, ".", ms=1.5, color="0.3", label="measured")
    ax[0].plot(th, predicted, "-", lw=0.8, color="C0", label="predicted (one step)")
    ax[0].plot(th, simulated, "-", lw=0.8, color="C3", label="simulated")
    ax[0].set_ylabel(ylabel)
    ax[0].legend(loc="best", fontsize=8)
    if title:
        ax[0].set_title(title)
    ax[1].plot(th, residuals, "-", lw=0.5, color="C0")
    ax[1].axhline(0, color="k", lw=0.5)
    ax[1].set_ylabel("residual")
    ax[1].set_xlabel("time [h]")
    rep = residual_report(residuals, nlags=nlags)
    ax[2].vlines(rep.lags, 0, rep.acf, color="C0")
    ax[2].axhline(rep.acf_band, ls="--", color="C3", lw=0.8)
    ax[2].axhline(-rep.acf_band, ls="--", color="C3", lw=0.8)
    ax[2].axhline(0, color="k", lw=0.5)
    ax[2].set_xlabel("lag")
    ax[2].set_ylabel("ACF of residuals")
    return save_figure(fig, path)


def phase_diagram(temperature: np.ndarray, opening: np.ndarray, path: str | Path, simulated: np.ndarray | None = None,
                  title: str = "") -> Path:
    """The paper's Fig. 5: valve opening against valve (gas) temperature; the hysteresis loop."""
    fig, ax = plt.subplots(figsize=(6, 5), constrained_layout=True)
    ax.plot(temperature, opening, ".", ms=1.5, color="0.4", label="measured")
    if simulated is not None:
        ax.plot(temperature, simulated, "-", lw=0.6, color="C3", label="simulated")
        ax.legend(loc="best", fontsize=8)
    ax.set_xlabel("T_g [degC]")
    ax.set_ylabel("x [mm]")
    if title:
        ax.set_title(title)
    return save_figure(fig, path)


def whiteness_figure(rep: ResidualReport, path: str | Path, title: str = "") -> Path:
    """Cumulated periodogram with its KS band and the cross-correlations with the inputs."""
    fig, ax = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    ax[0].plot(rep.freq, rep.cpgram, color="C0")
    line = rep.freq / 0.5
    ax[0].plot(rep.freq, line, "k", lw=0.6)
    ax[0].plot(rep.freq, line + rep.cpgram_band, "--", color="C3", lw=0.8)
    ax[0].plot(rep.freq, line - rep.cpgram_band, "--", color="C3", lw=0.8)
    ax[0].set_xlabel("frequency [1/sample]")
    ax[0].set_ylabel("cumulated periodogram")
    for i, (name, r) in enumerate(rep.ccf.items()):
        ax[1].plot(np.arange(len(r)), r, ".-", ms=3, lw=0.6, color=f"C{i}", label=name)
    ax[1].axhline(rep.ccf_band, ls="--", color="C3", lw=0.8)
    ax[1].axhline(-rep.ccf_band, ls="--", color="C3", lw=0.8)
    ax[1].set_xlabel("lag")
    ax[1].set_ylabel("cross-correlation with input")
    if rep.ccf:
        ax[1].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


__all__ = ["paper_figure", "phase_diagram", "whiteness_figure"]
