"""Reproducible PI tuning: step tests on the simulator, a process-model fit and SIMC rules
(:mod:`valve_env.controllers.process`, shared with the simulated plant loops).

Two loops are tuned, both on the outlet temperature ``T_out`` (observation 0):

* **setting loop** (ThermoValve-v0 and the setting channel of
  ThermoValveDual-v0): the manipulated variable is the valve's temperature
  setting. Step test: no draws, constant supply, the tank starts
  ``approach_K`` below the initial setting ``u0`` so that the valve settles
  while heating (friction at +F_hmax, the direction of a recovering tank),
  ``settle_h`` hours at ``u0``, then a step of ``du`` and ``record_h`` hours of
  response. Model: first order plus dead time (FOPDT),
  ``y(t) = y0 + K du (1 - exp(-(t - theta) / tau))`` for ``t > theta``.
* **pressure loop** (ThermoValvePressure-v0): the manipulated variable is the
  differential pressure across the valve. With the valve open the tank
  integrates the coil's heat, so the response to the pump is an integrator
  plus dead time (IPDT). Differential step test: two runs from the same state
  (the tank uniform at ``T0_C``, no draws), one at ``u0`` and one stepped to
  ``u0 + du`` at t = 0; the difference of their outlet temperatures is fitted
  over ``record_h`` hours with ``dy(t) = k du (t - theta)`` for ``t > theta``
  (the valve stays open in that window).

SIMC (Skogestad 2003, "Simple analytic rules for model reduction and PID
controller tuning", J. Process Control 13:291-309), with the sampling's zero
order hold adding half a step to the dead time (theta_eff = theta + dt/2):

* FOPDT: ``Kc = tau / (K (tau_c + theta_eff))``, ``Ti = min(tau, 4 (tau_c + theta_eff))``
* IPDT:  ``Kc = 1 / (k (tau_c + theta_eff))``,  ``Ti = 4 (tau_c + theta_eff)``

The closed-loop time constant ``tau_c`` is an input of the procedure (SIMC's
"tight" choice is tau_c = theta; the inputs below state what is used and why).
Everything is deterministic, so :func:`tune` reproduces the gains stored in
``valve_env/data/controllers.yaml`` to the precision of the least-squares fit.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

from valve_env.controllers.process import (
    ModelFit,
    PIGains,
    StepResponse,
    fit_fopdt,
    fit_ipdt,
    simc_pi,
)
from valve_env.data import data_file

GAINS_PATH: Traversable = data_file("controllers.yaml")
"""Where the tuned gains live: package data ``valve_env/data/controllers.yaml`` (read through
importlib.resources; rl-baselines3-zoo style: keyed by env id)."""

SETTING_ENV_IDS = ("ThermoValve-v0", "ThermoValveDual-v0")
PRESSURE_ENV_IDS = ("ThermoValvePressure-v0",)


@dataclass(frozen=True)
class StepTestSpec:
    """Inputs of one step test and of the SIMC rule (stored beside the gains)."""

    loop: str
    """"setting" (FOPDT fit) or "pressure" (differential IPDT fit)."""
    u0: float
    """Manipulated variable before the step (degC or mbar)."""
    du: float
    """Step size (K or mbar)."""
    T0_C: float
    """Initial, uniform tank temperature, degC."""
    settle_h: float
    """Hours at u0 before the step (setting loop)."""
    record_h: float
    """Hours of response used in the fit."""
    tau_c_s: float | None
    """SIMC closed-loop time constant, s; None: SIMC's "tight control" choice tau_c = theta_eff."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Scenario of the test (merged over the no-draw, constant-supply defaults)."""


