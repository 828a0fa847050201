"""Residual diagnostics and figures (the seed paper's Fig. 5-7).

Statistics from statsmodels where it has them (autocorrelation with bands,
Ljung-Box, cross-correlation); the cumulated periodogram with its
Kolmogorov-Smirnov band follows Holst, Holst, Madsen & Melgaard (1992) and
CTSM's validation tools. Figures use matplotlib's Agg backend.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from valve_env.plotting import headless

headless()

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from statsmodels.stats.diagnostic import acorr_ljungbox  # noqa: E402
from statsmodels.tsa.stattools import acf, ccf  # noqa: E402

#: 95 % Kolmogorov-Smirnov constant for the cumulated periodogram band.
KS_95 = 1.36


@dataclass
class ResidualReport:
    """Whiteness checks of one residual series (NaN removed)."""

    n: int
    lags: np.ndarray
    acf: np.ndarray
    acf_band: float
    ljung_box: pd.DataFrame
    freq: np.ndarray
    cpgram: np.ndarray
    cpgram_band: float
    cpgram_max_dev: float
    ccf: dict[str, np.ndarray] = field(default_factory=dict)
    ccf_band: float = 0.0

    @property
    def white(self) -> bool:
        """Ljung-Box at the largest lag and the cumulated periodogram both pass at 5 %."""
        return bool(self.ljung_box["lb_pvalue"].iloc[-1] > 0.05 and self.cpgram_max_dev < self.cpgram_band)

    def summary(self) -> dict[str, Any]:
        lb = self.ljung_box.iloc[-1]
        return {
            "n": self.n,
            "acf_outside_band": int(np.sum(np.abs(self.acf[1:]) > self.acf_band)),
            "acf_lags": int(len(self.acf) - 1),
            "ljung_box_lag": int(self.ljung_box.index[-1]),
            "ljung_box_stat": float(lb["lb_stat"]),
            "ljung_box_pvalue": float(lb["lb_pvalue"]),
            "cpgram_max_dev": float(self.cpgram_max_dev),
            "cpgram_band": float(self.cpgram_band),
            "white": self.white,
        }


def cumulated_periodogram(e: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Normalised cumulated periodogram at the Fourier frequencies (cycles/sample, 0..0.5]
    and the half-width of its 95 % Kolmogorov-Smirnov band around the white-noise line."""
    e = np.asarray(e, dtype=float)
    e = e - e.mean()
    n = len(e)
    I = np.abs(np.fft.rfft(e)) ** 2
    I = I[1:]
    freq = np.arange(1, len(I) + 1) / n
    c = np.cumsum(I)
    c = c / c[-1] if c[-1] > 0 else np.linspace(0, 1, len(c))
    m = len(I)
    return freq, c, KS_95 / np.sqrt(max(m - 1, 1))


def residual_report(e: np.ndarray, inputs: pd.DataFrame | None = None, nlags: int = 40) -> ResidualReport:
    """ACF with the +-1.96/sqrt(n) band, Ljung-Box up to ``nlags``, cumulated periodogram with
    its KS band, and the cross-correlation of the residuals with each input column."""
    e = np.asarray(e, dtype=float)
    ok = np.isfinite(e)
    x = e[ok]
    n = len(x)
    if n < 10:
        raise ValueError(f"too few residuals ({n}) for diagnostics")
    nl = int(min(nlags, n // 2 - 1))
    r = acf(x, nlags=nl, fft=True)
    lb = acorr_ljungbox(x, lags=[lag for lag in (5, 10, 20, nl) if lag <= nl] or [nl], return_df=True)
    freq, cp, band = cumulated_periodogram(x)
    dev = float(np.max(np.abs(cp - freq / 0.5)))
    out = ResidualReport(n=n, lags=np.arange(nl + 1), acf=r, acf_band=1.96 / np.sqrt(n), ljung_box=lb, freq=freq,
                         cpgram=cp, cpgram_band=band, cpgram_max_dev=dev, ccf_band=1.96 / np.sqrt(n))
    if inputs is not None:
        for col in inputs.columns:
            u = np.asarray(inputs[col], dtype=float)[ok]
            if np.nanstd(u) > 0:
                out.ccf[col] = ccf(x, u, adjusted=False)[: nl + 1]
    return out


# --------------------------------------------------------------------------- figures
def paper_figure(time_s: np.ndarray, measured: np.ndarray, predicted: np.ndarray, simulated: np.ndarray,
                 residuals: np.ndarray, path: str | Path, title: str = "", nlags: int = 40,
                 ylabel: str = "x [mm]") -> Path:
    """The paper's Fig. 6/7: measured, predicted and simulated output; residuals; residual ACF."""
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
    e = np.asarray(residuals, dtype=float)
    e = e[np.isfinite(e)]
    nl = int(min(nlags, len(e) // 2 - 1))
    r = acf(e, nlags=nl, fft=True)
    ax[2].vlines(np.arange(nl + 1), 0, r, color="C0")
    band = 1.96 / np.sqrt(len(e))
    ax[2].axhline(band, ls="--", color="C3", lw=0.8)
    ax[2].axhline(-band, ls="--", color="C3", lw=0.8)
    ax[2].axhline(0, color="k", lw=0.5)
    ax[2].set_xlabel("lag")
    ax[2].set_ylabel("ACF of residuals")
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


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
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


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
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ["ResidualReport", "residual_report", "cumulated_periodogram", "paper_figure", "phase_diagram",
           "whiteness_figure", "KS_95"]
