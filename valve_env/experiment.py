"""Synthetic measured runs like the seed paper's experiment (docs/reference.md, sections 2 and 3).

The valve sits in a small water tank. The tank temperature follows steps of
varying size and speed (first-order tank heat dynamics, so it moves smoothly):
a spread of slow and fast ramps around the set point so that the valve goes
both closed and nearly fully open and the hysteresis loop is excited in both
directions, including small inner loops. The differential and static pressures
are held constant (100 mbar, 2 bar) and the temperature of the water through
the valve, ``T_med``, follows its own, independent steps and ramps.

The valve opening comes from the force balance of docs/reference.md, section 1 with Dahl
friction driven by the gas temperature, integrated on a fine internal grid
(the Dahl update is exact for each monotone increment of ``T_g``). The flow
comes from the valve characteristic. White noise is added to the temperature
channels (``T_noise_C``) and to the opening (``x_noise_mm``); q, dp and ps
carry optional relative noise.

The named effects (docs/reference.md, "Named effects"; declared in :mod:`valve_env.effects`) are
switched on by name with their parameters; the valve's trajectory is
:func:`valve_env.physics.trajectory.valve_path`, the same physics as the environments':

| effect | parameters | what the generator does |
|---|---|---|
| sensor_lag | tau_s (s) | tau dT_g/dt = T_env - T_g (bulb heat dynamics) |
| medium_temperature | beta (-) | T_env = T_tank + beta (T_med - T_tank) (the medium heats the sensor) |
| stiction | band_mm, jump_mm (mm) | the (S, J) stick-slip of the stem (physics.stickslip, see below) |
| setpoint_drift | rate_MPa_per_h (MPa/h) | p_b,set(t) = p_b,set + rate t (charge ageing) |

Without sensor_lag ``T_g = T_env``; without medium_temperature ``T_env = T_tank``. With stiction
the resting stem sticks until the demanded opening has moved band_mm away, slips, follows the
demand, and sticks again where the demand stops or reverses.
Everything is seeded with a :class:`numpy.random.Generator` and deterministic.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from concurrent.futures import ProcessPoolExecutor
from contextlib import ExitStack
from typing import Any

import numpy as np
import pandas as pd

from valve_env import effects as _effects
from valve_env.params import ConfigError, ValveParams
from valve_env.physics.trajectory import valve_path
from valve_env.physics.valve import flow_kgh, setpoint_temperature

try:  # numba compiles the fine-grid kernel; the same source runs as plain Python without it
    from numba import njit as _njit

    def _jit(fn: Any) -> Any:
        return _njit(cache=True)(fn)
except ImportError:  # pragma: no cover - numba is a declared dependency

    def _jit(fn: Any) -> Any:
        return fn


#: Effect names and their parameters with their valid ranges (from the registry, valve_env.effects).
EFFECTS: dict[str, dict[str, tuple[float, float]]] = {
    name: {p.name: (p.lower, p.upper) for p in eff.all_parameters} for name, eff in _effects.REGISTRY.items()
}

#: Default options of :func:`simulate_experiment` (all may be overridden by keyword).
DEFAULT_OPTIONS: dict[str, float] = {
    "dp_mbar": 100.0,  # constant differential pressure across the valve, mbar
    "ps_bar": 2.0,  # constant static pressure, bar
    "q_noise_rel": 0.001,  # relative white noise on q_kgh
    "dp_noise_rel": 0.001,  # relative white noise on dp_mbar
    "ps_noise_rel": 0.001,  # relative white noise on ps_bar
    "jitter": 0.0,  # uneven sampling: each sample time moves by U(-jitter, jitter) * dt_s (jitter < 0.5)
    "fine_dt_s": 1.0,  # largest internal integration step, s
    "F_noise": 0.0,  # process noise intensity on the friction force, N / sqrt(s) (paper eq. 15 dw)
    "T_low_C": -13.0,  # lowest tank target relative to the set point (valve nearly fully open), K
    "T_high_C": 4.0,  # highest tank target relative to the set point (valve closed), K
    "seg_min_min": 25.0,  # shortest tank step, min
    "seg_max_min": 110.0,  # longest tank step, min
    "tau_tank_min_min": 3.0,  # fastest tank time constant (fast ramps), min
    "tau_tank_max_min": 30.0,  # slowest tank time constant (slow ramps), min
    "T_med_low_C": 45.0,  # lowest medium temperature target, degC
    "T_med_high_C": 75.0,  # highest medium temperature target, degC
    "med_seg_min_min": 15.0,  # shortest medium step, min
    "med_seg_max_min": 80.0,  # longest medium step, min
    "tau_med_min_min": 1.0,  # fastest medium time constant, min
    "tau_med_max_min": 12.0,  # slowest medium time constant, min
}

COLUMNS: tuple[str, ...] = ("time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm")


def _check_effects(effects: Mapping[str, Mapping[str, float]] | None) -> dict[str, dict[str, float]]:
    """The effects checked against the registry (ConfigError naming an unknown effect or parameter, a
    missing, non-numeric or out-of-range value); every identified parameter must be given."""
    out: dict[str, dict[str, float]] = {}
    for name, pars in (effects or {}).items():
        out[name] = _effects.check_parameters(name, pars, where="effect", fill_defaults=False)
    return out


def _segments(
    rng: np.random.Generator, t_end: float, lo: float, hi: float, seg_lo: float, seg_hi: float,
    tau_lo: float, tau_hi: float, start: float, alternate: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Piecewise-constant targets: (start times s, target values, time constants s)."""
    starts: list[float] = []
    targets: list[float] = []
    taus: list[float] = []
    t = 0.0
    cur = start
    up = bool(rng.integers(2))
    while t < t_end:
        if alternate:
            # alternate direction; a mix of large swings and small inner loops
            room = (hi - cur) if up else (cur - lo)
            if rng.random() < 0.3:
                amp = rng.uniform(0.3, 2.0)
            else:
                amp = rng.uniform(0.3, 1.0) * room
            amp = min(max(amp, 0.2), max(room, 0.2))
            cur = float(np.clip(cur + amp if up else cur - amp, lo, hi))
            up = not up
        else:
            cur = float(rng.uniform(lo, hi))
        starts.append(t)
        targets.append(cur)
        taus.append(float(math.exp(rng.uniform(math.log(tau_lo), math.log(tau_hi)))))
        t += float(rng.uniform(seg_lo, seg_hi))
    return np.array(starts), np.array(targets), np.array(taus)


