"""The bootstrap driver and its statistics: replicates drawn and refitted through callbacks, the failed refits
screened, each parameter's re-estimates summarised (bias, bias correction, sd, basic interval), and the
circular block bootstrap of residuals with Politis and White's block length.

:func:`replicates` runs ``B`` replicates: ``draw(rng)`` makes a replicate data set (every random number
comes from ``rng``, in replicate order, so a seed gives the same replicates), ``refit(data)`` re-estimates
on it and returns the re-estimates by name, or None for a failed refit. The caller's model decides what a
replicate is (a model-based world, re-measured inputs, ...); the valve's are
:func:`valve_env.valveid.bootstrap.bootstrap` and :func:`valve_env.valveid.eiv.temperature_bootstrap`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from arch.bootstrap import optimal_block_length
from scipy.stats import shapiro
from statsmodels.robust.scale import qn_scale

#: A re-estimate farther than this many robust sd (Qn) from the median is a failed refit.
GROSS_Z = 6.0
#: Re-estimates whose Shapiro-Wilk p-value is below this are too far from normal to bias-correct by their mean.
NORMAL_P = 1e-3

def replicates(B: int, rng: np.random.Generator, draw: Callable[[np.random.Generator], Any],
               refit: Callable[[Any], dict[str, float] | None]) -> tuple[list[dict[str, float]], int]:
    """``B`` bootstrap replicates: for each, ``draw(rng)`` then ``refit`` of what it drew. Returns the
    refits that succeeded (in replicate order) and the number that failed (``refit`` returned None)."""
    rows: list[dict[str, float]] = []
    failed = 0
    for _ in range(B):
        r = refit(draw(rng))
        if r is None:
            failed += 1
        else:
            rows.append(r)
    return rows, failed


def residual_block_length(resid: np.ndarray) -> int:
    """Block length for a circular block bootstrap of ``resid``: Politis and White's (2004)
    selection (with Patton, Politis and White's 2009 correction), within 1 .. n / 4."""
    n = resid.shape[0]
    L = float(optimal_block_length(resid)["circular"].iloc[0])
    return int(min(max(round(L), 1) if math.isfinite(L) else 1, max(n // 4, 1)))


def block_resample(resid: np.ndarray, block: int, rng: np.random.Generator) -> np.ndarray:
    """A circular block bootstrap draw of ``resid``: blocks of ``block`` consecutive values from
    random starts, wrapping around the end (every value is equally likely)."""
    n = resid.shape[0]
    starts = rng.integers(0, n, size=n // block + 1)
    idx = (starts[:, None] + np.arange(block)[None, :]).ravel()[:n] % n
    return resid[idx]


def gross_refits(reps: np.ndarray, z: float = GROSS_Z) -> np.ndarray:
    """Mask of the replicates (rows of ``reps``, one column per parameter) whose re-estimate of some
    parameter lies more than ``z`` robust sd (Rousseeuw and Croux's Qn scale) from the median of that
    parameter's re-estimates, or is not finite (nothing where the Qn scale is zero: re-estimates that
    mostly agree exactly)."""
    bad = np.zeros(reps.shape[0], dtype=bool)
    if reps.shape[0] < 4:
        return bad
    for col in reps.T:
        s = float(qn_scale(col))
        if math.isfinite(s) and s > 0:
            bad |= np.abs(col - np.median(col)) > z * s
        bad |= ~np.isfinite(col)
    return bad


def screen_refits(reps: np.ndarray, z: float = GROSS_Z) -> tuple[np.ndarray, bool]:
    """The failed refits among the replicates (rows of ``reps``) and whether the re-estimates split.

    The gross replicates (:func:`gross_refits`) are the failed refits, unless more than half of them
    are gross: then the re-estimates have split into groups, none of them a majority (e.g. half of the
    refits ran away to a bound), nothing is set aside, and ``split`` is true (no bias correction,
    see :func:`summarise`)."""
    bad = gross_refits(reps, z)
    split = bool(bad.sum() > reps.shape[0] // 2)
    return (np.zeros(reps.shape[0], dtype=bool) if split else bad), split


class Summary(NamedTuple):
    """Each parameter's summary of its re-estimates (:func:`summarise`), by name."""

    std: dict[str, float]
    bias: dict[str, float]
    interval_95: dict[str, tuple[float, float]]
    corrected: dict[str, float]
    bias_corrected: dict[str, bool]
    spread: dict[str, float]
    #: Shapiro-Wilk p-value of the re-estimates (1 where they do not vary)
    normality_p: dict[str, float]


def summarise(names: list[str], est: dict[str, float], reps: dict[str, np.ndarray], bias_z: float = 2.0,
              no_correction: set[str] | frozenset[str] = frozenset(), normal_p: float = NORMAL_P) -> Summary:
    """The summary of each parameter's re-estimates ``reps[k]`` about its estimate ``est[k]``
    (module docstring, step 4). Parameters in ``no_correction`` are never bias-corrected: their sd
    is the root-mean-square error about the estimate. Nor are parameters whose re-estimates are far
    from normal (Shapiro-Wilk p below ``normal_p``; 0 switches the check off): the mean of a
    heavy-tailed or split set of re-estimates is not a reliable centre to correct by."""
    out = Summary({}, {}, {}, {}, {}, {}, {})
    for k in names:
        r = np.asarray(reps[k], dtype=float)
        m_i, sd_i = float(r.mean()), float(r.std(ddof=1))
        out.spread[k] = sd_i
        out.bias[k] = bias = m_i - est[k]
        se = sd_i / math.sqrt(r.size)
        out.normality_p[k] = p = float(shapiro(r).pvalue) if r.size >= 3 and np.ptp(r) > 0 else 1.0
        corrected = bool(se > 0 and abs(bias) > bias_z * se and k not in no_correction and p >= normal_p)
        out.bias_corrected[k] = corrected
        if corrected:
            # a bias the replicates show clearly (e.g. the band's jumps overshoot a little): corrected,
            # and the sd includes the uncertainty of the correction (the mean of B replicates)
            out.corrected[k] = est[k] - bias
            out.std[k] = float(math.sqrt(sd_i**2 + se**2))
        else:
            # no clear bias, or none to trust: root-mean-square error about the estimate (spread and bias together)
            out.corrected[k] = est[k]
            out.std[k] = float(math.sqrt(sd_i**2 + bias**2))
        lo, hi = np.percentile(r, [2.5, 97.5])
        # basic bootstrap interval (reflected about the estimate)
        out.interval_95[k] = (float(2 * est[k] - hi), float(2 * est[k] - lo))
    return out
