"""Temperature pre-processing: the noisy temperature channels turned into the valve's driver.

The one module that owns it (docs/estimation.md, "Architecture"). Two methods, each used by one
likelihood, kept both for a measured reason (``studies/temperature_preprocessing.py``,
docs/estimation.md, "Temperature pre-processing"):

* :func:`smooth_temperature`: a robust integrated-random-walk Rauch-Tung-Striebel smoother
  (Student-t process noise for the kinks of the heating, the noise levels by variational EM; its
  measurement noise sd is the channel's ``s_T``/``s_M``). Smooth level and rate at every sample,
  zero phase. The output-error likelihood of the diagnosis
  (:mod:`valve_env.valveid.oe`) drives its fine-grid valve simulation with it, after removing
  reversals smaller than 5 noise sd (``monotone_path``).
* :func:`denoise_temperature`: relaxed total-variation denoising (:func:`relaxed_tv`, Condat's
  exact algorithm with the extreme blocks re-estimated). Piecewise-linear-free of spurious
  reversals by construction; the EKF's valve model (:mod:`valve_env.valveid.valve_model`) takes
  its rate over each sample interval as the Dahl driver, which a smoother's small wiggles (each a
  reversal of the friction) would bias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import minimize_scalar

from valve_env.ident.kalman import LOG2PI
from valve_env.ident.tests import second_difference_sd


def read_only(a: np.ndarray) -> np.ndarray:
    """A read-only, C-contiguous float64 view of ``a`` (a copy only where ``a`` is not already one; the caller's
    own array keeps its flags). The output-error path hands its compiled kernels read-only arrays only, because
    numba compiles a kernel once per read-only flag of each argument: a mix would compile each kernel twice or
    more in one process."""
    v = np.ascontiguousarray(a, dtype=np.float64).view()
    v.setflags(write=False)
    return v


# --------------------------------------------------------------------------- TV denoising
@njit(cache=True)
def _fill(x: np.ndarray, k0: int, last: int, v: float) -> int:  # pragma: no cover - compiled
    """``x[k0..last] = v`` (at least ``x[k0]``, as the C code's do-while); returns the next index."""
    while True:
        x[k0] = v
        k0 += 1
        if k0 > last:
            return k0


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
                k0 = _fill(x, k0, kminus, vmin)
                kminus = k0
                k = k0
                vmin = y[k0]
                umin = lam
                umax = vmin + umin - vmax
            elif umax > 0.0:
                k0 = _fill(x, k0, kplus, vmax)
                kplus = k0
                k = k0
                vmax = y[k0]
                umax = minlam
                umin = vmax + umax - vmin
            else:
                vmin += umin / (k - k0 + 1)
                _fill(x, k0, k, vmin)
                return x
        umin += y[k + 1] - vmin
        if umin < minlam:
            k0 = _fill(x, k0, kminus, vmin)
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
                k0 = _fill(x, k0, kplus, vmax)
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
    """Robust white-noise sd of a smooth signal plus noise: MAD of second differences / sqrt(6).

    Exactly 0 for a channel that holds its value in more than half of its samples (a quantised,
    stepped or noiseless channel): use :func:`channel_noise` for the noise level a likelihood needs."""
    y = np.asarray(y, dtype=float)
    return second_difference_sd(y) if len(y) >= 4 else 0.0


#: The finest temperature resolution a measured channel is taken to have where the data shows none
#: (a noiseless channel in full floating point), degC: a lab PT100 read to 0.001 K. Its
#: quantisation sd, RESOLUTION_FLOOR_C / sqrt(12), is the least noise sd any channel is given
#: (docs/reference.md, section 2: noiseless channels are valid runs).
RESOLUTION_FLOOR_C = 1.0e-3


def _on_grid(y: np.ndarray, step: float, tol: float, share: float) -> bool:
    z = (y - y[0]) / step
    return float(np.mean(np.abs(z - np.round(z)) <= tol)) >= share


def quantum(y: np.ndarray, tol: float = 0.02, share: float = 0.99) -> float | None:
    """The quantisation step of a channel, or None where it is not quantised.

    Two candidates: the smallest change between consecutive samples (ignoring changes below 1e-9 of
    the channel's magnitude, which are float rounding), and the coarsest decimal resolution (1 to
    1e-4) its values are written at. A candidate holds where at least ``share`` of the values lie
    within ``tol`` steps of its grid; the quantum is the larger that holds (a 0.05 K converter is
    0.05, not 0.01; a channel stored on change with a dead band at 0.01 K resolution is 0.01). A
    channel in full floating point (white noise on a smooth signal) has neither."""
    y = np.asarray(y, dtype=float)
    if y.size < 4:
        return None
    d = np.abs(np.diff(y))
    eps = 1e-9 * max(1.0, float(np.max(np.abs(y))))
    d = d[d > eps]
    if d.size < 3:
        return None
    found = []
    q = float(np.min(d))
    if _on_grid(y, q, tol, share):
        found.append(q)
    for k in range(5):
        step = 10.0**-k
        if step < q * 0.999 and found:
            break
        if _on_grid(y, step, 1e-9 * max(1.0, float(np.max(np.abs(y)))) / step, 1.0):
            found.append(step)
            break
    return float(f"{max(found):.10g}") if found else None


@dataclass(frozen=True)
class ChannelNoise:
    """The measurement-noise level of one temperature channel and how it was found.

    ``sd`` (degC) is what a likelihood uses: the robust second-difference sd (:func:`noise_sd`,
    ``method="mad"``) where the channel is noisy, else the sd of its quantisation, q / sqrt(12)
    (``"quantisation"``), else :data:`RESOLUTION_FLOOR_C` / sqrt(12) (``"resolution_floor"``).
    Never 0 or NaN. ``held_fraction``: the share of consecutive samples that are equal (a channel
    held by a thermostat or stored on change holds most of them)."""

    sd: float
    method: str
    quantum: float | None
    held_fraction: float
    mad_sd: float
    #: a value on the channel's quantisation grid (the grid is ``offset + k quantum``)
    offset: float = 0.0

    def remeasure(self, level: np.ndarray, sd: float, rng: np.random.Generator, *,
                  shift_grid: bool = False) -> np.ndarray:
        """The channel measured again from a latent ``level``, the way it was recorded: white noise of
        ``sd`` (the smoother's estimate) on a noisy channel; on a quantised one the noise that lies below
        its step (none: its noise is not seen, so the rounding is the measurement) and the rounding to
        its grid; on a noiseless one, nothing. For the null copies and bootstraps that must reproduce the
        record's measurement (a quantised channel given white noise of q / sqrt(12) instead is far
        noisier after smoothing than the rounded record). One standard normal per sample is drawn
        whatever the convention, so a noisy channel's copies are as before.

        ``shift_grid``: on a channel whose noise lies below its step, the rounding of one level is one
        fixed staircase, so copies would all be the same. Where the latent level lies inside its
        quantisation cells is unknown, so each copy shifts the grid by a uniform draw of +/- q / 2 and
        shifts the rounded values back: the staircase's steps fall at other times and the level stays
        centred (one more draw per copy, on such a channel only)."""
        eps = rng.standard_normal(level.shape[0])
        if self.method == "mad" and self.quantum is None:
            return level + sd * eps
        y = level + (sd * eps if self.method == "mad" else 0.0)
        if self.quantum is not None:
            u = rng.uniform(-0.5, 0.5) * self.quantum if shift_grid and self.method != "mad" else 0.0
            y = self.offset + np.round((y + u - self.offset) / self.quantum) * self.quantum - u
        return y

    def describe(self, channel: str) -> dict[str, object]:
        """A JSON-ready note: the channel, its noise sd and why (docs/reference.md, section 2)."""
        if self.method == "mad":
            why = "the robust sd of its second differences"
        elif self.method == "quantisation":
            why = f"its quantisation step {self.quantum:g} K (q / sqrt(12)); the noise is below it"
        else:
            why = f"the sensor resolution floor {RESOLUTION_FLOOR_C:g} K (q / sqrt(12)): the channel shows no noise"
        return {"channel": channel, "noise_sd_C": self.sd, "method": self.method, "quantum_C": self.quantum,
                "held_fraction": round(self.held_fraction, 4), "why": why}


def _floor_sd(noise: ChannelNoise) -> float:
    return (noise.quantum if noise.quantum is not None else RESOLUTION_FLOOR_C) / math.sqrt(12.0)


def channel_noise(y: np.ndarray) -> ChannelNoise:
    """The noise level of a temperature channel of any measurement convention (see :class:`ChannelNoise`).

    The floor is the quantisation sd of the channel's step (or of :data:`RESOLUTION_FLOOR_C`): a
    noisy channel whose robust sd is above it keeps that sd; a held, stepped, quantised or
    noiseless one, whose second differences are mostly 0, gets the floor."""
    y = np.asarray(y, dtype=float)
    mad = noise_sd(y)
    q = quantum(y)
    held = float(np.mean(np.diff(y) == 0.0)) if y.size > 1 else 1.0
    floor = (q if q is not None else RESOLUTION_FLOOR_C) / math.sqrt(12.0)
    off = float(y[0]) if y.size else 0.0
    if math.isfinite(mad) and mad > floor:
        return ChannelNoise(mad, "mad", q, held, mad, off)
    return ChannelNoise(floor, "quantisation" if q is not None else "resolution_floor", q, held,
                        mad if math.isfinite(mad) else 0.0, off)


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
    y = read_only(y)
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
    interval (K/s; 0 at the end). The noise level is :func:`channel_noise`'s.

    A quantised channel whose noise lies below its step (``method == "quantisation"``) is a staircase,
    which TV keeps, and whose one-step flips would each reverse the Dahl friction the EKF drives with
    this path: there it is the smoother's level (:func:`smooth_temperature`) freed of reversals smaller
    than 5 quantisation sd (:func:`monotone_path`, as the output-error likelihood treats its input),
    for either denoiser (docs/diagnosis.md, "Measured data of any convention")."""
    if denoiser not in DENOISERS:
        raise ValueError(f"unknown denoiser {denoiser!r}; use one of {DENOISERS}")
    y = np.ascontiguousarray(y, dtype=float)
    t = np.ascontiguousarray(t, dtype=float)
    noise = channel_noise(y)
    if noise.method == "quantisation" and y.shape[0] >= 4:
        ys = monotone_path(smooth_temperature(t, y)[0], 5.0 * noise.sd)
    else:
        lam = tv_factor * noise.sd
        ys = relaxed_tv(y, lam) if denoiser == "relaxed" else tv_denoise(read_only(y), lam)
    v = np.zeros_like(ys)
    if len(ys) > 1:
        v[:-1] = np.diff(ys) / np.diff(np.asarray(t, dtype=float))
    return ys, v


# --------------------------------------------------------------------------- monotone paths
@njit(cache=True)
def _pava(y: np.ndarray, a: int, b: int, increasing: bool, out: np.ndarray) -> None:
    """Isotonic least-squares fit of y[a:b] (pool adjacent violators), written to out[a:b]."""
    m = b - a
    if m <= 0:
        return
    val = np.empty(m)
    wt = np.empty(m)
    cnt = np.empty(m, dtype=np.int64)
    top = 0
    sgn = 1.0 if increasing else -1.0
    for i in range(a, b):
        val[top] = sgn * y[i]
        wt[top] = 1.0
        cnt[top] = 1
        top += 1
        while top > 1 and val[top - 2] > val[top - 1]:
            w = wt[top - 2] + wt[top - 1]
            val[top - 2] = (wt[top - 2] * val[top - 2] + wt[top - 1] * val[top - 1]) / w
            wt[top - 2] = w
            cnt[top - 2] += cnt[top - 1]
            top -= 1
    i = a
    for j in range(top):
        for _ in range(cnt[j]):
            out[i] = sgn * val[j]
            i += 1


@njit(cache=True)
def monotone_path(y: np.ndarray, delta: float) -> np.ndarray:
    """Remove reversals smaller than ``delta`` from a path, without shifting it in time.

    The turning points are the extremes of the path that are followed by a retrace of at least
    ``delta`` (a zig-zag with threshold delta; the extreme itself is the turning point, so no lag).
    Between turning points the path is replaced by its isotonic least-squares fit, which is
    monotone and level-unbiased. The Dahl model is driven by this path: the small wiggles that
    remain after smoothing a noisy channel would otherwise each flip the friction force."""
    n = y.shape[0]
    out = y.copy()
    if n < 3 or delta <= 0.0:
        return out
    tps = np.empty(n + 1, dtype=np.int64)
    ntp = 0
    tps[ntp] = 0
    ntp += 1
    # direction from the first retrace of delta
    hi = y[0]
    lo = y[0]
    ihi = 0
    ilo = 0
    direction = 0
    k = 1
    while k < n and direction == 0:
        if y[k] > hi:
            hi = y[k]
            ihi = k
        if y[k] < lo:
            lo = y[k]
            ilo = k
        first = second = 0
        if hi - y[k] >= delta and ihi >= ilo:
            direction, first, second = -1, ilo, ihi  # rose to hi, now falling
        elif y[k] - lo >= delta and ilo >= ihi:
            direction, first, second = 1, ihi, ilo  # fell to lo, now rising
        if direction != 0:
            if first > 0:
                tps[ntp] = first
                ntp += 1
            tps[ntp] = second
            ntp += 1
            ext = y[k]
            iext = k
        k += 1
    # a path that never retraces delta is one monotone run, from 0 to n - 1 (the loops below add its end)
    while k < n:
        # in the direction of travel (signs flip exactly): a new extreme, or a retrace of delta from it
        v = direction * y[k]
        e = direction * ext
        if v > e:
            ext = y[k]
            iext = k
        elif e - v >= delta:
            tps[ntp] = iext
            ntp += 1
            direction = -direction
            ext = y[k]
            iext = k
        k += 1
    if tps[ntp - 1] != n - 1:
        tps[ntp] = n - 1
        ntp += 1
    for j in range(ntp - 1):
        a = tps[j]
        b = tps[j + 1]
        inc = y[b] >= y[a]
        _pava(y, a, b + 1 if j == ntp - 2 else b, inc, out)
    return out


# --------------------------------------------------------------------------- IRW-RTS smoothing
@njit(cache=True)
def _irw_pass(t: np.ndarray, y: np.ndarray, q: float, r: float, smooth: bool,
              w: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, float]:  # pragma: no cover - compiled
    """Kalman filter (and RTS smoother) of an integrated random walk observed with white noise.

    ``w[k]`` scales the process noise of the interval ending at sample k (1 = the nominal q).
    Returns (log-likelihood, level, rate, e, res); level/rate are smoothed when ``smooth``, and then the
    log-likelihood is not computed (0). With
    ``smooth`` also the two posterior expectations the variational EM of :func:`smooth_temperature`
    needs: ``e[k] = tr(Q1(h_k)^-1 E[eta_k eta_k' | y])`` for the interval's process noise ``eta_k =
    x_k - F x_k-1`` in units of q (``Q1(h) = [[h^3/3, h^2/2], [h^2/2, h]]``; the lag-one smoothed
    covariance included), and ``res = sum_k E[(y_k - level_k)^2 | y]`` (the squared residual plus
    the level's posterior variance); otherwise e = 0 and res = 0."""
    n = t.shape[0]
    mf = np.empty((n, 2))
    Pf = np.empty((n, 3))
    mp = np.empty((n, 2))
    Pp = np.empty((n, 3))
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
            # F P F' + Q
            q00 = p00 + 2.0 * h * p01 + h * h * p11 + qk * h * h * h / 3.0
            q01 = p01 + h * p11 + qk * h * h / 2.0
            q11 = p11 + qk * h
            m0 = m0 + h * m1
            p00, p01, p11 = q00, q01, q11
        mp[k, 0] = m0
        mp[k, 1] = m1
        Pp[k, 0] = p00
        Pp[k, 1] = p01
        Pp[k, 2] = p11
        S = p00 + r
        nu = y[k] - m0
        if not smooth:  # the smoothing passes (variational EM) do not use the likelihood
            ll += -0.5 * (LOG2PI + math.log(S) + nu * nu / S)
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
        Pf[k, 0] = p00
        Pf[k, 1] = p01
        Pf[k, 2] = p11
    level = np.empty(n)
    rate = np.empty(n)
    e = np.zeros(n)
    if not smooth:
        for k in range(n):
            level[k] = mf[k, 0]
            rate[k] = mf[k, 1]
        return ll, level, rate, e, 0.0
    ms0 = mf[n - 1, 0]
    ms1 = mf[n - 1, 1]
    s00 = Pf[n - 1, 0]
    s01 = Pf[n - 1, 1]
    s11 = Pf[n - 1, 2]
    level[n - 1] = ms0
    rate[n - 1] = ms1
    res = (y[n - 1] - ms0) ** 2 + s00
    for k in range(n - 2, -1, -1):
        h = t[k + 1] - t[k]
        # C = Pf F' Pp^-1
        f00 = Pf[k, 0] + h * Pf[k, 1]
        f01 = Pf[k, 1]
        f10 = Pf[k, 1] + h * Pf[k, 2]
        f11 = Pf[k, 2]
        a = Pp[k + 1, 0]
        b = Pp[k + 1, 1]
        d = Pp[k + 1, 2]
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
        n0 = mf[k, 0] + c00 * d0 + c01 * d1
        n1 = mf[k, 1] + c10 * d0 + c11 * d1
        # smoothed covariance at k: Pf + C (Ps_k+1 - Pp_k+1) C'
        e00 = s00 - a
        e01 = s01 - b
        e11 = s11 - d
        g00 = c00 * e00 + c01 * e01
        g01 = c00 * e01 + c01 * e11
        g10 = c10 * e00 + c11 * e01
        g11 = c10 * e01 + c11 * e11
        t00 = Pf[k, 0] + g00 * c00 + g01 * c01
        t01 = Pf[k, 1] + g00 * c10 + g01 * c11
        t11 = Pf[k, 2] + g10 * c10 + g11 * c11
        # lag-one covariance X = Cov(x_k+1, x_k | y) = Ps_k+1 C'; then X F'
        x00 = s00 * c00 + s01 * c01
        x01 = s00 * c10 + s01 * c11
        x10 = s01 * c00 + s11 * c01
        x11 = s01 * c10 + s11 * c11
        xf00 = x00 + h * x01
        xf01 = x01
        xf10 = x10 + h * x11
        # E[eta eta'] with eta = x_k+1 - F x_k: Ps_k+1 - X F' - F X' + F Ps_k F' + mean outer product
        dm0 = ms0 - (n0 + h * n1)
        dm1 = ms1 - n1
        v00 = s00 - 2.0 * xf00 + t00 + 2.0 * h * t01 + h * h * t11 + dm0 * dm0
        v01 = s01 - xf01 - xf10 + t01 + h * t11 + dm0 * dm1
        v11 = s11 - 2.0 * x11 + t11 + dm1 * dm1
        # tr(Q1^-1 E), Q1^-1 = 12 / h^4 [[h, -h^2/2], [-h^2/2, h^3/3]]
        e[k + 1] = 12.0 / (h * h * h * h) * (h * v00 - h * h * v01 + h * h * h / 3.0 * v11)
        ms0, ms1 = n0, n1
        s00, s01, s11 = t00, t01, t11
        level[k] = ms0
        rate[k] = ms1
        res += (y[k] - ms0) ** 2 + s00
    return ll, level, rate, e, res


#: degrees of freedom of the Student-t process noise of :func:`smooth_temperature` (its mixing
#: Gamma(nu/2, nu/2)): the heaviest tail of 0.5, 1, 2 and 4 that recovered the noise sd best on the
#: development seeds (docs/estimation.md, "Temperature pre-processing")
STUDENT_NU = 1.0


def smooth_temperature(t: np.ndarray, y: np.ndarray, nu: float = STUDENT_NU, max_iter: int = 1000,
                       tol: float = 1e-3) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Latent temperature and its rate from a noisy channel: an integrated random walk whose process
    noise is Student-t, observed with white noise, smoothed by variational EM.

    A step of the tank's heating puts a kink in the temperature (the rate jumps). A Gaussian random
    walk of the rate would round each kink symmetrically: the smoothed temperature would start to
    move before the water does, which the Dahl friction turns into a spurious lead. The process
    noise of each interval is therefore a scale mixture, ``eta_k ~ N(0, q Q1(h_k) / lambda_k)`` with
    ``lambda_k ~ Gamma(nu/2, nu/2)`` (a bivariate Student-t with ``nu`` degrees of freedom), and the
    measurement noise ``N(0, r)``. Variational EM (mean field over the states and the lambdas,
    Agamennoni, Nieto and Nebot, IEEE Trans. Signal Process. 60 (2012) 3368-3378): the RTS smoother
    at the weights ``E[lambda_k] = (nu + 2) / (nu + e_k / q)``, where ``e_k`` includes the posterior
    covariance of the interval's process noise (:func:`_irw_pass`), then the closed-form M-step
    ``q = sum_k E[lambda_k] e_k / (2 (n - 1))``, ``r = mean_k E[(y_k - level_k)^2]``, until r moves by
    less than ``tol`` (relative) and the level by less than ``tol`` noise sd. It starts at the
    channel's noise level (:func:`channel_noise`) with q the Gaussian maximum likelihood at that r,
    and r never falls below the channel's resolution floor (the variance q^2 / 12 of its quantisation
    step, or of :data:`RESOLUTION_FLOOR_C`): a held or noiseless channel would otherwise drive r
    to 0 and the filter's gains to a division by zero.

    The former smoother (iteratively reweighted Gaussian passes with ``q`` and ``r`` re-estimated by
    Nelder-Mead at weights without a prior) drove r to 0 on a quarter of the channels of the
    development runs, returning the raw reading as the "smoothed" temperature (docs/estimation.md,
    "Temperature pre-processing").

    Returns (level degC, rate K/s, s_T degC, s_v K/s/sqrt(s)), with s_T = sqrt(r) and s_v = sqrt(q)
    the nominal (lambda = 1) scale of the rate's random walk."""
    t = read_only(t)
    y = read_only(y)
    n = t.shape[0]
    if n < 4:
        raise ValueError(f"smooth_temperature needs at least 4 samples, got {n}")
    if not (nu > 0 and max_iter >= 1 and tol > 0):
        raise ValueError(f"smooth_temperature: nu, max_iter and tol must be positive (got {nu}, {max_iter}, {tol})")
    noise = channel_noise(y)
    r = noise.sd**2
    r_floor = _floor_sd(noise) ** 2
    w = np.ones(n)
    lq = minimize_scalar(lambda z: -_irw_pass(t, y, math.exp(z), r, False, w)[0], bounds=(-40.0, 0.0),
                         method="bounded", options={"xatol": 1e-2}).x
    q, r = _variational_em(t, y, math.exp(lq), r, r_floor, float(nu), int(max_iter), float(tol), w, True)
    _, level, rate, _, _ = _irw_pass(t, y, q, r, True, w)
    return level, rate, math.sqrt(r), math.sqrt(q)


@njit(cache=True)
def _variational_em(t: np.ndarray, y: np.ndarray, q: float, r: float, r_floor: float, nu: float, max_iter: int,
                    tol: float, w: np.ndarray, smooth: bool) -> tuple[float, float]:  # pragma: no cover - compiled
    """The iterations of :func:`smooth_temperature`'s variational EM from ``q``, ``r``: the converged (q, r), with the
    weights ``w`` (1 / E[lambda_k]) updated in place. Its sum is NumPy's (:func:`_pairwise_sum`). ``smooth`` (True) is
    handed to :func:`_irw_pass` as an argument: a constant there would compile a second, literal-typed copy of it."""
    n = t.shape[0]
    level_prev = np.empty(0)
    for it in range(max_iter):
        _, level, _, e, res = _irw_pass(t, y, q, r, smooth, w)
        lam = (nu + 2.0) / (nu + e[1:] / q)
        q_new = max(_pairwise_sum(lam * e[1:], 0, n - 1) / (2.0 * (n - 1)), 1e-300)
        r_new = max(res / n, r_floor)
        for k in range(1, n):  # elementwise: a slice assignment would compile numba's shape-error formatting
            w[k] = 1.0 / lam[k - 1]
        done = (it > 0 and abs(math.log(r_new / r)) < tol
                and np.max(np.abs(level - level_prev)) < tol * math.sqrt(r_new))
        q, r, level_prev = q_new, r_new, level
        if done:
            break
    return q, r


@njit(cache=True)
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """NumPy's sum of a run of at most 128 values (:func:`_pairwise_sum`): eight interleaved partial sums."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    stop = n - n % 8
    while i < stop:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def _pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """The sum of ``a[lo:lo + n]`` in the order of NumPy's ``np.sum`` of a contiguous float64 array, so that a
    compiled loop gives NumPy's figures to the last digit: its pairwise summation, a run longer than 128 split
    in two at half its length rounded down to a multiple of 8, the halves summed and added (the recursion
    unrolled on a stack: numba's cache does not keep recursive functions)."""
    run_lo = np.empty(64, dtype=np.int64)
    run_n = np.empty(64, dtype=np.int64)
    right = np.zeros(64, dtype=np.bool_)  # the run's left half is summed (into ``left``), its right half is next
    left = np.empty(64)
    top = 0
    run_lo[0] = lo
    run_n[0] = n
    while True:
        m = run_n[top]
        if m > 128:  # split: the left half first
            half = m // 2 - (m // 2) % 8
            right[top] = False
            run_lo[top + 1] = run_lo[top]
            run_n[top + 1] = half
            top += 1
            continue
        v = _block_sum(a, run_lo[top], m)
        top -= 1
        while top >= 0 and right[top]:  # both halves done: their sum is this run's
            v = left[top] + v
            top -= 1
        if top < 0:
            return v
        left[top] = v
        right[top] = True
        half = run_n[top] // 2 - (run_n[top] // 2) % 8
        run_lo[top + 1] = run_lo[top] + half
        run_n[top + 1] = run_n[top] - half
        top += 1


__all__ = ["ChannelNoise", "RESOLUTION_FLOOR_C", "channel_noise", "quantum", "smooth_temperature", "STUDENT_NU",
           "denoise_temperature", "DENOISERS", "relaxed_tv", "tv_denoise", "noise_sd"]
