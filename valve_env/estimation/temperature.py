"""Temperature pre-processing: the noisy temperature channels turned into the valve's driver.

The one module that owns it (docs/estimation.md, "Architecture"). Two methods, each used by one
likelihood, kept both for a measured reason (``benchmarks/temperature_preprocessing.py``,
docs/estimation.md, "Temperature pre-processing"):

* :func:`smooth_temperature`: a robust integrated-random-walk Rauch-Tung-Striebel smoother
  (maximum-likelihood noise levels, a scale mixture for the kinks of the heating). Smooth level and
  rate at every sample, zero phase. The output-error likelihood of the diagnosis
  (:mod:`valve_env.diagnosis.engine`) drives its fine-grid valve simulation with it, after removing
  reversals smaller than 5 noise sd (``monotone_path``).
* :func:`denoise_temperature`: relaxed total-variation denoising (:func:`relaxed_tv`, Condat's
  exact algorithm with the extreme blocks re-estimated). Piecewise-linear-free of spurious
  reversals by construction; the EKF's valve model (:mod:`valve_env.estimation.valve_model`) takes
  its rate over each sample interval as the Dahl driver, which a smoother's small wiggles (each a
  reversal of the friction) would bias.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.optimize import minimize

_LOG2PI = math.log(2.0 * math.pi)


# --------------------------------------------------------------------------- TV denoising
@njit(cache=True)
def tv_denoise(y: np.ndarray, lam: float) -> np.ndarray:  # pragma: no cover - compiled
    """Total-variation denoising: argmin_x 0.5 sum (y - x)^2 + lam sum |x_i+1 - x_i|.

    Exact, O(n): L. Condat, "A direct algorithm for 1D total variation denoising",
    IEEE Signal Processing Letters 20 (2013) 1054-1057."""
    n = y.shape[0]
    x = np.empty(n)
    if n == 0:
        return x
    k = 0
    k0 = 0
    umin = lam
    umax = -lam
    vmin = y[0] - lam
    vmax = y[0] + lam
    kplus = 0
    kminus = 0
    twolam = 2.0 * lam
    minlam = -lam
    while True:
        while k == n - 1:
            if umin < 0.0:
                while True:
                    x[k0] = vmin
                    k0 += 1
                    if k0 > kminus:
                        break
                kminus = k0
                k = k0
                vmin = y[k0]
                umin = lam
                umax = vmin + umin - vmax
            elif umax > 0.0:
                while True:
                    x[k0] = vmax
                    k0 += 1
                    if k0 > kplus:
                        break
                kplus = k0
                k = k0
                vmax = y[k0]
                umax = minlam
                umin = vmax + umax - vmin
            else:
                vmin += umin / (k - k0 + 1)
                while True:
                    x[k0] = vmin
                    k0 += 1
                    if k0 > k:
                        break
                return x
        umin += y[k + 1] - vmin
        if umin < minlam:
            while True:
                x[k0] = vmin
                k0 += 1
                if k0 > kminus:
                    break
            kplus = k0
            kminus = k0
            k = k0
            vmin = y[k0]
            vmax = vmin + twolam
            umin = lam
            umax = minlam
        else:
            umax += y[k + 1] - vmax
            if umax > lam:
                while True:
                    x[k0] = vmax
                    k0 += 1
                    if k0 > kplus:
                        break
                kplus = k0
                kminus = k0
                k = k0
                vmax = y[k0]
                vmin = vmax - twolam
                umin = lam
                umax = minlam
            else:
                k += 1
                if umin >= lam:
                    kminus = k
                    vmin += (umin - lam) / (kminus - k0 + 1)
                    umin = lam
                if umax <= minlam:
                    kplus = k
                    vmax += (umax + lam) / (kplus - k0 + 1)
                    umax = minlam


def noise_sd(y: np.ndarray) -> float:
    """Robust white-noise sd of a smooth signal plus noise: MAD of second differences / sqrt(6)."""
    y = np.asarray(y, dtype=float)
    if len(y) < 4:
        return 0.0
    d2 = np.diff(y, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def relaxed_tv(y: np.ndarray, lam: float) -> np.ndarray:
    """TV denoising, then each local-extreme block (a constant run with jumps of opposite
    direction on its two sides) re-estimated from its own data without the TV penalty.

    TV pulls such a block towards its neighbours by 2 lam / length, which shaves every reversal
    of the temperature and delays the friction's reversal (plain TV biased sigma upwards by about
    3 %). The block's new level is the midpoint of its data mean (which still sits inside the
    turning point when the temperature creeps towards it within the block: sigma +0.5-1 %) and
    the more extreme end of a straight line fitted to the block's data (which overshoots:
    sigma -0.5-1 %); on 30 simulated runs the midpoint leaves sigma unbiased to 0.1 %. The new
    level lies beyond both neighbours, so TV's monotone runs, and its reversals, are kept."""
    y = np.ascontiguousarray(y, dtype=float)
    x = tv_denoise(y, lam)
    if len(x) < 3:
        return x
    brk = np.flatnonzero(np.diff(x) != 0.0) + 1
    starts = np.r_[0, brk]
    ends = np.r_[brk, len(x)]
    val = x[starts]
    left = np.r_[0.0, np.sign(val[1:] - val[:-1])]
    right = np.r_[np.sign(val[1:] - val[:-1]), 0.0]
    extreme = (left != 0) & (right != 0) & (left != right)
    out = x.copy()
    for a, b, up in zip(starts[extreme], ends[extreme], left[extreme] > 0, strict=True):
        seg = y[a:b]
        level = float(seg.mean())
        n = b - a
        if n >= 3:
            tt = np.arange(n, dtype=float)
            slope, icpt = np.polyfit(tt, seg, 1)
            e0, e1 = icpt, icpt + slope * (n - 1)
            edge = max(level, e0, e1) if up else min(level, e0, e1)
            level = 0.5 * (level + edge)
        out[a:b] = level
    return out


