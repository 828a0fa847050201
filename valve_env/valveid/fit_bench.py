"""Speed of the estimator (docs/reference.md, section 6): likelihood evaluations per second and the wall
time of a maximum-likelihood fit of the base valve model on 24 h of 10 s data.

    from valve_env.valveid.fit_bench import run_bench
    run_bench()  # {"estimator_nll_evals_per_s": ..., "estimator_fit_wall_s": ..., ...}

The first call of each compiled kernel is made before timing (numba compiles on first use
and caches on disk); the figures are for a warm process.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

from valve_env.ident.kalman import to_arrays
from valve_env.ident.mle import MLEstimator, negloglik
from valve_env.valveid.valve_model import ValveModel


def _bench_data(seed: int, hours: float) -> Any:
    from valve_env.experiment import simulate_experiment

    df = simulate_experiment(seed=seed, duration_h=hours, dt_s=10.0)
    return df[[c for c in df.columns if not c.startswith("true_")]]


def run_bench(*, seed: int = 0, hours: float = 24.0, min_time_s: float = 1.0, n_starts: int = 1,
              generic: bool = True) -> dict[str, float]:
    """Flat figures: ``estimator_nll_evals_per_s`` (base model, fast kernel),
    ``estimator_fit_wall_s`` (one fit with ``n_starts`` starts and standard errors, including the
    input preparation), ``estimator_fit_nll_evals``, ``estimator_n_samples``,
    ``estimator_prepare_s``, and for the generic compiled EKF (RK4, the path of extended models)
    ``estimator_generic_nll_evals_per_s``."""
    df = _bench_data(seed, hours)
    model = ValveModel()
    t0 = time.perf_counter()
    arr = to_arrays(model, df)
    prep = time.perf_counter() - t0
    p = model.param_vector()
    negloglik(model, p, arr)  # warm-up (compilation / cache load)
    n = 0
    t0 = time.perf_counter()
    while True:
        negloglik(model, p, arr)
        n += 1
        el = time.perf_counter() - t0
        if el >= min_time_s and n >= 5:
            break
    evals_per_s = n / el
    out: dict[str, float] = {
        "estimator_n_samples": float(len(arr.t)),
        "estimator_nll_evals_per_s": float(evals_per_s),
        "estimator_nll_eval_ms": float(1e3 / evals_per_s),
        "estimator_prepare_s": float(prep),
    }
    if generic:
        negloglik(model, p, arr, fast=False)
        m = 0
        t0 = time.perf_counter()
        while True:
            negloglik(model, p, arr, fast=False)
            m += 1
            el = time.perf_counter() - t0
            if el >= min_time_s and m >= 2:
                break
        out["estimator_generic_nll_evals_per_s"] = float(m / el)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        est = MLEstimator(ValveModel(), n_starts=n_starts, seed=seed).fit(df)
        out["estimator_fit_wall_s"] = float(time.perf_counter() - t0)
    out["estimator_fit_nll_evals"] = float(est.n_evals_)
    out["estimator_fit_sigma"] = float(est.params_["sigma"])
    out["estimator_fit_converged"] = float(est.converged_)
    return out


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run_bench(), indent=2))
