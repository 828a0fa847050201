"""The table of registered env ids, for the layers below the registration.

``import valve_env`` registers the three original ids and the benchmark tasks with Gymnasium
(valve_env/__init__.py, :func:`valve_env.tasks.register_tasks`) and records each one here: what its
agent sets and how its EnvConfig is built. Controllers and the evaluator read this table instead
of importing the package root or :mod:`valve_env.tasks`, which sits above them (the task benchmark,
``valve_env.tasks.benchmark``, runs controllers through the evaluator): so no import cycle
(docs/architecture.md). Importing any ``valve_env`` module runs valve_env/__init__.py first, so
the table is full before any code reads it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

#: the original env ids (docs/reference.md, section 5) -> what the agent sets ("setting", "pressure", "dual")
ENV_MODES: dict[str, str] = {
    "ThermoValve-v0": "setting",
    "ThermoValvePressure-v0": "pressure",
    "ThermoValveDual-v0": "dual",
}
#: every registered id (the original three, then the tasks) -> what the agent sets
ALL_ENV_MODES: dict[str, str] = {}
_CONFIG_BUILDERS: dict[str, Callable[..., Any]] = {}


def register_env(env_id: str, mode: str, config_builder: Callable[..., Any]) -> None:
    """Record ``env_id``: its mode and ``config_builder(config, **overrides)``, which returns the
    EnvConfig that ``gym.make(env_id, config=config, **overrides)`` builds."""
    ALL_ENV_MODES[env_id] = mode
    _CONFIG_BUILDERS[env_id] = config_builder


def env_config(env_id: str, config: Any = None, **overrides: Any) -> Any:
    """The EnvConfig that ``gym.make(env_id, config=config, **overrides)`` builds (a task's own
    configuration for a task id); ValueError naming the known ids for an unknown one."""
    try:
        build = _CONFIG_BUILDERS[env_id]
    except KeyError:
        raise ValueError(f"unknown env id {env_id!r}; known: {', '.join(ALL_ENV_MODES)}") from None
    return build(config, **overrides)
