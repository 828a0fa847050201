"""Standard errors of a maximum-likelihood fit: the one implementation both estimators use.

    H = fd_hessian(nll, z, steps)                      # on the optimiser's (transformed) scale
    ident = identified_inverse(H, widths)              # inverse over the identified directions
    sd = hessian_sandwich_sd(nll, contrib, z, widths, dnat, working)   # model-based vs HAC sandwich

The pieces (docs/estimation.md, "Standard errors"):

* :func:`fd_hessian`: the Hessian of the negative log-likelihood by central finite differences.
* :func:`identified_inverse`: the inverse of the Hessian over the directions the data identify. A
  direction (eigenvector ``v`` of ``H`` with eigenvalue ``lam``) is unidentified when ``lam`` is
  not positive (or below ``rtol`` times the largest), or when the +-1 sd interval of the
  likelihood along it (``2 / sqrt(lam)`` wide) is wider than the parameter box along it. Such
  directions carry no information; inverting them lets finite-difference noise and the scores of
  a flat direction inflate every sd (a 500-fold inflated sd of the medium-temperature beta
  where every direction was inverted).
* :func:`hac_meat`: the Newey-West (Bartlett) long-run covariance of per-sample scores
  (statsmodels' ``S_hac_simple``).
* :func:`hessian_sandwich_sd`: the larger of the model-based sd (inverse Hessian) and the robust
  one (HAC sandwich ``H^-1 M H^-1``), the residual model's (``working``) parameters held at their
  estimates in the sandwich of the others (Liang and Zeger 1986), delta method to the natural
  scale.

Used by :class:`valve_env.ident.mle.MLEstimator` (the EKF likelihood: inverse Hessian over
the identified directions) and by the output-error likelihood of the diagnosis
(:class:`valve_env.valveid.fitting.Model`: the sandwich).

**The EKF estimator's sandwich** (:func:`robust_std`). The prediction-error decomposition makes the
negative log-likelihood a sum of per-sample terms ``l_k(theta)`` (:func:`step_nll`: the filter's innovation
``e_k`` and its covariance ``S_k``, ``0.5 log det S_k + 0.5 e_k' S_k^-1 e_k + 0.5 m_k log 2 pi``). Their
gradients ``g_k`` (:func:`score_contributions`: central differences on the optimiser's scale, one filter
pass per step and parameter) are the score contributions. With a correct model they are martingale
differences and ``sum g_k g_k'`` equals the Hessian ``H`` on average; when the model is wrong they are
not, and

    cov = H^-1 M H^-1,    M = sum_k g_k g_k' + sum_{l=1..L} w_l sum_k (g_k g_{k-l}' + g_{k-l} g_k')

(Huber 1967, White 1982; with L > 0 the Newey-West HAC form, Bartlett weights w_l = 1 - l / (L + 1),
:func:`hac_meat`) is consistent for the estimator's covariance (the quasi-ML, "sandwich" covariance).
``H^-1`` is the fit's inverse Hessian (``MLEstimator.cov_work_``). ``lags=0`` gives Huber-White.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from statsmodels.stats.sandwich_covariance import S_hac_simple

from valve_env.ident.kalman import LOG2PI, FilterResult, run_filter
from valve_env.ident.sde import dnat_dwork, from_work


def fd_hessian(f: Callable[[np.ndarray], float], z: np.ndarray, steps: np.ndarray | float) -> np.ndarray:
    """Hessian of ``f`` at ``z`` by central differences with step ``steps[i]`` in coordinate i
    (``2 k^2 + 1`` evaluations: the diagonal from f(z +- h_i e_i), each off-diagonal pair from the
    four corners)."""
    z = np.asarray(z, dtype=float)
    k = z.size
    h = np.broadcast_to(np.asarray(steps, dtype=float), (k,))
    H = np.empty((k, k))
    f0 = f(z)
    for i in range(k):
        e = np.zeros(k)
        e[i] = h[i]
        H[i, i] = (f(z + e) - 2 * f0 + f(z - e)) / h[i] ** 2
        for j in range(i):
            ej = np.zeros(k)
            ej[j] = h[j]
            H[i, j] = H[j, i] = (f(z + e + ej) - f(z + e - ej) - f(z - e + ej) + f(z - e - ej)) / (4 * h[i] * h[j])
    return H


@dataclass(frozen=True)
class Identified:
    """The eigen-decomposition of a Hessian and which of its directions the data identify."""

    inverse: np.ndarray  #: the inverse over the identified directions (0 along the others)
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray  #: columns
    keep: np.ndarray  #: bool per direction

    def unidentified_members(self, threshold: float = 0.2) -> list[list[int]]:
        """For each unidentified direction, the coordinates with a component above ``threshold``,
        largest first."""
        out = []
        for m in np.flatnonzero(~self.keep):
            comp = np.abs(self.eigenvectors[:, m])
            out.append([int(i) for i in np.argsort(-comp) if comp[i] > threshold])
        return out


def identified_directions(H: np.ndarray, widths: Sequence[float] | np.ndarray | None = None,
                          rtol: float = 0.0) -> Identified | None:
    """Eigen-decomposition of the (symmetrised) Hessian ``H`` with its identified directions.

    ``widths``: the width of the parameter box in each coordinate on the optimiser's scale (``inf``
    or ``None`` for an unbounded one). A direction is kept when its eigenvalue is positive and above
    ``rtol`` times the largest absolute one, and its +-1 sd interval ``2 / sqrt(lam)`` is narrower
    than the box's extent along it. ``None`` when ``H`` is not finite."""
    Hs = 0.5 * (H + H.T)
    if not np.all(np.isfinite(Hs)):
        return None
    lam, V = np.linalg.eigh(Hs)
    w = np.full(Hs.shape[0], np.inf) if widths is None else np.asarray(widths, dtype=float)
    unbounded = np.isinf(w)
    extent = np.abs(V).T @ np.where(unbounded, 0.0, w)  # the box's extent along each eigenvector
    if unbounded.any():
        extent = np.where(np.abs(V).T @ unbounded.astype(float) > 0, np.inf, extent)
    tol = rtol * max(float(np.max(np.abs(lam))), 1e-300) if lam.size else 0.0
    keep = (lam > tol) & (2.0 / np.sqrt(np.where(lam > 0, lam, 1.0)) < extent)
    Vk = V[:, keep]
    return Identified(np.asarray((Vk / lam[keep]) @ Vk.T), lam, V, keep)


