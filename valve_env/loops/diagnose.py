"""Loop diagnosis: fit the three valve candidates, compare them, name the cause (docs/loops.md).

The candidates (linear, backlash, stiction) are nested and fitted by maximum likelihood
(:mod:`valve_env.loops.model`); the band grid of the valve fits also holds the best band of the LR scan
(:func:`valve_env.loops.model.scan_valve`: a dense (S, J, direction) grid, each path with its best process
structure), because the likelihood is rugged in S and the coarse grid alone missed its narrow ridges.
Because the output-error residuals of a real loop are serially correlated, the likelihood-ratio statistic
is scaled by ``n_eff / n`` (the residuals' effective-sample-size factor from their autocorrelation,
statsmodels ``acf``) before it is referred to chi-square and before the BIC difference is taken. A valve
nonlinearity is named ``stiction`` only when all of these hold:

1. the adjusted likelihood-ratio test rejects the linear valve at ``alpha``;
2. the adjusted BIC prefers it by more than 20 (``delta_bic < -20``; Kass & Raftery 1995 call 10 very strong);
3. on held-out data it does not lose: the record is cut in halves, the valve and process structure are
   fitted on one half, and on the other only the gain, offset and noise are re-estimated; the held-out
   log-likelihood gain over the linear valve, summed over both halves, must exceed ``-0.1`` times the
   adjusted LR statistic (a half often holds none of the record's few valve reversals, so a small loss
   there is no evidence against the valve);
4. on a record that oscillates, 1-3 hold again when every candidate's disturbance basis also carries a sinusoidal
   load at the oscillation's period (the periodogram peak near the oscillation test's period; the noise order
   chosen again): an external periodic load is the other explanation of an oscillation, and it is given to the
   linear valve and the nonlinear ones alike, so the comparison is between valves, not disturbances
   (:func:`with_periodic_load`; docs/loops.md, "Decision"). Not where the record rules an
   external load out: an oscillation the OP explains through the linear process, which the linear loop closed by the
   identified controller damps (:func:`oscillation_cause`), is the loop's own limit cycle, and a sinusoid at its
   period only absorbs its fundamental (docs/loops.md, "Oscillation causes").

A **parametric-bootstrap LR test** (the scan's statistic against 19 records simulated from the fitted
linear loop, :func:`bootstrap_test`; its replicates only with ``bootstrap=True``) is reported
(``decision.bootstrap``) but does not vote:
the grouped cross-validation rejected it (its Gaussian AR null is too narrow for the
simulated smooth loops' load drift; docs/loops.md, "Decision").

**The valve's seat** (docs/loops.md, "Loops from the environment"): where the comparison above does
not name stiction and the record holds a seat (:func:`valve_env.loops.model.scan_seats`), the same comparison runs
again with each kind of valve on its seat (the stick-slip's lower end stop; the linear valve's seat kept only where its
maximum-likelihood fit keeps it, :func:`linear_seat_kept`) and decides, naming only a band the record resolves
(:func:`band_resolved`: at least one sample's OP move, and crossed back by the fitted valve), crossed back within
each half of the held-out check (:func:`crosses_back_in_halves`).

Nothing else names it. The OP-PV cross-correlation's shape (:func:`valve_env.loops.detectors.horch` on
the same record, with the PV's increments when the fitted process integrates) is reported beside the
decision (``decision.shape``) but does not vote (docs/loops.md, "Grouped cross-validation").

Otherwise the cause is ``none`` when the loop does not oscillate, or, for an oscillating loop,
``external_oscillation`` when the linear loop model does not reproduce the PV oscillation from the OP, and when
it does (the oscillation is the loop's own): ``aggressive_tuning`` when the fitted linear process closed by the
controller identified from the record rings at the observed period (:func:`closed_loop`, :func:`rings`), or
when the controller cannot be identified (the earlier rule), and ``nonlinear_oscillation`` when the linear loop
damps it, so that a nonlinearity the likelihood did not confirm as stiction sustains it (docs/loops.md,
"Oscillation causes").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy import stats

from valve_env.loops.detectors import horch
from valve_env.loops.io import LoopData
from valve_env.loops.model import (
    BAND_J_FRACTIONS,
    FitMemo,
    ProcessFit,
    Seats,
    Settings,
    ValveFit,
    bootstrap_lr,
    dominant_period,
    fit_valve,
    load_sinusoid,
    refit_gain,
    residuals,
    resolution,
    scan_paths,
    scan_seats,
    scan_valve,
    simulate,
)

CAUSES: tuple[str, ...] = ("stiction", "none", "external_oscillation", "aggressive_tuning", "nonlinear_oscillation")
#: the controller counts as identified from the record when its velocity-form fit explains this share of the OP
#: moves (docs/loops.md, "Oscillation causes"); below it the earlier rule (R^2 of the linear simulation) alone decides
CONTROLLER_FIT_R2_MIN = 0.8
#: a linear closed-loop mode sustains the observed oscillation when it decays by less than this per cycle: the same
#: 0.3 as the oscillation test's first ACF peak, since a noise-driven mode's ACF peaks at about its decay per cycle
RING_DECAY_MIN = 0.3
#: ... and its period lies within this factor of the observed one
RING_PERIOD_FACTOR = 2.0
#: inflation of the profile-likelihood sd of the band, from the simulated calibration study
#: (benchmarks/loop_benchmark.py --calibrate; docs/loops.md, "Band uncertainty")
BAND_SD_INFLATION = 1.0
#: relative model-error sd of the band, calibrated on simulated loops (seeds 0-19, 1000-1019 and
#: 2000-2019 of benchmarks/loop_benchmark.py, 53 named bands): the smallest value whose 2-sd coverage reaches the
#: nominal 95 % (0.08: 92 %, 0.10: 98 %, 1-sd 74 %); docs/loops.md, "Band uncertainty"
BAND_REL_SD = 0.10
#: sd of the sampling offset as a share of it: the band's ends are known only to within one sample's OP move (the
#: recorded OP is an interval mean or a snapshot, the slip happens between samples and a fast cycle's OP peaks are
#: not in the record), so the correction is as uncertain as itself (calibrated with BAND_REL_SD: 0.41, two uniform
#: shortfalls, covered 94 % at 2 sd with BAND_REL_SD 0.10 but only 57 % at 1 sd; docs/loops.md, "Band uncertainty")
SAMPLING_SD_SHARE = 1.0
#: the candidate whose fit gives the band: the most general valve (J profiled; J = 0 is the backlash), whichever
#: nonlinearity the decision's BIC preferred (docs/loops.md, "Band uncertainty")
BAND_CANDIDATE = "stiction"
#: evidence needed on the BIC scale: delta BIC below -20 (beyond Kass & Raftery's "very strong", 10; set on the
#: development loops, docs/loops.md; chosen again by the grouped cross-validation, docs/loops.md, "Grouped
#: cross-validation")
DELTA_BIC_MAX = -20.0
#: level of the parametric-bootstrap LR test, reported beside the decision (round(1/alpha) - 1 = 19 replicates;
#: docs/loops.md, "Decision")
BOOTSTRAP_ALPHA = 0.05
#: the held-out halves may lose at most this share of the adjusted in-sample LR gain
HELDOUT_LOSS_SHARE = 0.1


@dataclass
class Diagnosis:
    result: dict[str, Any]
    fits: dict[str, ValveFit]
    settings: Settings
    loop: LoopData
    neff_factor: float
    #: the fit that gives the band when stiction is named: the ``BAND_CANDIDATE`` refitted with the valve at
    #: ``Settings.band_substeps`` (the decision's own fit when they are equal), else None
    band_fit: ValveFit | None = None

    @property
    def cause(self) -> str:
        return str(self.result["cause"])


def neff_factor(e: np.ndarray, max_lag: int = 40) -> float:
    """``n_eff / n`` of a serially correlated residual: ``1 / (1 + 2 sum rho_k)`` over the lags
    before the autocorrelation first drops below zero (clipped to [0.02, 1])."""
    from statsmodels.tsa.stattools import acf

    r = acf(e - e.mean(), nlags=min(max_lag, e.size // 4), fft=True)
    s = 0.0
    for v in r[1:]:
        if v <= 0:
            break
        s += v
    return float(min(1.0, max(0.02, 1.0 / (1.0 + 2.0 * s))))


def oscillation(y: np.ndarray, dt: float) -> dict[str, Any]:
    """Regularity of an oscillation from the zero crossings of the autocorrelation (Thornhill,
    Huang & Zhang 2003): ``r = mean(period) / (3 sd(period)) > 1`` with a first ACF peak above 0.3."""
    from statsmodels.tsa.stattools import acf

    z = y - np.polyval(np.polyfit(np.arange(y.size), y, 1), np.arange(y.size))
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


def closed_loop(loop: LoopData, pf: ProcessFit) -> dict[str, Any]:
    """The linear loop's own ringing (docs/loops.md, "Oscillation causes"): the controller identified from the record
    in velocity form, ``dOP[k] = b0 e[k] + b1 e[k-1] + b2 e[k-2]`` (``e = SP - PV``; a PI acting on this or the
    previous sample's error, least squares), closed around the fitted linear process ``pf``; returns the fit's R^2,
    the coefficients and the closed loop's oscillatory modes (period s, decay of the amplitude per cycle; a decay
    above 1 is unstable), least damped first."""
    e = loop.sp - loop.pv
    dop = np.diff(loop.op)[1:]
    X = np.column_stack([e[2:], e[1:-1], e[:-2]])
    b, *_ = np.linalg.lstsq(X, dop, rcond=None)
    r2 = 1.0 - float(np.var(dop - X @ b) / max(float(np.var(dop)), 1e-300))
    num_g, den_g = pf.transfer()  # polynomials in z^-1, ascending powers: the process of model.simulate
    char: np.ndarray = np.polynomial.polynomial.polyadd(np.convolve([1.0, -1.0], den_g), np.convolve(b, num_g))
    roots = np.roots(np.trim_zeros(char, "b"))  # ascending in z^-1 is descending in z
    modes = []
    for z in roots[roots.imag > 1e-9]:
        cycle = 2.0 * math.pi / abs(float(np.angle(z)))
        # in logs, capped at e^50: an unstable slow mode would overflow a float (and JSON has no infinity)
        modes.append({"period_s": cycle * loop.dt, "decay_per_cycle": math.exp(min(cycle * math.log(abs(z)), 50.0))})
    modes.sort(key=lambda m: -m["decay_per_cycle"])
    return {"controller_fit_r2": r2, "controller_coefs": [float(v) for v in b], "modes": modes}


def rings(cl: dict[str, Any], period_s: float) -> bool:
    """Whether a mode of :func:`closed_loop` sustains an oscillation of ``period_s``: its period within
    ``RING_PERIOD_FACTOR`` of it and its decay per cycle at least ``RING_DECAY_MIN``. Weak evidence of tuning: a
    dominating external oscillation biases the fitted process so that the loop seems to ring at its period too
    (closed-loop identification; docs/loops.md, "Oscillation causes"); a loop that does not ring is the informative
    case."""
    return any(m["decay_per_cycle"] >= RING_DECAY_MIN and period_s / RING_PERIOD_FACTOR <= m["period_s"]
               <= period_s * RING_PERIOD_FACTOR for m in cl["modes"])


def oscillation_cause(loop: LoopData, lin: ValveFit, period_s: float, k0: int) -> tuple[str, float, dict[str, Any]]:
    """The cause of an oscillation that is not named stiction (docs/loops.md, "Oscillation causes"), from the linear
    valve's fit ``lin``: ``external_oscillation`` when the linear loop's simulation from the OP does not reproduce
    the PV (R^2 <= 0.5), ``aggressive_tuning`` when the controller is not identified from the record or the identified
    loop rings at ``period_s`` (:func:`rings`), otherwise ``nonlinear_oscillation``. Returns the cause, the R^2 and
    :func:`closed_loop`'s result."""
    sim_lin = simulate(lin.path(loop.op), lin.process)
    r2 = 1.0 - float(np.var(loop.pv[k0:] - sim_lin[k0:]) / max(np.var(loop.pv[k0:]), 1e-300))
    cl = closed_loop(loop, lin.process)
    if r2 <= 0.5:  # OP does not explain the PV oscillation: it comes from outside the loop
        return "external_oscillation", r2, cl
    if cl["controller_fit_r2"] < CONTROLLER_FIT_R2_MIN or rings(cl, period_s):
        return "aggressive_tuning", r2, cl
    return "nonlinear_oscillation", r2, cl  # inside the loop, but the linear loop damps it: a nonlinearity sustains it