DEFAULT_SPECS: dict[str, StepTestSpec] = {
    # Setting loop: operate at the target (60 degC), approach from below,
    # +2 K step, 3 h of response. tau_c: SIMC's recommended "tight control"
    # choice tau_c = theta_eff (gain margin ~3, Ms ~1.6 on the model).
    "setting": StepTestSpec(
        loop="setting", u0=60.0, du=2.0, T0_C=58.0, settle_h=6.0, record_h=3.0, tau_c_s=None,
    ),
    # Pressure loop: the tank at the floor (55 degC), the pump at 50 mbar,
    # +10 mbar; 15 minutes of response (the valve stays open, setting 62).
    "pressure": StepTestSpec(
        loop="pressure", u0=50.0, du=10.0, T0_C=55.0, settle_h=0.0, record_h=0.25, tau_c_s=600.0,
    ),
}

_BASE_TEST_KWARGS: dict[str, Any] = {
    "tapping_profile": "none",
    "stochastic_draws": False,
    "supply_profile": "constant",
    "T_init_spread_K": 0.0,
    "dp_noise_mbar": 0.0,
}











def _make_test_env(spec: StepTestSpec, env_id: str, horizon_h: float) -> gym.Env:
    kw = {**_BASE_TEST_KWARGS, **spec.env_kwargs, "T_init_C": spec.T0_C, "horizon_h": horizon_h}
    from valve_env.config import make_config

    n = make_config(None, **kw).control.n_steps
    return gym.make(env_id, max_episode_steps=n, **kw)


def run_step_test(spec: StepTestSpec) -> StepResponse:
    """Run the step test ``spec`` on the simulator (deterministic)."""
    if spec.loop == "setting":
        env = _make_test_env(spec, "ThermoValve-v0", spec.settle_h + spec.record_h)
        dt = float(env.unwrapped.cfg.control.dt_s)  # type: ignore[attr-defined]
        n_settle = int(round(spec.settle_h * 3600.0 / dt))
        n_rec = int(round(spec.record_h * 3600.0 / dt))
        obs, _ = env.reset(seed=0)
        for _ in range(n_settle):
            obs, *_ = env.step(np.array([spec.u0], np.float32))
        y0 = float(obs[0])
        ys = np.empty(n_rec)
        for k in range(n_rec):
            obs, *_ = env.step(np.array([spec.u0 + spec.du], np.float32))
            ys[k] = obs[0]
        env.close()
        return StepResponse(t_s=dt * np.arange(1, n_rec + 1), y=ys, y0=y0, dt_s=dt)
    if spec.loop == "pressure":
        runs = []
        for u in (spec.u0, spec.u0 + spec.du):
            env = _make_test_env(spec, "ThermoValvePressure-v0", max(spec.record_h, 0.25) + 0.25)
            dt = float(env.unwrapped.cfg.control.dt_s)  # type: ignore[attr-defined]
            n_rec = int(round(spec.record_h * 3600.0 / dt))
            env.reset(seed=0)
            ys = np.empty(n_rec)
            for k in range(n_rec):
                obs, *_ = env.step(np.array([u], np.float32))
                ys[k] = obs[0]
            env.close()
            runs.append(ys)
        return StepResponse(t_s=dt * np.arange(1, n_rec + 1), y=runs[1] - runs[0], y0=0.0, dt_s=dt)
    raise ValueError(f"unknown loop {spec.loop!r}; expected 'setting' or 'pressure'")


def tune_loop(spec: StepTestSpec) -> tuple[ModelFit, PIGains, StepResponse]:
    """Step test, model fit and SIMC for one loop."""
    resp = run_step_test(spec)
    model = fit_fopdt(resp, spec.du) if spec.loop == "setting" else fit_ipdt(resp, spec.du)
    return model, simc_pi(model, spec.tau_c_s, resp.dt_s), resp


def _r(x: float, nd: int = 6) -> float:
    return float(f"{x:.{nd}g}") if math.isfinite(x) else float("nan")


