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
  positive lags, where PV follows OP; a feature of the combined detection, docs/loops.md "Detection").
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
* :func:`bicoherence` - Choudhury, M.A.A.S., Shah, S.L., Thornhill, N.F. (2004). Diagnosis of poor control-loop
  performance using higher-order statistics. *Automatica* 40(10), 1719-1728. The squared bicoherence of the control
  error (SP - PV, linear trend removed), estimated from ``K`` Hann-windowed half-overlapping segments, is
  chi-square with 2 degrees of freedom over ``2K`` at every bifrequency of a Gaussian (or linear) signal. Reported:
  ``ngi``, the mean squared bicoherence over the principal domain in excess of the Gaussian's ``1/K`` (the
  non-Gaussianity index's idea: about 0 for a linear loop); ``nli = max - (mean + 2 sd)`` with a robust (10 %
  trimmed) mean and sd (the non-linearity index: a peak standing out of the bicoherence plane); and the verdict:
  nonlinear when the largest squared bicoherence exceeds its chi-square limit at ``alpha`` 0.05 with a Bonferroni
  correction over the bifrequencies. The paper reads stiction from the OP-PV plot of a nonlinear loop (below); as a
  detector alone the verdict here is "nonlinear".
* :func:`ellipse_area` - the OP-PV plot's enclosed area (Choudhury et al. 2004's ellipse; the relay's
  parallelogram of a sticky valve): OP and PV are band-passed about the control error's dominant oscillation, and
  the signed area their path sweeps (shoelace) is divided by ``n omega sd(OP) sd(PV)``, which is ``sin(phi)`` for
  two sinusoids ``phi`` apart (0: a line, the PV in phase or in antiphase with OP; 1: a circle). Positive when the
  path runs counter-clockwise in the (OP, PV) plane. Reported as a feature (no published threshold).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from valve_env.ident.tests import second_difference_sd
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


def he_curve_fit(loop: LoopData, upper: float = 0.6, lower: float = 0.4, on: str = "op") -> dict[str, Any]:
    """He et al.'s curve fit (module doc) of the controller output (``on="op"``, the default) or of the PV."""
    from scipy.signal import savgol_filter

    y = _detrend(loop.op if on == "op" else loop.pv)
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
    noise = second_difference_sd(loop.pv, centred=False)
    op_noise = 3.0 * second_difference_sd(loop.op, centred=False)
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


def _bicoherence_segment(n: int) -> int:
    """The segment length of :func:`bicoherence`: a power of two near a sixth of the record, 32-256 samples (about ten
    half-overlapping segments on a 2 h record at 10 s)."""
    return int(min(256, max(32, 2 ** round(math.log2(max(n, 2) / 6.0)))))


