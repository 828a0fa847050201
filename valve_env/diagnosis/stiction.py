"""The stick band measured from the staircase of the opening (a moment estimator).

A sticking stem rests until the demanded opening is the band away and then slips onto it, so
while the demand moves slowly every slip is a jump of the band (a little more while it moves
fast, and several slips can fall between two samples). The likelihood of the stick-slip filter
is rough in the band and the band trades off against the Dahl friction's F_hmax (both make
hysteresis), which traps the joint fit; the jumps measure the band directly, without the valve
model. Used by :class:`valve_env.diagnosis.fitting.Model` for ``band_mm``.
"""

from __future__ import annotations

import math

import numpy as np


def _responsibilities(a: np.ndarray, b: float, sig: float, w: np.ndarray,
                      top: float) -> tuple[np.ndarray, np.ndarray]:
    """E-step of the step-size mixture: resting |N(0, sig)|, single slips |N(b, sig)|, double
    slips |N(2b, sig)| and a uniform part on [0, top]; returns the responsibilities (4, n) and
    the new weights."""
    c = 1.0 / (sig * math.sqrt(2.0 * math.pi))
    f0 = 2.0 * c * np.exp(-0.5 * (a / sig) ** 2)
    f1 = c * (np.exp(-0.5 * ((a - b) / sig) ** 2) + np.exp(-0.5 * ((a + b) / sig) ** 2))
    f2 = c * (np.exp(-0.5 * ((a - 2 * b) / sig) ** 2) + np.exp(-0.5 * ((a + 2 * b) / sig) ** 2))
    f3 = np.full_like(a, 1.0 / max(top, 1e-9))
    F = np.vstack([w[0] * f0, w[1] * f1, w[2] * f2, w[3] * f3])
    tot = F.sum(axis=0)
    tot[tot <= 0] = 1e-300
    R = F / tot
    return R, R.sum(axis=1) / a.size


def _away_from_stops(x: np.ndarray, stroke: float, edge_mm: float) -> np.ndarray:
    """Mask of the steps of ``x`` whose both ends lie more than ``edge_mm`` from the end stops."""
    lo, hi = edge_mm, stroke - edge_mm
    return (x[:-1] > lo) & (x[1:] > lo) & (x[:-1] < hi) & (x[1:] < hi)


def noise_sd(x: np.ndarray) -> float:
    """sd of the white noise on the opening from the resting steps (median absolute difference)."""
    d = np.abs(np.diff(x))
    return float(np.median(d) / (0.6745 * math.sqrt(2.0))) if d.size else 0.0


def resting_noise_sd(x: np.ndarray, stroke: float, band: float | None = None, edge_mm: float = 0.02,
                     iters: int = 100) -> float:
    """sd of the white noise on the opening from the resting steps alone, the slips set apart.

    :func:`noise_sd` takes the median of all absolute steps, slips included; where slips are a good
    share of the steps (coarse sampling, a small band) it overstates the noise (by up to about 20 %
    at 20-30 s sampling). Here the absolute steps away from the end stops are a mixture of resting
    steps (|N(0, sig)|, sig = sqrt(2) s), single and double slips (|N(b, sig)|, |N(2 b, sig)|) and a
    broad uniform part, fitted by EM with the resting width free; the noise sd is ``sig / sqrt(2)``.
    ``band``: the band (default :func:`jump_band`'s); without a band it is :func:`noise_sd`."""
    x = np.asarray(x, dtype=float)
    s0 = noise_sd(x)
    b = jump_band(x, stroke)[0] if band is None else float(band)
    if not (math.isfinite(b) and b > 0 and s0 > 0):
        return s0
    d = np.diff(x)
    inside = _away_from_stops(x, stroke, edge_mm)
    a = np.abs(d[inside])
    if a.size < 20:
        return s0
    sig = math.sqrt(2.0) * s0
    top = float(a.max())
    w = np.array([0.9, 0.05, 0.02, 0.03])
    for _ in range(iters):
        R, w = _responsibilities(a, b, sig, w, top)
        # the resting steps set the width (the slips' sizes also vary with the demand's speed)
        if R[0].sum() <= 0:
            return s0
        ns = math.sqrt(float(R[0] @ (a * a)) / float(R[0].sum()))
        if abs(ns - sig) <= 1e-6 * sig:
            sig = ns
            break
        sig = ns
    return sig / math.sqrt(2.0)