def heldout_halves(n: int, k0: int) -> tuple[tuple[int, int], tuple[int, int]]:
    """The two halves of the held-out check (condition 3 of the module docstring), as sample ranges ``[a, b)`` of a
    record of ``n`` samples: each starts ``k0`` samples (the fits' warm-up) after its cut."""
    mid = n // 2
    return (k0, mid), (mid + k0, n)


def _heldout_gain(loop: LoopData, valve: str, s: Settings, seat_lin: float = -math.inf,
                  seat: float = -math.inf, memo: FitMemo | None = None, extra_S: tuple[float, ...] = ()) -> float:
    """Held-out log-likelihood gain of ``valve`` (on its ``seat``) over the linear valve (on ``seat_lin``), summed
    over the two halves (the fits looked up in ``memo`` first: :func:`~valve_env.loops.model.fit_valve`); ``extra_S``
    are bands added to each half's band grid (the seat search's band, paired with the seat the halves are given:
    :func:`~valve_env.loops.model.scan_seats`)."""
    first, second = heldout_halves(loop.n, s.k0)
    gain = 0.0
    s = replace(s, n_grid=10)
    for (a0, a1), (b0, b1) in ((first, second), (second, first)):
        lin = fit_valve(loop.op, loop.pv, "linear", replace(s, seat=seat_lin), k1=a1, k0=a0, memo=memo)
        cand = fit_valve(loop.op, loop.pv, valve, replace(s, seat=seat), k1=a1, k0=a0, extra_S=extra_S, memo=memo)
        ll_lin = refit_gain(loop.pv, lin.path(loop.op), lin.process, s, b0, b1).loglik
        ll_c = refit_gain(loop.pv, cand.path(loop.op), cand.process, s, b0, b1).loglik
        gain += ll_c - ll_lin
    return float(gain)


