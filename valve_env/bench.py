"""``thermovalve bench``: the speed figures of docs/reference.md, section 6, measured in one run.

    thermovalve bench [--json OUT.json] [--quick]

Measures, on this machine and in this process:

* ThermoValve-v0 through ``gym.make`` (PassiveEnvChecker, OrderEnforcing,
  TimeLimit) next to gymnasium's Pendulum-v1 through ``gym.make``, single env,
  random actions from ``action_space.sample()`` drawn in advance the same way
  for both; rounds alternate between the two and the ratio is of the medians;
* the native batched env (``gym.make_vec(id, num_envs=N)``) over N next to
  gymnasium's SyncVectorEnv of the same env; the ratio at N = 1024 and at
  the best N; the reset cost per env and the steady rate including it;
* the peak memory of the batched env at N = 4096 (tracemalloc: the
  Python/NumPy allocations made by construction, reset and 20 steps);
* a year of 30 s steps with the PI baseline (365 daily episodes stepped in
  parallel by the batched env, the PI's batched ``predict``);
* the evidence for the means: the numba kernel against its pure-Python
  ``py_func`` and against NumPy vectorised over envs, threads against the
  serial loop, and numba's on-disk cache against compiling at start-up;
* the identification: the valve estimator's likelihood evaluations and fit (:func:`bench_fit`) and full
  diagnoses of 24 h of 10 s data, bootstrap included (:func:`bench_diagnosis`; target
  :data:`DIAGNOSIS_TARGET_S`).

It prints a markdown table and writes every figure and ratio to ``--json``.
Speed is measured here, never asserted in tests.
"""

from __future__ import annotations

import argparse
import gc
import inspect
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numba import njit

import valve_env  # noqa: F401  (registers the envs)
from valve_env import simulator as sim
from valve_env.envs.vector import ThermoValveVectorEnv
from valve_env.physics.valve import dahl_update, flow_kgh, opening, setpoint_pressure

ENV_ID = "ThermoValve-v0"
SIZES: tuple[int, ...] = (1, 16, 64, 256, 1024, 4096, 16384)
QUICK_SIZES: tuple[int, ...] = (1, 16, 256, 1024, 4096)
YEAR_DAYS = 365
ENV_STEPS_PER_DAY = 2880  # 24 h at the 30 s control step
#: measure the start-up of a fresh interpreter (cached, and compiling in full runs)
MEASURE_STARTUP = True
SYNC_SIZES: tuple[int, ...] = (1, 16, 64, 1024)
QUICK_SYNC_SIZES: tuple[int, ...] = (16, 1024)
MEMORY_N = 4096
EVIDENCE_N = 1024
TARGETS: dict[str, float] = {
    "single_vs_pendulum": 1.0,
    "batched_vs_sync_at_1024": 100.0,
    "best_batched_env_steps_per_s": 5.0e6,
    "pi_year_s": 10.0,
}


# -- machine --------------------------------------------------------------------
def machine() -> dict[str, Any]:
    """CPU model, cores, load and the software versions the figures depend on."""
    import numba

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = list(os.getloadavg())
    except OSError:
        load = []
    return {
        "cpu": cpu,
        "logical_cores": os.cpu_count(),
        "cores_available": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "numba_threads": numba.get_num_threads(),
        "numba_threading_layer": _threading_layer(),
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "unset"),
        "gomp_spincount": os.environ.get("GOMP_SPINCOUNT", "unset"),
        "load_average_1_5_15min": load,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "gymnasium": gym.__version__,
        "valve_env": valve_env.__version__,
    }


def _threading_layer() -> str:
    import numba

    try:
        return str(numba.threading_layer())
    except ValueError:
        return "not initialised"


# -- single env -------------------------------------------------------------------
def _single_rate(env_id: str, actions: list[np.ndarray], env: gym.Env) -> float:
    t0 = time.perf_counter()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    return len(actions) / (time.perf_counter() - t0)