#: the denoisers of :func:`denoise_temperature`: ``relaxed`` (the default, :func:`relaxed_tv`) and
#: ``tv`` (plain :func:`tv_denoise`); they bracket a reversal's excursion (docs/uncertainty.md)
DENOISERS: tuple[str, ...] = ("relaxed", "tv")


def denoise_temperature(y: np.ndarray, t: np.ndarray, tv_factor: float = 4.5,
                        denoiser: str = "relaxed") -> tuple[np.ndarray, np.ndarray]:
    """Denoised temperature (:func:`relaxed_tv`, or plain :func:`tv_denoise` with
    ``denoiser="tv"``, with lam = tv_factor x :func:`noise_sd`) and its rate over the following
    interval (K/s; 0 at the end)."""
    if denoiser not in DENOISERS:
        raise ValueError(f"unknown denoiser {denoiser!r}; use one of {DENOISERS}")
    y = np.ascontiguousarray(y, dtype=float)
    lam = tv_factor * noise_sd(y)
    if lam <= 0:
        ys = y.copy()
    else:
        ys = relaxed_tv(y, lam) if denoiser == "relaxed" else tv_denoise(y, lam)
    v = np.zeros_like(ys)
    if len(ys) > 1:
        v[:-1] = np.diff(ys) / np.diff(np.asarray(t, dtype=float))
    return ys, v