def jump_band(x: np.ndarray, stroke: float, s_w: float | None = None, z: float = 3.5,
              edge_mm: float = 0.02, min_jumps: int = 10) -> tuple[float, int]:
    """Band (mm) from the jumps of the measured opening; (nan, n) if fewer than ``min_jumps``.

    Jumps are steps larger than ``z`` noise sd of a difference, away from the end stops. The band
    is the centre of the smallest cluster of jump sizes (single slips): the median of the jumps
    below 1.5 times the current estimate, iterated from the lower quartile."""
    x = np.asarray(x, dtype=float)
    s = noise_sd(x) if s_w is None else float(s_w)
    d = np.diff(x)
    inside = _away_from_stops(x, stroke, edge_mm)
    J = np.abs(d[inside & (np.abs(d) > z * math.sqrt(2.0) * max(s, 1e-6))])
    if J.size < min_jumps:
        return float("nan"), int(J.size)
    b = float(np.quantile(J, 0.25))
    for _ in range(20):
        sel = J[J < 1.5 * b]
        if sel.size < min_jumps // 2:
            break
        nb = float(np.median(sel))
        if abs(nb - b) <= 1e-4 * b:
            b = nb
            break
        b = nb
    return _mixture_band(np.abs(d[inside]), b, math.sqrt(2.0) * max(s, 1e-6)), int(J.size)


def _mixture_band(a: np.ndarray, b0: float, sig: float, iters: int = 50) -> float:
    """Refine the band by EM on the absolute steps ``a``: a mixture of resting steps (|N(0, sig)|),
    single slips (|N(b, sig)|), double slips (|N(2b, sig)|) and a broad uniform part (slips of
    fast ramps). Unlike the thresholded jumps it keeps the small slips that the noise hides."""
    b = b0
    top = float(a.max()) if a.size else 1.0
    w = np.array([0.9, 0.05, 0.02, 0.03])
    for _ in range(iters):
        R, w = _responsibilities(a, b, sig, w, top)
        den = R[1].sum() + 4.0 * R[2].sum()
        if den <= 0:
            break
        nb = float((R[1] @ a + 2.0 * (R[2] @ a)) / den)
        if abs(nb - b) <= 1e-6 * b:
            b = nb
            break
        b = nb
    return b


def band_sampling(x_true: np.ndarray, noise_sd_mm: float, stroke: float, draws: int = 200,
                  seed: int = 0) -> np.ndarray:
    """The band estimator's sampling distribution on a known opening: :func:`jump_band` of
    ``x_true`` plus fresh white noise of ``noise_sd_mm``, ``draws`` times (nan where too few jumps).

    With the true opening of a generated run (``true_x_mm``) this is the estimator's own spread and
    bias for that run, which no method that sees only the measured opening can know: the yardstick
    the bootstrap's sd and bias correction are measured against (``benchmarks/diagnosis_coverage.py``);
    with a simulated opening it tells how precisely a planned experiment measures the band."""
    x_true = np.asarray(x_true, dtype=float)
    if not (math.isfinite(noise_sd_mm) and noise_sd_mm >= 0):
        raise ValueError(f"noise_sd_mm must be finite and >= 0, got {noise_sd_mm}")
    if draws < 2:
        raise ValueError(f"draws must be at least 2, got {draws}")
    return band_draws(x_true, noise_sd_mm, stroke, draws, np.random.default_rng(seed))


def band_draws(x_true: np.ndarray, noise_sd_mm: float, stroke: float, draws: int,
               rng: np.random.Generator) -> np.ndarray:
    """``draws`` band estimates (:func:`jump_band`) of ``x_true`` plus white noise of ``noise_sd_mm``
    from ``rng``, nan where too few jumps: :func:`band_sampling` without its checks, and the band's
    extra replicates of the bootstrap (:func:`valve_env.diagnosis.uncertainty.bootstrap`)."""
    return np.array([jump_band(x_true + noise_sd_mm * rng.standard_normal(x_true.shape[0]), stroke)[0]
                     for _ in range(draws)])


__all__ = ["band_sampling", "jump_band", "noise_sd", "resting_noise_sd"]