def sampling_offset(op: np.ndarray) -> float:
    """The band's sampling correction, % of OP: the median OP move per sample.

    The valve reverses (slips) between two samples, when the controller's continuous output crosses
    the band; the record shows OP at most one sample's move short of that point at each of the band's
    two ends (half a move on average), so the band fitted to the record is short by one sample's move in
    all; its sd is ``SAMPLING_SD_SHARE`` (one) times the offset (docs/loops.md, "Band uncertainty"). It is
    the record's resolution (:func:`valve_env.loops.model.resolution`)."""
    return resolution(op)


def crosses_back(x: np.ndarray) -> bool:
    """Whether the valve path ``x`` reverses its direction of motion at least once in the record."""
    dx = np.diff(x)
    moves = np.sign(dx[np.abs(dx) > 1e-9 * max(1.0, float(np.max(np.abs(x))))])
    return bool(np.any(moves[1:] != moves[:-1]))


def band_resolved(fit: ValveFit, op: np.ndarray) -> bool:
    """Whether the record ``op`` resolves the band of the valve ``fit`` (docs/loops.md, "Band uncertainty"): the band
    is at least one sample's OP move
    (:func:`sampling_offset`: a narrower band holds the valve for less than a sample), and the fitted valve crosses it
    back at least once (:func:`crosses_back`). A valve that only moves on in its first direction shows its slip jump J
    and that the band exceeds every push back in the record, not the band: a band wider than the OP's whole range,
    max - min, is never crossed back, and every such band gives the same path but for the resting offset
    ``(S - J) / 2``, which the process's offset absorbs."""
    return bool(fit.S >= sampling_offset(op) and crosses_back(fit.path(op)))


