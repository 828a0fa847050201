"""Measurement wrappers: sensor noise and dead time (never in the physics).

Both draw their randomness from the wrapped env's seeded generator, so seeded
rollouts stay reproducible.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np

from valve_env.envs.thermovalve import FLOW_OBS, TEMPERATURE_OBS

_T_IDX = np.array(TEMPERATURE_OBS)
_F_IDX = np.array(FLOW_OBS)


def noisy_observation(
    observation: np.ndarray,
    rng: np.random.Generator,
    noise_K: float,
    flow_noise_rel: float,
    low: np.ndarray,
    high: np.ndarray,
) -> np.ndarray:
    """A copy of ``observation`` with white noise on the temperatures (sd
    ``noise_K``) and relative noise on flow and dp, drawn from ``rng`` and
    clipped to [low, high]. Shared by :class:`SensorNoise` and the batched env."""
    o = np.array(observation, dtype=np.float32, copy=True)
    if noise_K > 0:
        o[_T_IDX] += rng.normal(0.0, noise_K, size=_T_IDX.size).astype(np.float32)
    if flow_noise_rel > 0:
        o[_F_IDX] *= (1.0 + rng.normal(0.0, flow_noise_rel, size=_F_IDX.size)).astype(np.float32)
    return np.clip(o, low, high)


class SensorNoise(gym.ObservationWrapper[np.ndarray, np.ndarray, np.ndarray]):
    """White Gaussian noise on the observed temperatures (``noise_K``, K) and a
    relative noise on the observed flow and differential pressure
    (``flow_noise_rel``). Observations are clipped to the observation space."""

    def __init__(self, env: gym.Env, noise_K: float = 0.05, flow_noise_rel: float = 0.0) -> None:
        super().__init__(env)
        if not (np.isfinite(noise_K) and noise_K >= 0 and np.isfinite(flow_noise_rel) and flow_noise_rel >= 0):
            raise ValueError("SensorNoise: noise_K and flow_noise_rel must be finite and >= 0")
        self.noise_K = float(noise_K)
        self.flow_noise_rel = float(flow_noise_rel)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        space = self.observation_space
        assert isinstance(space, gym.spaces.Box)
        return noisy_observation(
            observation, self.env.unwrapped.np_random, self.noise_K, self.flow_noise_rel, space.low, space.high
        )


class ObservationDelay(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """The agent sees the observation of ``steps`` control steps ago (a
    transport or communication dead time). After reset the first observation
    is repeated until the delay line fills."""

    def __init__(self, env: gym.Env, steps: int = 1) -> None:
        super().__init__(env)
        if int(steps) != steps or steps < 0:
            raise ValueError(f"ObservationDelay: steps must be an integer >= 0, got {steps!r}")
        self.steps = int(steps)
        self._buf: deque[np.ndarray] = deque(maxlen=self.steps + 1)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        self._buf.clear()
        for _ in range(self.steps + 1):
            self._buf.append(obs)
        return obs.copy(), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, r, term, trunc, info = self.env.step(action)
        self._buf.append(obs)
        return self._buf[0].copy(), float(r), term, trunc, info
