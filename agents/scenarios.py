"""Named evaluation (and sweep) scenarios: the one registry lives in the core,
:mod:`valve_env.evaluation.scenarios` (also behind ``valve_env/data/scenarios/*.yaml``); this module
re-exports it for the agents' code."""

from valve_env.evaluation.scenarios import (
    DESCRIPTIONS,
    LEADERBOARD_SCENARIOS,
    RANDOMISED_SCENARIOS,
    SCENARIOS,
    STATIC_SCENARIOS,
    check_scenario,
    episode_env_kwargs,
    is_randomised,
    random_valve,
    scenario_env_kwargs,
)

__all__ = ["STATIC_SCENARIOS", "RANDOMISED_SCENARIOS", "SCENARIOS", "LEADERBOARD_SCENARIOS", "DESCRIPTIONS",
           "check_scenario", "random_valve", "is_randomised", "scenario_env_kwargs", "episode_env_kwargs"]