def bench_single(steps: int, rounds: int) -> dict[str, Any]:
    """ThermoValve-v0 vs Pendulum-v1, both through gym.make, alternating rounds."""
    envs: dict[str, gym.Env] = {}
    acts: dict[str, list[np.ndarray]] = {}
    for env_id in (ENV_ID, "Pendulum-v1"):
        env = gym.make(env_id)
        env.reset(seed=0)
        env.action_space.seed(0)
        acts[env_id] = [env.action_space.sample() for _ in range(steps)]
        _single_rate(env_id, acts[env_id][:200], env)  # warm-up (compiled kernel loaded, checker passed)
        envs[env_id] = env
    rates: dict[str, list[float]] = {ENV_ID: [], "Pendulum-v1": []}
    for _ in range(rounds):
        for env_id, env in envs.items():
            rates[env_id].append(_single_rate(env_id, acts[env_id], env))
    tv = statistics.median(rates[ENV_ID])
    pe = statistics.median(rates["Pendulum-v1"])
    return {
        "method": (
            f"gym.make with default wrappers; {steps} steps per round, {rounds} alternating rounds, "
            "actions from action_space.sample() drawn in advance, reset at episode end; medians"
        ),
        "thermovalve_steps_per_s": tv,
        "pendulum_steps_per_s": pe,
        "thermovalve_rounds": rates[ENV_ID],
        "pendulum_rounds": rates["Pendulum-v1"],
        "ratio": tv / pe,
    }


# -- batched and sync vector envs --------------------------------------------------
def _vector_rate(env: gym.vector.VectorEnv, seconds: float, min_steps: int) -> tuple[float, int]:
    """Env-steps per second of ``env.step`` with a pool of random actions, stepping
    only: a step that autoresets envs whose episode ended (at 30 s, every 2880
    steps) is run but not timed. Resets are counted once, by the caller, from
    ``env.reset``'s time (a 1 s window at N = 1024 spans an episode's end, and
    timing its autoreset had cut the N = 1024 figure by a third)."""
    env.action_space.seed(1)
    pool = [env.action_space.sample() for _ in range(4)]
    *_, term, trunc, _ = env.step(pool[0])
    resetting = bool(np.any(term) or np.any(trunc))
    steps = 0
    timed = 0.0
    t0 = time.perf_counter()
    while True:
        t = time.perf_counter()
        *_, term, trunc, _ = env.step(pool[steps % 4])
        if not resetting:
            timed += time.perf_counter() - t
            steps += 1
        resetting = bool(np.any(term) or np.any(trunc))
        if steps >= min_steps and time.perf_counter() - t0 >= seconds:
            break
    return env.num_envs * steps / timed, steps


def bench_batched(sizes: tuple[int, ...], seconds: float) -> list[dict[str, Any]]:
    """The native batched env's env-steps/s over N (stepping, and including the amortised resets)."""
    rows = []
    episode = valve_env.ControlParams().n_steps
    for n in sizes:
        env = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point")
        t0 = time.perf_counter()
        env.reset(seed=0)
        reset_s = time.perf_counter() - t0
        rate, steps = _vector_rate(env, seconds, 20)
        per_env_reset = reset_s / n
        with_resets = 1.0 / (1.0 / rate + per_env_reset / episode)
        rows.append({
            "num_envs": n,
            "env_steps_per_s": rate,
            "steps_timed": steps,
            "reset_s": reset_s,
            "reset_ms_per_env": per_env_reset * 1e3,
            "env_steps_per_s_incl_resets": with_resets,
        })
        env.close()
        del env
        gc.collect()
    return rows


def bench_sync(sizes: tuple[int, ...], seconds: float) -> list[dict[str, Any]]:
    """gymnasium's SyncVectorEnv of the same env (timed briefly: it is slow)."""
    rows = []
    for n in sizes:
        env = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="sync")
        env.reset(seed=0)
        rate, steps = _vector_rate(env, seconds, 5)
        rows.append({"num_envs": n, "env_steps_per_s": rate, "steps_timed": steps})
        env.close()
        del env
        gc.collect()
    return rows


def bench_memory(n: int) -> dict[str, Any]:
    """Peak Python/NumPy allocation (tracemalloc) of the batched env: construction, reset, 20 steps."""
    gc.collect()
    tracemalloc.start()
    env = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    a = np.full((n, 1), 60.0, np.float32)
    for _ in range(20):
        env.step(a)
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    u = env.unwrapped
    assert isinstance(u, ThermoValveVectorEnv)
    state_bytes = sum(
        getattr(u, name).nbytes
        for name in ("_Z", "_OBS", "_K", "_SD", "_CUR", "_NRUN", "_ROW", "_NEXT", "_RK", "_RV", "_E0")
    )
    dense = n * u.n_steps * sim.N_SCEN * 8
    env.close()
    return {
        "num_envs": n,
        "method": "tracemalloc peak over construction + reset(seed) + 20 steps (Python and NumPy allocations; "
        "numba's compiled code and thread pools not included)",
        "peak_MB": peak / 1e6,
        "retained_MB": current / 1e6,
        "env_arrays_MB": state_bytes / 1e6,
        "dense_scenario_MB_avoided": dense / 1e6,
    }


