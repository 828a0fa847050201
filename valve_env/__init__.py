"""ThermoValve: a self-acting thermostatic valve with Dahl-friction hysteresis,
its hot-water tank as Gymnasium environments, controllers and grey-box
identification.

``import valve_env`` registers ThermoValve-v0, ThermoValvePressure-v0 and
ThermoValveDual-v0, and the benchmark tasks of valve_env.tasks (TASK_IDS, superseded
versions included; CURRENT_TASK_IDS, which ``thermovalve tasks`` lists).
"""

from __future__ import annotations

import functools
import os

# The batched env runs on numba's threads (OpenMP, GNU libgomp). With
# libgomp's default busy-waiting (3 ms), a step on a machine whose cores are
# busy with other work waits for a parked thread and ran 10x slower than
# serial here; so waiters sleep (passive), but only after a short spin
# (GOMP_SPINCOUNT 30 000, about 0.3 ms): a thread that sleeps between two
# steps costs a futex wake-up in every step, which made the threads slower
# than one core below N = 4096; with the spin they win from N = 1024, and on
# a machine with both cores busy they did not collapse (docs/speed.md).
# Defaults only: a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "passive")
os.environ.setdefault("GOMP_SPINCOUNT", "30000")

from gymnasium.envs.registration import register, registry  # noqa: E402

from valve_env.config import ControlParams, EnvConfig, SensorParams, make_config  # noqa: E402
from valve_env.env_registry import ALL_ENV_MODES, ENV_MODES, register_env  # noqa: E402
from valve_env.params import BulbParams, ConfigError, TankParams, ValveParams  # noqa: E402
from valve_env.scenario import ScenarioParams  # noqa: E402

__version__ = "0.1.0"

ENV_IDS: tuple[str, ...] = tuple(ENV_MODES)
MAX_EPISODE_STEPS = ControlParams().n_steps

_VECTOR_CLASSES = {
    "setting": "ThermoValveVectorEnv",
    "pressure": "ThermoValvePressureVectorEnv",
    "dual": "ThermoValveDualVectorEnv",
}
for _id, _mode in ENV_MODES.items():
    if _id not in registry:
        register(
            id=_id,
            entry_point=f"valve_env.envs:make_{_mode}",
            # the native batched env (valve_env.envs.vector): gym.make_vec(id, num_envs=N)
            vector_entry_point=f"valve_env.envs.vector:{_VECTOR_CLASSES[_mode]}",
            max_episode_steps=MAX_EPISODE_STEPS,
        )

from valve_env.tasks import CURRENT_TASK_IDS, TASK_IDS, TASKS, register_tasks, task_config  # noqa: E402

register_tasks(MAX_EPISODE_STEPS)
# every registered id (the original three, then the tasks) -> what the agent sets and its EnvConfig, for the
# layers below this one (valve_env.env_registry: ALL_ENV_MODES)
for _id, _task in TASKS.items():
    register_env(_id, _task.mode, make_config if _task.is_original else functools.partial(task_config, _id))
ALL_ENV_IDS: tuple[str, ...] = tuple(ALL_ENV_MODES)

__all__ = [
    "ALL_ENV_IDS",
    "ALL_ENV_MODES",
    "ENV_IDS",
    "ENV_MODES",
    "BulbParams",
    "CURRENT_TASK_IDS",
    "ConfigError",
    "ControlParams",
    "EnvConfig",
    "ScenarioParams",
    "SensorParams",
    "TASK_IDS",
    "TankParams",
    "ValveParams",
    "make_config",
]