@_jit
def _first_order_profile(t_fine: np.ndarray, starts: np.ndarray, targets: np.ndarray, taus: np.ndarray,
                         y0: float) -> np.ndarray:  # pragma: no cover - compiled
    n = t_fine.shape[0]
    y = np.empty(n)
    y[0] = y0
    j = 0
    for i in range(1, n):
        while j + 1 < starts.shape[0] and t_fine[i - 1] >= starts[j + 1]:
            j += 1
        h = t_fine[i] - t_fine[i - 1]
        y[i] = targets[j] + (y[i - 1] - targets[j]) * math.exp(-h / taus[j])
    return y


_valve_path = _jit(valve_path)


def simulate_experiment(
    *,
    seed: int,
    duration_h: float = 24.0,
    dt_s: float = 10.0,
    effects: dict[str, dict[str, float]] | None = None,
    valve: ValveParams = ValveParams(),  # noqa: B008 - frozen dataclass, immutable default
    T_noise_C: float = 0.01,
    x_noise_mm: float = 2.4e-3,
    **options: float,
) -> pd.DataFrame:
    """Simulate a measured run like the paper's experiment.

    Returns a DataFrame with the docs/reference.md, section 2 columns ``time_s, T_tank_C,
    T_med_C, q_kgh, dp_mbar, ps_bar, x_mm`` and the latent truth
    ``true_T_tank_C, true_T_med_C, true_T_g_C, true_F_h_N, true_x_mm``.

    ``effects`` maps effect names (docs/reference.md, section 3) to their parameters, e.g.
    ``{"sensor_lag": {"tau_s": 60.0}}``. ``options`` override
    :data:`DEFAULT_OPTIONS` (``jitter`` for uneven sampling, noise levels,
    pressures, the shape of the temperature programme). Raises
    :class:`~valve_env.params.ConfigError` naming a bad argument.
    """
    unknown = sorted(set(options) - set(DEFAULT_OPTIONS))
    if unknown:
        raise ConfigError(f"unknown option(s) {unknown}; known: {sorted(DEFAULT_OPTIONS)}")
    opt = {**DEFAULT_OPTIONS, **{k: float(v) for k, v in options.items()}}
    for name, val in (("duration_h", duration_h), ("dt_s", dt_s), ("fine_dt_s", opt["fine_dt_s"])):
        if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
            raise ConfigError(f"{name} must be a positive number, got {val!r}")
    for name, val in (("T_noise_C", T_noise_C), ("x_noise_mm", x_noise_mm), ("q_noise_rel", opt["q_noise_rel"]),
                      ("dp_noise_rel", opt["dp_noise_rel"]), ("ps_noise_rel", opt["ps_noise_rel"]),
                      ("F_noise", opt["F_noise"])):
        if not (math.isfinite(val) and val >= 0):
            raise ConfigError(f"{name} must be >= 0, got {val!r}")
    if not 0.0 <= opt["jitter"] < 0.5:
        raise ConfigError(f"jitter must be in [0, 0.5), got {opt['jitter']!r}")
    if duration_h * 3600.0 < 3.0 * dt_s:
        raise ConfigError(f"duration_h={duration_h!r} gives fewer than 3 samples at dt_s={dt_s!r}")
    eff = _check_effects(effects)
    if not isinstance(valve, ValveParams):
        raise ConfigError(f"valve must be a ValveParams, got {type(valve).__name__}")

    rng = np.random.default_rng(seed)
    vp = valve.to_array()
    t_end = duration_h * 3600.0
    T_sp = float(setpoint_temperature(valve.p_bset, vp))

    # sample times (optionally jittered, always strictly increasing)
    n = int(math.floor(t_end / dt_s + 1e-9)) + 1
    n_steps = t_end / min(dt_s, opt["fine_dt_s"])
    if n_steps > 5e7:
        raise ConfigError(f"duration_h={duration_h!r} needs {n_steps:.3g} internal steps; at most 5e7 "
                          "(shorten the run or raise fine_dt_s)")
    t_s = np.arange(n) * dt_s
    if opt["jitter"] > 0:
        t_s = t_s + rng.uniform(-opt["jitter"], opt["jitter"], n) * dt_s
        t_s[0] = 0.0
        t_s = np.clip(t_s, 0.0, t_end)
        t_s = np.maximum.accumulate(t_s)
        bad = np.diff(t_s) <= 0
        if bad.any():  # pragma: no cover - jitter < 0.5 keeps the order
            raise ConfigError("jitter produced non-increasing time stamps")
    # fine internal grid
    sub = max(1, int(math.ceil(dt_s / opt["fine_dt_s"])))
    h = dt_s / sub
    n_fine = int(math.ceil(t_end / h)) + 2
    t_fine = np.arange(n_fine) * h

    # tank temperature: steps of varying size and speed around the set point
    lo, hi = T_sp + opt["T_low_C"], T_sp + opt["T_high_C"]
    T0 = float(rng.uniform(T_sp - 6.0, T_sp + 2.0))
    st, tg, ta = _segments(rng, t_end + h, lo, hi, opt["seg_min_min"] * 60, opt["seg_max_min"] * 60,
                           opt["tau_tank_min_min"] * 60, opt["tau_tank_max_min"] * 60, T0, True)
    T_tank = _first_order_profile(t_fine, st, tg, ta, T0)
    # medium temperature: independent steps and ramps
    M0 = float(rng.uniform(opt["T_med_low_C"], opt["T_med_high_C"]))
    sm, mg, ma = _segments(rng, t_end + h, opt["T_med_low_C"], opt["T_med_high_C"], opt["med_seg_min_min"] * 60,
                           opt["med_seg_max_min"] * 60, opt["tau_med_min_min"] * 60, opt["tau_med_max_min"] * 60,
                           M0, False)
    T_med = _first_order_profile(t_fine, sm, mg, ma, M0)

    e = _effects.parse_effects(eff, where="effects").vector()
    band = e[_effects.ENGINE_INDEX["band_mm"]]
    dW = rng.standard_normal(n_fine) * math.sqrt(h)
    path = _valve_path(t_fine, T_tank, T_med, np.full(n_fine, opt["dp_mbar"]), np.full(n_fine, opt["ps_bar"]),
                       valve.p_bset, e, vp, False, opt["F_noise"], dW, np.empty((5, n_fine)))
    Tg, F, x = path[0], path[1], path[2]

    def at(y: np.ndarray) -> np.ndarray:
        return np.interp(t_s, t_fine, y)

    if band > 0:  # the stem sticks and slips: sample it, do not interpolate across a slip
        idx = np.minimum(np.searchsorted(t_fine, t_s + 1e-9 * h, side="right") - 1, n_fine - 1)
        x_true = x[idx]
    else:
        x_true = at(x)
    T_tank_s, T_med_s = at(T_tank), at(T_med)
    dp_true = np.full(n, opt["dp_mbar"])
    ps_true = np.full(n, opt["ps_bar"])
    q_true = flow_kgh(x_true, dp_true, vp)
    noise = rng.standard_normal((6, n))
    df = pd.DataFrame(
        {
            "time_s": t_s,
            "T_tank_C": T_tank_s + T_noise_C * noise[0],
            "T_med_C": T_med_s + T_noise_C * noise[1],
            "q_kgh": q_true * (1.0 + opt["q_noise_rel"] * noise[2]),
            "dp_mbar": dp_true * (1.0 + opt["dp_noise_rel"] * noise[3]),
            "ps_bar": ps_true * (1.0 + opt["ps_noise_rel"] * noise[4]),
            "x_mm": x_true + x_noise_mm * noise[5],
            "true_T_tank_C": T_tank_s,
            "true_T_med_C": T_med_s,
            "true_T_g_C": at(Tg),
            "true_F_h_N": at(F),
            "true_x_mm": x_true,
        }
    )
    df.attrs["effects"] = eff
    df.attrs["seed"] = seed
    return df