# -- the PI year ---------------------------------------------------------------------
def run_year(policy: Any, env_id: str = ENV_ID, days: int = 365, **env_kwargs: Any) -> dict[str, Any]:
    """Run ``days`` daily episodes in parallel in the batched env with a controller's
    batched SB3 ``predict``; returns the time split and the mean KPIs."""
    env = gym.make_vec(env_id, num_envs=days, vectorization_mode="vector_entry_point", **env_kwargs)
    t0 = time.perf_counter()
    obs, _ = env.reset(seed=2026)
    u = env.unwrapped
    assert isinstance(u, ThermoValveVectorEnv)
    n_steps = u.episode_steps
    state = None
    episode_start = np.ones(days, bool)
    t_env = time.perf_counter() - t0
    t_ctl = 0.0
    kpis: dict[str, np.ndarray] | None = None
    ret = np.zeros(days)
    for _ in range(n_steps):
        t1 = time.perf_counter()
        action, state = policy.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        t2 = time.perf_counter()
        obs, r, term, trunc, info = env.step(action)
        t_env += time.perf_counter() - t2
        t_ctl += t2 - t1
        ret += r
        episode_start = term | trunc
        if "kpis" in info:
            kpis = {k: v for k, v in info["kpis"].items() if not k.startswith("_")}
    env.close()
    total = t_env + t_ctl
    return {
        "episodes": days,
        "env_steps": days * n_steps,
        "seconds": total,
        "env_seconds": t_env,
        "controller_seconds": t_ctl,
        "env_steps_per_s": days * n_steps / total,
        "mean_return": float(ret.mean()),
        "mean_kpis": {k: float(np.nanmean(v)) for k, v in (kpis or {}).items()},
    }


def bench_year(days: int = YEAR_DAYS) -> dict[str, Any]:
    """A year at the 30 s step with the PI baseline (``days`` = 365 parallel daily episodes)."""
    try:
        from valve_env.controllers import make_controller

        policy = make_controller("pi", env_id=ENV_ID)
        name = "pi (valve_env.controllers.make_controller)"
    except Exception as exc:  # the baselines are another engineer's module
        return {"not available": f"PI baseline: {type(exc).__name__}: {exc}"}
    out = run_year(policy, days=days)
    out["controller"] = name
    out["how"] = (
        f"{days} daily episodes (the registered 24 h, seeds 2026..{2026 + days - 1}) stepped together by the "
        "batched env, actions from the PI's batched predict; reset included"
    )
    return out


# -- evidence for the means -------------------------------------------------------------
def _kernel_inputs() -> tuple[Any, ...]:
    """A block of one env (its state after reset, a fixed scenario row) for ``plant_step``."""
    from valve_env.envs.thermovalve import ThermoValveEnv

    env = ThermoValveEnv()
    env.reset(seed=0)
    ns = env._s.shape[0]
    Z = np.zeros((sim.block_rows(env.cfg.tank.n_layers), 1))
    Z[:ns, 0] = env._s
    sim.load_inputs(Z, 0, ns, env._scen[0], 62.0, 100.0)
    return Z, env._vp, env._pp