def tune(specs: Mapping[str, StepTestSpec] | None = None) -> dict[str, dict[str, Any]]:
    """Run the whole procedure; returns the ``valve_env/data/controllers.yaml`` content
    (keyed by env id: the PI gains, the fitted model and the test's inputs)."""
    specs = dict(DEFAULT_SPECS if specs is None else specs)
    out: dict[str, dict[str, Any]] = {}
    for loop, env_ids in (("setting", SETTING_ENV_IDS), ("pressure", PRESSURE_ENV_IDS)):
        spec = specs[loop]
        model, gains, resp = tune_loop(spec)
        entry = {
            "pi": {"loop": loop, "Kp": _r(gains.Kp), "Ti_s": _r(gains.Ti_s), "tau_c_s": _r(gains.tau_c_s)},
            "model": {
                "kind": model.kind,
                "K": _r(model.K),
                "tau_s": _r(model.tau_s) if model.kind == "fopdt" else None,
                "theta_s": _r(model.theta_s),
                "rms_K": _r(model.rms, 3),
            },
            "procedure": {**asdict(spec), "dt_s": resp.dt_s, "rule": "SIMC (Skogestad 2003), theta_eff = theta + dt/2"},
        }
        for env_id in env_ids:
            out[env_id] = copy.deepcopy(entry)
    return out


def gains_yaml(table: Mapping[str, Any], keep: Mapping[str, Any] | None = None) -> str:
    """The tuning table as YAML with a header naming the procedure; the other controllers' stored
    settings in ``keep`` (the current file's table: pi_wear, knocker, oracle, ...) are kept."""
    old = keep or {}
    table = {env_id: {**{k: v for k, v in dict(old.get(env_id) or {}).items() if k not in entry}, **entry}
             for env_id, entry in table.items()}
    header = (
        "# PI gains and stored settings of the built-in controllers, keyed by env id (rl-baselines3-zoo style).\n"
        "# Produced by `thermovalve tune` (valve_env.controllers.tuning.tune): a step test on the\n"
        "# simulator, a least-squares FOPDT/IPDT fit and SIMC rules; `procedure` holds the inputs.\n"
        "# tests/controllers/test_tuning.py re-runs the procedure and checks it reproduces these gains.\n"
        "# pi_wear, knocker, constant_reinforcement, two_move, oracle: settings chosen on tuning seeds 0-4\n"
        "# (docs/controllers.md); `thermovalve tune --write` rewrites the PI entries and keeps these.\n"
    )
    return header + yaml.safe_dump(dict(table), sort_keys=False)


def write_gains(table: Mapping[str, Any], path: str | Path | Traversable = GAINS_PATH) -> Path:
    """Write the tuning table (:func:`gains_yaml`) atomically (the packaged file only where the package
    is a directory on disk: a clone or an unpacked install)."""
    from valve_env.outputs import atomic_write_text

    p = Path(str(path))
    p.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(p, gains_yaml(table, stored_gains(p)))


def stored_gains(path: str | Path | Traversable = GAINS_PATH) -> dict[str, Any]:
    """The table in a gains file, or {} when there is none."""
    p = Path(path) if isinstance(path, str) else path
    return dict(yaml.safe_load(p.read_text()) or {}) if p.is_file() else {}


def load_gains(env_id: str, path: str | Path | Traversable | None = None) -> dict[str, Any]:
    """The stored tuning entry of ``env_id`` (``{"pi": {...}, "model": {...}, "procedure": {...}}``);
    a task id without its own entry takes the entry of the original id with its action."""
    p = GAINS_PATH if path is None else Path(path) if isinstance(path, str) else path
    if not p.is_file():
        raise FileNotFoundError(f"controller gains file {str(p)!r} not found; run `thermovalve tune`")
    data = yaml.safe_load(p.read_text()) or {}
    if env_id not in data:
        from valve_env.controllers.base import original_id

        try:
            env_id = original_id(env_id)
        except ValueError:
            pass
    if env_id not in data:
        raise KeyError(f"no PI gains for env {env_id!r} in {str(p)!r}; known: {sorted(data)}")
    return dict(data[env_id])
