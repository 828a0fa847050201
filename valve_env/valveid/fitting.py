"""Maximum-likelihood fits of the base valve model and its extensions (simulation likelihood).

The likelihood is that of :mod:`valve_env.valveid.oe`: the valve is
simulated from the latent (smoothed) temperatures, and the residual of the
measured opening is an Ornstein-Uhlenbeck model error plus white noise. Free
parameters: the paper's Table 4 (``sigma``, ``F_hmax``, ``p_bset``), the
noise (``s_w``, ``s_e``, ``tau_e``) and the parameters of the effects
switched on. Stiction's band is not fitted by the optimiser: its likelihood
is rough and trades off against F_hmax, so it is measured from the jumps of
the opening (:mod:`valve_env.valveid.stiction`) and held while the rest is
fitted. Standard deviations here are the larger of the inverse-Hessian and
the HAC-sandwich ones (:meth:`Model.std_parts`) (delta method to the natural scale); they ignore the
smoothing error of the temperatures and are optimistic, so the diagnosis
replaces them for the named effects by a model-based bootstrap
(:mod:`valve_env.valveid.bootstrap`).

This is the output-error back-end of the identification framework
(docs/estimation.md, "Architecture"): the data container is
:class:`valve_env.valveid.data.RunData`, the parameters and their
transforms are :mod:`valve_env.ident.sde`'s, the standard errors
:func:`valve_env.ident.uncertainty.hessian_sandwich_parts`; the scikit-learn
style front is ``ValveEstimator(effects, likelihood="output_error")``
(:mod:`valve_env.valveid.estimator`).
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from valve_env.effects import ENGINE_INDEX, N_EFFECT_PARAMS, EffectParameter
from valve_env.effects import REGISTRY as EFFECTS
from valve_env.ident.kalman import ou_loglik
from valve_env.ident.mle import minimise, past_kink
from valve_env.ident.sde import Parameter, dnat_dwork, from_work, to_work, work_bounds
from valve_env.ident.uncertainty import hessian_sandwich_parts
from valve_env.params import I_F_HMAX, I_P_BSET, I_SIGMA, I_STROKE, ValveParams
from valve_env.physics.trajectory import drifted_set_pressure
from valve_env.physics.valve import demanded_opening
from valve_env.valveid.data import RunData
from valve_env.valveid.oe import (
    BAND_SPREAD,
    LANDING_SD,
    LOG2PI,
    stick_demand,
    stick_loglik,
    stick_simulate_sj,
    valve_drive,
    valve_pass,
)
from valve_env.valveid.stiction import jump_band

_PAPER = ValveParams()
#: the base (paper Table 4) and residual-model parameters, all on a log scale (the estimation's
#: :class:`~valve_env.ident.sde.Parameter` and its transforms); ``init`` is only nominal:
#: :meth:`Model.default_start` sets the start
BASE_PARAMS: tuple[Parameter, ...] = (
    Parameter("sigma", _PAPER.sigma, 0.3, 100.0, "log", unit="N/K"),
    Parameter("F_hmax", _PAPER.F_hmax, 0.01, 20.0, "log", unit="N"),
    Parameter("p_bset", _PAPER.p_bset, 0.01, 0.5, "log", unit="MPa"),
)
NOISE_PARAMS: tuple[Parameter, ...] = (
    Parameter("s_w", 1e-3, 1e-5, 1.0, "log", unit="mm"),
    Parameter("s_e", 1e-2, 1e-6, 1.0, "log", unit="mm"),
    Parameter("tau_e", 300.0, 1.0, 900.0, "log", unit="s"),
)
NOISE_NAMES: frozenset[str] = frozenset(q.name for q in NOISE_PARAMS)


def effect_parameter(p: EffectParameter) -> Parameter:
    """An effect's parameter as the output-error fit sees it: its search range, on the scale of its
    typical size (``value / scale``), starting at its null value."""
    return Parameter(p.name, p.null, p.fit_lower, p.fit_upper, "none", unit=p.unit, scale=p.scale)


@dataclass
class FitResult:
    """A fitted model: natural-scale parameters with standard deviations, log-likelihood, RMS."""

    effects: tuple[str, ...]
    params: dict[str, float]
    std: dict[str, float]
    loglik: float
    n: int
    n_free: int
    rms_mm: float
    converged: bool
    message: str = ""
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def effect_params(self) -> dict[str, float]:
        names = [p.name for e in self.effects for p in EFFECTS[e].parameters]
        return {k: self.params[k] for k in names}


#: Nelder-Mead's evaluations per free parameter where L-BFGS-B's line search failed at a kink of the
#: likelihood (:meth:`Model._past_kink`)
KINK_FEVALS = 60
#: how much higher (log-likelihood units) a cold fit's noise-first path must end to replace the joint fit from the
#: start (:meth:`Model._noise_first`); below it the two are the same optimum to within L-BFGS-B's tolerance
NOISE_FIRST_MARGIN = 1.0


#: valve paths (:func:`~valve_env.valveid.oe.simulate_valve`'s output) that a :class:`Model` keeps, the
#: most recently used first out (:meth:`Model._valve_path`). A finite-difference gradient moves one parameter at a
#: time, and the three noise parameters and stiction's band leave the path as it is: with the base point and
#: the valve parameters' steps kept, those evaluations run only the filter (docs/diagnosis.md, "Speed")
PATH_CACHE = 8
#: the valve drives (:func:`~valve_env.valveid.oe.valve_drive`: the gas temperature's path and the bellows' pressure
#: along it) that a :class:`Model` keeps: the valve parameters and the set point's drift leave a drive as it is, so
#: the paths of their steps evaluate only :func:`~valve_env.valveid.oe.valve_pass` on it
DRIVE_CACHE = 4
#: the log-likelihoods (one float each) that a :class:`Model` keeps, by their exact inputs, for the run it last
#: evaluated: a minimisation that starts where another ended, a profile or a Hessian re-evaluates points already
#: evaluated (a quarter of the stick-slip filter's calls in a diagnosis), and the filter is deterministic, so a kept
#: value is the value. They are kept for the last LOGLIK_RUNS runs evaluated, so that a model evaluated on many runs
#: (the null and bootstrap copies) holds a few of them, not each (at most PATH_CACHE, as its valve paths do)
LOGLIK_CACHE = 4096
LOGLIK_RUNS = 4


def _kept(cache: OrderedDict[Any, tuple[RunData, Any]], key: Any, data: RunData, limit: int,
          make: Callable[[], Any]) -> Any:
    """The value ``cache`` keeps under ``key``, else ``make()``'s, kept beside ``data`` (the last ``limit`` keys used
    stay). An entry holds its run, so no other live run has its identity: a key with ``id(data)`` cannot be reused."""
    hit = cache.get(key)
    if hit is not None:
        cache.move_to_end(key)
        return hit[1]
    out = make()
    cache[key] = (data, out)
    if len(cache) > limit:
        cache.popitem(last=False)
    return out


def _clip(v: float, q: Parameter) -> float:
    """``v`` clipped to ``q``'s bounds (an open side does not clip)."""
    lo = -math.inf if q.lower is None else q.lower
    hi = math.inf if q.upper is None else q.upper
    return min(max(v, lo), hi)