def bench_evidence(quick: bool) -> dict[str, Any]:
    """The jitted kernel vs its pure-Python py_func and vs NumPy vectorised over envs;
    threads vs the serial loop; numba's on-disk cache vs compiling at start-up."""
    Z, vp, pp = _kernel_inputs()
    ev: dict[str, Any] = {}
    # 1. numba vs the same source run by the Python interpreter (physics as plain NumPy),
    #    one env (a block of one column) per call
    n_py = 30 if quick else 100
    t0 = time.perf_counter()
    for _ in range(n_py):
        sim.plant_step.py_func(Z, 0, 1, vp, pp)
    py_us = (time.perf_counter() - t0) / n_py * 1e6
    Z, vp, pp = _kernel_inputs()
    n_jit = 20000
    t0 = time.perf_counter()
    for _ in range(n_jit):
        sim.plant_step(Z, 0, 1, vp, pp)
    jit_us = (time.perf_counter() - t0) / n_jit * 1e6
    ev["kernel_step_us"] = {
        "numba_jit_call_from_python": jit_us,
        "pure_python_py_func": py_us,
        "speedup": py_us / jit_us,
    }
    # 2. the same valve functions over a batch: a numba loop (scalar libm) vs NumPy on arrays
    #    (SIMD ufuncs), per env-step (setpoint + 3 sub-steps of Dahl, opening, flow)
    ev["numpy_vs_numba_valve_part"] = [_valve_part(n, vp) for n in (64, EVIDENCE_N)]
    # 3. the whole batched step: numba's threads vs its serial loop
    n = EVIDENCE_N
    env = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    a = np.full((n, 1), 60.0, np.float32)
    # interleaved rounds, medians: a single timing of 30 steps (about 10 ms) was too short to read
    reps, rounds = 60, 7
    per: dict[str, list[float]] = {"serial": [], "threads": []}
    for _ in range(rounds):
        for label, thr in (("serial", 10**9), ("threads", 1)):
            env.unwrapped.parallel_threshold = thr  # type: ignore[attr-defined]
            env.step(a)
            t0 = time.perf_counter()
            for _ in range(reps):
                env.step(a)
            per[label].append(n * reps / (time.perf_counter() - t0))
    rates = {label: float(np.median(v)) for label, v in per.items()}
    env.close()
    ev["threads_vs_serial"] = {
        "num_envs": n,
        "serial_env_steps_per_s": rates["serial"],
        "threads_env_steps_per_s": rates["threads"],
        "serial_ns_per_env_step": 1e9 / rates["serial"],
        "ratio": rates["threads"] / rates["serial"],
    }
    # 4. the sub-steps: the default 3 against a fine reference
    ev["substeps"] = bench_substeps()
    # 5. numba's on-disk cache: a fresh interpreter building and stepping an env
    code = (
        "import time; t=time.perf_counter(); import gymnasium as gym, valve_env; "
        "e=gym.make('ThermoValve-v0'); e.reset(seed=0); e.step(e.action_space.sample()); "
        "v=gym.make_vec('ThermoValve-v0', num_envs=64); v.reset(seed=0); v.step(v.action_space.sample()); "
        "print(time.perf_counter()-t)"
    )
    if not MEASURE_STARTUP:
        ev["startup_s"] = {"cached": "not measured", "compiled_without_cache": "not measured"}
    elif quick:
        ev["startup_s"] = {"cached": _startup(code, None)}
        ev["startup_s"]["compiled_without_cache"] = "skipped in --quick"
    else:
        ev["startup_s"] = {"cached": _startup(code, None)}
        with tempfile.TemporaryDirectory() as tmp:
            ev["startup_s"]["compiled_without_cache"] = _startup(code, tmp)
    return ev


def bench_substeps(n_subs: tuple[int, ...] = (1, 3, 10), ref: int = 60) -> list[dict[str, Any]]:
    """Discretisation error of the plant's sub-steps (``control.n_sub``) against a
    fine reference: one default day (seed 0) at a fixed setting of 60 degC."""
    runs: dict[int, tuple[np.ndarray, dict[str, float], float]] = {}
    for n_sub in (*n_subs, ref):
        env = gym.make(ENV_ID, control={"n_sub": n_sub})
        env.reset(seed=0)
        a = np.array([60.0], np.float32)
        T_top = np.empty(ENV_STEPS_PER_DAY)
        t0 = time.perf_counter()
        for k in range(ENV_STEPS_PER_DAY):
            obs, _, _, _, info = env.step(a)
            T_top[k] = obs[0]
        runs[n_sub] = (T_top, info["kpis"], time.perf_counter() - t0)
        env.close()
    T_ref, k_ref, _ = runs[ref]
    return [
        {
            "n_sub": n,
            "reference_n_sub": ref,
            "max_abs_dT_top_K": float(np.max(np.abs(T - T_ref))),
            "rms_dT_top_K": float(np.sqrt(np.mean((T - T_ref) ** 2))),
            "heat_rel_error": abs(kp["heat_kWh"] - k_ref["heat_kWh"]) / k_ref["heat_kWh"],
            "rmse_K": kp["rmse_K"],
            "rmse_K_reference": k_ref["rmse_K"],
            "day_s": secs,
        }
        for n, (T, kp, secs) in runs.items()
        if n != ref
    ]


@njit(cache=True)
def _valve_loop(T_g, F_h, dp, T_set, dT, vp, q):  # type: ignore[no-untyped-def]
    for i in range(T_g.shape[0]):
        p_bset = setpoint_pressure(T_set[i], vp)
        F = F_h[i]
        for j in range(3):
            F = dahl_update(F, dT[j, i], vp)
            x = opening(T_g[i] + dT[j, i], F, dp[i], 2.0, p_bset, vp)
            q[i] = flow_kgh(x, dp[i], vp)
        F_h[i] = F


