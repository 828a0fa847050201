"""Maximum-likelihood estimation (scikit-learn style) for :class:`SDEModel` models.

The estimator interface of the identification framework: ``fit(data)`` returns the estimator itself, and
what it learned ends in ``_`` (``params_``, ``std_``, ``loglik_``, ``n_obs_``, ``n_free_``, ``aic_``,
``bic_``, ``converged_``). :class:`MLEstimator` (the EKF likelihood of an :class:`SDEModel`) and
:class:`valve_env.valveid.estimator.ValveEstimator` (the valve with effects of the registry, either
likelihood) implement it (:class:`Estimator`).

    est = MLEstimator(model, n_starts=3, seed=0).fit(df)
    est.params_, est.std_, est.corr_, est.tstat_, est.loglik_, est.n_obs_
    est.predict(df), est.simulate(df), est.smooth(df), est.residuals(df)

The optimiser (scipy's L-BFGS-B, bounded, several starts) works on each
parameter's transformed scale (``Parameter.transform``). Standard errors come
from the inverse of the Hessian of the negative log-likelihood, computed by
central finite differences on the transformed scale, over the directions the
data identify (:mod:`valve_env.ident.uncertainty`, shared with the
diagnosis), and are mapped to the natural scale with the delta method. A parameter that ends on a bound is
reported with a NaN standard error; a (near-)singular Hessian names the
parameters that the data do not identify (``identifiability_`` and an
:class:`IdentifiabilityWarning`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
import scipy.optimize

from valve_env.ident.kalman import Arrays, FilterResult, rts_smooth, run_filter, to_arrays
from valve_env.ident.sde import Parameter, SDEModel, dnat_dwork, from_work, to_work, work_bounds
from valve_env.ident.tests import bic, lr_test
from valve_env.ident.uncertainty import fd_hessian, identified_directions


class NotFittedError(RuntimeError):
    """The estimator is used before ``fit``."""


class Estimator:
    """Base class: ``fit`` returns ``self``; learned attributes end in ``_``."""

    params_: dict[str, float]
    std_: dict[str, float]
    loglik_: float
    n_obs_: int
    n_free_: int
    converged_: bool

    @property
    def aic_(self) -> float:
        """Akaike's criterion -2 loglik + 2 k."""
        return -2.0 * self.loglik_ + 2.0 * self.n_free_

    @property
    def bic_(self) -> float:
        """Schwarz's criterion (:func:`valve_env.ident.tests.bic`)."""
        return bic(self.loglik_, self.n_free_, self.n_obs_)

    def fit(self, data: Any) -> Estimator:  # pragma: no cover - interface
        raise NotImplementedError

    def _check(self) -> None:
        if not hasattr(self, "params_"):
            raise NotFittedError("call fit(data) first")

    def summary(self) -> pd.DataFrame:
        """Table of estimates: estimate, std and t-statistic per parameter."""
        self._check()
        rows = []
        for name, value in self.params_.items():
            sd = self.std_.get(name, float("nan"))
            rows.append({"parameter": name, "estimate": value, "std": sd,
                         "t": value / sd if sd == sd and sd > 0 else float("nan")})
        return pd.DataFrame(rows).set_index("parameter")



class IdentifiabilityWarning(UserWarning):
    """The data do not identify some parameters (flat or singular likelihood)."""


def negloglik(model: SDEModel, params: Mapping[str, float] | np.ndarray | None, data: pd.DataFrame | Arrays, *,
              method: str = "ekf", n_sub: int = 1, foh: bool = False, compiled: bool | None = None,
              fast: bool | None = None) -> float:
    """The negative log-likelihood of ``data`` at natural-scale ``params`` (a dict, the
    missing names at their ``init``, or a full vector in ``model.param_names`` order).
    Includes 0.5 log(2 pi) per scalar observation (ctsmTMB's convention)."""
    arr = data if isinstance(data, Arrays) else to_arrays(model, data)
    p = np.asarray(params, dtype=float) if isinstance(params, np.ndarray) else model.param_vector(
        dict(params) if params is not None else None)
    try:
        return float(run_filter(model, p, arr, method=method, n_sub=n_sub, foh=foh, compiled=compiled,
                                fast=fast).nll)
    except np.linalg.LinAlgError:
        return float("inf")


