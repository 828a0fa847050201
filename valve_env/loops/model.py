"""The grey-box loop model: a valve behind the controller output, a low-order process behind the valve.

    op --[valve: linear | backlash | stiction (S, J)]--> x --[first order + delay, or
    integrating + delay]--> pv = K w + c (+ g t) + v,   v = AR(p) noise

The valve is the project's one stick-slip model, :mod:`valve_env.physics.stickslip`, in % of
OP: ``J = 0`` is backlash (a deadband of width ``S``), ``0 < J <= S`` stick-slip with band ``S``
and slip jump ``J`` (Choudhury et al. 2005), ``S = 0`` a linear valve. A historian records OP as interval
means, so the valve runs at ``Settings.substeps`` steps per sample on a mean-preserving sub-sample OP
(:func:`subsample_op`) and the process is fed its position averaged over each sample (one substep: the valve
at the record's rate, nested).

The process is an output-error model (docs/loops.md, "Model"): the valve path ``x`` delayed by
``d + f >= 1`` samples, a fractional delay ``u[k] = (1-f) x[k-d] + f x[k-d-1]`` (the controller reacts to the
same sample's PV, so a delay below one sample would identify the controller, not the process), through a
unit-gain first-order lag ``w[k] = a w[k-1] + (1-a) u[k]`` (self-regulating, ``a = exp(-dt/tau)``) or an
integrator ``w[k] = w[k-1] + u[k] - mean(x)`` (level loops, with a trend term), scaled by the gain ``K``.
The noise ``v`` is AR(p). For given ``(a, d + f)`` the model is linear in ``(K, c, g)`` once the AR filter
is fixed, and the AR filter is least squares on the residual, so the Gaussian maximum-likelihood fit
alternates the two; the likelihood is concentrated over the innovation variance:
``loglik = -n/2 (log(2 pi RSS/n) + 1)``.
``(a, d + f)`` are searched over a grid, (S, J) over a grid in S (fractions of the OP range) and J/S,
refined by a bounded scalar search in S. Every candidate uses the same samples (``k0`` on), so
their likelihoods compare.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.linalg import solve_banded

from valve_env.ident.mle import profile_maximum
from valve_env.ident.tests import bic, second_difference_sd
from valve_env.physics.stickslip import stick_slip_path

#: valve candidates, nested: linear (S = 0) in backlash (J = 0) in stiction (S, J free)
VALVES: tuple[str, ...] = ("linear", "backlash", "stiction")
#: extra parameters of each valve over the linear one
VALVE_EXTRA_PARAMS = {"linear": 0, "backlash": 1, "stiction": 2}
#: J / S values tried for the stiction valve (it includes J = 0, so it nests the backlash candidate)
J_FRACTIONS: tuple[float, ...] = (0.0, 0.5, 1.0)
#: J / S values tried by the band's fit (docs/loops.md, "Band uncertainty"): a finer
#: grid holding J_FRACTIONS (nested), so that a small slip jump (J/S 0.3-0.4) is not read as J = 0
BAND_J_FRACTIONS: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)
#: time constants tried for the self-regulating process, s
TAUS_S: tuple[float, ...] = (1e-3, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0, 640.0)
#: band grid: fractions of the OP range (1st-99th percentile)
S_FRACTIONS = (0.01, 3.0)


#: the valve's last direction of motion before the record (both tried: docs/loops.md, "Model")
DIRECTIONS: tuple[float, ...] = (1.0, -1.0)


@njit(cache=True)
def _valve_path(op: np.ndarray, S: float, J: float, d0: float, out: np.ndarray) -> np.ndarray:
    # pragma: no cover - compiled
    return stick_slip_path(op, S, J, -np.inf, np.inf, out, d0)


@functools.lru_cache(maxsize=4)
def _centre_system(n: int) -> np.ndarray:
    """The banded matrix (scipy ``solve_banded`` form) of :func:`subsample_op`: interval ``k``'s mean of the
    line through the centre values is ``(c[k-1] + 6 c[k] + c[k+1]) / 8`` (flat beyond the ends)."""
    ab = np.zeros((3, n))
    ab[0, 1:] = 1.0 / 8.0
    ab[1, :] = 6.0 / 8.0
    ab[2, :-1] = 1.0 / 8.0
    ab[1, 0] += 1.0 / 8.0
    ab[1, -1] += 1.0 / 8.0
    return ab


def subsample_op(op: np.ndarray, substeps: int) -> np.ndarray:
    """The controller output between the recorded samples, ``substeps`` values per sample (docs/loops.md,
    "Model"): a historian's sample is the mean of OP over its interval, so OP is reconstructed as the line
    through values at the intervals' centres chosen so that each interval's mean is the recorded one
    (mean-preserving; flat beyond the record's ends), taken at the midpoints of ``substeps`` equal parts of
    each interval (exactly mean-preserving for an even ``substeps``: the centre is then a part's boundary).
    ``substeps`` 1 returns the record itself."""
    op = np.ascontiguousarray(op, dtype=float)
    if substeps <= 1 or op.size < 3:
        return op.copy() if substeps <= 1 else np.repeat(op, substeps)
    c = solve_banded((1, 1), _centre_system(op.size), op)
    t = (np.arange(op.size * substeps) + 0.5) / substeps - 0.5
    return np.interp(t, np.arange(op.size, dtype=float), c)


#: random draws of the hidden within-sample OP jitter whose valve positions are averaged (:func:`valve_path`)
JITTER_DRAWS = 8
#: the seed of those draws: the same draws for every candidate valve, so that their likelihoods compare (common
#: random numbers) and the profile in S is not roughened by fresh noise at each S
JITTER_SEED = 20261129


@functools.lru_cache(maxsize=4)
def _jitter_draws(size: int, draws: int) -> np.ndarray:
    """Standard normal draws (``draws`` rows of ``size``) for the within-sample jitter, read-only."""
    z = np.random.default_rng(JITTER_SEED).standard_normal((draws, size))
    z.setflags(write=False)
    return z


def op_jitter(op: np.ndarray, dt: float, scan_s: float) -> float:
    """The sd of the controller output's motion within a recorded sample that the record does not show, % of OP
    (docs/loops.md, "Model"). A controller scanning every ``scan_s`` acts on each scan's measurement noise, so its
    output jitters from scan to scan; the historian's interval mean over ``m = dt / scan_s`` scans keeps ``1/sqrt(m)``
    of that jitter's sd. The kept part is read from the record's second differences, in which a slow OP (a ramp, a
    load) cancels: for white jitter of sd ``s / sqrt(m)`` per sample, ``OP[k+1] - 2 OP[k] + OP[k-1]`` has sd
    ``sqrt(6) s / sqrt(m)``, estimated robustly (:func:`second_difference_sd`). 0 when the controller scans at
    the record's rate or slower (``m <= 1``: the record holds every move), or when the OP is held between samples."""
    op = np.asarray(op, dtype=float)
    m = dt / scan_s if scan_s > 0 else 1.0
    if m <= 1.0 or op.size < 3:
        return 0.0
    return second_difference_sd(op, centred=False) * math.sqrt(m)


def valve_path(op: np.ndarray, S: float, J: float, direction: float = 1.0, substeps: int = 1,
               jitter: float = 0.0) -> np.ndarray:
    """The valve position (% of OP) for the controller output ``op``: at rest at ``op[0]``, stuck after a
    motion upwards (``direction`` +1, :func:`valve_env.physics.stickslip.initial_state`) or downwards (-1).
    With ``substeps`` > 1 the valve is driven by the sub-sample OP of :func:`subsample_op` and its position
    averaged over each sample's interval (as the record averages OP); 1 is the sample-rate valve.

    ``jitter`` > 0 (% of OP; :func:`op_jitter`) adds the controller's motion within a sample that the record does not
    show, white at the sub-steps: a stuck valve slips when the jittering OP first reaches its band's end, and a
    moving one sticks at each reversal of it (Kano's rule), neither of which the smooth sub-sample OP does. The
    valve's position is then the mean over :data:`JITTER_DRAWS` fixed draws of the jitter (its expected position
    given the record)."""
    op = np.ascontiguousarray(op, dtype=float)
    if S <= 0.0:
        return op.copy()
    if substeps <= 1 and jitter <= 0.0:
        return _valve_path(op, float(S), float(J), float(direction), np.empty_like(op))
    fine = subsample_op(op, substeps)
    if jitter <= 0.0:
        x = _valve_path(fine, float(S), float(J), float(direction), np.empty_like(fine))
        return x.reshape(op.size, substeps).mean(axis=1)
    z = _jitter_draws(fine.size, JITTER_DRAWS)
    acc = np.zeros(fine.size)
    buf = np.empty_like(fine)
    for row in z:
        acc += _valve_path(fine + jitter * row, float(S), float(J), float(direction), buf)
    return (acc / JITTER_DRAWS).reshape(op.size, substeps).mean(axis=1)


@njit(cache=True)
def _filtered(x: np.ndarray, a: float, delay: float, integ: bool) -> np.ndarray:  # pragma: no cover - compiled
    n = x.size
    w = np.zeros(n)
    xm = x.mean()
    d = int(math.floor(delay))
    f = delay - d
    w[0] = 0.0 if integ else x[0]
    for k in range(1, n):
        j = k - d
        xk = x[j] if j >= 0 else x[0]
        if f > 0.0:  # a fractional delay: the input between its samples k-d and k-d-1 (docs/loops.md, "Model")
            xk = (1.0 - f) * xk + f * (x[j - 1] if j >= 1 else x[0])
        if integ:
            w[k] = w[k - 1] + (xk - xm)
        else:
            w[k] = a * w[k - 1] + (1.0 - a) * xk
    return w


@njit(cache=True)
def _ar_fit(r: np.ndarray, k0: int, k1: int, p: int) -> tuple[float, float]:  # pragma: no cover - compiled
    """The AR(p <= 2) filter of the residual ``r`` by least squares over samples ``k0..k1-1`` (p >= 1)."""
    b00 = 1e-12
    b01 = 0.0
    b11 = 1e-12
    c0 = 0.0
    c1 = 0.0
    for k in range(k0, k1):
        b00 += r[k - 1] * r[k - 1]
        b01 += r[k - 1] * r[k - 2]
        b11 += r[k - 2] * r[k - 2]
        c0 += r[k - 1] * r[k]
        c1 += r[k - 2] * r[k]
    if p == 1:
        return c0 / b00, 0.0
    det = b00 * b11 - b01 * b01
    return (c0 * b11 - c1 * b01) / det, (b00 * c1 - b01 * c0) / det


@njit(cache=True)
def _ar_rss(r: np.ndarray, rho0: float, rho1: float, k0: int, k1: int) -> float:  # pragma: no cover - compiled
    """The residual sum of squares of ``r`` after the AR filter ``(rho0, rho1)`` over samples ``k0..k1-1``."""
    rss = 0.0
    for k in range(k0, k1):
        e = r[k] - rho0 * r[k - 1] - rho1 * r[k - 2]
        rss += e * e
    return rss


@njit(cache=True)
def _fixed_moments(pv: np.ndarray, bidx: np.ndarray, bval: np.ndarray, q: int, k0: int,
                   k1: int) -> tuple:  # pragma: no cover - compiled
    """The lagged cross moments of the terms every candidate of :func:`_best_process` shares, over samples
    ``k0..k1-1``: ``PB[l1, l2, j] = sum_k pv[k-l1] B[k-l2, j]`` and ``BB[l1, l2, i, j] = sum_k B[k-l1, i] B[k-l2, j]``
    (lags 0-2, the AR(2) filter's; the basis ``B`` in the sparse form of :func:`_sparse_basis`)."""
    wd = bidx.shape[1]
    PB = np.zeros((3, 3, q))
    BB = np.zeros((3, 3, q, q))
    for k in range(k0, k1):
        for l1 in range(3):
            pk = pv[k - l1]
            r1 = k - l1
            for l2 in range(3):
                r2 = k - l2
                for u in range(wd):
                    PB[l1, l2, bidx[r2, u]] += pk * bval[r2, u]
                    for v in range(wd):
                        BB[l1, l2, bidx[r1, u], bidx[r2, v]] += bval[r1, u] * bval[r2, v]
    return PB, BB


@njit(cache=True)
def _oe_fit_moments(pv: np.ndarray, w: np.ndarray, bidx: np.ndarray, bval: np.ndarray, PB: np.ndarray,
                    BB: np.ndarray, k0: int, k1: int, p: int, n_iter: int, r: np.ndarray) -> tuple:
    # pragma: no cover - compiled
    """:func:`_best_process`'s output-error fit of one candidate over samples ``k0..k1-1``: least squares for
    ``theta = [K, basis weights]`` given the AR(p <= 2) filter, alternated ``n_iter`` times with the filter given the
    residual (:func:`_ar_fit`). The AR-filtered normal equations are sums over the lag pairs of the AR(2) filter of
    the terms' lagged cross moments, so the moments of ``w`` are taken once (the basis's and ``pv``'s,
    :func:`_fixed_moments`, once for all candidates) and each iteration assembles its equations from them instead of
    a pass over the record; the residual, the AR filter and the RSS are computed on the record, with the sparse
    basis. ``r`` is work space of ``pv``'s size. Returns (rss, theta, rho1, rho2)."""
    q = PB.shape[2]
    m = 1 + q
    wd = bidx.shape[1]
    # the lag pairs with a lag 0 by passes over the record, the rest from them by their window's two end terms
    # (the pair (l1 + 1, l2 + 1) is the pair (l1, l2) over the window one sample earlier)
    WW = np.zeros((3, 3))
    WP = np.zeros((3, 3))
    WB = np.zeros((3, 3, q))
    for k in range(k0, k1):
        w0 = w[k]
        w1 = w[k - 1]
        w2 = w[k - 2]
        WW[0, 0] += w0 * w0
        WW[0, 1] += w0 * w1
        WW[0, 2] += w0 * w2
        WP[0, 0] += w0 * pv[k]
        WP[0, 1] += w0 * pv[k - 1]
        WP[0, 2] += w0 * pv[k - 2]
        WP[1, 0] += w1 * pv[k]
        WP[2, 0] += w2 * pv[k]
        for u in range(wd):
            WB[0, 0, bidx[k, u]] += w0 * bval[k, u]
            WB[1, 0, bidx[k, u]] += w1 * bval[k, u]
            WB[2, 0, bidx[k, u]] += w2 * bval[k, u]
            WB[0, 1, bidx[k - 1, u]] += w0 * bval[k - 1, u]
            WB[0, 2, bidx[k - 2, u]] += w0 * bval[k - 2, u]
    WW[1, 0] = WW[0, 1]
    WW[2, 0] = WW[0, 2]
    for l1, l2 in ((0, 0), (0, 1), (1, 0), (1, 1)):
        a0 = k0 - 1 - l1  # the term entering the window one sample earlier
        b0 = k0 - 1 - l2
        a1 = k1 - 1 - l1  # the term leaving it
        b1 = k1 - 1 - l2
        WW[l1 + 1, l2 + 1] = WW[l1, l2] + w[a0] * w[b0] - w[a1] * w[b1]
        WP[l1 + 1, l2 + 1] = WP[l1, l2] + w[a0] * pv[b0] - w[a1] * pv[b1]
        for u in range(WB.shape[2]):  # elementwise: a slice assignment compiles numba's shape-error formatting
            WB[l1 + 1, l2 + 1, u] = WB[l1, l2, u]
        for u in range(wd):
            WB[l1 + 1, l2 + 1, bidx[b0, u]] += w[a0] * bval[b0, u]
            WB[l1 + 1, l2 + 1, bidx[b1, u]] -= w[a1] * bval[b1, u]
    c = np.zeros(3)
    rho0 = 0.0
    rho1 = 0.0
    theta = np.zeros(m)
    A = np.empty((m, m))
    bb = np.empty(m)
    iters = 1 if p == 0 else n_iter
    for _ in range(iters):
        c[0] = 1.0
        c[1] = -rho0
        c[2] = -rho1
        A[:, :] = 0.0
        bb[:] = 0.0
        for l1 in range(3):
            for l2 in range(3):
                cc = c[l1] * c[l2]
                if cc == 0.0:
                    continue
                A[0, 0] += cc * WW[l1, l2]
                bb[0] += cc * WP[l2, l1]
                for j in range(q):
                    A[0, 1 + j] += cc * WB[l1, l2, j]
                    A[1 + j, 0] += cc * WB[l2, l1, j]
                    bb[1 + j] += cc * PB[l1, l2, j]
                    for i in range(q):
                        A[1 + i, 1 + j] += cc * BB[l1, l2, i, j]
        for i in range(m):
            A[i, i] += 1e-9 * A[i, i] + 1e-12
        theta = np.linalg.solve(A, bb)
        for k in range(k0 - 2, k1):
            v = pv[k] - theta[0] * w[k]
            for u in range(wd):
                v -= theta[1 + bidx[k, u]] * bval[k, u]
            r[k] = v
        if p > 0:
            rho0, rho1 = _ar_fit(r, k0, k1, p)
    return _ar_rss(r, rho0, rho1, k0, k1), theta, rho0, rho1


@njit(cache=True)
def _best_process(pv: np.ndarray, x: np.ndarray, bidx: np.ndarray, bval: np.ndarray, q: int, alist: np.ndarray,
                  delays: np.ndarray, k0: int, k1: int, p: int, n_iter: int,
                  allow_integ: bool) -> tuple:  # pragma: no cover - compiled
    """The best (lag, delay) for the valve path ``x`` (the disturbance basis in the sparse form of
    :func:`_sparse_basis`, ``q`` columns; each candidate fitted by :func:`_oe_fit_moments`). Delays of a whole sample
    or more first; a delay below one sample only with a gain of their best fit's sign (the controller's own relation
    between the same samples has the opposite sign, negative feedback: docs/loops.md, "Model")."""
    PB, BB = _fixed_moments(pv, bidx, bval, q, k0, k1)
    r = np.zeros(pv.size)
    best_rss = 1e300
    best = (1e300, 0.0, 0.0, False, np.zeros(1 + q), 0.0, 0.0)
    na = alist.size + (1 if allow_integ else 0)
    sign = 0.0
    for sub in (False, True):
        for ia in range(na):
            integ = ia == alist.size
            a = 1.0 if integ else alist[ia]
            for d in delays:
                if (d < 1.0) != sub:
                    continue
                w = _filtered(x, a, d, integ)
                rss, theta, r1, r2 = _oe_fit_moments(pv, w, bidx, bval, PB, BB, k0, k1, p, n_iter, r)
                if sub and theta[0] * sign <= 0.0:
                    continue
                if rss < best_rss:
                    best_rss = rss
                    best = (rss, a, d, integ, theta, r1, r2)
        sign = best[4][0]
    return best


def disturbance_basis(n: int, dt: float, knot_s: float) -> np.ndarray:
    """Hat functions (linear B-splines) with knots every ``knot_s``: a slow load disturbance (one
    column, a constant, when ``knot_s`` is infinite or longer than the record)."""
    t = np.arange(n) * dt
    if not np.isfinite(knot_s) or knot_s >= t[-1]:
        B = np.ones((n, 1))
    else:
        knots = np.arange(0.0, t[-1] + knot_s, knot_s)
        B = np.maximum(0.0, 1.0 - np.abs(t[:, None] - knots[None, :]) / knot_s)
        B = B[:, B.sum(axis=0) > 0]
    return np.ascontiguousarray(B)


@dataclass(frozen=True)
class Settings:
    """Search settings of the grey-box fit (docs/loops.md, "Model")."""

    dt: float = 10.0
    min_delay: float = 1.0
    max_delay: int = 12
    #: delays below ``fine_below`` samples are searched in steps of ``fine_step`` (a fractional delay), the rest in
    #: whole samples; ``fine_step`` 1 is the integer-delay model (docs/loops.md, "Model")
    fine_step: float = 0.25
    fine_below: float = 3.0
    noise_order: int = 2
    n_iter: int = 3
    allow_integrating: bool = True
    n_grid: int = 16
    disturbance_knot_s: float = 1200.0
    #: the valve's steps per recorded sample, driven by the mean-preserving sub-sample OP (:func:`subsample_op`) and
    #: averaged back over each sample, as the historian averages OP; 1 is the sample-rate valve (nested). The
    #: decision's fits use ``substeps``, the band's fit ``band_substeps`` (docs/loops.md, "Model" and "Band
    #: uncertainty")
    substeps: int = 1
    band_substeps: int = 4
    #: the controller's scan period, s: the band's valve takes a step per scan (at least ``band_substeps`` per sample)
    #: and is driven by the OP's within-sample jitter read from the record (:func:`op_jitter`; docs/loops.md, "Model")
    scan_s: float = 1.0
    #: the within-sample OP jitter's sd (% of OP) that drives the valve (:func:`valve_path`); 0: none (the decision's
    #: fits); the band's fit sets it from the record (``diagnose.fit_band``)
    jitter: float = 0.0

    @property
    def k0(self) -> int:
        return self.max_delay + 2

    def alist(self) -> np.ndarray:
        return np.exp(-self.dt / np.asarray(TAUS_S))

    def delays(self) -> np.ndarray:
        """The delays searched, samples: ``min_delay`` up in steps of ``fine_step`` below ``fine_below``, then whole
        samples up to ``max_delay``."""
        fine = np.arange(self.min_delay, min(self.fine_below, self.max_delay), self.fine_step)
        whole = np.arange(math.ceil(self.min_delay), self.max_delay + 1, 1.0)
        return np.unique(np.round(np.concatenate([fine, whole]), 9))


@dataclass
class ProcessFit:
    """The process part of a fit: lag (``a``; 1 = integrating), delay (samples), gain, the slow
    disturbance (weights of its basis), AR noise, residual sum of squares over ``n`` samples."""

    a: float
    delay: float
    integrating: bool
    K: float
    weights: np.ndarray
    basis: np.ndarray
    rho: tuple[float, float]
    rss: float
    n: int
    n_params: int

    @property
    def loglik(self) -> float:
        return concentrated_loglik(self.rss, self.n)

    def tau_s(self, dt: float) -> float:
        if self.integrating:
            return math.inf
        return 0.0 if self.a <= 1e-12 else -dt / math.log(self.a)

    def describe(self, dt: float) -> str:
        if self.integrating:
            return f"integrating, gain {self.K:.4g}/sample per %, delay {self.delay * dt:g} s"
        return f"first order, gain {self.K:.4g} per %, tau {self.tau_s(dt):.0f} s, delay {self.delay * dt:g} s"


def concentrated_loglik(rss: float, n: int) -> float:
    return -0.5 * n * (math.log(2.0 * math.pi * max(rss, 1e-300) / n) + 1.0)


def fit_process(pv: np.ndarray, x: np.ndarray, s: Settings) -> ProcessFit:
    """Maximum-likelihood process for a given valve path ``x`` (samples ``s.k0`` on)."""
    k0, k1 = s.k0, pv.size
    basis, idx, val = _settings_basis(pv.size, s)
    rss, a, d, integ, theta, r1, r2 = _best_process(
        np.ascontiguousarray(pv, dtype=float), np.ascontiguousarray(x, dtype=float), idx, val, basis.shape[1],
        s.alist(), s.delays(), k0, k1, s.noise_order, s.n_iter, s.allow_integrating)
    n_params = 3 + basis.shape[1] + s.noise_order + 1  # K, a, d, disturbance weights, rho, sigma
    return ProcessFit(float(a), float(d), bool(integ), float(theta[0]), np.asarray(theta[1:]), basis,
                      (float(r1), float(r2)), float(rss), k1 - k0, n_params)


def simulate(x: np.ndarray, pf: ProcessFit) -> np.ndarray:
    """The fitted process's free-run output for the valve path ``x`` plus the fitted slow disturbance
    (no noise): the fitted loop's simulation against the data, for the report."""
    w = _filtered(np.ascontiguousarray(x, dtype=float), pf.a, pf.delay, pf.integrating)
    return pf.K * w + pf.basis @ pf.weights


def residuals(pv: np.ndarray, x: np.ndarray, pf: ProcessFit, k0: int) -> np.ndarray:
    """The innovations ``e`` (after the AR noise filter) from sample ``k0`` on."""
    r = pv - simulate(x, pf)
    e = r[k0:] - pf.rho[0] * r[k0 - 1:-1] - pf.rho[1] * r[k0 - 2:-2]
    return e


@dataclass
class ValveFit:
    """The maximum-likelihood fit of one valve candidate."""

    valve: str
    S: float
    J: float
    process: ProcessFit
    n_params: int
    profile: list[tuple[float, float]] = field(default_factory=list)  # (S, loglik maximised over J and process)
    direction: float = 1.0  # the valve's last motion before the record (+1 up, -1 down)
    substeps: int = 1  # the valve's steps per recorded sample (Settings.substeps)
    jitter: float = 0.0  # the within-sample OP jitter's sd driving the valve, % of OP (Settings.jitter)

    @property
    def loglik(self) -> float:
        return self.process.loglik

    @property
    def n(self) -> int:
        return self.process.n

    @property
    def bic(self) -> float:
        return bic(self.loglik, self.n_params, self.n)

    def path(self, op: np.ndarray) -> np.ndarray:
        return valve_path(op, self.S, self.J, self.direction, self.substeps, self.jitter)


def op_scale(op: np.ndarray) -> float:
    """The OP range that bounds a band: 1st to 99th percentile, %."""
    lo, hi = np.percentile(op, [1.0, 99.0])
    return float(max(hi - lo, 1e-6))


def fit_valve(op: np.ndarray, pv: np.ndarray, valve: str, s: Settings, extra_S: tuple[float, ...] = (),
              j_fractions: tuple[float, ...] = J_FRACTIONS) -> ValveFit:
    """Maximum-likelihood fit of one valve candidate (the process re-fitted for each S, J); ``extra_S`` are bands
    added to the grid (the dense search's best band, :func:`scan_valve`); ``j_fractions`` the J / S values of the
    stiction valve (J profiled out at each S). The band is the maximum of the profile likelihood in S
    (:func:`valve_env.ident.mle.profile_maximum`: the grid, then a bounded scalar search between the best point's
    neighbours)."""
    if valve == "linear":
        pf = fit_process(pv, op, s)
        return ValveFit("linear", 0.0, 0.0, pf, pf.n_params)
    fracs = (0.0,) if valve == "backlash" else j_fractions
    r = op_scale(op)
    grid = np.unique(np.concatenate([r * np.geomspace(S_FRACTIONS[0], S_FRACTIONS[1], s.n_grid),
                                     [v for v in extra_S if v > 0.0]]))
    fits: dict[float, tuple[ProcessFit, float, float]] = {}  # S: the best (process, J, direction) over J

    def profile_ll(S: float) -> float:
        if S not in fits:
            cand = [(fit_process(pv, valve_path(op, S, f * S, d0, s.substeps, s.jitter), s), f * S, d0)
                    for f in fracs for d0 in DIRECTIONS]
            fits[S] = max(cand, key=lambda c: c[0].loglik)
        return fits[S][0].loglik

    S, _, profile = profile_maximum(profile_ll, grid, xatol=2e-3 * r, maxiter=12)
    pf, J, d0 = fits[S]
    return ValveFit(valve, S, J, pf, pf.n_params + VALVE_EXTRA_PARAMS[valve], profile, d0, s.substeps, s.jitter)


#: the dense band search's J / S values and band grid (fractions of the OP range: from, to, points; docs/loops.md,
#: "Model")
SCAN_J_FRACTIONS: tuple[float, ...] = (0.0, 0.5, 1.0)
#: how many of the scan's best distinct bands start the band's fit (:class:`Scan`)
SCAN_STARTS = 3
SCAN_S_FRACTIONS: tuple[float, float, int] = (0.01, 3.0, 24)


@njit(cache=True)
def _scan_rss(pv: np.ndarray, xs: np.ndarray, bidx: np.ndarray, bval: np.ndarray, q: int, alist: np.ndarray,
              delays: np.ndarray, k0: int, allow_integ: bool) -> np.ndarray:  # pragma: no cover - compiled
    """For each valve path (row of ``xs``), the least white-noise RSS of ``pv ~ K w + basis weights`` over the
    process structures (lag, delay) on samples ``k0..``. The basis (hat functions) is given sparsely: row ``k``
    has the values ``bval[k]`` in the columns ``bidx[k]``. A delay shifts the lag's output (the filter starts
    at rest at ``x[0]``; for the integrator the shift adds a constant, which the basis holds).

    Computed fast: the basis block of the normal equations is the same
    for every path and structure, so each is solved by its Schur complement with the basis block's inverse taken
    once; the lag's output's moments are taken once per whole-sample delay (its squares and lag-one products from
    prefix sums), a fractional delay's being the linear interpolation's combinations of its two whole delays'."""
    n = pv.size
    G = np.zeros((q, q))
    Bp = np.zeros(q)
    pp = 0.0
    for k in range(k0, n):
        pp += pv[k] * pv[k]
        for u in range(bidx.shape[1]):
            Bp[bidx[k, u]] += bval[k, u] * pv[k]
            for v in range(bidx.shape[1]):
                G[bidx[k, u], bidx[k, v]] += bval[k, u] * bval[k, v]
    for i in range(q):
        G[i, i] += 1e-9 * G[i, i] + 1e-12
    Gi = np.linalg.inv(G)
    GiBp = Gi @ Bp
    pp_basis = pp - np.dot(Bp, GiBp)  # the RSS of the basis alone
    d_lo = int(math.floor(delays[0]))
    nd = int(math.floor(delays[-1])) + 2 - d_lo  # the whole delays of the grid and one beyond (a fraction's upper)
    WW = np.empty(nd)
    WC = np.empty(nd)
    WP = np.empty(nd)
    WB = np.empty((nd, q))
    P2 = np.zeros(n + 1)
    PC = np.zeros(n + 1)
    wb = np.empty(q)
    na = alist.size + (1 if allow_integ else 0)
    out = np.empty(xs.shape[0])
    for ix in range(xs.shape[0]):
        best = 1e300
        sign = 0.0
        x = xs[ix]
        for sub in (False, True):  # whole-sample delays first, then sub-sample ones of their gain's sign
            if sub and delays[0] >= 1.0:
                break
            best_k = 0.0
            for ia in range(na):
                integ = ia == alist.size
                a = alist[ia] if not integ else 1.0
                w = _filtered(x, a, 0.0, integ)
                P2[1] = w[0] * w[0]
                for k in range(1, n):
                    P2[k + 1] = P2[k] + w[k] * w[k]
                    PC[k + 1] = PC[k] + w[k] * w[k - 1]
                for i in range(nd):  # the moments of w delayed by the whole delay d_lo + i
                    d = d_lo + i
                    WW[i] = P2[n - d] - P2[k0 - d]
                    WC[i] = PC[n - d] - PC[k0 - d]
                    wp = 0.0
                    WB[i, :] = 0.0
                    for k in range(k0, n):
                        wk = w[k - d]
                        wp += wk * pv[k]
                        for u in range(bidx.shape[1]):
                            WB[i, bidx[k, u]] += wk * bval[k, u]
                    WP[i] = wp
                for dly in delays:
                    if (dly < 1.0) != sub:
                        continue
                    i = int(math.floor(dly)) - d_lo
                    f = dly - math.floor(dly)
                    if f == 0.0:
                        ww = WW[i]
                        wp = WP[i]
                        for j in range(q):
                            wb[j] = WB[i, j]
                    else:  # (1 - f) w[k - d] + f w[k - d - 1]
                        ww = (1.0 - f) ** 2 * WW[i] + 2.0 * f * (1.0 - f) * WC[i] + f * f * WW[i + 1]
                        wp = (1.0 - f) * WP[i] + f * WP[i + 1]
                        for j in range(q):
                            wb[j] = (1.0 - f) * WB[i, j] + f * WB[i + 1, j]
                    ww += 1e-9 * ww + 1e-12
                    t = wp
                    sc = ww
                    for j in range(q):
                        acc = 0.0
                        for jj in range(q):
                            acc += Gi[j, jj] * wb[jj]
                        t -= wb[j] * GiBp[j]
                        sc -= wb[j] * acc
                    k_gain = t / sc  # the gain; the basis weights GiBp - K Gi wb
                    if sub and k_gain * sign <= 0.0:
                        continue
                    rss = max(pp_basis - t * k_gain, 1e-300)
                    if rss < best:
                        best = rss
                        best_k = k_gain
            if not sub:
                sign = best_k
        out[ix] = best
    return out


def _sparse_basis(basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise nonzero columns and values of a basis with few nonzeros per row (padded with zero values)."""
    width = max(int((basis != 0).sum(axis=1).max()), 1)
    idx = np.zeros((basis.shape[0], width), dtype=np.int64)
    val = np.zeros((basis.shape[0], width))
    for k in range(basis.shape[0]):
        nz = np.flatnonzero(basis[k])
        idx[k, :nz.size] = nz
        val[k, :nz.size] = basis[k, nz]
    return idx, val


@dataclass
class Scan:
    """The LR scan: the white-noise least-squares LR statistic of the stick-slip valve (backlash included,
    J = 0) against the linear valve, each with its best process structure (lag, delay), and the grid point
    that attains it: the seed of the band's maximum-likelihood fit (docs/loops.md, "Model"), not a test."""

    lr: float
    S: float
    J: float
    direction: float
    #: the bands of the scan's :data:`SCAN_STARTS` best distinct grid bands (best first, ``S`` among them): the band
    #: fit's starts (the likelihood is rugged in S; a record with few slips can put its best band on a narrow ridge
    #: that the best least-squares band alone misses)
    starts: tuple[float, ...] = ()


def resolution(op: np.ndarray) -> float:
    """The record's resolution of a band, % of OP: the median OP move per sample. The valve slips between two
    samples; a band narrower than one sample's move holds the valve for less than a sample, which the record
    cannot show (the same move is the band's sampling offset, docs/loops.md "Model").
    It is the record's: a sub-sample OP (:func:`subsample_op`) interpolates the record and adds no information
    about where between two samples the valve slipped."""
    return float(np.median(np.abs(np.diff(op))))


def scan_paths(op: np.ndarray, substeps: int = 1,
               jitter: float = 0.0) -> tuple[np.ndarray, list[tuple[float, float, float]]]:
    """The valve paths of the scan: the linear valve first, then every (S, J, direction) of the grid (the valve
    at ``substeps`` steps per sample, driven by the within-sample OP ``jitter``: :func:`valve_path`)."""
    op = np.ascontiguousarray(op, dtype=float)
    r = op_scale(op)
    lo = max(SCAN_S_FRACTIONS[0] * r, resolution(op))
    params: list[tuple[float, float, float]] = [(0.0, 0.0, 1.0)]
    for S in np.geomspace(lo, max(SCAN_S_FRACTIONS[1] * r, 2.0 * lo), SCAN_S_FRACTIONS[2]):
        for f in SCAN_J_FRACTIONS:
            for d0 in DIRECTIONS:
                params.append((float(S), float(f * S), d0))
    xs = np.empty((len(params), op.size))
    xs[0] = op
    for i, (S, J, d0) in enumerate(params[1:], start=1):
        xs[i] = valve_path(op, S, J, d0, substeps, jitter)
    return xs, params


@functools.lru_cache(maxsize=8)
def _cached_basis(n: int, dt: float, knot_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The disturbance basis of a record of ``n`` samples (:func:`disturbance_basis`), dense and in the sparse form
    of :func:`_sparse_basis` (columns, values): the same for every fit and scan of the record,
    so built once (read-only: the fits hold it)."""
    basis = disturbance_basis(n, dt, knot_s)
    idx, val = _sparse_basis(basis)
    for arr in (basis, idx, val):
        arr.setflags(write=False)
    return basis, idx, val


def _settings_basis(n: int, s: Settings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_cached_basis` of a record of ``n`` samples with the disturbance model of ``s``."""
    return _cached_basis(n, float(s.dt), float(s.disturbance_knot_s))


def _scan_rss_paths(pv: np.ndarray, xs: np.ndarray, s: Settings) -> np.ndarray:
    """The scan's residual sum of squares of ``pv`` behind each valve path of ``xs`` (each with its best process
    structure and the disturbance basis of ``s``)."""
    basis, idx, val = _settings_basis(pv.size, s)
    return _scan_rss(pv, xs, idx, val, basis.shape[1], s.alist(), s.delays(), s.k0, s.allow_integrating)


def scan_valve(pv: np.ndarray, paths: tuple[np.ndarray, list[tuple[float, float, float]]], s: Settings) -> Scan:
    """The LR scan (:class:`Scan`) of ``pv`` over the valve ``paths`` of :func:`scan_paths`."""
    xs, params = paths
    pv = np.ascontiguousarray(pv, dtype=float)
    rss = _scan_rss_paths(pv, xs, s)
    i = int(np.argmin(rss[1:])) + 1
    n = pv.size - s.k0
    lr = n * math.log(rss[0] / min(rss[i], rss[0]))
    S, J, d0 = params[i]
    starts: list[float] = []
    for j in np.argsort(rss[1:]) + 1:
        if params[j][0] not in starts:
            starts.append(params[j][0])
        if len(starts) == SCAN_STARTS:
            break
    return Scan(float(lr), S, J, d0, tuple(float(v) for v in starts))


__all__ = ["VALVES", "Settings", "ProcessFit", "ValveFit", "valve_path", "fit_process", "fit_valve",
           "simulate", "residuals", "op_scale", "concentrated_loglik", "Scan", "scan_valve",
           "scan_paths", "resolution", "subsample_op", "disturbance_basis", "op_jitter", "JITTER_DRAWS"]