def _valve_part(n: int, vp: np.ndarray) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    T_g = 55.0 + rng.uniform(-1.0, 1.0, n)
    F_h = np.zeros(n)
    dp = np.full(n, 100.0)
    T_set = np.full(n, 62.0)
    dT = rng.normal(0.0, 0.01, (3, n))
    q = np.zeros(n)
    _valve_loop(T_g, F_h, dp, T_set, dT, vp, q)
    reps = max(20, 100_000 // n)
    t0 = time.perf_counter()
    for _ in range(reps):
        _valve_loop(T_g, F_h, dp, T_set, dT, vp, q)
    t_nb = (time.perf_counter() - t0) / reps / n * 1e9
    t0 = time.perf_counter()
    for _ in range(reps):
        p_bset = setpoint_pressure(T_set, vp)
        F = F_h
        for j in range(3):
            F = dahl_update(F, dT[j], vp)
            x = opening(T_g + dT[j], F, dp, 2.0, p_bset, vp)
            flow_kgh(x, dp, vp)
    t_np = (time.perf_counter() - t0) / reps / n * 1e9
    return {"num_envs": n, "numba_loop_ns_per_env_step": t_nb, "numpy_arrays_ns_per_env_step": t_np,
            "numpy_over_numba": t_np / t_nb}


def _startup(code: str, cache_dir: str | None) -> float | str:
    envv = dict(os.environ)
    if cache_dir is not None:
        envv["NUMBA_CACHE_DIR"] = cache_dir  # an empty cache: everything compiles
    try:
        res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=envv, timeout=600)
    except subprocess.TimeoutExpired:
        return "timed out after 600 s"
    if res.returncode != 0:
        return f"failed: {res.stderr.strip().splitlines()[-1] if res.stderr.strip() else res.returncode}"
    return float(res.stdout.strip().splitlines()[-1])


# -- the identification's figures --------------------------------------------------------------
def _fit_data(seed: int, hours: float) -> Any:
    from valve_env.experiment import simulate_experiment

    df = simulate_experiment(seed=seed, duration_h=hours, dt_s=10.0)
    return df[[c for c in df.columns if not c.startswith("true_")]]


def bench_fit(*, seed: int = 0, hours: float = 24.0, min_time_s: float = 1.0, n_starts: int = 1,
              generic: bool = True) -> dict[str, float]:
    """Flat figures: ``estimator_nll_evals_per_s`` (base model, fast kernel),
    ``estimator_fit_wall_s`` (one fit with ``n_starts`` starts and standard errors, including the
    input preparation), ``estimator_fit_nll_evals``, ``estimator_n_samples``,
    ``estimator_prepare_s``, and for the generic compiled EKF (RK4, the path of extended models)
    ``estimator_generic_nll_evals_per_s``."""
    from valve_env.ident.kalman import to_arrays
    from valve_env.ident.mle import MLEstimator, negloglik
    from valve_env.valveid.valve_model import ValveModel

    df = _fit_data(seed, hours)
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


#: the target wall time of one diagnosis of 24 h at 10 s, bootstrap included (docs/diagnosis.md, "Speed")
DIAGNOSIS_TARGET_S = 30.0


def default_bootstrap_b() -> int:
    """The bootstrap size ``diagnose`` uses by default (read from its signature, so it cannot drift)."""
    from valve_env.valveid.diagnose import diagnose

    return int(inspect.signature(diagnose).parameters["bootstrap_B"].default)

DIAGNOSIS_CASES: dict[str, dict[str, dict[str, float]]] = {
    "none": {},
    "sensor_lag": {"sensor_lag": {"tau_s": 60.0}},
    "stiction": {"stiction": {"band_mm": 0.02}},
}


