"""The shipped agents (agents/zoo/<env_id>/<algo>.zip) load through the
controller registry and act with valid actions."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import yaml

import valve_env
from agents.loader import available_agents
from agents.train import ZOO_DIR

SHIPPED = [(env_id, name) for env_id in valve_env.ALL_ENV_IDS for name in available_agents(env_id)]


def test_at_least_the_setting_env_has_a_shipped_agent() -> None:
    assert available_agents("ThermoValve-v0"), "no shipped agent in agents/zoo/ThermoValve-v0"


@pytest.mark.parametrize(("env_id", "name"), SHIPPED)
def test_shipped_agent_loads_and_acts(env_id: str, name: str, short: dict[str, Any]) -> None:
    from valve_env.controllers import make_controller

    d = ZOO_DIR / env_id
    assert (d / f"{name}.zip").stat().st_size < 2_000_000
    cfg = yaml.safe_load((d / f"{name}.yml").read_text())
    assert cfg["env_id"] == env_id and "shipped_from" in cfg and "command" in cfg["shipped_from"]
    ctrl = make_controller(name, env_id)
    env = gym.make(env_id, **short)
    obs, _ = env.reset(seed=0)
    state = None
    for t in range(60):
        act, state = ctrl.predict(obs, state, np.array([t == 0]))
        assert act.shape == env.action_space.shape and env.action_space.contains(act)
        obs, r, *_ = env.step(act)
        assert np.isfinite(r)