def parse_effect(text: str) -> tuple[str, dict[str, float]]:
    """Parse ``NAME:key=value[,key=value]`` (the ``--effect`` option), e.g. ``sensor_lag:tau_s=60``."""
    name, _, rest = text.partition(":")
    name = name.strip()
    pars: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise ConfigError(f"bad effect {text!r}: expected NAME:key=value[,key=value]")
        try:
            pars[key.strip()] = float(val)
        except ValueError as exc:
            raise ConfigError(f"bad effect {text!r}: {val!r} is not a number") from exc
    _check_effects({name: pars})
    return name, pars


#: the classes of the randomised studies: no effect, then each named effect of docs/reference.md, section 3
STUDY_CLASSES: tuple[str, ...] = ("none", *_effects.REGISTRY)


def draw_effect(name: str, rng: np.random.Generator) -> dict[str, dict[str, float]]:
    """A random size of effect ``name`` (``{}`` for ``"none"``), as the diagnosis studies draw it."""
    if name == "none":
        return {}
    if name in _effects.REGISTRY:
        return {name: _effects.draw(name, rng)}
    raise ConfigError(f"unknown effect {name!r}; expected one of {', '.join(STUDY_CLASSES)}")


def random_cases(n: int, seed: int, classes: tuple[str, ...] = STUDY_CLASSES) -> list[dict[str, Any]]:
    """``n`` randomised runs for a diagnosis study: the classes in turn (balanced); the effect's size,
    the run's seed, sampling interval, length, noise levels and jitter drawn from ``seed``. Each case
    holds the keyword arguments of :func:`simulate_experiment` plus ``i`` and ``truth``."""
    rng = np.random.default_rng(seed)
    cases = []
    for i in range(n):
        truth = classes[i % len(classes)]
        cases.append({
            "i": i,
            "truth": truth,
            "effects": draw_effect(truth, rng),
            "seed": int(rng.integers(0, 2**31 - 1)),
            "dt_s": float(rng.choice([5.0, 10.0, 20.0, 30.0])),
            "duration_h": float(rng.uniform(12.0, 30.0)),
            "T_noise_C": float(rng.uniform(0.0, 0.01)),
            "x_noise_mm": float(rng.uniform(1.5e-3, 3.0e-3)),
            "jitter": float(rng.choice([0.0, 0.2])),
        })
    return cases