def bench_diagnosis(hours: float = 24.0, dt_s: float = 10.0, seed: int = 2024,
              cases: dict[str, dict[str, dict[str, float]]] | None = None,
              bootstrap_B: int | None = None) -> dict[str, Any]:
    """Time full diagnoses (all candidates, hold-out validation, forward selection) of generated runs.

    One run per case: no effect (the cheapest: forward selection stops at once), a sensor lag (a
    second selection step) and stiction (the slowest likelihood). ``diagnosis_wall_s`` is the
    slowest of them. Numba compilation is done (and timed) first, separately. ``bootstrap_B``: the
    bootstrap replicates of the named effects' sd (default: ``diagnose``'s default)."""
    from valve_env.experiment import simulate_experiment
    from valve_env.valveid.diagnose import diagnose

    cases = DIAGNOSIS_CASES if cases is None else cases
    B = default_bootstrap_b() if bootstrap_B is None else int(bootstrap_B)
    t0 = time.perf_counter()
    warm = simulate_experiment(seed=seed + 1, duration_h=3.0, dt_s=dt_s,
                               effects={"stiction": {"band_mm": 0.02}, "sensor_lag": {"tau_s": 30.0}})
    diagnose(warm, max_effects=1)
    compile_s = time.perf_counter() - t0
    per_case: dict[str, Any] = {}
    n = 0
    for name, effects in cases.items():
        df = simulate_experiment(seed=seed, duration_h=hours, dt_s=dt_s, effects=effects or None)
        n = len(df)
        t1, c1 = time.perf_counter(), time.process_time()
        d = diagnose(df, bootstrap_B=B)
        wall, cpu = time.perf_counter() - t1, time.process_time() - c1
        per_case[name] = {"wall_s": wall, "cpu_s": cpu, "cause": d.cause, "selected": list(d.selected),
                          "fits": int(1 + sum(len(s) for s in d.steps)),
                          "bootstraps": int(sum(1 for s in d.steps if s and s[0].accepted)) if B > 0 else 0}
    worst = max((c["wall_s"] for c in per_case.values()), default=float("nan"))
    # the CPU seconds of this process: what the wall time is on a core of its own (the machine is shared)
    worst_cpu = max((c["cpu_s"] for c in per_case.values()), default=float("nan"))
    return {
        "diagnosis_wall_s": worst,
        "diagnosis_cpu_s": worst_cpu,
        "diagnosis_target_s": DIAGNOSIS_TARGET_S,
        "diagnosis_within_target": bool(worst <= DIAGNOSIS_TARGET_S),
        "bootstrap_B": B,
        "diagnosis_cases": per_case,
        "samples": int(n),
        "hours": hours,
        "dt_s": dt_s,
        "candidates": 4,
        "warmup_compile_s": compile_s,
        "numpy": np.__version__,
    }



def _guarded(fn: Callable[[], Any]) -> dict[str, Any]:
    try:
        result = fn()
    except Exception as exc:
        return {"not available": f"{fn.__name__}(): {type(exc).__name__}: {exc}"}
    return result if isinstance(result, dict) else {"result": result}


