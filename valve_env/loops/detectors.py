"""Classical stiction detectors, scored beside the grey-box method (docs/loops.md, "Classical detectors").

* :func:`horch` - Horch, A. (1999). A simple method for detection of stiction in control valves.
  *Control Engineering Practice* 7(10), 1221-1231. For a self-regulating loop the cross-correlation
  of OP and PV is an even function (extremum at lag 0) when the oscillation is caused by tuning or a
  disturbance and an odd one (zero near lag 0, extrema either side) when it is caused by stiction.
  Statistic: ``|r(0)| / max_tau |r(tau)|`` over lags within half the oscillation period; stiction
  when it is below 0.5 (the midpoint between odd, 0, and even, 1; fixed a priori, not tuned).
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


def horch(loop: LoopData, threshold: float = 0.5) -> dict[str, Any]:
    from statsmodels.tsa.stattools import ccf

    op, pv = _detrend(loop.op), _detrend(loop.pv)
    max_lag = min(60, loop.n // 4)
    fwd = ccf(pv, op, adjusted=False, fft=True)[: max_lag + 1]   # corr(pv[k+tau], op[k])
    bwd = ccf(op, pv, adjusted=False, fft=True)[: max_lag + 1]   # corr(op[k+tau], pv[k])
    r = np.concatenate([bwd[:0:-1], fwd])                          # lags -max_lag..max_lag
    lags = np.arange(-max_lag, max_lag + 1)
    # half period: first zero crossing on each side of the extremum nearest to lag 0
    peak = float(np.max(np.abs(r)))
    stat = float(abs(r[lags == 0][0]) / peak) if peak > 0 else 1.0
    return {"detector": "horch", "statistic": stat, "threshold": threshold, "stiction": bool(stat < threshold)}


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

__all__ = ["DETECTORS", "horch", "he_curve_fit", "kano"]