def bicoherence(loop: LoopData, alpha: float = 0.05, seg: int | None = None) -> dict[str, Any]:
    """Choudhury et al.'s bicoherence test of the control error (module doc)."""
    from scipy import stats
    from scipy.signal.windows import hann

    e = _detrend(loop.sp - loop.pv)
    m = seg or _bicoherence_segment(e.size)
    m = min(m, e.size)
    step = m // 2
    starts = range(0, e.size - m + 1, step)
    X = np.fft.rfft(np.array([e[a:a + m] for a in starts]) * hann(m, sym=False), axis=1)
    K = X.shape[0]
    f1, f2 = np.meshgrid(np.arange(1, m // 2), np.arange(1, m // 2), indexing="ij")
    keep = (f2 <= f1) & (f1 + f2 <= m // 2 - 1)
    f1, f2 = f1[keep], f2[keep]
    x1, x2, x3 = X[:, f1], X[:, f2], np.conj(X[:, f1 + f2])
    num = np.abs(np.mean(x1 * x2 * x3, axis=0)) ** 2
    den = np.mean(np.abs(x1 * x2) ** 2, axis=0) * np.mean(np.abs(x3) ** 2, axis=0)
    bic2 = num / np.maximum(den, 1e-300 + 1e-12 * float(den.max()))
    limit = float(stats.chi2.isf(alpha / bic2.size, 2) / (2.0 * K))
    tm = float(stats.trim_mean(bic2, 0.1))
    lo, hi = np.quantile(bic2, [0.1, 0.9])
    core = bic2[(bic2 >= lo) & (bic2 <= hi)]
    sd = float(core.std()) if core.size > 1 else 0.0
    peak = float(bic2.max())
    nonlinear = bool(peak > limit)
    return {"detector": "bicoherence", "statistic": peak, "ngi": float(bic2.mean() - 1.0 / K),
            "nli": float(peak - (tm + 2.0 * sd)), "limit": limit, "segments": int(K), "segment": int(m),
            "nonlinear": nonlinear, "verdict": "nonlinear" if nonlinear else "linear", "stiction": nonlinear}


def oscillation(y: np.ndarray, dt: float) -> dict[str, Any]:
    """Regularity of an oscillation from the zero crossings of the autocorrelation (Thornhill,
    Huang & Zhang 2003): ``r = mean(period) / (3 sd(period)) > 1`` with a first ACF peak above 0.3."""
    from statsmodels.tsa.stattools import acf

    z = _detrend(y)
    r = acf(z, nlags=y.size // 2, fft=True)
    zc = np.flatnonzero(np.diff(np.sign(r)) != 0)
    if zc.size < 4:
        return {"oscillating": False, "period_s": None, "regularity": 0.0, "acf_peak": 0.0}
    intervals = np.diff(zc[:12]) * 2.0
    period = float(intervals.mean())
    reg = float(period / (3.0 * intervals.std())) if intervals.std() > 0 else math.inf
    i0, i1 = zc[1], zc[2] if zc.size > 2 else zc[1] + 1
    peak = float(r[i0:i1 + 1].max())
    osc = bool(reg > 1.0 and peak > 0.3)
    return {"oscillating": osc, "period_s": period * dt, "regularity": min(reg, 1e6), "acf_peak": peak}


def dominant_frequency(y: np.ndarray) -> float:
    """The frequency (cycles per sample) of the largest periodogram peak of ``y`` (trend removed), between one cycle
    per record and a quarter of the sampling rate."""
    z = _detrend(y)
    m = 4 * z.size
    p = np.abs(np.fft.rfft(z * np.hanning(z.size), m)) ** 2
    f = np.fft.rfftfreq(m)
    ok = (f >= 1.5 / z.size) & (f <= 0.25)
    return float(f[ok][int(np.argmax(p[ok]))]) if ok.any() else 0.05


def ellipse_area(loop: LoopData) -> dict[str, Any]:
    """The OP-PV plot's normalised signed area (module doc), OP and PV band-passed (Butterworth, order 2, forwards
    and backwards) over a factor of two either side of the control error's dominant frequency."""
    from scipy.signal import butter, sosfiltfilt

    f0 = dominant_frequency(loop.sp - loop.pv)
    lo, hi = max(f0 / 2.0, 0.5 / loop.n), min(2.0 * f0, 0.45)
    sos = butter(2, [2.0 * lo, 2.0 * hi], btype="bandpass", output="sos")
    x = sosfiltfilt(sos, _detrend(loop.op))
    y = sosfiltfilt(sos, _detrend(loop.pv))
    sx, sy = float(x.std()), float(y.std())
    if sx <= 0 or sy <= 0:
        return {"detector": "ellipse", "statistic": 0.0, "signed": 0.0, "period_samples": 1.0 / f0,
                "stiction": False}
    area = 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))
    omega = math.sqrt(float(np.std(np.diff(x))) / sx * float(np.std(np.diff(y))) / sy)
    signed = area / (x.size * omega * sx * sy) if omega > 0 else 0.0
    return {"detector": "ellipse", "statistic": abs(signed), "signed": float(signed), "period_samples": 1.0 / f0,
            "stiction": False}


DETECTORS = {"horch": horch, "he": he_curve_fit, "kano": kano, "bicoherence": bicoherence}

__all__ = ["DETECTORS", "HORCH_EVEN_DEG", "HORCH_MIN_HALF_PERIOD", "HORCH_ODD_DEG", "bicoherence",
           "cross_correlation", "dominant_frequency", "ellipse_area", "he_curve_fit", "horch", "kano", "oscillation"]