# -- the whole run ---------------------------------------------------------------------------
def run_bench(quick: bool = False, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every figure of docs/reference.md, section 6 and docs/speed.md, "The latest run", measured in this process."""
    say = progress or (lambda _m: None)
    res: dict[str, Any] = {"quick": quick, "machine": machine()}
    t_start = time.perf_counter()
    say("single env vs Pendulum-v1")
    res["single_env"] = bench_single(steps=5000 if quick else 20000, rounds=3 if quick else 5)
    say("batched env over N")
    res["batched"] = bench_batched(QUICK_SIZES if quick else SIZES, seconds=0.2 if quick else 1.5)
    say("SyncVectorEnv")
    res["sync"] = bench_sync(QUICK_SYNC_SIZES if quick else SYNC_SIZES, seconds=0.5 if quick else 1.5)
    say(f"memory at N = {MEMORY_N}")
    res["memory"] = bench_memory(MEMORY_N)
    say("PI year")
    res["pi_year"] = bench_year(YEAR_DAYS)
    say("evidence for the means")
    res["evidence"] = bench_evidence(quick)
    say("estimator and diagnosis")
    res["estimation"] = _guarded(bench_fit)
    res["diagnosis"] = _guarded(bench_diagnosis)
    best = max(res["batched"], key=lambda r: r["env_steps_per_s"])
    native = {r["num_envs"]: r for r in res["batched"]}
    sync = {r["num_envs"]: r for r in res["sync"]}
    ratios: dict[str, Any] = {"single_vs_pendulum": res["single_env"]["ratio"]}
    if 1024 in native and 1024 in sync:
        ratios["batched_vs_sync_at_1024"] = native[1024]["env_steps_per_s"] / sync[1024]["env_steps_per_s"]
        ratios["best_batched_vs_sync_at_1024"] = best["env_steps_per_s"] / sync[1024]["env_steps_per_s"]
    for n_ in sorted(set(native) & set(sync)):
        ratios[f"batched_vs_sync_at_{n_}"] = native[n_]["env_steps_per_s"] / sync[n_]["env_steps_per_s"]
    res["best_batched"] = {"num_envs": best["num_envs"], "env_steps_per_s": best["env_steps_per_s"],
                           "env_steps_per_s_incl_resets": best["env_steps_per_s_incl_resets"]}
    res["ratios"] = ratios
    year_s = res["pi_year"].get("seconds")
    res["targets"] = {
        "single_vs_pendulum": {"target": TARGETS["single_vs_pendulum"], "measured": ratios["single_vs_pendulum"]},
        "batched_vs_sync_at_1024": {
            "target": TARGETS["batched_vs_sync_at_1024"], "measured": ratios.get("batched_vs_sync_at_1024")},
        "best_batched_env_steps_per_s": {
            "target": TARGETS["best_batched_env_steps_per_s"], "measured": best["env_steps_per_s"]},
        "pi_year_s": {"target": TARGETS["pi_year_s"], "measured": year_s, "lower_is_better": True},
    }
    for t in res["targets"].values():
        m = t["measured"]
        t["met"] = None if m is None else (m <= t["target"] if t.get("lower_is_better") else m >= t["target"])
    res["wall_s"] = time.perf_counter() - t_start
    return res


def _fmt(x: Any, digits: int = 3) -> str:
    if isinstance(x, (int, float)) and not isinstance(x, bool):
        if abs(x) >= 1e4:
            return f"{x:,.0f}"
        return f"{x:.{digits}g}"
    return str(x)


def markdown(res: dict[str, Any]) -> str:
    """The figures as markdown tables (what docs/speed.md and the README show)."""
    m = res["machine"]
    lines = [
        f"Machine: {m['cpu']}, {m['cores_available']} cores available (numba threads {m['numba_threads']}, "
        f"{m['numba_threading_layer']}, OMP_WAIT_POLICY {m.get('omp_wait_policy', 'unset')}, "
        f"GOMP_SPINCOUNT {m.get('gomp_spincount', 'unset')}), "
        f"load average {', '.join(f'{v:.1f}' for v in m['load_average_1_5_15min'])}; "
        f"Python {m['python']}, NumPy {m['numpy']}, numba {m['numba']}, gymnasium {m['gymnasium']}"
        + (" (--quick)" if res["quick"] else ""),
        "",
        "| figure | measured | target | met |",
        "|---|---|---|---|",
    ]
    s = res["single_env"]
    t = res["targets"]
    lines.append(f"| ThermoValve-v0 steps/s (gym.make, single) | {_fmt(s['thermovalve_steps_per_s'])} | | |")
    lines.append(f"| Pendulum-v1 steps/s (gym.make, single) | {_fmt(s['pendulum_steps_per_s'])} | | |")
    lines.append(f"| ratio ThermoValve / Pendulum | {_fmt(s['ratio'])} | >= 1 | {t['single_vs_pendulum']['met']} |")
    r = res["ratios"]
    if "batched_vs_sync_at_1024" in r:
        lines.append(f"| batched / SyncVectorEnv at N = 1024 | {_fmt(r['batched_vs_sync_at_1024'])} | >= 100 | "
                     f"{t['batched_vs_sync_at_1024']['met']} |")
    b = res["best_batched"]
    lines.append(f"| best batched env-steps/s (N = {b['num_envs']}) | {_fmt(b['env_steps_per_s'])} | >= 5,000,000 | "
                 f"{t['best_batched_env_steps_per_s']['met']} |")
    lines.append(f"| best batched env-steps/s incl. amortised resets | {_fmt(b['env_steps_per_s_incl_resets'])} | | |")
    y = res["pi_year"]
    if "seconds" in y:
        lines.append(f"| PI year: {y['env_steps']:,} env-steps, 365 parallel days, s | {_fmt(y['seconds'])} "
                     f"(env {_fmt(y['env_seconds'])}, PI {_fmt(y['controller_seconds'])}) | < 10 | "
                     f"{t['pi_year_s']['met']} |")
    else:
        lines.append(f"| PI year | {y.get('not available')} | < 10 | |")
    mem = res["memory"]
    lines.append(f"| batched env peak memory at N = {mem['num_envs']} (tracemalloc), MB | {_fmt(mem['peak_MB'])} | "
                 "report | |")
    lines += ["", "| N | batched env-steps/s | incl. resets | reset ms/env | SyncVectorEnv env-steps/s | ratio |",
              "|---|---|---|---|---|---|"]
    sync = {row["num_envs"]: row for row in res["sync"]}
    for row in res["batched"]:
        n = row["num_envs"]
        sy = sync.get(n)
        lines.append(
            f"| {n} | {_fmt(row['env_steps_per_s'])} | {_fmt(row['env_steps_per_s_incl_resets'])} | "
            f"{_fmt(row['reset_ms_per_env'])} | {_fmt(sy['env_steps_per_s']) if sy else ''} | "
            f"{_fmt(row['env_steps_per_s'] / sy['env_steps_per_s']) if sy else ''} |"
        )
    ev = res["evidence"]
    k = ev["kernel_step_us"]
    th = ev["threads_vs_serial"]
    st = ev["startup_s"]
    lines += [
        "",
        "| evidence | figure |",
        "|---|---|",
        f"| plant_step, numba (one call from Python), us/step | {_fmt(k['numba_jit_call_from_python'])} |",
        f"| plant_step.py_func (same source, interpreted, physics as NumPy scalars), us/step | "
        f"{_fmt(k['pure_python_py_func'])} ({_fmt(k['speedup'])}x the numba time) |",
    ]
    for v in ev["numpy_vs_numba_valve_part"]:
        lines.append(
            f"| valve functions over N = {v['num_envs']}: numba loop / NumPy arrays, ns/env-step | "
            f"{_fmt(v['numba_loop_ns_per_env_step'])} / {_fmt(v['numpy_arrays_ns_per_env_step'])} |"
        )
    lines += [
        f"| whole batched step at N = {th['num_envs']}, serial loop, ns/env-step | "
        f"{_fmt(th['serial_ns_per_env_step'])} |",
        f"| threads / serial at N = {th['num_envs']} | {_fmt(th['ratio'])} |",
    ]
    for v in ev.get("substeps", []):
        lines.append(
            f"| n_sub = {v['n_sub']} vs {v['reference_n_sub']} over a day (fixed setting 60 degC): "
            f"max / rms error of T_top, K; heat error | {_fmt(v['max_abs_dT_top_K'])} / {_fmt(v['rms_dT_top_K'])}; "
            f"{100 * v['heat_rel_error']:.2f} % |"
        )
    lines += [
        f"| start-up (import, make, reset, step; single and N = 64), cached, s | {_fmt(st['cached'])} |",
        f"| start-up, compiling (empty NUMBA_CACHE_DIR), s | {_fmt(st.get('compiled_without_cache'))} |",
    ]
    est, dg = res["estimation"], res["diagnosis"]
    if "not available" in est or "not available" in dg:
        for key, val in (("estimation", est), ("diagnosis", dg)):
            if "not available" in val:
                lines.append(f"| {key} | not available: {val['not available']} |")
        return "\n".join(lines)
    lines += [
        "",
        f"| estimator and diagnosis ({dg['hours']:g} h of {dg['dt_s']:g} s data, {dg['samples']} samples) "
        "| measured | target | met |",
        "|---|---|---|---|",
        f"| base valve model: likelihood evaluations per second | {_fmt(est['estimator_nll_evals_per_s'])} | | |",
        f"| base valve model: wall time of a maximum-likelihood fit, s | {_fmt(est['estimator_fit_wall_s'])} "
        f"| < 2 | {est['estimator_fit_wall_s'] < 2.0} |",
        f"| diagnosis with all four candidates and the bootstrap, slowest case, s | {_fmt(dg['diagnosis_wall_s'])} "
        f"| <= {dg['diagnosis_target_s']:g} (B = {dg.get('bootstrap_B', '?')}) | {dg['diagnosis_within_target']} |",
    ]
    return "\n".join(lines)


def _cmd(args: argparse.Namespace) -> int:
    from valve_env.outputs import OutputSet, json_text

    outs = OutputSet(force=args.force)
    json_out = outs.add(args.json, "--json") if args.json else None  # checked before the long run
    res = run_bench(quick=args.quick, progress=lambda m: print(f"bench: {m} ...", file=sys.stderr, flush=True))
    print(markdown(res))
    if json_out is not None:
        with outs:
            outs.write_text(json_out, json_text(res, default=_jsonable))
    print(outs.summary())
    return 0



def _jsonable(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def register(subparsers: Any) -> None:
    """Add ``thermovalve bench`` to the CLI."""
    p = subparsers.add_parser(
        "bench",
        help="measure speed: the simulator against gymnasium's anchors, the estimator, the diagnosis "
             "(docs/reference.md, section 6)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", metavar="OUT.json", help="write every figure and ratio to this file")
    p.add_argument("--quick", action="store_true", help="shorter timings and fewer N (a smoke run, noisier)")
    p.add_argument("--force", action="store_true", help="replace an existing --json")
    p.set_defaults(func=_cmd)
