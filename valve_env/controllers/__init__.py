"""Controllers for the ThermoValve environments, all with stable-baselines3's
``predict(observation, state, episode_start, deterministic)``.

Built-in baselines (see docs/baselines.md):

* ``self_acting``: the valve alone at a fixed setting (today's practice);
* ``pi``: a discrete PI on the outlet temperature with anti-windup and a
  bumpless start, SIMC-tuned on a simulator step test
  (:mod:`valve_env.controllers.tuning`, gains in ``configs/controllers.yaml``);
* ``pi_compensated``: the PI plus an inverse-model Dahl hysteresis compensator.

``make_controller(name, env_id)`` builds one; any other name (``ppo``,
``sac``, ...) is delegated to ``agents.loader.load_agent(name, env_id)``.
"""

from __future__ import annotations

from typing import Any

from valve_env.controllers.base import ALL_ENV_MODES, Controller, PredictPolicy, original_id
from valve_env.controllers.baselines import DahlCompensator, PICompensated, PIController, SelfActing

BASELINES: dict[str, type[Controller]] = {
    SelfActing.name: SelfActing,
    PIController.name: PIController,
    PICompensated.name: PICompensated,
}


class UnknownControllerError(ValueError):
    """A controller name that is neither a baseline nor a loadable agent."""


def make_controller(name: str, env_id: str = "ThermoValve-v0", **kwargs: Any) -> PredictPolicy:
    """A controller by name for ``env_id``.

    Baselines: ``self_acting``, ``pi``, ``pi_compensated`` (keyword arguments
    go to their constructors). Any other name is a trained agent, loaded by
    ``agents.loader.load_agent(name, env_id, **kwargs)``; a missing ``agents``
    package or loader raises :class:`UnknownControllerError` naming the agent.
    """
    if env_id not in ALL_ENV_MODES:
        raise ValueError(f"unknown env id {env_id!r}; known: {list(ALL_ENV_MODES)}")
    if name in BASELINES:
        return BASELINES[name](env_id, **kwargs)
    try:
        from agents.loader import load_agent  # type: ignore[import-not-found]
    except ImportError as exc:
        raise UnknownControllerError(
            f"unknown controller {name!r}: not a baseline ({', '.join(BASELINES)}) and the agent loader "
            f"agents.loader.load_agent could not be imported ({exc})"
        ) from exc
    return load_agent(name, env_id, **kwargs)


__all__ = [
    "BASELINES",
    "Controller",
    "DahlCompensator",
    "PICompensated",
    "PIController",
    "PredictPolicy",
    "SelfActing",
    "UnknownControllerError",
    "make_controller",
    "original_id",
]