# --------------------------------------------------------------------------- IRW-RTS smoothing
@njit(cache=True)
def _irw_pass(t: np.ndarray, y: np.ndarray, q: float, r: float, smooth: bool,
              w: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Kalman filter (and RTS smoother) of an integrated random walk observed with white noise.

    ``w[k]`` scales the process noise of the interval ending at sample k (1 = the nominal q).
    Returns (log-likelihood, level, rate); level/rate are smoothed when ``smooth``."""
    n = t.shape[0]
    mf = np.empty((n, 2))
    Pf = np.empty((n, 2, 2))
    mp = np.empty((n, 2))
    Pp = np.empty((n, 2, 2))
    m0 = y[0]
    m1 = 0.0
    p00 = r + 1.0
    p01 = 0.0
    p11 = 1e-4
    ll = 0.0
    for k in range(n):
        if k > 0:
            h = t[k] - t[k - 1]
            qk = q * w[k]
            a0 = m0 + h * m1
            a1 = m1
            # F P F' + Q
            q00 = p00 + 2.0 * h * p01 + h * h * p11 + qk * h * h * h / 3.0
            q01 = p01 + h * p11 + qk * h * h / 2.0
            q11 = p11 + qk * h
            m0, m1, p00, p01, p11 = a0, a1, q00, q01, q11
        mp[k, 0] = m0
        mp[k, 1] = m1
        Pp[k, 0, 0] = p00
        Pp[k, 0, 1] = p01
        Pp[k, 1, 0] = p01
        Pp[k, 1, 1] = p11
        S = p00 + r
        nu = y[k] - m0
        ll += -0.5 * (_LOG2PI + math.log(S) + nu * nu / S)
        k0 = p00 / S
        k1 = p01 / S
        m0 = m0 + k0 * nu
        m1 = m1 + k1 * nu
        n00 = p00 - k0 * p00
        n01 = p01 - k0 * p01
        n11 = p11 - k1 * p01
        p00, p01, p11 = n00, n01, n11
        mf[k, 0] = m0
        mf[k, 1] = m1
        Pf[k, 0, 0] = p00
        Pf[k, 0, 1] = p01
        Pf[k, 1, 0] = p01
        Pf[k, 1, 1] = p11
    level = np.empty(n)
    rate = np.empty(n)
    if not smooth:
        for k in range(n):
            level[k] = mf[k, 0]
            rate[k] = mf[k, 1]
        return ll, level, rate
    ms0 = mf[n - 1, 0]
    ms1 = mf[n - 1, 1]
    level[n - 1] = ms0
    rate[n - 1] = ms1
    for k in range(n - 2, -1, -1):
        h = t[k + 1] - t[k]
        # C = Pf F' Pp^-1
        f00 = Pf[k, 0, 0] + h * Pf[k, 0, 1]
        f01 = Pf[k, 0, 1]
        f10 = Pf[k, 1, 0] + h * Pf[k, 1, 1]
        f11 = Pf[k, 1, 1]
        a = Pp[k + 1, 0, 0]
        b = Pp[k + 1, 0, 1]
        d = Pp[k + 1, 1, 1]
        det = a * d - b * b
        i00 = d / det
        i01 = -b / det
        i11 = a / det
        c00 = f00 * i00 + f01 * i01
        c01 = f00 * i01 + f01 * i11
        c10 = f10 * i00 + f11 * i01
        c11 = f10 * i01 + f11 * i11
        d0 = ms0 - mp[k + 1, 0]
        d1 = ms1 - mp[k + 1, 1]
        ms0 = mf[k, 0] + c00 * d0 + c01 * d1
        ms1 = mf[k, 1] + c10 * d0 + c11 * d1
        level[k] = ms0
        rate[k] = ms1
    return ll, level, rate


def smooth_temperature(t: np.ndarray, y: np.ndarray, robust_passes: int = 3,
                       z_thr: float = 3.0) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Latent temperature and its rate from a noisy channel (ML integrated random walk + RTS smoother).

    A step of the tank's heating puts a kink in the temperature (the rate jumps). A Gaussian random
    walk of the rate would round each kink symmetrically: the smoothed temperature would start to
    move before the water does, which the Dahl friction turns into a spurious lead. The rate's
    process noise is therefore a scale mixture (iteratively reweighted, as for a Student-t): where
    the smoothed rate changes by more than ``z_thr`` standard deviations in one interval, that
    interval's process noise is raised to match, and the smoother is run again.

    Returns (level degC, rate K/s, s_T degC, s_v K/s/sqrt(s))."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    n = t.shape[0]
    d2 = np.diff(y, 2)
    r0 = max(float(np.var(d2)) / 6.0, 1e-8)
    w = np.ones(n)

    def nll(z: np.ndarray) -> float:
        return -_irw_pass(t, y, math.exp(z[0]), math.exp(z[1]), False, w)[0]

    best = None
    for lq in (-18.0, -14.0):
        res = minimize(nll, np.array([lq, math.log(r0)]), method="Nelder-Mead",
                       options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 400})
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    q, r = math.exp(best.x[0]), math.exp(best.x[1])
    _, level, rate = _irw_pass(t, y, q, r, True, w)
    h = np.empty(n)
    h[0] = 1.0
    h[1:] = np.diff(t)
    for _ in range(robust_passes):
        z2 = np.zeros(n)
        z2[1:] = np.diff(rate) ** 2 / (q * h[1:])
        w = np.maximum(1.0, z2 / z_thr**2)
        # the likelihood of the nominal level moves when kinks are freed: re-estimate q and r
        res = minimize(nll, np.array([math.log(q), math.log(r)]), method="Nelder-Mead",
                       options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 200})
        q, r = math.exp(res.x[0]), math.exp(res.x[1])
        _, level, rate = _irw_pass(t, y, q, r, True, w)
    return level, rate, math.sqrt(r), math.sqrt(q)


__all__ = ["smooth_temperature", "denoise_temperature", "DENOISERS", "relaxed_tv", "tv_denoise", "noise_sd"]