def crosses_back_in_halves(fit: ValveFit, loop: LoopData, k0: int) -> bool:
    """Whether the fitted valve crosses its band back (:func:`crosses_back`) within each half of the held-out check
    (:func:`heldout_halves`; the path is the whole record's). A half in which the valve never reverses holds no
    evidence of the band, so the held-out check on it tests the valve only on the other half (docs/loops.md,
    "Decision", condition 3)."""
    x = fit.path(loop.op)
    return all(crosses_back(x[a:b]) for a, b in heldout_halves(loop.n, k0))


def band_uncertainty(fit: ValveFit, factor: float, offset: float = 0.0,
                     inflation: float = BAND_SD_INFLATION) -> tuple[float, float, float, float]:
    """The band, its sd and 95 % interval: the fitted band plus the sampling ``offset``; the sd
    combines the profile-likelihood interval (LR scaled by ``factor``,
    ``{S: factor * 2 (ll_max - ll(S)) <= 3.84}``, interpolated in log S, sd = width / 3.92), the
    model-error sd ``BAND_REL_SD * band`` of the simulated calibration study and the offset's own sd."""
    S = np.array([p[0] for p in fit.profile])
    ll = np.array([p[1] for p in fit.profile])
    dev = factor * 2.0 * (ll.max() - ll)
    i = int(np.argmax(ll))
    logS = np.log(S)

    def edge(step: int) -> float:
        j = i
        while 0 <= j + step < S.size and dev[j + step] <= 3.84:
            j += step
        if not 0 <= j + step < S.size:
            return float(S[j])
        # interpolate between j (inside) and j+step (outside)
        t = (3.84 - dev[j]) / max(dev[j + step] - dev[j], 1e-12)
        return float(math.exp(logS[j] + t * (logS[j + step] - logS[j])))

    lo, hi = edge(-1) + offset, edge(+1) + offset
    sd_prof = inflation * max(hi - lo, 0.0) / 3.92
    band = fit.S + offset
    sd = math.sqrt(sd_prof ** 2 + (BAND_REL_SD * band) ** 2 + (SAMPLING_SD_SHARE * offset) ** 2)
    return band, sd, min(lo, band - 1.96 * sd), max(hi, band + 1.96 * sd)


