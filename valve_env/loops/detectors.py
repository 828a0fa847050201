"""Classical stiction detectors, scored beside the grey-box method (docs/loops.md, "Classical detectors").

* :func:`horch` - Horch, A. (1999). A simple method for detection of stiction in control valves.
  *Control Engineering Practice* 7(10), 1221-1231. For a self-regulating loop the cross-correlation
  of OP and PV is an even function (extremum at lag 0) when the oscillation is caused by tuning or a
  disturbance and an odd one (zero near lag 0, extrema either side) when it is caused by stiction.
  The decision is Horch's, from the first zero crossings of the CCF right (``tau_r``) and left
  (``tau_l``) of lag 0: the phase ``|phi| = 180 |tau_r - tau_l| / (tau_r + tau_l)`` degrees is 0 for an
  even CCF and 180 for an odd one; ``|phi| > 120`` stiction, ``< 60`` none, between undetermined
  (counted as no stiction). The CCF is taken over lags up to half the record (the slow cycles of a
  sticky valve span hours). For an integrating (level) process the PV is the integral of the flow,
  which shifts the CCF by a quarter period, so the test correlates OP with the PV's increments instead
  (Horch's variant for integrating loops). Horch's test is a diagnosis of an oscillation: when the
  CCF's half period ``tau_r + tau_l`` is shorter than 5 samples (a noise-driven loop, no resolved
  cycle), the verdict is none. Also reported: ``ratio = |r(0)| / max |r|`` (the even-ness of the CCF) and
  the signed phase ``180 (tau_r - tau_l) / (tau_r + tau_l)`` (positive: the far zero crossing lies at
  positive lags, where PV follows OP; used by the grey-box decision, docs/loops.md "Decision").
* :func:`he_curve_fit` - He, Q.P., Wang, J., Pottmann, M., Qin, S.J. (2007). A curve fitting method
  for detecting valve stiction in oscillating control loops. *Ind. Eng. Chem. Res.* 46(13),
  4549-4560. Each half cycle of the mean-removed controller output is fitted by a half sine and
  by a triangle (least squares in the amplitude, the peak position of the triangle free); the
  stiction index ``SI = MSE_sin / (MSE_sin + MSE_tri)``: > 0.6 stiction, < 0.4 none, between
  undetermined (counted as no stiction). The paper fits OP for fast self-regulating loops and PV for
  integrating ones; here OP, as the loop type is not known from a loop CSV.
* :func:`kano` - Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model and
  detection algorithm for valve stiction. *IFAC DYCOPS*, Boston. With the valve position estimated
  by PV (flow loops), the stiction index is the fraction of the time the OP keeps moving while the
  PV stays within its noise (``|dPV| < 2 sd`` of PV's white noise, from second differences) over sections where OP
  moves monotonically; stiction when the index exceeds 0.25 (the paper's threshold).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from valve_env.loops.io import LoopData


def _detrend(y: np.ndarray) -> np.ndarray:
    t = np.arange(y.size)
    return y - np.polyval(np.polyfit(t, y, 1), t)


#: Horch's phase limits, degrees: above ODD the CCF is odd (stiction), below EVEN it is even (none)
HORCH_ODD_DEG = 120.0
HORCH_EVEN_DEG = 60.0
#: the shortest CCF half period (tau_r + tau_l, samples) read as a resolved cycle
HORCH_MIN_HALF_PERIOD = 5.0


def _first_zero(r: np.ndarray) -> float:
    """Fractional lag of the first sign change of ``r`` (``r[0]`` at lag 0); the end when none."""
    s0 = np.sign(r[0])
    for i in range(1, r.size):
        if np.sign(r[i]) != s0 or r[i] == 0.0:
            return float(i - 1 + r[i - 1] / (r[i - 1] - r[i])) if r[i - 1] != r[i] else float(i)
    return float(r.size - 1)


def cross_correlation(op: np.ndarray, y: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """``corr(y[k + tau], op[k])`` for ``tau = -max_lag..max_lag`` (linear trends removed first)."""
    from statsmodels.tsa.stattools import ccf

    op, y = _detrend(op), _detrend(y)
    fwd = ccf(y, op, adjusted=False, fft=True)[: max_lag + 1]
    bwd = ccf(op, y, adjusted=False, fft=True)[: max_lag + 1]
    return np.arange(-max_lag, max_lag + 1), np.concatenate([bwd[:0:-1], fwd])


def horch(loop: LoopData, integrating: bool = False) -> dict[str, Any]:
    """Horch's cross-correlation test (module doc); ``integrating`` uses the PV's increments."""
    op, y = (loop.op[1:], np.diff(loop.pv)) if integrating else (loop.op, loop.pv)
    max_lag = max(op.size // 2 - 1, 2)
    lags, r = cross_correlation(op, y, max_lag)
    i0 = max_lag
    tau_r, tau_l = _first_zero(r[i0:]), _first_zero(r[i0::-1])
    half = tau_r + tau_l
    signed = 180.0 * (tau_r - tau_l) / half if half > 0 else 0.0
    phase = abs(signed)
    peak = float(np.max(np.abs(r)))
    ratio = float(abs(r[i0]) / peak) if peak > 0 else 1.0
    if half < HORCH_MIN_HALF_PERIOD:
        verdict = "none"
    else:
        verdict = "stiction" if phase > HORCH_ODD_DEG else ("none" if phase < HORCH_EVEN_DEG else "undetermined")
    return {"detector": "horch", "statistic": float(phase), "phase_signed_deg": float(signed), "ratio": ratio,
            "tau_r": tau_r, "tau_l": tau_l,
            "integrating": bool(integrating), "verdict": verdict, "stiction": verdict == "stiction"}


def _half_cycles(y: np.ndarray) -> list[tuple[int, int]]:
    s = np.sign(y)
    zc = np.flatnonzero(np.diff(s) != 0) + 1
    return [(int(a), int(b)) for a, b in zip(zc[:-1], zc[1:], strict=False) if b - a >= 4]


def he_curve_fit(loop: LoopData, upper: float = 0.6, lower: float = 0.4) -> dict[str, Any]:
    from scipy.signal import savgol_filter

    y = _detrend(loop.op)
    w = min(11, (y.size // 2) * 2 - 1)
    ys = savgol_filter(y, w, 2) if w >= 5 else y  # zero crossings of the smoothed signal
    mse_sin = mse_tri = 0.0
    segs = _half_cycles(ys)
    for a, b in segs:
        seg = y[a:b]
        t = (np.arange(seg.size) + 0.5) / seg.size
        sb = np.sin(np.pi * t)
        amp = float(seg @ sb / (sb @ sb))
        mse_sin += float(np.mean((seg - amp * sb) ** 2))
        best = np.inf
        for peak in np.linspace(0.1, 0.9, 17):
            tb = np.where(t < peak, t / peak, (1 - t) / (1 - peak))
            amp_t = float(seg @ tb / (tb @ tb))
            best = min(best, float(np.mean((seg - amp_t * tb) ** 2)))
        mse_tri += best
    if not segs or mse_sin + mse_tri == 0:
        return {"detector": "he", "statistic": 0.5, "stiction": False, "verdict": "undetermined", "half_cycles": 0}
    si = mse_sin / (mse_sin + mse_tri)
    verdict = "stiction" if si > upper else ("none" if si < lower else "undetermined")
    return {"detector": "he", "statistic": float(si), "stiction": verdict == "stiction", "verdict": verdict,
            "half_cycles": len(segs)}


def kano(loop: LoopData, threshold: float = 0.25) -> dict[str, Any]:
    dpv = np.diff(loop.pv)
    dop = np.diff(loop.op)
    # white-noise sd from second differences (robust: 1.4826 MAD / sqrt(6)); a signal's smooth part cancels
    noise = float(np.median(np.abs(np.diff(loop.pv, 2))) * 1.4826 / np.sqrt(6.0))
    op_noise = 3.0 * float(np.median(np.abs(np.diff(loop.op, 2))) * 1.4826 / np.sqrt(6.0))
    # sections of monotonic OP motion (sign of a smoothed increment)
    k = 3
    dop_s = np.convolve(loop.op, np.ones(k) / k, mode="same")
    direction = np.sign(np.diff(dop_s))
    moving = np.abs(dop) > op_noise
    still_pv = np.abs(dpv) < 2.0 * noise
    stuck = moving & still_pv & (direction != 0)
    # a stuck stretch must last at least 3 samples
    run = 0
    count = 0
    for v in stuck:
        run = run + 1 if v else 0
        if run == 3:
            count += 3
        elif run > 3:
            count += 1
    rho = count / max(int(np.count_nonzero(moving)), 1)
    return {"detector": "kano", "statistic": float(rho), "threshold": threshold, "stiction": bool(rho > threshold)}


DETECTORS = {"horch": horch, "he": he_curve_fit, "kano": kano}

__all__ = ["DETECTORS", "HORCH_EVEN_DEG", "HORCH_MIN_HALF_PERIOD", "HORCH_ODD_DEG", "cross_correlation", "horch",
           "he_curve_fit", "kano"]
