"""Environment classes and the factory that ``gym.make`` calls."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from valve_env.config import make_config
from valve_env.envs.thermovalve import (
    OBS_NAMES,
    SimState,
    ThermoValveDualEnv,
    ThermoValveEnv,
    ThermoValvePressureEnv,
)

_CLASSES = {"setting": ThermoValveEnv, "pressure": ThermoValvePressureEnv, "dual": ThermoValveDualEnv}


def make_thermovalve(
    mode: str = "setting", config: Any = None, render_mode: str | None = None, **overrides: Any
) -> gym.Env:
    """Build the env for ``mode`` and wrap it with the measurement wrappers that
    its ``sensors`` configuration asks for (noise, dead time)."""
    from valve_env.envs.wrappers import ObservationDelay, SensorNoise

    cfg = make_config(config, **overrides)
    env: gym.Env = _CLASSES[mode](config=cfg, render_mode=render_mode)
    if cfg.sensors.noise_K > 0 or cfg.sensors.flow_noise_rel > 0:
        env = SensorNoise(env, cfg.sensors.noise_K, cfg.sensors.flow_noise_rel)
    if cfg.sensors.dead_time_steps > 0:
        env = ObservationDelay(env, cfg.sensors.dead_time_steps)
    return env


def make_setting(**kw: Any) -> gym.Env:
    return make_thermovalve("setting", **kw)


def make_pressure(**kw: Any) -> gym.Env:
    return make_thermovalve("pressure", **kw)


def make_dual(**kw: Any) -> gym.Env:
    return make_thermovalve("dual", **kw)


__all__ = [
    "OBS_NAMES",
    "SimState",
    "ThermoValveEnv",
    "ThermoValvePressureEnv",
    "ThermoValveDualEnv",
    "make_thermovalve",
]