def _band_fit(loop: LoopData, fit: ValveFit, s: Settings, scan_S: float) -> ValveFit:
    """The fit that gives the band: ``fit`` (the decision's ``BAND_CANDIDATE``) refitted with the valve at
    ``s.band_substeps`` steps per sample on the mean-preserving sub-sample OP (docs/loops.md, "Band uncertainty":
    the recorded OP is an interval mean, so the sample-rate valve never sees the band's ends on a fast cycle),
    its band grid holding the decision fit's and the LR scan's bands and its J / S grid the finer ``BAND_J_FRACTIONS``
    (on the coarser grid a small slip jump was read as J = 0). The decision itself stays with the
    sample-rate valve, whose false-alarm rate and held-out check were calibrated."""
    if s.band_substeps == fit.substeps:
        return fit
    return fit_valve(loop.op, loop.pv, fit.valve, replace(s, substeps=s.band_substeps, seat=fit.seat),
                     extra_S=(fit.S, scan_S),
                     j_fractions=BAND_J_FRACTIONS)


def select_noise_order(loop: LoopData, orders: tuple[int, ...] = (0, 1, 2),
                       load_period_s: float = math.inf) -> Settings:
    """The AR order of the noise by BIC of the linear-valve model (then fixed for every candidate), with the
    periodic load ``load_period_s`` in the disturbance basis (inf: none)."""
    best: tuple[float, Settings] | None = None
    for p in orders:
        s = Settings(dt=loop.dt, noise_order=p, load_period_s=load_period_s)
        fit = fit_valve(loop.op, loop.pv, "linear", s)
        if best is None or fit.bic < best[0]:
            best = (fit.bic, s)
    assert best is not None
    return best[1]


def bootstrap_test(loop: LoopData, lin: ValveFit, s: Settings, alpha: float, seed: int = 0,
                   run: bool = True) -> dict[str, Any]:
    """The parametric-bootstrap likelihood-ratio test of the linear valve (docs/loops.md, "Decision"): the
    scan's statistic on the record against ``round(1/alpha) - 1`` records simulated from the fitted linear
    loop; ``p = (1 + #{replicates >= observed}) / (1 + replicates run)``, stopped at the first replicate that
    reaches the observed statistic (then ``p >= 2 alpha``: not significant). Seeded, so a record's verdict
    repeats. With ``run`` false only the scan is done (its best band seeds the valve fits): no replicates,
    ``n_run`` 0 and the null's figures and ``p_value`` None."""
    paths = scan_paths(loop.op, s.substeps)
    sc = scan_valve(loop.pv, paths, s)
    n_boot = max(int(round(1.0 / alpha)) - 1, 1)
    if not run:
        return {"lr_scan": sc.lr, "S_scan_pct": sc.S, "J_scan_pct": sc.J, "n_boot": n_boot, "n_run": 0,
                "null_mean": None, "null_max": None, "p_value": None, "resolution_pct": resolution(loop.op)}
    null = bootstrap_lr(loop.op, lin.process, s, n_boot, seed=seed, paths=paths, stop_at=sc.lr)
    exceed = int(np.sum(null >= sc.lr))
    return {"lr_scan": sc.lr, "S_scan_pct": sc.S, "J_scan_pct": sc.J, "n_boot": n_boot, "n_run": int(null.size),
            "null_mean": float(null.mean()), "null_max": float(null.max()),
            "p_value": (1.0 + exceed) / (1.0 + null.size), "resolution_pct": resolution(loop.op)}