def identified_inverse(H: np.ndarray, widths: Sequence[float] | np.ndarray | None = None,
                       rtol: float = 0.0) -> np.ndarray | None:
    """The inverse of the Hessian over the identified directions (:func:`identified_directions`);
    ``None`` when no direction is identified or ``H`` is not finite."""
    ident = identified_directions(H, widths, rtol)
    if ident is None or not ident.keep.any():
        return None
    return ident.inverse


def newey_west_lags(n: int) -> int:
    """The Newey-West (1994) rule floor(4 (n / 100)^(2/9)) (statsmodels' default)."""
    return int(np.floor(4.0 * (n / 100.0) ** (2.0 / 9.0)))


def hac_meat(G: np.ndarray, nlags: int | None = None, *, demean: bool = True) -> np.ndarray:
    """Newey-West (Bartlett kernel) long-run covariance of the rows of ``G`` (per-sample scores);
    ``nlags`` defaults to :func:`newey_west_lags`, 0 gives Huber-White's outer product ``G' G``.

    The one HAC meat of the project (statsmodels' ``S_hac_simple``): the output-error sandwich
    (:func:`hessian_sandwich_parts`) takes it about the scores' mean (``demean``, the default), the
    EKF's (:func:`robust_std`) about zero, the scores' expectation at the
    maximum (``demean=False``). At an interior maximum the mean score is zero to the optimiser's
    tolerance, so the two agree there."""
    G = np.asarray(G, dtype=float)
    if demean:
        G = G - G.mean(axis=0)
    return np.asarray(S_hac_simple(G, nlags=nlags))


