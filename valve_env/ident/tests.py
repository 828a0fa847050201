"""The statistical tests of the identification: the likelihood-ratio test (with the chi-bar-squared
mixture of a parameter on the boundary of its space), the information criteria, the whiteness of
one-step residuals (statsmodels' Ljung-Box, the cumulated periodogram with its Kolmogorov-Smirnov band,
the autocorrelation and the cross-correlation with the inputs) and the misspecification check built on
them.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats
from statsmodels.stats.diagnostic import acorr_ljungbox
from statsmodels.tsa.stattools import acf, ccf

# --------------------------------------------------------------------------- noise level
#: the median absolute deviation of a normal sample over its sd (1 / the normal's 3/4 quantile, to 5 digits)
MAD_TO_SD = 1.4826


def sd_from_second_differences(d2: np.ndarray, centred: bool = True) -> float:
    """The sd of the white noise behind second differences ``d2`` (their variance is 6 sd^2): their median absolute
    deviation (about their median, or about 0 where not ``centred``) times :data:`MAD_TO_SD` / sqrt(6)."""
    d2 = np.asarray(d2, dtype=float)
    return float(MAD_TO_SD * np.median(np.abs(d2 - np.median(d2) if centred else d2)) / math.sqrt(6.0))


def second_difference_sd(y: np.ndarray, centred: bool = True) -> float:
    """The sd of white noise on a smooth signal ``y``, read robustly from its second differences, in which the smooth
    part cancels (:func:`sd_from_second_differences`). 0 for fewer than 3 samples."""
    y = np.asarray(y, dtype=float)
    return sd_from_second_differences(np.diff(y, 2), centred) if y.size >= 3 else 0.0


# --------------------------------------------------------------------------- likelihood ratio and criteria
def lr_pvalue(lr: float, df: int, boundary: bool = False) -> float:
    """p-value of the likelihood-ratio statistic ``lr`` (negative values count as 0) for ``df`` added
    parameters: chi^2 with ``df`` degrees of freedom, or, for one parameter whose null value lies on the
    boundary of its space (``boundary``), the mixture 0.5 chi^2_0 + 0.5 chi^2_1 (Self and Liang 1987)."""
    lr = max(lr, 0.0)
    if boundary and df == 1:
        return float(0.5 * stats.chi2.sf(lr, 1)) if lr > 0 else 1.0
    return float(stats.chi2.sf(lr, df))


def lr_test(loglik_restricted: float, loglik_full: float, df: int, boundary: bool = False) -> tuple[float, float]:
    """The likelihood-ratio statistic 2 (l_full - l_restricted) (at least 0) and its p-value (:func:`lr_pvalue`)."""
    lr = max(2.0 * (loglik_full - loglik_restricted), 0.0)
    return lr, lr_pvalue(lr, df, boundary)


def bic(loglik: float, k: int, n: int) -> float:
    """Schwarz's criterion -2 loglik + k log n (``n`` at least 1)."""
    return -2.0 * loglik + math.log(max(n, 1)) * k


def delta_bic(lr: float, k: int, n: int) -> float:
    """The BIC change of adding ``k`` parameters that raise the log-likelihood by ``lr`` / 2."""
    return k * math.log(n) - lr


# --------------------------------------------------------------------------- whiteness
def ljung_box(e: np.ndarray, lags: list[int] | int) -> pd.DataFrame:
    """statsmodels' Ljung-Box test of ``e`` at ``lags`` (``lb_stat``, ``lb_pvalue`` by lag)."""
    return acorr_ljungbox(e, lags=[lags] if isinstance(lags, int) else lags, return_df=True)


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
    lb = ljung_box(x, [lag for lag in (5, 10, 20, nl) if lag <= nl] or [nl])
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


class MisspecificationWarning(UserWarning):
    """The residuals say the model does not fit the data (not white)."""


#: what a rejected check means where the reported sd is the sandwich's (the base fit's)
ROBUST_ADVICE = "trust the robust standard errors, not the inverse Hessian's"


def whiteness_check(residuals: dict[str, np.ndarray], *, alpha: float = 0.01, nlags: int = 40, warn: bool = True,
                    label: str = "model", advice: str = ROBUST_ADVICE) -> dict[str, Any]:
    """The misspecification check of :func:`misspecification_check` on given standardised one-step
    residuals (one array per output, NaN where unobserved); ``label`` names the model in the warning,
    ``advice`` ends it (what to make of the reported sd, which depends on where it comes from).
    Used by the base fit and by the diagnosis's named effects
    (:func:`effect_misspecification`)."""
    out: dict[str, Any] = {"alpha": alpha, "outputs": {}}
    bad: list[str] = []
    c_alpha = float(stats.kstwobign.isf(alpha))
    for name, e in residuals.items():
        rep = residual_report(np.asarray(e, dtype=float), nlags=nlags)
        lb = rep.ljung_box.iloc[-1]
        band = c_alpha / np.sqrt(max(len(rep.cpgram) - 1, 1))
        entry = {"ljung_box_lag": int(rep.ljung_box.index[-1]), "ljung_box_stat": float(lb["lb_stat"]),
                 "ljung_box_p": float(lb["lb_pvalue"]), "cpgram_max_dev": float(rep.cpgram_max_dev),
                 "cpgram_band": float(band), "acf_lag1": float(rep.acf[1]) if len(rep.acf) > 1 else float("nan")}
        entry["white"] = bool(entry["ljung_box_p"] > alpha and entry["cpgram_max_dev"] < band)
        out["outputs"][name] = entry
        if not entry["white"]:
            bad.append(f"{name} (Ljung-Box p = {entry['ljung_box_p']:.2g} at lag {entry['ljung_box_lag']}, "
                       f"cumulated periodogram {entry['cpgram_max_dev']:.3f} against its band {band:.3f})")
    out["misspecified"] = bool(bad)
    out["message"] = ("the one-step residuals of " + "; ".join(bad) + " are not white at the "
                      f"{alpha:g} level: the model does not explain the data's dynamics; {advice}") if bad else ""
    if bad and warn:
        warnings.warn(f"{label}: {out['message']}", MisspecificationWarning, stacklevel=3)
    return out


# --------------------------------------------------------------------------- misspecification-robust sd and check


def misspecification_check(est: Any, data: Any = None, *, alpha: float = 0.01, nlags: int = 40,
                           warn: bool = True) -> dict[str, Any]:
    """The misspecification check of a fitted :class:`~valve_env.ident.mle.MLEstimator`: the whiteness of
    each output's standardised one-step residuals (Ljung-Box at ``nlags`` and the cumulated periodogram's KS
    band, both at level ``alpha``, :func:`whiteness_check`); a :class:`MisspecificationWarning` when
    either rejects: the model does not explain the data's dynamics, so its inverse-Hessian standard errors
    are not to be trusted (docs/uncertainty.md). Returns the JSON-ready result: per output the statistics,
    then ``misspecified`` and ``message``."""
    res = est.residuals(data)
    return whiteness_check({name: res[name].to_numpy(dtype=float) for name in est.model.outputs},
                           alpha=alpha, nlags=nlags, warn=warn, label=est.model.name)