def with_periodic_load(loop: LoopData, s: Settings, period_s: float, reselect: bool = True) -> Settings:
    """``s`` with a sinusoidal load in every candidate's disturbance basis (docs/loops.md, "Decision",
    condition 4), at the periodogram peak of the control error near the oscillation test's ``period_s``
    (:func:`~valve_env.loops.model.dominant_period`); with ``reselect`` the noise order is chosen again with it."""
    period = dominant_period(loop.pv - loop.sp, loop.dt, period_s)
    if reselect:
        return replace(select_noise_order(loop, load_period_s=period), dt=loop.dt)
    return replace(s, load_period_s=period)


def _pct_or_none(seat: float) -> float | None:
    """A seat level for the JSON: None for no seat (JSON has no infinity)."""
    return float(seat) if math.isfinite(seat) else None


#: no seat for either kind of valve (the unseated comparison)
NO_SEAT = Seats(-math.inf, -math.inf, 0.0, 0.0)


def linear_seat_kept(loop: LoopData, s: Settings, seats: Seats, unseated: ValveFit,
                     memo: FitMemo | None = None) -> Seats:
    """``seats`` with the linear valve's seat dropped where the decision's own likelihood does not keep it: the seat
    search chooses it by the white-noise least squares of the LR scan (:func:`~valve_env.loops.model.scan_seats`), and
    where the maximum-likelihood linear valve on that seat (its AR noise fitted) does not gain a parameter's BIC cost
    (``log n`` in 2 ln L) over the linear valve without a seat (``unseated``, the first comparison's), a nonlinear
    valve would be compared with a linear one that fits worse than the linear valve the record already has
    (docs/loops.md, "Loops from the environment")."""
    if not math.isfinite(seats.linear):
        return seats
    lin = fit_valve(loop.op, loop.pv, "linear", replace(s, seat=seats.linear), memo=memo)
    if 2.0 * (lin.loglik - unseated.loglik) > math.log(lin.n):
        return seats
    return replace(seats, linear=-math.inf)


@dataclass
class Comparison:
    """The likelihood comparison of the valve candidates under one disturbance model (settings ``s``) and on given
    seats (the linear valve on ``seats.linear``, the nonlinear ones on ``seats.nonlinear``): the fits, the LR scan
    (``boot``), the residuals' ``n_eff / n`` factor, each candidate's finding, the better nonlinearity's finding (with
    its held-out gain) and whether it is justified (the first three conditions of the module docstring)."""

    s: Settings
    seats: Seats
    fits: dict[str, ValveFit]
    boot: dict[str, Any]
    neff: float
    findings: list[dict[str, Any]]
    nonlin: dict[str, Any]
    justified: bool


def compare(loop: LoopData, s: Settings, alpha: float = 0.01, heldout: bool = True,
            bootstrap: bool = False, seats: Seats = NO_SEAT, memo: FitMemo | None = None) -> Comparison:
    """Fit the three valve candidates with the disturbance model of ``s`` on ``seats`` and compare them
    (:class:`Comparison`). ``memo`` holds the record's process fits across the comparisons of one diagnosis (a fit
    repeated is looked up: :func:`~valve_env.loops.model.fit_valve`)."""
    if memo is None:
        memo = {}
    s_nl = replace(s, seat=seats.nonlinear)
    fits = {"linear": fit_valve(loop.op, loop.pv, "linear", replace(s, seat=seats.linear), memo=memo)}
    boot = bootstrap_test(loop, fits["linear"], s_nl, BOOTSTRAP_ALPHA, run=bootstrap)
    for v in ("backlash", "stiction"):
        fits[v] = fit_valve(loop.op, loop.pv, v, s_nl, extra_S=(boot["S_scan_pct"], seats.S), memo=memo)
    lin = fits["linear"]
    e_lin = residuals(loop.pv, lin.path(loop.op), lin.process, s.k0)
    f = neff_factor(e_lin)
    n = lin.n
    findings: list[dict[str, Any]] = []
    for name, fit in fits.items():
        df = fit.n_params - lin.n_params  # VALVE_EXTRA_PARAMS, and a seat the linear valve has not
        lr = 2.0 * (fit.loglik - lin.loglik)
        lr_adj = max(lr, 0.0) * f
        p = float(stats.chi2.sf(lr_adj, df)) if df else 1.0
        findings.append({
            "candidate": name,
            "valve": name,
            "loglik": fit.loglik,
            "n_params": fit.n_params,
            "n": n,
            "lr_stat": lr,
            "lr_stat_adjusted": lr_adj,
            "p_value": p,
            "delta_bic": -lr_adj + df * math.log(n),
            "S_pct": fit.S,
            "J_pct": fit.J,
            "process": fit.process.describe(s.dt),
        })
    # the better valve nonlinearity by adjusted BIC
    nonlin = min((fd for fd in findings if fd["candidate"] != "linear"), key=lambda fd: fd["delta_bic"])
    # the halves are given the seats and the seat search's band with them (none without a seat: seats.S 0)
    gain = (_heldout_gain(loop, nonlin["candidate"], s, seats.linear, seats.nonlinear, memo, (seats.S,)) if heldout
            else math.nan)
    nonlin["heldout_loglik_gain"] = gain
    justified = (nonlin["p_value"] < alpha and nonlin["delta_bic"] < DELTA_BIC_MAX
                 and (not heldout or gain > -HELDOUT_LOSS_SHARE * nonlin["lr_stat_adjusted"]))
    return Comparison(s, seats, fits, boot, f, findings, nonlin, bool(justified))