def _width(lo: float | None, hi: float | None) -> float:
    """The width of a work-scale box (infinite where a side is open)."""
    return float(hi - lo) if lo is not None and hi is not None else math.inf


class MLEstimator(Estimator):
    """Maximum-likelihood estimator of a continuous-discrete stochastic model.

    Parameters: ``n_starts`` optimiser starts (the first at the parameters'
    ``init``, the others spread by ``start_spread`` on the transformed scale,
    seeded by ``seed``); ``method`` "ekf" or "lkf"; ``n_sub`` RK4 steps per
    sample interval; ``foh`` first-order hold of the inputs (default zero-order);
    ``fixed`` a mapping of parameter names to values held fixed (parameters
    declared ``fixed`` stay at their ``init``); ``fast`` (default: when the model has
    one) the model's specialised filter; ``compiled`` force the compiled or the Python
    EKF (default: compiled when the model has it); ``maxiter``
    iterations per start; ``max_restarts`` L-BFGS-B restarts per start; ``hessian``
    compute standard errors (default True); ``hessian_step`` finite-difference step on the transformed scale.

    Learned attributes end in ``_``: ``params_``, ``std_`` (natural scale),
    ``params_work_``/``std_work_``/``cov_work_`` (transformed scale; ``cov_work_`` the inverse
    Hessian, the bread of :func:`valve_env.ident.uncertainty.robust_std`), ``corr_`` (DataFrame),
    ``cov_`` (natural scale, DataFrame), ``tstat_``, ``loglik_``, ``nll_``,
    ``n_obs_`` (scalar observations), ``n_samples_``, ``n_free_``, ``aic_``,
    ``bic_``, ``free_``, ``at_bound_``, ``identifiability_`` (messages),
    ``converged_``, ``starts_`` (nll per start), ``n_evals_``, ``fit_time_s_``,
    ``filter_`` (the filter pass on the fitted data), ``rms_`` (per output).
    """

    def __init__(self, model: SDEModel, *, n_starts: int = 3, seed: int | None = 0, method: str = "ekf",
                 n_sub: int = 1, foh: bool = False, fixed: Mapping[str, float] | None = None,
                 compiled: bool | None = None, fast: bool | None = None, start_spread: float = 0.3, maxiter: int = 300,
                 hessian: bool = True, hessian_step: float = 1e-3, tol: float = 1e-13, max_restarts: int = 10) -> None:
        self.model = model
        self.n_starts = int(n_starts)
        self.seed = seed
        self.method = method
        self.n_sub = int(n_sub)
        self.foh = bool(foh)
        self.fixed = dict(fixed or {})
        self.compiled = compiled
        self.fast = fast
        self.start_spread = float(start_spread)
        self.maxiter = int(maxiter)
        self.hessian = bool(hessian)
        self.hessian_step = float(hessian_step)
        self.tol = float(tol)
        self.max_restarts = int(max_restarts)
        self._evals = 0
        self._failures = 0
        self._good: tuple[np.ndarray, float] | None = None
        unknown = sorted(set(self.fixed) - set(model.param_names))
        if unknown:
            raise KeyError(f"{model.name}: cannot fix unknown parameter(s) {unknown}")
        if self.n_starts < 1:
            raise ValueError("n_starts must be >= 1")

    # ------------------------------------------------------------------ helpers
    def _base_vector(self) -> np.ndarray:
        return self.model.param_vector(self.fixed)

    def _free(self) -> list[int]:
        return [i for i, q in enumerate(self.model.parameters) if not q.fixed and q.name not in self.fixed]

    def _full(self, theta: np.ndarray, base: np.ndarray, free: list[int]) -> np.ndarray:
        p = base.copy()
        for j, i in enumerate(free):
            p[i] = from_work(theta[j], self.model.parameters[i])
        return p

    def _nll_work(self, theta: np.ndarray, arr: Arrays, base: np.ndarray, free: list[int]) -> float:
        self._evals += 1
        v = float("inf")
        if np.all(np.isfinite(theta)):
            p = self._full(theta, base, free)
            try:
                v = run_filter(self.model, p, arr, method=self.method, n_sub=self.n_sub, foh=self.foh,
                               compiled=self.compiled, fast=self.fast).nll
            except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
                v = float("inf")
        if np.isfinite(v):
            if self._good is None or v < self._good[1]:
                self._good = (np.array(theta, dtype=float), float(v))
            return float(v)
        # the filter failed (e.g. an unstable discretisation): a large value that grows away from the
        # best point so far, so that the line search backs off instead of stalling on a flat plateau
        self._failures += 1
        ref, fref = self._good if self._good is not None else (np.zeros_like(theta), 0.0)
        dist = float(np.sum((np.nan_to_num(np.asarray(theta, dtype=float), nan=1e3) - ref) ** 2))
        return abs(fref) + 1e6 * (1.0 + dist)

    def _starts(self, free: list[int], base: np.ndarray) -> list[np.ndarray]:
        rng = np.random.default_rng(self.seed)
        qs = [self.model.parameters[i] for i in free]
        th0 = np.array([to_work(base[i], q) for i, q in zip(free, qs, strict=True)])
        starts = [th0]
        for _ in range(self.n_starts - 1):
            th = th0 + self.start_spread * rng.standard_normal(len(th0))
            starts.append(_clip_work(th, qs))
        return starts

    # ------------------------------------------------------------------ fit
    def fit(self, data: pd.DataFrame | Arrays) -> MLEstimator:
        t_start = time.perf_counter()
        model = self.model
        arr = data if isinstance(data, Arrays) else to_arrays(model, data)
        base = self._base_vector()
        free = self._free()
        qs = [model.parameters[i] for i in free]
        bounds = [work_bounds(q) for q in qs]
        self._evals = 0
        self._failures = 0
        self._good = None
        best: scipy.optimize.OptimizeResult | None = None
        starts_nll = []
        for th0 in self._starts(free, base):
            if not free:
                break
            r = self._minimize(th0, arr, base, free, bounds)
            starts_nll.append(float(r.fun))
            if best is None or r.fun < best.fun:
                best = r
        theta = np.asarray(best.x, dtype=float) if best is not None else np.zeros(0)
        p_hat = self._full(theta, base, free)
        self.p_ = p_hat
        self.free_ = [model.param_names[i] for i in free]
        self.converged_ = bool(best.success) if best is not None else True
        self.optimizer_message_ = str(best.message) if best is not None else "no free parameters"
        self.starts_ = starts_nll
        self.params_ = {n: float(v) for n, v in zip(model.param_names, p_hat, strict=True)}
        self.params_work_ = {model.param_names[i]: float(theta[j]) for j, i in enumerate(free)}
        self.filter_ = run_filter(model, p_hat, arr, method=self.method, n_sub=self.n_sub, foh=self.foh,
                                  compiled=self.compiled, fast=self.fast)
        self.nll_ = float(self.filter_.nll)
        self.loglik_ = -self.nll_
        self.n_samples_ = int(len(arr.t))
        self.n_obs_ = int(np.isfinite(arr.Y).sum())
        self.n_free_ = len(free)
        self.rms_ = {name: float(np.sqrt(np.nanmean(self.filter_.innov[:, j] ** 2)))
                     for j, name in enumerate(model.outputs)}
        self._uncertainty(theta, arr, base, free, qs, bounds)
        self.n_evals_ = int(self._evals)
        self.fit_time_s_ = time.perf_counter() - t_start
        self._arr = arr
        return self

    def _minimize(self, th0: np.ndarray, arr: Arrays, base: np.ndarray, free: list[int],
                  bounds: list[tuple[float | None, float | None]]) -> scipy.optimize.OptimizeResult:
        """:func:`minimise` of the negative log-likelihood on the working scale, with restarts."""
        return minimise(lambda th: self._nll_work(th, arr, base, free), th0, bounds,
                        {"maxiter": self.maxiter, "ftol": self.tol, "gtol": 1e-6, "eps": 1e-7, "maxls": 40},
                        restarts=self.max_restarts)

    def _uncertainty(self, theta: np.ndarray, arr: Arrays, base: np.ndarray, free: list[int],
                     qs: list[Parameter], bounds: list[tuple[float | None, float | None]]) -> None:
        model = self.model
        names = [q.name for q in qs]
        k = len(free)
        msgs: list[str] = []
        at_bound = []
        for j, (lo, hi) in enumerate(bounds):
            span = (hi - lo) if (lo is not None and hi is not None) else 1.0
            if (lo is not None and theta[j] - lo < 1e-4 * span) or (hi is not None and hi - theta[j] < 1e-4 * span):
                at_bound.append(j)
        self.at_bound_ = [names[j] for j in at_bound]
        for j in at_bound:
            msgs.append(f"parameter {names[j]!r} is at a bound ({self.params_[names[j]]:.6g}): "
                        "no standard error; the data do not identify it within its bounds (or fix it)")
        std_w = np.full(k, np.nan)
        cov_w = np.full((k, k), np.nan)
        inner = [j for j in range(k) if j not in at_bound]
        if self.hessian and inner:
            Hs = self._hessian(theta, arr, base, free, inner)
            widths = [_width(*bounds[j]) for j in inner]
            ident = identified_directions(Hs, widths, rtol=1e-10)
            if ident is not None:
                bad = set()
                for m, members in zip(np.flatnonzero(~ident.keep), ident.unidentified_members(), strict=True):
                    who = [names[inner[i]] for i in members]
                    bad |= {inner[i] for i in members}
                    if ident.eigenvalues[m] <= 1e-10 * max(float(np.max(np.abs(ident.eigenvalues))), 1e-300):
                        msgs.append(f"the likelihood is flat or not concave along a combination of {who}: "
                                    "these parameters are not identifiable from the data (fix one or more)")
                    else:
                        msgs.append(f"the data constrain a combination of {who} less than its bounds do: "
                                    "these parameters are not identifiable from the data (fix one or more)")
                for a, ja in enumerate(inner):
                    for b, jb in enumerate(inner):
                        cov_w[ja, jb] = ident.inverse[a, b]
                d = np.diag(cov_w)
                std_w = np.where(np.isfinite(d) & (d > 0), np.sqrt(np.abs(d)), np.nan)
                for j in bad:
                    std_w[j] = np.nan
            else:
                msgs.append("the Hessian could not be computed (non-finite likelihood near the optimum)")
        jac = np.array([dnat_dwork(theta[j], q) for j, q in enumerate(qs)])
        cov_n = cov_w * np.outer(jac, jac)
        std_n = std_w * np.abs(jac)
        self.cov_work_ = pd.DataFrame(cov_w, index=names, columns=names)
        self.std_work_ = {n: float(s) for n, s in zip(names, std_w, strict=True)}
        self.std_ = {n: float(s) for n, s in zip(names, std_n, strict=True)}
        with np.errstate(invalid="ignore", divide="ignore"):
            sd = np.sqrt(np.diag(cov_w))
            corr = cov_w / np.outer(sd, sd)
        self.cov_ = pd.DataFrame(cov_n, index=names, columns=names)
        self.corr_ = pd.DataFrame(corr, index=names, columns=names)
        self.tstat_ = {n: (self.params_[n] / self.std_[n]) if np.isfinite(self.std_[n]) and self.std_[n] > 0
                       else float("nan") for n in names}
        self.identifiability_ = msgs
        for msg in msgs:
            warnings.warn(f"{model.name}: {msg}", IdentifiabilityWarning, stacklevel=3)

    def _hessian(self, theta: np.ndarray, arr: Arrays, base: np.ndarray, free: list[int],
                 inner: list[int]) -> np.ndarray:
        """The Hessian over the ``inner`` coordinates (:func:`valve_env.ident.uncertainty.fd_hessian`,
        relative steps); NaN when the filter fails at one of its points. (A steep likelihood is not a failure:
        a record without noise, or a long one at 1 s, changes the log-likelihood by far more than 1e5 over a
        step.)"""
        failures = self._failures

        def f(z: np.ndarray) -> float:
            th = theta.copy()
            th[inner] = z
            return self._nll_work(th, arr, base, free)

        H = fd_hessian(f, theta[inner], self.hessian_step * np.maximum(1.0, np.abs(theta[inner])))
        if self._failures > failures:  # a failed filter near the optimum
            H[:] = np.nan
        return H

    # ------------------------------------------------------------------ outputs
    def _run(self, data: pd.DataFrame | Arrays | None, mask_outputs: tuple[str, ...] = ()) -> tuple[Arrays,
                                                                                                    FilterResult]:
        self._check()
        arr = self._arr if data is None else (data if isinstance(data, Arrays) else to_arrays(self.model, data))
        if mask_outputs:
            Y = arr.Y.copy()
            for name in mask_outputs:
                Y[:, self.model.outputs.index(name)] = np.nan
            arr = Arrays(arr.t, arr.U, Y)
        res = run_filter(self.model, self.p_, arr, method=self.method, n_sub=self.n_sub, foh=self.foh,
                         compiled=self.compiled, fast=self.fast)
        return arr, res

    def predict(self, data: pd.DataFrame | Arrays | None = None) -> pd.DataFrame:
        """One-step predictions of each output (``name``) and their standard deviations (``name_sd``)."""
        arr, res = self._run(data)
        return _frame(self.model.outputs, arr.t, res.y_pred, res.S)

    def simulate(self, data: pd.DataFrame | Arrays | None = None) -> pd.DataFrame:
        """Pure simulation: the outputs predicted from the inputs alone, never updated by the
        measured outputs, except those the model lists in ``simulation_outputs`` (for the
        valve model the noisy temperature, which plays the paper's input T_tank)."""
        keep = tuple(getattr(self.model, "simulation_outputs", ()))
        arr, res = self._run(data, tuple(n for n in self.model.outputs if n not in keep))
        return _frame(self.model.outputs, arr.t, res.y_pred, res.S)

    def filter(self, data: pd.DataFrame | Arrays | None = None) -> pd.DataFrame:
        """Filtered states and their standard deviations."""
        arr, res = self._run(data)
        return _frame(self.model.states, arr.t, res.x_filt, res.P_filt)

    def smooth(self, data: pd.DataFrame | Arrays | None = None) -> pd.DataFrame:
        """Smoothed states (Rauch-Tung-Striebel on the linearised filter) and standard deviations."""
        arr, res = self._run(data)
        xs, Ps = rts_smooth(res)
        return _frame(self.model.states, arr.t, xs, Ps)

    def residuals(self, data: pd.DataFrame | Arrays | None = None, standardised: bool = True) -> pd.DataFrame:
        """One-step prediction errors per output, standardised by their predicted sd (NaN where missing)."""
        arr, res = self._run(data)
        out = {"time_s": arr.t}
        for j, name in enumerate(self.model.outputs):
            e = res.innov[:, j]
            out[name] = e / np.sqrt(res.S[:, j, j]) if standardised else e
        return pd.DataFrame(out)

    def nll(self, params: Mapping[str, float] | None = None, data: pd.DataFrame | Arrays | None = None) -> float:
        """Negative log-likelihood at ``params`` (default the fitted ones) on ``data`` (default the fitted data)."""
        self._check()
        p = self.p_.copy()
        for k, v in (params or {}).items():
            p[self.model.param_names.index(k)] = float(v)
        arr = self._arr if data is None else (data if isinstance(data, Arrays) else to_arrays(self.model, data))
        return negloglik(self.model, p, arr, method=self.method, n_sub=self.n_sub, foh=self.foh,
                         compiled=self.compiled, fast=self.fast)

    def summary(self) -> pd.DataFrame:
        """Table of estimates: estimate, std, t-statistic, lower and upper bound, fixed flag."""
        self._check()
        rows = []
        for q in self.model.parameters:
            free = q.name in self.std_
            rows.append({"parameter": q.name, "estimate": self.params_[q.name],
                         "std": self.std_.get(q.name, float("nan")), "t": self.tstat_.get(q.name, float("nan")),
                         "lower": q.lower, "upper": q.upper, "unit": q.unit, "fixed": not free})
        return pd.DataFrame(rows).set_index("parameter")

    def to_dict(self) -> dict[str, Any]:
        self._check()
        return {"params": self.params_, "std": self.std_, "loglik": self.loglik_, "n_obs": self.n_obs_,
                "n": self.n_samples_, "aic": self.aic_, "bic": self.bic_, "converged": self.converged_,
                "identifiability": self.identifiability_, "corr": self.corr_.to_dict()}