def score_matrix(contrib: Callable[[np.ndarray], np.ndarray], z: np.ndarray, h: float) -> np.ndarray:
    """Per-sample scores (n samples x k parameters) of the log-likelihood contributions
    ``contrib(z)`` by central differences with step ``h``."""
    k = z.size
    G: np.ndarray | None = None
    for i in range(k):
        e = np.zeros(k)
        e[i] = h
        col = (contrib(z + e) - contrib(z - e)) / (2 * h)
        if G is None:
            G = np.empty((col.size, k))
        G[:, i] = col
    assert G is not None
    return G


def hessian_sandwich_parts(nll: Callable[[np.ndarray], float], contrib: Callable[[np.ndarray], np.ndarray],
                           z: np.ndarray, widths: Sequence[float] | np.ndarray, dnat: np.ndarray,
                           working: np.ndarray, h: float = 1e-3) -> tuple[np.ndarray, np.ndarray, int]:
    """Natural-scale sd of each parameter two ways: the model-based one (inverse Hessian of ``nll``
    over the identified directions) and the robust one (HAC sandwich of the per-sample scores of
    ``contrib``, the log-likelihood contributions); delta method with ``dnat`` (the derivative of each
    natural value with respect to its transformed one). Returns ``(sd_model, sd_robust, lags)``,
    ``lags`` the Newey-West window used.

    ``working`` marks the residual model's parameters (noise levels, correlation time): in the
    sandwich of the others they are held at their estimates (a working covariance: the sandwich for
    the parameters of the mean stays valid however wrong it is, Liang and Zeger 1986); letting their
    scores in carried the misfit of a nearly flat noise direction into every sd (500 times
    the bootstrap sd of beta). The working parameters keep the full sandwich. NaN where nothing is
    identified."""
    z = np.asarray(z, dtype=float)
    k = z.size
    widths = np.asarray(widths, dtype=float)
    sd_model = np.full(k, np.nan)
    sd_robust = np.full(k, np.nan)
    H = fd_hessian(nll, z, h)
    Hi = identified_inverse(H, widths)
    if Hi is None:
        return sd_model, sd_robust, 0
    G = score_matrix(contrib, z, h)
    lags = newey_west_lags(G.shape[0])
    M = hac_meat(G, lags)
    phys = ~np.asarray(working, dtype=bool)
    cov_robust = Hi @ M @ Hi
    if phys.any():
        Hp = identified_inverse(H[np.ix_(phys, phys)], widths[phys])
        if Hp is not None:
            cov_robust[np.ix_(phys, phys)] = Hp @ M[np.ix_(phys, phys)] @ Hp
    for out, cov in ((sd_model, Hi), (sd_robust, cov_robust)):
        for i in range(k):
            v = cov[i, i]
            out[i] = float(math.sqrt(v) * abs(dnat[i])) if v > 0 and math.isfinite(v) else float("nan")
    return sd_model, sd_robust, lags


