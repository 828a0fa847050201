"""Shared fixtures for the agent tests: one short PPO run per session."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

#: one simulated hour per episode (120 control steps) keeps the tests short
SHORT: dict[str, Any] = {"control": {"horizon_h": 1.0}}
TINY_PPO: tuple[str, ...] = (
    "n_envs=2",
    "hyperparams.n_steps=128",
    "hyperparams.batch_size=64",
    "hyperparams.n_epochs=2",
    "eval.episodes=1",
)


@pytest.fixture(scope="session")
def short_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A PPO run of a few thousand steps on one-hour episodes, with a periodic evaluation."""
    from agents.train import train

    out = tmp_path_factory.mktemp("runs") / "ppo_short"
    return train(
        "ppo",
        "ThermoValve-v0",
        seed=3,
        timesteps=2048,
        out=out,
        overrides=TINY_PPO,
        env_kwargs=SHORT,
        progress_bar=False,
        eval_freq=1024,
        command="pytest short_run",
    )


@pytest.fixture
def short() -> dict[str, Any]:
    """gym.make keywords for one-hour episodes."""
    return {"control": {"horizon_h": 1.0}}