def minimise(f: Callable[[np.ndarray], float], x0: np.ndarray, bounds: Any, options: dict[str, Any], *,
             restarts: int = 0) -> scipy.optimize.OptimizeResult:
    """The optimiser of every maximum-likelihood fit: scipy's L-BFGS-B (bounded, finite-difference
    gradient) with ``options``, restarted from its end point (fresh curvature memory) up to ``restarts``
    times while that still improves: L-BFGS-B can stop on a failed line search far from the optimum."""
    x = np.asarray(x0, dtype=float)
    best: scipy.optimize.OptimizeResult | None = None
    for _ in range(restarts + 1):
        r = scipy.optimize.minimize(f, x, method="L-BFGS-B", bounds=bounds, options=options)
        improved = best is None or r.fun < best.fun - 1e-9 * (1.0 + abs(best.fun))
        if best is None or r.fun < best.fun:
            best = r
        if not improved or np.allclose(r.x, x, rtol=0.0, atol=1e-9):
            break
        x = np.asarray(r.x, dtype=float)
    assert best is not None
    return best


def past_kink(f: Callable[[np.ndarray], float], x0: np.ndarray, max_fevals: int) -> scipy.optimize.OptimizeResult:
    """Nelder-Mead (no gradient) from ``x0``, where L-BFGS-B stopped on a failed line search at a kink of
    the likelihood (along which a finite-difference gradient points downhill in no usable direction):
    the fit's caller restarts :func:`minimise` from its end point and keeps the better."""
    return scipy.optimize.minimize(f, x0, method="Nelder-Mead",
                                   options={"maxfev": max_fevals, "xatol": 1e-4, "fatol": 0.01})