def hessian_sandwich_sd(nll: Callable[[np.ndarray], float], contrib: Callable[[np.ndarray], np.ndarray],
                        z: np.ndarray, widths: Sequence[float] | np.ndarray, dnat: np.ndarray,
                        working: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """Natural-scale sd of each parameter: the larger of the model-based one and the robust one of
    :func:`hessian_sandwich_parts` (NaN where nothing is identified)."""
    sd_model, sd_robust, _ = hessian_sandwich_parts(nll, contrib, z, widths, dnat, working, h)
    return np.fmax(sd_model, sd_robust)


# --------------------------------------------------------------------------- the EKF estimator's sandwich
def step_nll(res: FilterResult) -> np.ndarray:
    """The per-sample terms of the negative log-likelihood from a filter pass (sum = ``res.nll``)."""
    innov = res.innov
    N, ny = innov.shape
    if ny == 1:
        e = innov[:, 0]
        S = res.S[:, 0, 0]
        ok = np.isfinite(e)
        out = np.zeros(N)
        out[ok] = 0.5 * np.log(S[ok]) + 0.5 * e[ok] ** 2 / S[ok] + 0.5 * LOG2PI
        return out
    out = np.zeros(N)
    for k in range(N):
        obs = np.isfinite(innov[k])
        if not obs.any():
            continue
        e = innov[k, obs]
        S = res.S[k][np.ix_(obs, obs)]
        sign, logdet = np.linalg.slogdet(S)
        out[k] = 0.5 * logdet + 0.5 * float(e @ np.linalg.solve(S, e)) + 0.5 * obs.sum() * LOG2PI
    return out


def score_contributions(est: Any, step: float = 1e-4) -> pd.DataFrame:
    """Per-sample score contributions d l_k / d theta_j (optimiser's scale) at the estimate, for the
    free parameters that have a standard error (central differences, 2 filter passes each)."""
    est._check()  # raises NotFittedError before fit
    model = est.model
    names = [n for n in est.free_ if np.isfinite(est.std_work_.get(n, np.nan))]
    arr = est._arr
    G = np.zeros((len(arr.t), len(names)))
    for j, name in enumerate(names):
        i = model.param_names.index(name)
        q = model.parameters[i]
        th = est.params_work_[name]
        h = step * max(1.0, abs(th))
        parts = []
        for sgn in (1.0, -1.0):
            p = est.p_.copy()
            p[i] = from_work(th + sgn * h, q)
            res = run_filter(model, p, arr, method=est.method, n_sub=est.n_sub, foh=est.foh,
                             compiled=est.compiled, fast=est.fast)
            parts.append(step_nll(res))
        G[:, j] = (parts[0] - parts[1]) / (2.0 * h)
    return pd.DataFrame(G, columns=names)


@dataclass(frozen=True)
class RobustResult:
    """Sandwich standard errors. ``std`` natural scale, ``std_work`` optimiser's scale, ``cov_work``
    the sandwich on the optimiser's scale, ``lags`` the HAC lag window (0: Huber-White),
    ``ratio`` std / the inverse Hessian's std."""

    std: dict[str, float]
    std_work: dict[str, float]
    cov_work: pd.DataFrame
    lags: int
    ratio: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"std": dict(self.std), "lags": self.lags, "ratio": dict(self.ratio),
                "method": "sandwich H^-1 M H^-1, M the Newey-West (Bartlett) HAC of the EKF score contributions"
                          if self.lags > 0 else "sandwich H^-1 M H^-1 (Huber-White), M the outer product of "
                                                "the EKF score contributions"}


def robust_std(est: Any, *, lags: int | None = None, scores: pd.DataFrame | None = None) -> RobustResult:
    """Sandwich (HAC) standard errors of a fitted estimator (see the module doc). ``lags``: the
    Bartlett window (default :func:`newey_west_lags`; 0 = Huber-White); ``scores`` precomputed
    :func:`score_contributions` (to try several windows at the cost of one)."""
    G = score_contributions(est) if scores is None else scores
    names = list(G.columns)
    n = len(G)
    L = newey_west_lags(n) if lags is None else int(lags)
    M = hac_meat(G.to_numpy(), L, demean=False)
    C = est.cov_work_.loc[names, names].to_numpy()
    V = C @ M @ C
    sd_w = np.sqrt(np.clip(np.diag(V), 0.0, None))
    model = est.model
    std_w = {k: float(s) for k, s in zip(names, sd_w, strict=True)}
    std = {k: float(s * abs(dnat_dwork(est.params_work_[k], model.parameter(k))))
           for k, s in zip(names, sd_w, strict=True)}
    ratio = {k: float(std_w[k] / est.std_work_[k]) for k in names}
    return RobustResult(std=std, std_work=std_w, cov_work=pd.DataFrame(V, index=names, columns=names), lags=L,
                        ratio=ratio)


__all__ = ["Identified", "newey_west_lags", "fd_hessian", "identified_directions", "identified_inverse", "hac_meat",
           "score_matrix", "hessian_sandwich_parts", "hessian_sandwich_sd", "step_nll", "score_contributions",
           "RobustResult", "robust_std"]