def simulate_case(case: Mapping[str, Any]) -> pd.DataFrame:
    """The generated run of a study case (one of :func:`random_cases`)."""
    return simulate_experiment(seed=case["seed"], duration_h=case["duration_h"], dt_s=case["dt_s"],
                               effects=case["effects"] or None, T_noise_C=case["T_noise_C"],
                               x_noise_mm=case["x_noise_mm"], jitter=case["jitter"])


def run_cases(fn: Callable[[dict[str, Any]], dict[str, Any]], cases: list[dict[str, Any]], workers: int = 1,
              on_result: Callable[[dict[str, Any], int], None] | None = None) -> list[dict[str, Any]]:
    """``fn`` over the study ``cases``, in order, in this process (``workers <= 1``) or on a pool of
    ``workers`` processes (``fn`` must then be importable by name); ``on_result(result, done)`` is
    called as each result arrives."""
    results: list[dict[str, Any]] = []
    with ExitStack() as stack:
        mapper = map if workers <= 1 else stack.enter_context(ProcessPoolExecutor(max_workers=workers)).map
        for r in mapper(fn, cases):
            results.append(r)
            if on_result is not None:
                on_result(r, len(results))
    return results


__all__ = ["EFFECTS", "DEFAULT_OPTIONS", "COLUMNS", "simulate_experiment", "parse_effect", "STUDY_CLASSES",
           "draw_effect", "random_cases", "simulate_case", "run_cases"]