class Model:
    """The base valve model with a set of effects switched on (the simulation likelihood)."""

    def __init__(self, effects: tuple[str, ...] = (), valve: ValveParams | None = None, max_step_s: float = 2.5):
        self.effects = tuple(effects)
        self.valve = valve if valve is not None else ValveParams()
        self.max_step_s = float(max_step_s)
        self.eff_params = [p for e in self.effects for p in EFFECTS[e].parameters]
        #: every parameter of the fit, in order (the estimation's Parameter: bounds and transform)
        self.parameters: tuple[Parameter, ...] = (*BASE_PARAMS, *map(effect_parameter, self.eff_params),
                                                  *NOISE_PARAMS)
        self.names = [q.name for q in self.parameters]
        self._vp = self.valve.to_array()
        #: the stick-slip filter's breakaway spread and landing sd, relative to the band
        self.band_spread = BAND_SPREAD
        self.landing_sd = LANDING_SD
        self._paths: OrderedDict[tuple[int, bytes, bytes, float, bool], tuple[RunData, tuple[np.ndarray, ...]]] = (
            OrderedDict())
        self._drives: OrderedDict[tuple[int, bytes, float, float, float, bool], tuple[RunData, tuple[Any, ...]]] = (
            OrderedDict())
        #: per run (by identity, the run held): its kept log-likelihoods by their other inputs
        self._lls: OrderedDict[int, tuple[RunData, OrderedDict[tuple[Any, ...], tuple[RunData, float]]]] = (
            OrderedDict())

    def forget_paths(self) -> None:
        """Drop the kept valve paths (:meth:`_valve_path`, about 0.5 MB each for 24 h at 10 s): a fitted model kept
        beside its result (an estimator's ``backend_``, a diagnosis's findings) need not hold them."""
        self._paths.clear()
        self._drives.clear()
        self._lls.clear()

    def __getstate__(self) -> dict[str, object]:
        # the kept valve paths hold runs and their simulations: a copied or pickled model starts without them
        return {**self.__dict__, "_paths": OrderedDict(), "_drives": OrderedDict(), "_lls": OrderedDict()}

    # --- the work (optimiser) scale: the transforms of valve_env.ident.sde ----------
    def to_work(self, values: dict[str, float]) -> np.ndarray:
        """Natural values (clipped to their bounds) -> the optimiser's scale."""
        return np.array([to_work(_clip(values[q.name], q), q) for q in self.parameters])

    def from_work(self, z: np.ndarray) -> dict[str, float]:
        return {q.name: from_work(zi, q) for q, zi in zip(self.parameters, z, strict=True)}

    def work_bounds(self) -> list[tuple[float, float]]:
        return [work_bounds(q) for q in self.parameters]  # type: ignore[misc]  # every bound is finite

    def delta(self, data: RunData, values: dict[str, float] | None = None) -> float:
        """Smallest reversal of the sensed temperature that drives the friction: 5 sd of its noise.

        The sensed temperature T + beta (T_med - T) has the noise sd sqrt((1-beta)^2 s_T^2 + beta^2 s_M^2),
        continuous in beta and equal to the base model's at beta = 0."""
        beta = float((values or {}).get("beta", 0.0))
        sd = math.sqrt((1.0 - beta) ** 2 * data.s_T**2 + beta**2 * data.s_M**2)
        return max(5.0 * sd, 1e-3)

    # --- the likelihood ----------------------------------------------------------------
    def _vectors(self, values: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        vp = self._vp.copy()
        vp[I_SIGMA] = values["sigma"]
        vp[I_F_HMAX] = values["F_hmax"]
        vp[I_P_BSET] = values["p_bset"]
        e = np.zeros(N_EFFECT_PARAMS)
        for p in self.eff_params:
            e[ENGINE_INDEX[p.name]] = values[p.name]
        return vp, e

    def _stuck(self, values: dict[str, float]) -> bool:
        return "stiction" in self.effects and values.get("band_mm", 0.0) > 0.0

    def _valve_path(self, data: RunData, vp: np.ndarray, e: np.ndarray, delta: float,
                    want_sub: bool) -> tuple[np.ndarray, ...]:
        """:func:`~valve_env.valveid.oe.simulate_valve` of ``data``, kept for the last :data:`PATH_CACHE`
        distinct inputs, with the sub-step path the stick-slip's demand (:func:`~valve_env.valveid.oe.stick_demand`)
        as a sixth array. The path depends on the run's time, temperatures and pressures, the valve vector, the
        effects that shape the demand (the bulb lag, the medium's weight, the drift: not the band or the slip,
        which act after it), the reversal threshold and whether the sub-step path is wanted; a run is one object
        (:class:`RunData` is frozen), held by its entry so that its identity cannot be reused. Callers only read
        the arrays; :meth:`simulate` hands out copies."""
        shape = e.copy()
        shape[ENGINE_INDEX["band_mm"]] = 0.0
        shape[ENGINE_INDEX["jump_mm"]] = 0.0
        key = (id(data), vp.tobytes(), shape.tobytes(), float(delta), bool(want_sub))

        def path() -> tuple[np.ndarray, ...]:
            dT, pb, tt, kk, Tg, pb0 = self._drive(data, vp, e, delta, want_sub)
            rate = float(e[ENGINE_INDEX["rate_MPa_per_h"]])
            x, F, x_sub, sub_idx = valve_pass(dT, pb, tt, kk, pb0, data.dp, data.ps, vp, rate, want_sub)
            out: tuple[np.ndarray, ...] = (x, Tg, F, x_sub, sub_idx)
            if want_sub:  # the stick-slip's demand, freed of its noise's reversals: the same for every band here
                out = (*out, stick_demand(x_sub, sub_idx, float(vp[I_STROKE])))
            return out

        return _kept(self._paths, key, data, PATH_CACHE, path)

    def _drive(self, data: RunData, vp: np.ndarray, e: np.ndarray, delta: float, want_sub: bool) -> tuple[Any, ...]:
        """:func:`~valve_env.valveid.oe.valve_drive` of ``data``, kept for the last :data:`DRIVE_CACHE` distinct inputs.
        A drive depends on the run, the bulb lag, the medium's weight, the reversal threshold, the sub-step flag and
        the valve vector apart from the fitted sigma, F_hmax and p_bset; :meth:`_valve_path` runs the valve on it
        (:func:`~valve_env.valveid.oe.simulate_valve` is the two in one)."""
        unfitted = vp.copy()
        unfitted[[I_SIGMA, I_F_HMAX, I_P_BSET]] = 0.0
        key = (id(data), unfitted.tobytes(), float(e[ENGINE_INDEX["tau_s"]]), float(e[ENGINE_INDEX["beta"]]),
               float(delta), bool(want_sub))
        return _kept(self._drives, key, data, DRIVE_CACHE,
                     lambda: valve_drive(data.t, data.T, data.M, vp, e, self.max_step_s, delta, want_sub))

    def simulate(self, data: RunData, values: dict[str, float],
                 slip: float = -1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Open-loop simulation: (opening mm, gas temperature degC, friction force N) at the samples. With
        stiction the stem breaks away at ``band_mm`` and slips ``slip`` where ``0 < slip < band_mm`` (the (S, J)
        stem, :func:`~valve_env.valveid.oe.stick_simulate_sj`), else the whole band (J = S)."""
        vp, e = self._vectors(values)
        stuck = self._stuck(values)
        x, Tg, F, x_sub, idx, *demand = self._valve_path(data, vp, e, self.delta(data, values), stuck)
        if stuck:  # a new array: the stem's stick-slip on the kept demand
            band = values["band_mm"]
            x = stick_simulate_sj(x_sub, idx, band, slip if 0.0 < slip < band else band, float(vp[I_STROKE]),
                                  demand[0])
        else:
            x = x.copy()
        return x, Tg.copy(), F.copy()

    def simulate_substeps(self, data: RunData, values: dict[str, float],
                          part: tuple[int, int] | None = None) -> np.ndarray:
        """The open-loop opening (mm) on the simulation's sub-step grid (at most ``max_step_s`` apart): the
        valve as a record sampled that finely would show it, with stiction's rests and slips between the
        samples; ``part``: only from sample ``part[0]`` to sample ``part[1] - 1`` of a record simulated whole."""
        vp, e = self._vectors(values)
        _, _, _, x_sub, idx, _ = self._valve_path(data, vp, e, self.delta(data, values), True)
        if not self._stuck(values):
            x = x_sub.copy()
        else:
            band = values["band_mm"]
            x = stick_simulate_sj(x_sub, np.arange(x_sub.shape[0]), band, band, float(vp[I_STROKE]))
        return x if part is None else x[idx[part[0]]:idx[part[1] - 1] + 1]

    def demand(self, data: RunData, values: dict[str, float]) -> np.ndarray:
        """The opening the force balance demands without friction (mm, limited to the stroke) at the
        samples: the simulated gas temperature and set pressure with the friction force at 0. Unlike the
        opening, it has no memory: where the sensed temperature is freed of small reversals
        (:func:`~valve_env.valveid.oe.monotone_path`), a tiny change of it can keep or drop a reversal and
        leave the friction force, and so the opening, a different offset until the next reversal."""
        vp, e = self._vectors(values)
        _, Tg, _ = self.simulate(data, values)
        p_set = drifted_set_pressure(vp[I_P_BSET], e[ENGINE_INDEX["rate_MPa_per_h"]], data.t - data.t[0])
        return np.clip(demanded_opening(Tg, 0.0, data.dp, data.ps, p_set, vp), 0.0, vp[I_STROKE])

    def _filter(self, data: RunData, values: dict[str, float], mask: np.ndarray | None = None,
                slip: float = -1.0) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(log-likelihood, one-step prediction errors, their variances, each sample's log-likelihood term);
        ``slip`` is the stick-slip filter's (:func:`~valve_env.valveid.oe.stick_loglik`; negative: J = S)."""
        vp, e = self._vectors(values)
        stuck = self._stuck(values)
        x, _, _, x_sub, idx, *demand = self._valve_path(data, vp, e, self.delta(data, values), stuck)
        if mask is None:
            mask = np.ones(len(data), dtype=np.bool_)
        if stuck:
            return stick_loglik(data.t, data.x, x_sub, idx, values["band_mm"], float(vp[I_STROKE]),
                                values["s_w"], values["s_e"], values["tau_e"], mask, self.band_spread,
                                self.landing_sd, slip, demand[0], data.x_scale)
        ll, innov, S = ou_loglik(data.t, data.x - x, values["s_w"], values["s_e"], values["tau_e"], mask,
                                 data.x_scale)
        return ll, innov, S, np.where(mask, -0.5 * (LOG2PI + np.log(S) + innov**2 / S), 0.0)

    def loglik(self, data: RunData, values: dict[str, float], mask: np.ndarray | None = None,
               slip: float = -1.0) -> float:
        """Exact Gaussian log-likelihood of the measured opening (over the samples in ``mask``); with stiction
        ``slip`` is the stick-slip filter's slip J (negative, the default: J = ``band_mm``). The last
        :data:`LOGLIK_CACHE` distinct inputs' values on each of the last :data:`LOGLIK_RUNS` runs evaluated are
        kept."""
        kept = _kept(self._lls, id(data), data, LOGLIK_RUNS, OrderedDict)
        vp, e = self._vectors(values)
        key = (vp.tobytes(), e.tobytes(), values["s_w"], values["s_e"], values["tau_e"],
               None if mask is None else hashlib.blake2b(np.ascontiguousarray(mask).tobytes(), digest_size=16).digest(),
               float(slip), self.band_spread, self.landing_sd, self.delta(data, values))
        return float(_kept(kept, key, data, LOGLIK_CACHE, lambda: float(self._filter(data, values, mask, slip)[0])))

    def one_step(self, data: RunData, values: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One filter pass: the one-step prediction errors (mm), their variances and each sample's term of
        the log-likelihood (they sum to :meth:`loglik`: the Gaussian of the prediction error, or the
        stick-slip filter's mixture term where it weighed hypotheses)."""
        _, innov, S, terms = self._filter(data, values)
        return innov, S, terms

    def loglik_terms(self, data: RunData, values: dict[str, float]) -> np.ndarray:
        """Each sample's term of the log-likelihood (:meth:`one_step`)."""
        return self.one_step(data, values)[2]

    def prediction_errors(self, data: RunData, values: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """One-step prediction errors (mm) and their variances (:meth:`one_step`)."""
        innov, S, _ = self.one_step(data, values)
        return innov, S

    # --- fitting -------------------------------------------------------------------------
    def default_start(self, data: RunData) -> dict[str, float]:
        """Paper values, the set pressure scanned, noise levels from the residual of that start."""
        v = self.valve
        d = np.diff(data.x)
        s_w = max(float(np.std(d)) / math.sqrt(2.0), 1e-4)
        start = {"sigma": v.sigma, "F_hmax": v.F_hmax, "p_bset": v.p_bset, "s_w": s_w, "s_e": 0.01,
                 "tau_e": max(10.0 * data.median_dt, 300.0)}
        for p in self.eff_params:
            start[p.name] = p.null
        best, best_r = v.p_bset, math.inf
        for f in np.linspace(0.9, 1.1, 21):
            xs, _, _ = self.simulate(data, {**start, "p_bset": v.p_bset * f})
            r = float(np.mean((data.x - xs) ** 2))
            if r < best_r:
                best, best_r = v.p_bset * f, r
        start["p_bset"] = best
        start["s_e"] = max(math.sqrt(best_r), 2.0 * s_w)
        return start

    def fit(self, data: RunData, start: dict[str, float] | None = None, fixed: dict[str, float] | None = None,
            maxiter: int = 300, with_std: bool = True) -> FitResult:
        """Maximum likelihood from ``start`` (defaults: paper values), keeping ``fixed`` parameters fixed.

        Each effect parameter is first scanned over a grid with the other parameters at ``start`` (a
        robust start: the likelihood can be far from quadratic away from the optimum). Stiction's band
        is measured from the slips of the opening (:func:`valve_env.valveid.stiction.jump_band`) and
        held fixed; only where the record has too few slips is it fitted, by a 1-D profile search
        alternating with fits of the other parameters (:meth:`_coordinate_ascent`). The measured band is
        not profiled by the likelihood afterwards: on generated (S, J) runs that named stiction more often
        but put the band at half its value where the slips' median was within 1 % (docs/diagnosis.md; on a
        generated 27.8 h run at 5 s it moved a band of 0.0312 mm, measured 0.0309, to 0.0158)."""
        cold = start is None
        start = {**self.default_start(data), **(start or {})}
        fixed = dict(fixed or {})
        # stiction's band is measured from the staircase of the opening (valve_env.valveid.stiction):
        # its likelihood is rough and trades the band off against F_hmax, which traps a joint fit
        for p in self.eff_params:
            if p.name == "band_mm" and p.name not in fixed:
                b, _ = jump_band(data.x, float(self.valve.stroke))
                if math.isfinite(b) and b > 0:
                    fixed[p.name] = min(max(b, p.fit_lower), p.fit_upper)
                    start[p.name] = fixed[p.name]
        # a set-point drift's rate and p_bset trade off along the record: its scans are tried both with
        # p_bset held and turned about the record's middle (:meth:`_moved`), and the fit with the higher
        # likelihood is kept (each alone ended 12-16 log-likelihood units short on one test run)
        turns = (False, True) if any(p.name == "rate_MPa_per_h" and p.name not in fixed
                                     for p in self.eff_params) else (False,)
        fit = max((self._fit_path(data, dict(start), fixed, cold, maxiter, turn) for turn in turns),
                  key=lambda f: f.loglik)
        if with_std:
            fit = self._fit_smooth(data, fit.params, fixed, 50, True)
        return fit

    def _fit_path(self, data: RunData, start: dict[str, float], fixed: dict[str, float], cold: bool, maxiter: int,
                  turn: bool) -> FitResult:
        """:meth:`fit`'s path from ``start`` (the parameters ``fixed`` held): from a cold start least squares
        and the effects' grid scans, then L-BFGS-B, a second look at each effect's grid and a polish;
        ``turn`` turns a set-point drift's scans about the record's middle (:meth:`_moved`)."""
        if cold:
            # stage 1, from the paper's values: least squares of the simulation error, so that the slowly
            # varying model error cannot absorb a wrong set point or friction and trap the fit (e.g. a
            # valve simulated shut all the time); with effects: scan them, then least squares jointly
            start.update(self._least_squares(data, start, fixed, ()))
            for p in self.eff_params:
                if p.name not in fixed:
                    start.update(self._scan(data, start, p, fixed, turn))
            smooth = tuple(p for p in self.eff_params if not p.log_grid and p.name not in fixed)
            if smooth:
                start.update(self._least_squares(data, start, fixed, smooth))
            xs, _, _ = self.simulate(data, start)
            start["s_e"] = max(float(np.sqrt(np.mean((data.x - xs) ** 2))), 1e-4)
        # a warm start (an earlier fit) keeps its value unless a grid value is better (a refit from a good
        # estimate once ended 6 log-likelihood units lower); a cold fit takes the best grid value: its
        # least-squares value can sit in the basin of a worse optimum (11 units lower on one run)
        for p in self.eff_params:
            if p.name not in fixed:
                start.update(self._scan(data, start, p, fixed, turn, keep_start=not cold))
        fit = self._fit_smooth(data, start, fixed, maxiter, False)
        if cold:
            fit = self._noise_first(data, start, fixed, maxiter, fit)
        fit = self._coordinate_ascent(data, fit, fixed, maxiter)
        # a second look: scan each effect parameter again around the fit (the first scan saw the
        # effect against base parameters that had absorbed part of it); refit where it helps
        for _ in range(2):
            better = dict(fit.params)
            ll0 = self.loglik(data, better)
            moved = False
            for p in self.eff_params:
                if p.name in fixed:
                    continue
                v = float(fit.params[p.name])
                grid = np.concatenate([self._grid(data, p), v * np.array([0.5, 0.7, 0.85, 1.2, 1.4, 2.0])])
                grid = np.clip(grid, p.fit_lower, p.fit_upper)
                for g in grid:
                    trial = self._moved(data, better, p, float(g), fixed, turn)
                    ll = self.loglik(data, trial)
                    if ll > ll0 + 0.1:
                        ll0, better, moved = ll, trial, True
            if not moved:
                break
            fit = self._fit_smooth(data, better, fixed, maxiter, False)
        # polish: L-BFGS-B restarted from its own solution (a fresh curvature estimate) goes on where a
        # long record's flat valley stopped it; the likelihood-ratio tests need converged fits
        for _ in range(3):
            again = self._fit_smooth(data, fit.params, fixed, maxiter, False)
            improved = again.loglik > fit.loglik + 0.05
            fit = again if again.loglik > fit.loglik else fit
            if not improved:
                break
        return self._past_kink(data, fit, fixed, maxiter)

    def _noise_first(self, data: RunData, start: dict[str, float], fixed: dict[str, float], maxiter: int,
                     fit: FitResult) -> FitResult:
        """A cold fit's second path: the noise model's parameters (``NOISE_PARAMS``, whose cold start is a guess)
        fitted first with the others held at ``start``, then every free parameter from there. ``fit``, the joint
        fit straight from ``start``, is kept unless this path ends more than ``NOISE_FIRST_MARGIN`` higher. From a
        start whose noise model is far off, L-BFGS-B's first line search can leave the basin of the optimum: on
        the 8 h stiction run of the bootstrap's coverage test (seed 23) the joint fit stopped ABNORMAL at 6001, this
        path converged at 6443, and which of the two the joint fit found changed with the CPU's floating-point
        rounding (docs/diagnosis.md, "Fitting")."""
        if all(n in fixed for n in NOISE_NAMES):
            return fit
        held = {**fixed, **{n: start[n] for n in self.names if n not in NOISE_NAMES and n not in fixed}}
        noise = self._fit_smooth(data, start, held, maxiter, False)
        again = self._fit_smooth(data, noise.params, fixed, maxiter, False)
        return again if again.loglik > fit.loglik + NOISE_FIRST_MARGIN else fit

    def _past_kink(self, data: RunData, fit: FitResult, fixed: dict[str, float], maxiter: int) -> FitResult:
        """``fit`` carried on where L-BFGS-B stopped because its line search failed (``converged`` false,
        ``ABNORMAL``): the likelihood of the stick-slip filter has kinks (a slip moves by a sample as a
        parameter crosses a value), along which a finite-difference gradient points downhill in no direction
        that the line search can use, and restarting L-BFGS-B from there fails the same way. Nelder-Mead
        (``scipy.optimize.minimize``, no gradient; ``KINK_FEVALS`` evaluations per free parameter) from that
        point, then L-BFGS-B again; the better fit is kept (on the development
        study 20270705, run 28, the stiction fit from the base fit stopped at its start, LR 255 and a held-out
        gain of +0.01, and Nelder-Mead carried it to LR 357)."""
        if fit.converged or "ABNORMAL" not in fit.message:
            return fit
        free, z0, _, at, nll = self._objective(data, fit.params, fixed, clip=True)
        res = past_kink(nll, z0, KINK_FEVALS * len(free))
        if -float(res.fun) <= fit.loglik + 0.05:
            return fit
        moved = at(res.x)
        again = self._fit_smooth(data, moved, fixed, maxiter, False)
        if again.loglik >= -float(res.fun):
            return again
        return self._result(data, moved, again.std, -float(res.fun), len(free), False, "Nelder-Mead past a kink")

    def profile_1d(self, data: RunData, values: dict[str, float], name: str, centre: float,
                   lo: float = 0.4, hi: float = 2.5, n: int = 25) -> tuple[float, float]:
        """Maximise the log-likelihood in one parameter, the others held: a log grid from ``lo`` to
        ``hi`` times ``centre``, refined once on a finer grid around the best point. Returns (value,
        log-likelihood)."""
        c = max(float(centre), 1e-6)
        grid = c * np.geomspace(lo, hi, n)
        lls = np.array([self.loglik(data, {**values, name: float(g)}) for g in grid])
        i = int(np.argmax(lls))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        fine = np.geomspace(a, b, 9)
        llf = np.array([self.loglik(data, {**values, name: float(g)}) for g in fine])
        j = int(np.argmax(llf))
        return (float(fine[j]), float(llf[j])) if llf[j] >= lls[i] else (float(grid[i]), float(lls[i]))

    def _coordinate_ascent(self, data: RunData, fit: FitResult, fixed: dict[str, float], maxiter: int,
                           rounds: int = 6) -> FitResult:
        """For parameters with a rough likelihood (``log_grid``: stiction's band), which L-BFGS-B cannot
        move: alternate a 1-D profile search of each with an L-BFGS-B fit of the others (the band
        trades off against the Dahl friction's F_hmax, so one profile step is not enough)."""
        rough = [p for p in self.eff_params if p.log_grid and p.name not in fixed]
        if not rough:
            return fit
        for _ in range(rounds):
            vals = dict(fit.params)
            moved = False
            for p in rough:
                c = float(vals[p.name])
                if c <= 0.0:
                    continue
                b, ll = self.profile_1d(data, vals, p.name, c)
                if abs(b / c - 1.0) > 0.005:
                    vals[p.name] = b
                    moved = True
            if not moved:
                break
            again = self._fit_smooth(data, vals, {**fixed, **{p.name: vals[p.name] for p in rough}}, maxiter,
                                     False)
            if again.loglik <= fit.loglik + 0.05:
                break
            fit = again
        return fit

    def _least_squares(self, data: RunData, start: dict[str, float], fixed: dict[str, float],
                       effects: tuple[EffectParameter, ...]) -> dict[str, float]:
        """sigma, F_hmax, p_bset (log scale) and the given effect parameters (scaled) by trust-region
        least squares of the simulation error."""
        names = [q.name for q in BASE_PARAMS if q.name not in fixed] + [p.name for p in effects]
        if not names:
            return {}
        _, z0, bounds, at, _ = self._objective(data, start, {n: start[n] for n in self.names if n not in names})
        lo = np.array([b[0] for b in bounds])
        hi = np.array([b[1] for b in bounds])

        def resid(zs: np.ndarray) -> np.ndarray:
            xs, _, _ = self.simulate(data, at(zs))
            return data.x - xs

        res = least_squares(resid, np.clip(z0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi),
                            x_scale=np.full(len(names), 0.05), max_nfev=80, diff_step=1e-4)
        vals = at(res.x)
        return {n: vals[n] for n in names}

    def _grid(self, data: RunData, p: EffectParameter) -> np.ndarray:
        if p.log_grid:
            lo = max(0.5 * float(np.std(np.diff(data.x))), 1e-3)
            return np.concatenate([[p.null], np.geomspace(lo, min(p.fit_upper, 0.3), 8)])
        if p.name == "tau_s":
            return np.array([0.0, 1.0, 3.0, 10.0, 20.0, 40.0, 70.0, 120.0, 200.0, 350.0, 600.0, 1000.0])
        if p.name == "beta":
            return np.array([0.0, 0.01, 0.03, 0.06, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6])
        span = np.array([0.0, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0]) * p.scale
        return np.clip(np.unique(np.concatenate([-span, span])), p.fit_lower, p.fit_upper)

    @staticmethod
    def _moved(data: RunData, vals: dict[str, float], p: EffectParameter, g: float, fixed: dict[str, float],
               turn: bool) -> dict[str, float]:
        """``vals`` with the effect parameter ``p`` at ``g``. With ``turn``, a set-point drift turns about
        the record's middle: its rate and p_bset trade off along the record (p_b,set(t) = p_bset + rate t,
        docs/reference.md "Named effects"), and a fit without the drift has put p_bset at the drifted set
        pressure's mean, so a rate tried at that p_bset shifts the whole record and can look worse than none.
        p_bset then moves with the rate so that the set pressure at the record's middle stays (unless p_bset
        is fixed). On a 10 h run drifting -6e-5 MPa/h (tests/diagnosis/test_diagnose.py, seed 104) the held
        scans kept the rate at 0 (LR 0; on another machine's last bits they had found it) and the turned ones
        find it (LR 32); on seed 22 of tests/diagnosis/test_uncertainty.py the held path ends 12 units
        higher. :meth:`fit` runs both and keeps the better."""
        out = {**vals, p.name: g}
        if turn and p.name == "rate_MPa_per_h" and "p_bset" not in fixed:
            t_mid_h = 0.5 * float(data.t[-1] - data.t[0]) / 3600.0
            out["p_bset"] = vals["p_bset"] - (g - vals[p.name]) * t_mid_h
        return out

    def _scan(self, data: RunData, start: dict[str, float], p: EffectParameter, fixed: dict[str, float],
              turn: bool = False, keep_start: bool = False) -> dict[str, float]:
        """The values (``p``'s, and p_bset's where a drift moves it: :meth:`_moved`) with the highest
        likelihood on ``p``'s grid, the other parameters at ``start``; with ``keep_start``, ``start``
        competes too, so that a warm start is only left for a better grid value."""
        ll0 = self.loglik(data, start) if keep_start else -math.inf
        best, best_ll = {p.name: start[p.name]}, (ll0 if math.isfinite(ll0) else -math.inf)
        for g in self._grid(data, p):
            vals = self._moved(data, start, p, float(g), fixed, turn)
            ll = self.loglik(data, vals)
            if ll > best_ll:
                best, best_ll = {k: vals[k] for k in (p.name, "p_bset") if k in vals and k not in fixed}, ll
        return best

    def _objective(self, data: RunData, start: dict[str, float], fixed: dict[str, float], clip: bool = False
                   ) -> tuple[list[int], np.ndarray, list[tuple[float, float]],
                              Callable[[np.ndarray], dict[str, float]], Callable[[np.ndarray], float]]:
        """The fits' objective over the working scale of the parameters not in ``fixed``: their indices, their
        start (from ``start``), their bounds, the values at a working point (the fixed ones held; ``clip``: the
        point clipped into the bounds, for a method without bounds) and the negative log-likelihood there
        (1e300 where it is not finite)."""
        free = [i for i, n in enumerate(self.names) if n not in fixed]
        z_all = self.to_work({**start, **fixed})
        work_bounds = self.work_bounds()
        bounds = [work_bounds[i] for i in free]
        lo = np.array([b[0] for b in bounds])
        hi = np.array([b[1] for b in bounds])

        def at(zf: np.ndarray) -> dict[str, float]:
            z = z_all.copy()
            z[free] = np.clip(zf, lo, hi) if clip else zf
            return self.from_work(z)

        def nll(zf: np.ndarray) -> float:
            ll = self.loglik(data, at(zf))
            return -ll if math.isfinite(ll) else 1e300

        return free, z_all[free], bounds, at, nll

    def _fit_smooth(self, data: RunData, start: dict[str, float], fixed: dict[str, float], maxiter: int,
                    with_std: bool) -> FitResult:
        free, z0, bounds, at, nll = self._objective(data, start, fixed)
        res = minimise(nll, z0, bounds, {"maxiter": maxiter, "ftol": 1e-8, "gtol": 1e-5, "eps": 1e-7})
        vals = at(res.x)
        std = {n: float("nan") for n in self.names}
        if with_std:
            names, sd_h, sd_r, _ = self.std_parts(data, free, res.x, at, nll)
            std.update({n: float(v) for n, v in zip(names, np.fmax(sd_h, sd_r), strict=True)})
        return self._result(data, vals, std, -float(res.fun), len(free), bool(res.success), str(res.message))

    def std_parts(self, data: RunData, free: list[int], zf: np.ndarray, at: Callable[[np.ndarray], dict[str, float]],
                  nll: Callable[[np.ndarray], float]) -> tuple[list[str], np.ndarray, np.ndarray, int]:
        """The free parameters' names and their two likelihood-based sds at the working point ``zf`` of
        :meth:`_objective`'s ``free``, ``at`` and ``nll``: the model-based one (inverse Hessian of the negative
        log-likelihood over the identified directions) and the robust one (Newey-West HAC sandwich of the
        per-sample scores, the residual model's parameters held as a working covariance), delta method to
        the natural scale (:func:`valve_env.ident.uncertainty.hessian_sandwich_parts`), and the HAC window."""

        def contrib(z: np.ndarray) -> np.ndarray:
            nu, S = self.prediction_errors(data, at(z))
            return -0.5 * (np.log(2.0 * np.pi * S) + nu * nu / S)

        names = [self.names[i] for i in free]
        bounds = self.work_bounds()
        widths = np.array([bounds[i][1] - bounds[i][0] for i in free], dtype=float)
        g = np.array([dnat_dwork(zf[j], self.parameters[i]) for j, i in enumerate(free)])
        working = np.array([n in NOISE_NAMES for n in names])
        return names, *hessian_sandwich_parts(nll, contrib, zf, widths, g, working)

    def _result(self, data: RunData, vals: dict[str, float], std: dict[str, float], ll: float, n_free: int,
                ok: bool, msg: str) -> FitResult:
        xs, _, _ = self.simulate(data, vals)
        rms = float(np.sqrt(np.mean((data.x - xs) ** 2)))
        return FitResult(self.effects, vals, std, ll, len(data), n_free, rms, ok, msg)


__all__ = ["RunData", "FitResult", "Model", "BASE_PARAMS", "NOISE_PARAMS"]