def profile_maximum(f: Callable[[float], float], grid: np.ndarray, *, xatol: float,
                    maxiter: int) -> tuple[float, float, list[tuple[float, float]]]:
    """The maximum of a rugged one-dimensional (profile) log-likelihood ``f``, where a gradient method stalls:
    ``f`` on every point of ``grid`` (increasing), then Brent's bounded search (scipy's ``minimize_scalar``,
    ``xatol``, ``maxiter``) between the best grid point's two neighbours. Returns the best argument, its value
    and the profile, every ``(x, f(x))`` evaluated on the grid and the refined point, sorted by ``x``; the
    first of equal maxima wins, and the refined point only when it is strictly better."""
    profile = [(float(x), f(float(x))) for x in grid]
    i = int(np.argmax([p[1] for p in profile]))
    best = profile[i]
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if hi > lo:
        res = scipy.optimize.minimize_scalar(lambda v: -f(float(v)), bounds=(lo, hi), method="bounded",
                                             options={"xatol": xatol, "maxiter": maxiter})
        refined = (float(res.x), -float(res.fun))
        profile.append(refined)
        if refined[1] > best[1]:
            best = refined
    profile.sort()
    return best[0], best[1], profile


def _frame(names: tuple[str, ...], t: np.ndarray, X: np.ndarray, P: np.ndarray) -> pd.DataFrame:
    """Means ``X`` (``name``) and the sds of their covariances ``P`` (``name_sd``) of the ``names`` at times ``t``:
    a filter pass's predicted outputs, filtered or smoothed states."""
    out: dict[str, np.ndarray] = {"time_s": t}
    for j, name in enumerate(names):
        out[name] = X[:, j]
        out[f"{name}_sd"] = np.sqrt(np.maximum(P[:, j, j], 0.0))
    return pd.DataFrame(out)


def _clip_work(theta: np.ndarray, qs: list[Parameter]) -> np.ndarray:
    out = theta.copy()
    for j, q in enumerate(qs):
        lo, hi = work_bounds(q)
        if lo is not None:
            out[j] = max(out[j], lo + 1e-6 * (1 + abs(lo)))
        if hi is not None:
            out[j] = min(out[j], hi - 1e-6 * (1 + abs(hi)))
    return out


def likelihood_ratio(restricted: MLEstimator, full: MLEstimator) -> tuple[float, int, float]:
    """Likelihood-ratio statistic 2 (l_full - l_restricted), its degrees of freedom and the chi^2 p-value
    (:func:`valve_env.ident.tests.lr_test`)."""
    df = max(full.n_free_ - restricted.n_free_, 1)
    stat, p = lr_test(restricted.loglik_, full.loglik_, df)
    return stat, df, p
