"""ThermoValve: a self-acting thermostatic valve with Dahl-friction hysteresis,
its hot-water tank as Gymnasium environments, controllers and grey-box
identification.

``import valve_env`` registers ThermoValve-v0, ThermoValvePressure-v0 and
ThermoValveDual-v0.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from valve_env.config import ControlParams, EnvConfig, SensorParams, make_config
from valve_env.params import BulbParams, ConfigError, TankParams, ValveParams
from valve_env.scenario import ScenarioParams

__version__ = "0.1.0"

ENV_IDS: tuple[str, ...] = ("ThermoValve-v0", "ThermoValvePressure-v0", "ThermoValveDual-v0")
MAX_EPISODE_STEPS = ControlParams().n_steps

_VECTOR_CLASSES = ("ThermoValveVectorEnv", "ThermoValvePressureVectorEnv", "ThermoValveDualVectorEnv")
for _id, _fn, _vec in zip(ENV_IDS, ("make_setting", "make_pressure", "make_dual"), _VECTOR_CLASSES, strict=True):
    if _id not in registry:
        register(
            id=_id,
            entry_point=f"valve_env.envs:{_fn}",
            # the native batched env (valve_env.envs.vector): gym.make_vec(id, num_envs=N)
            vector_entry_point=f"valve_env.envs.vector:{_vec}",
            max_episode_steps=MAX_EPISODE_STEPS,
        )

__all__ = [
    "ENV_IDS",
    "BulbParams",
    "ConfigError",
    "ControlParams",
    "EnvConfig",
    "ScenarioParams",
    "SensorParams",
    "TankParams",
    "ValveParams",
    "make_config",
]
