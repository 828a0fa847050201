"""The fast likelihood engine of the diagnosis (compiled by numba).

Three pieces, each a small state-space computation:

1. **Latent temperatures** (:func:`valve_env.valveid.temperature.smooth_temperature`, the
   estimation's temperature pre-processing): each channel is an integrated random walk observed
   with white noise, smoothed by Rauch-Tung-Striebel (two-sided, zero phase: a lag found later is
   in the valve, not in the pre-processing). A raw finite difference of the channel is never used
   as the Dahl driver.
2. **The valve simulation** of docs/reference.md, section 1 with every effect of
   section 3 as an optional term (all switched off by zero parameters), on a
   fine grid between samples (cubic Hermite interpolation of the smoothed
   temperature, at most ``max_step_s`` per sub-step). The Dahl update is exact
   per monotone increment of ``T_g``; the bulb lag is exact for an input linear
   over a sub-step; the stiction is the stick-slip of the data generator.
3. **The output-error model.** The residual ``r = x_mm - x_sim`` is modelled
   as ``e + w``: ``e`` an Ornstein-Uhlenbeck process (sd ``s_e``, time
   constant ``tau_e``: slowly varying model error and the smoothing error of
   the temperature) and ``w`` white measurement noise (sd ``s_w``). A scalar
   Kalman filter gives the exact Gaussian log-likelihood (prediction-error
   decomposition) for uneven sampling and the one-step prediction residuals.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from valve_env.ident.kalman import LOG2PI, ou_innovation, ou_predict, ou_update
from valve_env.ident.tests import MAD_TO_SD
from valve_env.params import I_P_BSET, I_STROKE
from valve_env.physics import valve as phys
from valve_env.physics.stickslip import initial_state as stick_initial_state
from valve_env.physics.trajectory import (
    E_BETA,
    E_RATE,
    E_TAU,
    bulb_coefficients,
    bulb_lag,
    drifted_set_pressure,
    sensed_temperature,
    stem_step,
)
from valve_env.valveid.temperature import monotone_path

SQRT2 = math.sqrt(2.0)
#: sd of the breakaway band relative to the band (static friction varies from one breakaway to the next)
BAND_SPREAD = 0.5
#: sd of the landing position after a slip relative to the band: the (S, J = S) stem lands on the demand, so
#: this only absorbs the simulated demand's error (0.5, as the earlier re-sticking filter used, peaked at 1.3
#: times the band on exact stick-slip data; 0.2 at the band)
LANDING_SD = 0.2
#: the probability of a slip since the stem last stuck at which the stick-slip filter decides that it moves
DECIDE_MOVING = 0.5
#: prior probability that a stem which moved at the last sample has stuck since without a reversal of the
#: demand (a valve that re-sticks after every slip, or at a pause of the demand), before the band's own
#: probability that it stays stuck there; exp(-2), the log-likelihood ratio of 2 at which the earlier filter
#: re-stuck it
RESTICK_P = math.exp(-2.0)
#: the prior probability of a slip (between measurements) at which the stick-slip filter decides that a
#: resting stem moves
DECIDE_PRIOR = 0.999


# --------------------------------------------------------------------------- 2. the valve simulation
# the effect parameter vector e: valve_env.effects.ENGINE_INDEX (tau_s, beta, band_mm, jump_mm, rate_MPa_per_h),
# positions E_* from valve_env.physics.trajectory


@njit(cache=True)
def valve_drive(t: np.ndarray, T: np.ndarray, M: np.ndarray, vp: np.ndarray, e: np.ndarray, max_step_s: float,
                delta: float, want_sub: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                        float]:
    """The part of :func:`simulate_valve` that the fitted valve parameters (sigma, F_hmax, p_bset) and the set
    point's drift leave as it is: the gas temperature's path and the bellows' pressure along it.

    Returns, per step of the simulation grid (``m`` steps between samples k-1 and k, m = 1 unless the bulb lags or
    ``want_sub``): the gas temperature's increment ``dT``, the bellows' pressure ``pb`` (:func:`vapour_pressure
    <valve_env.physics.valve.vapour_pressure>` of the gas temperature) and the time since the start ``tt`` where
    the opening is evaluated (every step with ``want_sub``, else each sample's last), the sample index ``kk`` of
    each step; then the gas temperature at the samples and the bellows' pressure at the first.
    :func:`valve_pass` turns them into the opening and the friction force."""
    n = t.shape[0]
    tau = e[E_TAU]
    beta = e[E_BETA]
    t0 = t[0]
    lagged = tau > 1e-9
    fine = lagged or want_sub
    n_steps = 0
    for k in range(1, n):
        m = 1
        if fine:
            m = max(int(math.ceil((t[k] - t[k - 1]) / max_step_s - 1e-9)), 1)
        n_steps += m
    dT = np.empty(n_steps)
    pb = np.empty(n_steps)
    tt = np.empty(n_steps)
    kk = np.empty(n_steps, dtype=np.int64)
    Tg_out = np.empty(n)
    env_raw = np.empty(n)
    for k in range(n):
        env_raw[k] = sensed_temperature(T[k], M[k], beta)
    env_s = monotone_path(env_raw, delta)
    Tg = env_s[0]
    Tg_out[0] = Tg
    s = 0
    for k in range(1, n):
        h = t[k] - t[k - 1]
        m = 1
        if fine:
            m = max(int(math.ceil(h / max_step_s - 1e-9)), 1)
        hs = h / m
        a, b = bulb_coefficients(hs, tau if lagged else 0.0)
        e0 = env_s[k - 1]
        de = (env_s[k] - e0) / m
        for j in range(1, m + 1):
            env_prev = e0 + (j - 1) * de
            env = e0 + j * de
            Tg_new = bulb_lag(Tg, env_prev, env, a, b)
            dT[s] = Tg_new - Tg
            Tg = Tg_new
            kk[s] = k
            if j == m or want_sub:
                tt[s] = t[k] - t0 if j == m else t[k - 1] + j * hs - t0
                pb[s] = phys.vapour_pressure(Tg, vp)
            s += 1
        Tg_out[k] = Tg
    return dT, pb, tt, kk, Tg_out, phys.vapour_pressure(env_s[0], vp)


@njit(cache=True)
def valve_pass(dT: np.ndarray, pb: np.ndarray, tt: np.ndarray, kk: np.ndarray, pb0: float, dp: np.ndarray,
               ps: np.ndarray, vp: np.ndarray, rate: float,
               want_sub: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The valve on a drive of :func:`valve_drive`: (x, F_h) at the samples, and with ``want_sub`` the opening
    at every step (``x_sub``) and the index of each sample in it (``sub_idx``), as :func:`simulate_valve` returns
    them. The Dahl step runs on each step's increment of the gas temperature; the opening is the force balance at
    the step's pressures (those of the sample the step ends in or leads to) and drifted set pressure, clipped to
    [0, stroke]."""
    n = dp.shape[0]
    p0 = vp[I_P_BSET]
    stroke = vp[I_STROKE]
    n_steps = dT.shape[0]
    x_out = np.empty(n)
    F_out = np.empty(n)
    x_sub = np.empty(n_steps + 1 if want_sub else 0)
    sub_idx = np.zeros(n, dtype=np.int64)
    F = 0.0
    x_out[0] = min(max(phys.opening_at_pressure(pb0, F, dp[0], ps[0], p0, vp), 0.0), stroke)
    F_out[0] = F
    if want_sub:
        x_sub[0] = x_out[0]
    for s in range(n_steps):
        k = kk[s]
        if dT[s] != 0.0:  # a step of no change leaves the force as it is (the Dahl step's decay is 1)
            F = phys.dahl_update(F, dT[s], vp)
        last = s + 1 == n_steps or kk[s + 1] != k
        if last or want_sub:
            p_set = p0 if rate == 0.0 else drifted_set_pressure(p0, rate, tt[s])
            xd = phys.opening_at_pressure(pb[s], F, dp[k], ps[k], p_set, vp)
            xc = min(max(xd, 0.0), stroke)
            if want_sub:
                x_sub[s + 1] = xc
            if last:
                x_out[k] = xc
                F_out[k] = F
                if want_sub:
                    sub_idx[k] = s + 1
    return x_out, F_out, x_sub, sub_idx


@njit(cache=True)
def simulate_valve(t: np.ndarray, T: np.ndarray, M: np.ndarray, dp: np.ndarray, ps: np.ndarray,
                   vp: np.ndarray, e: np.ndarray, max_step_s: float, delta: float,
                   want_sub: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Simulate the valve without stiction: (x, T_g, F_h) at the sample times, and the demanded opening
    on the sub-step grid (for the stick-slip of :func:`stick_simulate`).

    ``T``, ``M``: latent tank and medium temperatures at the samples. The sensed temperature
    T_env = T + beta (M - T) is freed of reversals smaller than ``delta`` (:func:`monotone_path`;
    doing this on each channel separately instead would create spurious reversals where one channel
    rests on an isotonic plateau while the other moves). ``vp`` is the packed ValveParams
    (sigma, F_hmax, p_bset taken from it); ``e`` the effect vector (valve_env.effects.ENGINE_INDEX),
    zeros switch the effects off (``band_mm`` is used by :func:`stick_simulate` and :func:`stick_loglik`).
    The bulb lag, the sensed temperature, the Dahl step and the drifted set pressure are the
    functions of :mod:`valve_env.physics.trajectory` that the generator and the environments run.
    T_env is interpolated linearly between samples on sub-steps of at most ``max_step_s``. ``x`` is
    the opening clipped to [0, stroke]; with ``want_sub`` the clipped opening at every sub-step is
    returned in ``x_sub`` and ``sub_idx[k]`` is the index of sample k in it.

    It is :func:`valve_pass` on :func:`valve_drive`: a fit keeps the drive, which its valve parameters' steps
    leave as it is (:meth:`valve_env.valveid.fitting.Model._valve_path`)."""
    dT, pb, tt, kk, Tg, pb0 = valve_drive(t, T, M, vp, e, max_step_s, delta, want_sub)
    x, F, x_sub, sub_idx = valve_pass(dT, pb, tt, kk, pb0, dp, ps, vp, e[E_RATE], want_sub)
    return x, Tg, F, x_sub, sub_idx


@njit(cache=True)
def stick_demand(x_sub: np.ndarray, sub_idx: np.ndarray, stroke: float) -> np.ndarray:
    """The demanded opening on the sub-step grid freed of the reversals that its input noise makes.

    The demand is computed from the measured pressures of each sample (and the smoothed temperatures),
    so it carries their white noise: at 0.1 % pressure noise about 1e-5 mm, at the paper's 1.5 % about
    5e-4 mm from sample to sample. That is nothing against the opening's noise, but every reversal of
    the demand re-sticks an (S, J) stem (:mod:`valve_env.physics.stickslip`: it sticks when its input
    stops or reverses): on a generated day at 10 s the demand reversed 1920 times where the true one
    reversed 18 times, and the simulated stem slipped twice as often as the true one, every slip
    exactly a band. The true stem sees the true pressures. So the stick-slip runs on this path: the
    reversals smaller than the range that the demand's noise rarely exceeds over the record,
    ``2 sd sqrt(2 ln n)`` (n samples, sd the robust second-difference sd of the demand at the
    samples off the end stops, where it is not clipped; 8.5 sd for a day at 10 s) are removed without lag
    (:func:`monotone_path`), and the flat blocks that the isotonic fit leaves (a pause re-sticks the
    stem too) are replaced by straight lines through their centres. Samples at an end stop keep
    their value (the end stops win)."""
    n = x_sub.shape[0]
    m = sub_idx.shape[0]
    if n < 3 or m < 4:
        return x_sub.copy()
    xs = np.empty(m)
    for k in range(m):
        xs[k] = x_sub[sub_idx[k]]
    d2 = xs[2:] - 2.0 * xs[1:-1] + xs[:-2]
    # the noise is read off the stops: a seated demand is clipped to exactly 0, and where more than half of
    # the samples are seated the deviation of all the second differences is 0
    inside = (xs > 0.0) & (xs < stroke)
    free = inside[2:] & inside[1:-1] & inside[:-2]
    if np.sum(free) >= 3:
        d2 = d2[free]
    mad = np.median(np.abs(d2 - np.median(d2)))
    # the range that m white noise values rarely exceed: 2 sd sqrt(2 ln m) (the universal threshold of
    # Donoho and Johnstone 1994 on either side)
    delta = 2.0 * math.sqrt(2.0 * math.log(m)) * MAD_TO_SD * mad / math.sqrt(6.0)
    c = monotone_path(x_sub, delta)
    # straight lines through the centres of the flat blocks (a block of one sample is its own centre)
    out = c.copy()
    a = 0
    prev_c = -1.0
    prev_v = 0.0
    while a < n:
        b = a
        while b + 1 < n and c[b + 1] == c[a]:
            b += 1
        cen = 0.5 * (a + b)
        v = c[a]
        if prev_c >= 0.0:
            i0 = int(math.ceil(prev_c))
            for i in range(i0, int(math.floor(cen)) + 1):
                w = (i - prev_c) / (cen - prev_c)
                out[i] = prev_v + w * (v - prev_v)
        prev_c = cen
        prev_v = v
        a = b + 1
    for i in range(n):
        if x_sub[i] <= 0.0 or x_sub[i] >= stroke:
            out[i] = x_sub[i]
    return out


@njit(cache=True)
def _stick_path(x_sub: np.ndarray, sub_idx: np.ndarray, stroke: float, band: float,
                demand: np.ndarray | None) -> np.ndarray:
    """The path a stem of breakaway ``band`` runs on: ``x_sub`` itself without a band, else the demand freed of its
    noise's reversals (``demand`` where the caller keeps it, else :func:`stick_demand` of ``x_sub``)."""
    if band <= 0.0:
        return x_sub
    if demand is None:
        return stick_demand(x_sub, sub_idx, stroke)
    return demand


@njit(cache=True)
def stick_simulate_sj(x_sub: np.ndarray, sub_idx: np.ndarray, S: float, J: float, stroke: float,
                      demand: np.ndarray | None = None) -> np.ndarray:
    """Open-loop stick-slip of the stem on the sub-step grid, sampled: the (S, J) model of
    :mod:`valve_env.physics.stickslip` (the generator's and the environments'): the resting stem
    sticks until the demanded opening has moved ``S`` away, slips by ``J`` towards it and follows it until
    it stops or reverses; the end stops win (physics.trajectory.stem_step). The model runs on the demand
    freed of its noise's reversals (:func:`stick_demand`); a moving stem follows the demand as
    computed (its deviation from the cleaned path included, as in the base model's opening) and a
    stuck one keeps the deviation it had when it stuck, so that ``S = 0`` is the base model. The
    diagnosis's stem is its ``J = S`` case (:func:`stick_simulate`); the (S, J) profile of the band
    (valve_env.valveid.stick_profile) uses ``J < S``. ``demand``: :func:`stick_demand` of ``x_sub``, where the
    caller keeps it (``None`` computes it)."""
    n = sub_idx.shape[0]
    out = np.empty(n)
    c = _stick_path(x_sub, sub_idx, stroke, S, demand)
    y, u_prev, du_prev, u_s, stuck, d = stick_initial_state(c[0], S, J, 0.0, stroke)
    # the demand's deviation from the cleaned path, which a moving stem follows and a stuck one keeps
    off = x_sub[0] - c[0]
    out[0] = y + off
    for k in range(1, n):
        for j in range(sub_idx[k - 1] + 1, sub_idx[k] + 1):
            y, u_prev, du_prev, u_s, stuck, d = stem_step(c[j], y, u_prev, du_prev, u_s, stuck, d, S, J, stroke)
            if stuck == 0.0:
                off = x_sub[j] - c[j]
        out[k] = min(max(y + off, 0.0), stroke)
    return out


@njit(cache=True)
def stick_simulate(x_sub: np.ndarray, sub_idx: np.ndarray, band: float, stroke: float) -> np.ndarray:
    """The diagnosis's open-loop stem, :func:`stick_simulate_sj` with ``J = S = band`` (the project's
    stick-slip, J = S), so that ``band = 0`` is the base model and the stem of :func:`stick_loglik` (which
    follows the computed demand's increments) is this one."""
    return stick_simulate_sj(x_sub, sub_idx, band, band, stroke)


# --------------------------------------------------------------------------- 3. the output-error model
@njit(cache=True)
def _band_cdf(x: float, band: float, sd: float) -> float:
    """P(breakaway band <= x) for a band ~ N(band, sd^2)."""
    if sd <= 0.0:
        return 1.0 if x >= band else 0.0
    return 0.5 * (1.0 + math.erf((x - band) / (sd * SQRT2)))


@njit(cache=True)
def stick_loglik(t: np.ndarray, y: np.ndarray, x_sub: np.ndarray, sub_idx: np.ndarray, band: float,
                 stroke: float, s_w: float, s_e: float, tau_e: float,
                 mask: np.ndarray, spread: float = BAND_SPREAD,
                 landing: float = LANDING_SD,
                 slip: float = -1.0,
                 demand: np.ndarray | None = None,
                 w_scale: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Log-likelihood of the measured opening under stick-slip (a decision-directed Kalman filter).

    The stem follows the (S, J = S) model of :mod:`valve_env.physics.stickslip` (:func:`stick_simulate`):
    a resting stem sticks until the demanded opening has moved ``band`` away, slips onto it and follows
    it until the demand stops or reverses, where it sticks again.

    States: the stem position ``s`` and the model error ``e`` (Ornstein-Uhlenbeck, as in
    :func:`ou_loglik`); observation ``y = s + e + w``. Between samples, on the sub-step grid: a resting
    stem slips with the probability of breakaway *in this sub-step*, landing on the demand with an
    uncertainty of ``landing * band`` (sd). The breakaway band itself varies (sd ``spread * band``) and
    the stem position is uncertain, so the filter weighs the two outcomes (a first-order generalised
    pseudo-Bayes filter; this also makes the likelihood continuous in ``band``); once the probability that
    the stem has slipped since it last stuck passes ``DECIDE_MOVING``, the filter decides that it moves and
    lets it follow the demand's increments until the demand stops or reverses (decision-directed). Where
    the stem sticks, ``s`` is unchanged and the measurements pin it down.
    "Stops or reverses" is judged on the demand freed of its noise's reversals (:func:`stick_demand`),
    as in :func:`stick_simulate`. While the filter holds that the stem moves, each measurement is scored
    once, under the predictive mixture of three hypotheses with their prior probabilities: it moves, it
    never slipped since it last stuck (prior ``1 - p_slip``), and it stuck where it was at the last
    sample (prior ``RESTICK_P`` times the probability that the band holds it at the demand's present
    distance); the filter then goes on with the most probable one, and while it goes on moving the
    measurement's posterior updates ``p_slip``. A valve that re-sticks after every slip (a staircase)
    or at a pause of the demand is followed as well as an (S, J) one (docs/diagnosis.md, "The (S, J)
    stick-slip"); as the band vanishes both alternatives lose their prior, so the statistic tends to 0
    (a filter that scores the measurement against the hypothesis the measurement had chosen does not: its twice
    the log-likelihood gain at a band of 1e-8 mm was 18.8-76.8 on development runs).

    The breakaway probability is a first-passage hazard: a stem that has stuck while the demand
    was ``dmax`` away has a band larger than ``dmax``, so it slips in this sub-step with
    probability ``(F(|d|) - F(dmax)) / (1 - F(dmax))`` (F the distribution of the band), and not at
    all while ``|d|`` stays below ``dmax``. ``dmax`` restarts where the stem sticks again and after a
    measurement that moves the stem estimate towards the demand.

    **The measured slip decision** (docs/diagnosis.md, "Method"): a resting stem is not moment-matched
    between measurements. Each
    measurement is scored once under the mixture of "stuck where it rests" (prior ``1 - p_slip``) and
    "slipped onto the demand" (prior ``p_slip``, landing sd ``landing * band``); Bayes' rule updates
    ``p_slip``, and where the slip is the more probable (``DECIDE_MOVING``) the stem is put on the demand
    and moves. Between measurements the slip is decided only where the prior alone makes it near certain
    (``DECIDE_PRIOR``). The moment-matched filter caught a slip that came before its prior slip probability
    reached one half many samples late (-594 held-out log-units on a 20 s run of seed 20270127, run 33), and
    each measurement scored under the moment-matched predictive instead of the two-component mixture was
    worse on the null (LR 157 and 111 on two development `none` runs).

    Because the resting position is estimated from the data rather than simulated open loop, a
    small error in the demand does not put the simulated and the measured stems out of step.
    With ``band = 0`` the stem always slips onto the demand with no uncertainty and the likelihood
    is exactly that of :func:`ou_loglik` on ``y - x`` (the base model): the models are nested.

    **The slip J** (``slip``; negative, the default: ``J = band``, the diagnosis's stem, whose arithmetic is
    then the J = S filter's exactly): with ``0 < slip < band`` the stem of :func:`stick_simulate_sj` with
    ``S = band``: a slip lands ``band - slip`` short of the demand (at most the distance it broke away at),
    and the moving stem follows the demand's increments with that lag (docs/diagnosis.md, "What
    ``band_mm`` is on a valve with J < S").

    ``demand``: :func:`stick_demand` of ``x_sub`` where the caller keeps it (a fit evaluates the likelihood
    many times on one path); ``None`` computes it. ``w_scale``: the white noise's sd at sample k is ``s_w w_scale[k]``
    (an opening whose noise grows with its level, :attr:`valve_env.valveid.data.RunData.x_scale`); None: ``s_w``.

    Returns (loglik, one-step prediction errors of the hypothesis followed, their variances, each
    sample's log-likelihood term: the mixture's where the filter weighed hypotheses, 0 off ``mask``)."""
    n = t.shape[0]
    ve = s_e * s_e
    vw = s_w * s_w
    vl = (landing * band) ** 2
    vb = (spread * band) ** 2
    # the lag of a slipped stem behind the demand (0: J = S, the stem lands on the demand) and the side of
    # the demand on which the resting stem last broke away
    lag = band - slip if 0.0 < slip < band else 0.0
    side = 0.0
    me = 0.0
    ms = min(max(x_sub[0], 0.0), stroke)
    Pee = ve
    Pes = 0.0
    Pss = 0.0
    dmax = 0.0
    moving = False
    p_slip = 0.0
    s_alt = ms
    s_hold = ms
    was_moving = False
    x_prev = ms
    c = _stick_path(x_sub, sub_idx, stroke, band, demand)
    c_prev = c[0]
    dc_prev = 0.0
    ll = 0.0
    innov = np.empty(n)
    Sout = np.empty(n)
    terms = np.zeros(n)
    dt = -1.0
    phi = 0.0
    for k in range(n):
        if k > 0:
            # the model error's OU step (the scalar OU filter's), then the stem's between the samples
            h = t[k] - t[k - 1]
            phi, me, Pee = ou_predict(h, tau_e, ve, me, Pee, dt, phi)
            dt = h
            Pes = phi * Pes
            s_hold = ms
            was_moving = moving
            for j in range(sub_idx[k - 1] + 1, sub_idx[k] + 1):
                xd = x_sub[j]
                if xd <= 0.0 or xd >= stroke:
                    # the end stops win: the stem rests on the stop (physics.trajectory.stem_step)
                    ms = min(max(xd, 0.0), stroke)
                    Pss = 0.0
                    Pes = 0.0
                    dmax = 0.0
                    moving = False
                    p_slip = 0.0
                    x_prev = ms
                    c_prev = c[j]
                    continue
                du = xd - x_prev
                x_prev = xd
                dc = c[j] - c_prev
                c_prev = c[j]
                if dc * dc_prev <= 0.0:
                    # the demand (freed of its noise's reversals, stick_demand) stops or reverses: a moving
                    # stem sticks where it is; with the measured slip decision a resting one that has more
                    # likely than not slipped since it stuck has followed the demand here and sticks here
                    if not moving and p_slip >= DECIDE_MOVING:
                        ms = min(max(xd - side * lag, 0.0), stroke) if lag > 0.0 else min(max(xd, 0.0), stroke)
                        Pss = vl
                        Pes = 0.0
                    moving = False
                    p_slip = 0.0
                    dmax = 0.0
                if dc != 0.0:
                    dc_prev = dc
                if moving:
                    ms = ms + du  # it follows the demand
                    continue
                d = xd - ms
                ad = abs(d)
                if ad <= dmax:
                    continue  # stuck before at this distance: the band is larger
                # the band's spread and the stem's position uncertainty, the latter at most the band's
                # spread: an unbounded one kept the hazard smooth as the band vanished (a stem a micrometre
                # from the demand 'slipped' with probability 0.5 at band 1e-5 mm), so the statistic did not
                # tend to the base model's (2 x 27 log-units at one sample of development seed 31's run 0)
                sd = math.sqrt(vb + min(Pss, vb))
                F0 = _band_cdf(dmax, band, sd)
                F1 = _band_cdf(ad, band, sd)
                pi = 1.0 if F0 >= 1.0 - 1e-12 else (F1 - F0) / (1.0 - F0)
                dmax = ad
                if pi > 1e-12:
                    # two hypotheses, "still stuck at ms" and "slipped onto the demand"; the next measurement
                    # weighs them (below). Between measurements the filter decides that the stem moves only
                    # where the prior alone makes it near certain
                    p_slip = 1.0 - (1.0 - p_slip) * (1.0 - pi)
                    if lag > 0.0:
                        side = 1.0 if d > 0.0 else -1.0
                    if p_slip >= DECIDE_PRIOR:
                        moving = True
                        s_alt = ms  # where it would be had it not slipped
                        ms = xd - side * min(lag, ad) if lag > 0.0 else xd
                        Pss = vl
                        Pes = 0.0
        vwk = vw if w_scale is None else vw * w_scale[k] * w_scale[k]
        nu, S, lk = ou_innovation(y[k], me, Pee, vwk, ms, Pes, Pss)
        if mask[k] and band > 0.0 and k > 0 and moving:
            # the decision that the stem moves, revisited honestly: the measurement is scored once, under
            # the predictive mixture of three hypotheses with their prior probabilities (first-order
            # generalised pseudo-Bayes), and the filter then goes on with the most probable one:
            # "moves" (ms), "never slipped since it stuck" (s_alt, prior 1 - p_slip) and, for a stem that
            # moved at the last sample, "stuck there since" (s_hold, prior RESTICK_P times the
            # probability that the band holds it at the demand's distance). As the band vanishes both
            # alternatives lose their prior (p_slip -> 1, the band holds nothing): the base model's score
            xk = x_sub[sub_idx[k]]
            # a stem that never slipped is held by its band at the demand's present distance: p_slip was
            # decided at a smaller distance and no longer grows once the stem moves (without this bound a
            # position left 1400 bands behind kept prior 1e-4 and won a measurement by model error)
            w_a = min(1.0 - p_slip, 1.0 - _band_cdf(abs(xk - s_alt), band, spread * band))
            w_h = 0.0
            if was_moving:
                w_h = RESTICK_P * (1.0 - _band_cdf(abs(xk - s_hold), band, spread * band))
            w_m = 1.0 - w_a - w_h
            nu_s = y[k] - s_alt - me
            nu_h = y[k] - s_hold - me
            l_m = math.log(w_m) - 0.5 * nu * nu / S if w_m > 0.0 else -math.inf
            l_a = math.log(w_a) - 0.5 * nu_s * nu_s / S if w_a > 0.0 else -math.inf
            l_h = math.log(w_h) - 0.5 * nu_h * nu_h / S if w_h > 0.0 else -math.inf
            top = max(l_m, max(l_a, l_h))
            tot = math.exp(l_m - top) + math.exp(l_a - top) + math.exp(l_h - top)
            lk = -0.5 * (LOG2PI + math.log(S)) + top + math.log(tot)
            if l_a == top or l_h == top:
                # it rests: where it never slipped, or where it was at the last sample
                moving = False
                p_slip = 0.0
                ms = s_alt if l_a == top else s_hold
                nu = nu_s if l_a == top else nu_h
                dmax = abs(xk - ms)
            else:
                # it moves: the measurement's evidence against "never slipped" carries to the next sample
                p_slip = 1.0 - math.exp(l_a - top) / tot
        elif mask[k] and band > 0.0 and k > 0 and p_slip > 0.0:
            # a resting stem that may have slipped since it stuck: the measurement is scored once under the
            # mixture of "stuck at ms" (prior 1 - p_slip) and "on the demand" (p_slip), and updates the slip
            # probability by Bayes' rule; where the slip is now the more probable, the stem moves
            xk = x_sub[sub_idx[k]]
            if lag > 0.0:
                # a slip of J < S lands the lag short of the demand, on the side it broke away to
                xk = xk - side * min(lag, abs(xk - ms))
            S1 = Pee + vl + vwk
            nu1 = y[k] - xk - me
            l_s = math.log(1.0 - p_slip) - 0.5 * (math.log(S) + nu * nu / S) if p_slip < 1.0 else -math.inf
            l_1 = math.log(p_slip) - 0.5 * (math.log(S1) + nu1 * nu1 / S1)
            top = max(l_s, l_1)
            tot = math.exp(l_s - top) + math.exp(l_1 - top)
            lk = -0.5 * LOG2PI + top + math.log(tot)
            p_slip = math.exp(l_1 - top) / tot
            if p_slip >= DECIDE_MOVING:
                moving = True
                s_alt = ms
                ms = xk
                Pss = vl
                Pes = 0.0
                nu = nu1
                S = S1
        innov[k] = nu
        Sout[k] = S
        if mask[k]:
            ll += lk
            terms[k] = lk
            me, Pee, ms, Pes, Pss = ou_update(nu, S, me, Pee, ms, Pes, Pss)
            dk = abs(x_sub[sub_idx[k]] - ms)
            if dk < dmax:
                dmax = dk
    return ll, innov, Sout, terms