def diagnose(loop: LoopData, settings: Settings | None = None, alpha: float = 0.01,
             heldout: bool = True, bootstrap: bool = False, periodic_load: bool = True) -> Diagnosis:
    """Diagnose one loop record; returns the docs/reference.md, section 10 result and the fits behind it.
    ``bootstrap`` runs the replicates of the non-voting parametric-bootstrap test (:func:`bootstrap_test`;
    the LR scan itself always runs). With ``periodic_load``, a stiction finding on an oscillating record must also
    hold when every candidate carries a sinusoidal load at the oscillation's period (:func:`with_periodic_load`;
    docs/loops.md, "Decision", condition 4). Where the comparison without a seat does not name
    stiction and the record holds a seat, the same comparison with each kind of valve on its seat decides, its band
    resolved by the record (docs/loops.md, "Loops from the environment")."""
    s = settings or select_noise_order(loop)
    if s.dt != loop.dt:
        s = replace(s, dt=loop.dt)
    osc = oscillation(loop.pv - loop.sp, loop.dt)
    memo: FitMemo = {}  # the record's process fits, shared by its comparisons (the same fits, each computed once)

    def checked(c: Comparison) -> tuple[bool, Comparison | None]:
        """Whether ``c`` names stiction, with condition 4 (the periodic load, on the same seats) where it applies: not
        where the record itself rules an external load out, an oscillation the OP explains through the linear process
        and the linear loop closed by the identified controller damps (:func:`oscillation_cause`'s
        ``nonlinear_oscillation``; docs/loops.md, "Oscillation causes")."""
        if not (periodic_load and c.justified and osc["oscillating"] and not math.isfinite(s.load_period_s)):
            return c.justified, None
        if oscillation_cause(loop, c.fits["linear"], osc["period_s"], s.k0)[0] == "nonlinear_oscillation":
            return True, None
        per = compare(loop, with_periodic_load(loop, s, osc["period_s"], settings is None), alpha, heldout,
                      seats=c.seats, memo=memo)
        return per.justified, per

    cmp = compare(loop, s, alpha, heldout, bootstrap, memo=memo)
    by_likelihood, periodic = checked(cmp)
    # the valve's seat: searched only where the comparison without one does not name stiction
    seats = NO_SEAT if by_likelihood else linear_seat_kept(loop, s, scan_seats(loop.op, loop.pv, s),
                                                           cmp.fits["linear"], memo)
    seated = False
    if not by_likelihood and (math.isfinite(seats.linear) or math.isfinite(seats.nonlinear)):
        alt = compare(loop, s, alpha, heldout, bootstrap, seats=seats, memo=memo)
        # the seated fallback names only a band the record resolves (band_resolved): not one below one sample's OP
        # move (the flow loops' smooth twins 16612 and 16616 were named at 0.06-0.07 % of OP), nor one its valve never
        # crosses back (smooth seat seeds 5 and 8: two slips upwards in 4 h, bands 5.6 and 7.3 % of OP),
        # nor one it does not cross back within each of the held-out check's halves (smooth seat seeds 364 and
        # 408: one and two reversals, all in the second half)
        band_fit_alt = alt.fits[BAND_CANDIDATE]
        if (alt.justified and band_resolved(band_fit_alt, loop.op)
                and crosses_back_in_halves(band_fit_alt, loop, s.k0)):
            alt_named, alt_periodic = checked(alt)
            if alt_named:
                cmp, by_likelihood, periodic, seated = alt, True, alt_periodic, True
    fits, boot, f, findings, nonlin = cmp.fits, cmp.boot, cmp.neff, cmp.findings, cmp.nonlin
    gain = nonlin["heldout_loglik_gain"]
    lin = fits["linear"]
    # reported beside the decision, not part of it: Horch's CCF test on the same loop (PV increments for an
    # integrating process)
    shape = horch(loop, integrating=lin.process.integrating)
    osc_cause, r2, cl = oscillation_cause(loop, lin, osc["period_s"] or math.inf, s.k0)
    result: dict[str, Any] = {"cause": "none"}
    band_fit: ValveFit | None = None
    if by_likelihood:  # the decision is the likelihood comparison alone (docs/loops.md)
        result["cause"] = "stiction"
        fit = band_fit = _band_fit(loop, fits[BAND_CANDIDATE], s, boot["S_scan_pct"])
        offset = sampling_offset(loop.op)
        band, sd, lo, hi = band_uncertainty(fit, f, offset)
        result["stiction"] = {
            "band_pct": band,
            "band_fitted_pct": fit.S,
            "sampling_offset_pct": offset,
            "band_resolved": band_resolved(fit, loop.op),
            "std_pct": sd,
            "ci95_pct": [lo, hi],
            "jump_pct": fit.J,
            "kind": "deadband (backlash, J = 0)" if fit.J <= 0.0 else "stick-slip",
            "model": nonlin["candidate"],
            "initial_direction": "up" if fit.direction > 0 else "down",
            "valve_substeps": fit.substeps,
            "seat_pct": _pct_or_none(fit.seat),
        }
    if not by_likelihood and osc["oscillating"]:
        result["cause"] = osc_cause
    result["findings"] = findings
    result["decision"] = {
        "alpha": alpha,
        "bootstrap": boot,
        "best_nonlinear": nonlin["candidate"],
        "neff_factor": f,
        "seat": {"linear_pct": _pct_or_none(seats.linear), "nonlinear_pct": _pct_or_none(seats.nonlinear),
                 "lr_scan_linear": seats.lr_linear, "lr_scan_nonlinear": seats.lr_nonlinear, "seated": seated},
        "heldout_loglik_gain": gain,
        "justified": bool(by_likelihood),
        "by_likelihood": bool(by_likelihood),
        "shape": {k: shape[k] for k in ("statistic", "phase_signed_deg", "ratio", "tau_r", "tau_l", "integrating",
                                        "verdict")},
    }
    if periodic is not None:  # the check under a periodic load (docs/loops.md, "Decision", condition 4)
        pn = periodic.nonlin
        result["decision"]["periodic_load"] = {
            "period_s": periodic.s.load_period_s,
            "amplitude": float(math.sqrt(2.0) * np.std(load_sinusoid(periodic.fits["linear"].process, periodic.s))),
            "justified": periodic.justified, "best_nonlinear": pn["candidate"], "delta_bic": pn["delta_bic"],
            "p_value": pn["p_value"], "heldout_loglik_gain": pn["heldout_loglik_gain"], "neff_factor": periodic.neff}
    # what the linear loop says of the oscillation (oscillation_cause), also where stiction is named: its
    # nonlinear_oscillation waives condition 4 (docs/loops.md, "Decision" and "Oscillation causes")
    result["oscillation"] = {**osc, "linear_sim_r2": r2, "closed_loop": cl,
                             "linear_loop_cause": osc_cause if osc["oscillating"] else None}
    result["loop"] = {"tag": loop.tag, "source": loop.source, "n_samples": loop.n, "dt_s": loop.dt,
                      "op_range_pct": [float(loop.op.min()), float(loop.op.max())],
                      "process": lin.process.describe(s.dt)}
    result["notes"] = list(loop.notes)
    return Diagnosis(result, fits, s, loop, f, band_fit)


__all__ = ["CAUSES", "Diagnosis", "diagnose", "neff_factor", "oscillation", "band_uncertainty",
           "sampling_offset", "band_resolved", "crosses_back", "BAND_CANDIDATE", "closed_loop", "rings", "Comparison",
           "compare", "with_periodic_load", "linear_seat_kept", "oscillation_cause", "heldout_halves",
           "crosses_back_in_halves"]
