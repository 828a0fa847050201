"""Controllers for the ThermoValve environments, all with stable-baselines3's
``predict(observation, state, episode_start, deterministic)``.

Built-in baselines (see docs/baselines.md):

* ``self_acting``: the valve alone at a fixed setting (today's practice);
* ``pi``: a discrete PI on the outlet temperature with anti-windup and a
  bumpless start, SIMC-tuned on a simulator step test
  (:mod:`valve_env.controllers.tuning`, gains in ``configs/controllers.yaml``);
* ``pi_compensated``: the PI plus an inverse-model Dahl hysteresis compensator;
* ``knocker``, ``constant_reinforcement``, ``two_move``, ``two_move_position``,
  ``pi_integral_band``: stiction compensators from the literature on the PI's setting, and
  ``pi_wear``: an event-based PI that spares the stem (:mod:`valve_env.controllers.compensators`,
  docs/controllers.md); ``pi_stiction_tuned``: a PI whose gains compensate stiction by tuning, from a
  describing-function analysis (Mohammad & Huang 2012; :mod:`valve_env.controllers.stiction_tuning`);
* ``oracle``: MPC with the true plant and perfect preview, the bound on what
  is achievable (:mod:`valve_env.controllers.oracle`; it must be bound to the
  envs it controls, which the evaluator does).

``make_controller(name, env_id)`` builds one; any other name (``ppo``,
``sac``, ...) is delegated to ``agents.loader.load_agent(name, env_id)``.
"""

from __future__ import annotations

from typing import Any

from valve_env.controllers.base import ALL_ENV_MODES, Controller, PredictPolicy, original_id
from valve_env.controllers.baselines import DahlCompensator, PICompensated, PIController, SelfActing
from valve_env.controllers.compensators import (
    ConstantReinforcement,
    Knocker,
    PIIntegralBand,
    PIWear,
    TwoMove,
    TwoMovePosition,
)
from valve_env.controllers.oracle import Oracle, OracleSettings
from valve_env.controllers.stiction_tuning import PIStictionTuned

BASELINES: dict[str, type[Controller]] = {
    SelfActing.name: SelfActing,
    PIController.name: PIController,
    PICompensated.name: PICompensated,
    PIWear.name: PIWear,
    Knocker.name: Knocker,
    ConstantReinforcement.name: ConstantReinforcement,
    TwoMove.name: TwoMove,
    TwoMovePosition.name: TwoMovePosition,
    PIIntegralBand.name: PIIntegralBand,
    PIStictionTuned.name: PIStictionTuned,
}
"""Controllers that read only the observation (the default set of ``thermovalve evaluate``)."""
ORACLES: dict[str, type[Controller]] = {Oracle.name: Oracle}
"""Controllers that read the true plant (bound to their envs by the evaluator; not a default: slow)."""
CONTROLLERS: dict[str, type[Controller]] = {**BASELINES, **ORACLES}


class UnknownControllerError(ValueError):
    """A controller name that is neither a baseline nor a loadable agent."""


def make_controller(name: str, env_id: str = "ThermoValve-v0", **kwargs: Any) -> PredictPolicy:
    """A controller by name for ``env_id``.

    Built-ins (:data:`CONTROLLERS`): ``self_acting``, ``pi``, ``pi_compensated``, ``pi_wear``,
    ``knocker``, ``constant_reinforcement``, ``two_move``, ``two_move_position``, ``pi_integral_band``,
    ``pi_stiction_tuned``, ``oracle``
    (keyword arguments go to their constructors). Any other name is a trained agent, loaded by
    ``agents.loader.load_agent(name, env_id, **kwargs)``; a missing ``agents``
    package or loader raises :class:`UnknownControllerError` naming the agent.
    """
    if env_id not in ALL_ENV_MODES:
        raise ValueError(f"unknown env id {env_id!r}; known: {list(ALL_ENV_MODES)}")
    if name in CONTROLLERS:
        return CONTROLLERS[name](env_id, **kwargs)
    try:
        from agents.loader import load_agent  # type: ignore[import-not-found]
    except ImportError as exc:
        missing = (exc.name or "").split(".")[0]
        if missing in ("stable_baselines3", "torch"):
            hint = f"trained agents need the RL extra ({missing} is missing): install it with pip install -e '.[rl]'"
        else:
            hint = f"the agent loader agents.loader.load_agent could not be imported ({exc})"
        raise UnknownControllerError(
            f"controller {name!r} is not a built-in ({', '.join(CONTROLLERS)}); {hint}"
        ) from exc
    return load_agent(name, env_id, **kwargs)


__all__ = [
    "BASELINES",
    "CONTROLLERS",
    "ORACLES",
    "ConstantReinforcement",
    "Controller",
    "DahlCompensator",
    "Knocker",
    "Oracle",
    "OracleSettings",
    "PIIntegralBand",
    "PIStictionTuned",
    "PIWear",
    "TwoMove",
    "TwoMovePosition",
    "PICompensated",
    "PIController",
    "PredictPolicy",
    "SelfActing",
    "UnknownControllerError",
    "make_controller",
    "original_id",
]
