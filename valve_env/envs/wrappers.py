"""Measurement wrappers: sensor noise and dead time (never in the physics),
and snapshots of a whole wrapper stack.

Both wrappers draw their randomness from the wrapped env's seeded generator,
so seeded rollouts stay reproducible.

:func:`snapshot` and :func:`restore` save and restore everything that
determines an env's future through any stack of wrappers, e.g. the one
``gym.make`` builds (TimeLimit, OrderEnforcing, PassiveEnvChecker around
make_thermovalve's ObservationDelay and SensorNoise): the simulator's
:class:`~valve_env.envs.thermovalve.SimState` (which holds the env's
generator, and so the sensor noise's) and the state of every wrapper. A
wrapper with state takes part by defining ``wrapper_state()`` and
``set_wrapper_state(state)``; gymnasium's TimeLimit and OrderEnforcing are
known; any other wrapper is refused rather than silently left behind.
"""

from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker, TimeLimit

from valve_env.envs.thermovalve import FLOW_OBS, TEMPERATURE_OBS, SimState, ThermoValveEnv

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

    def wrapper_state(self) -> None:
        """No state of its own: the noise comes from the base env's generator, which
        the snapshot's SimState holds (``rng_state``)."""
        return None

    def set_wrapper_state(self, state: None) -> None:
        """Nothing to restore (see :meth:`wrapper_state`)."""

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

    def wrapper_state(self) -> tuple[np.ndarray, ...]:
        """The delay line: the last ``steps + 1`` observations, oldest first (copies)."""
        return tuple(o.copy() for o in self._buf)

    def set_wrapper_state(self, state: tuple[np.ndarray, ...]) -> None:
        """Restore the delay line saved by :meth:`wrapper_state`."""
        if len(state) not in (0, self.steps + 1):
            raise ValueError(f"ObservationDelay: a snapshot of {len(state)} observations, expected {self.steps + 1}")
        self._buf.clear()
        self._buf.extend(o.copy() for o in state)


#: gymnasium's wrappers that gym.make applies: the attributes that are their state
_GYM_WRAPPER_STATE: dict[type, tuple[str, ...]] = {
    TimeLimit: ("_elapsed_steps",),
    OrderEnforcing: ("_has_reset",),
    PassiveEnvChecker: (),
}


@dataclass
class EnvSnapshot:
    """Everything that determines a wrapped env's future: the simulator's state and
    each wrapper's, outermost first (``(wrapper class name, its state)``)."""

    sim: SimState
    wrappers: tuple[tuple[str, Any], ...]


def _stack(env: gym.Env) -> tuple[list[gym.Wrapper], ThermoValveEnv]:
    layers: list[gym.Wrapper] = []
    e: gym.Env = env
    while isinstance(e, gym.Wrapper):
        layers.append(e)
        e = e.env
    if not isinstance(e, ThermoValveEnv):
        raise TypeError(f"snapshot/restore need a ThermoValve env (possibly wrapped), got {type(e).__name__}")
    return layers, e


def _layer_state(w: gym.Wrapper) -> Any:
    if hasattr(w, "wrapper_state") and hasattr(w, "set_wrapper_state"):
        return w.wrapper_state()
    if type(w) in _GYM_WRAPPER_STATE:
        return {a: copy.deepcopy(getattr(w, a)) for a in _GYM_WRAPPER_STATE[type(w)]}
    raise TypeError(
        f"cannot snapshot through the wrapper {type(w).__name__}: it is not one of gym.make's and defines no "
        "wrapper_state()/set_wrapper_state()"
    )


def snapshot(env: gym.Env) -> EnvSnapshot:
    """A deep copy of everything that determines ``env``'s future, through its wrappers
    (for MPC and branching rollouts): ``snap = snapshot(env)``, ..., ``restore(env, snap)``.

    Use this rather than ``env.unwrapped.get_state()`` on a wrapped env: the latter
    leaves the wrappers' state (a dead time's delay line, TimeLimit's step count) behind."""
    layers, base = _stack(env)
    return EnvSnapshot(sim=base.get_state(), wrappers=tuple((type(w).__name__, _layer_state(w)) for w in layers))


def restore(env: gym.Env, snap: EnvSnapshot) -> None:
    """Restore a :func:`snapshot` of an env with the same configuration and wrappers;
    the next observations are those of the restored branch."""
    layers, base = _stack(env)
    names = tuple(type(w).__name__ for w in layers)
    if names != tuple(name for name, _ in snap.wrappers):
        raise ValueError(
            f"the snapshot was taken through the wrappers {[n for n, _ in snap.wrappers]}, this env has {list(names)}"
        )
    base.set_state(snap.sim)
    for w, (_, state) in zip(layers, snap.wrappers, strict=True):
        if hasattr(w, "set_wrapper_state") and hasattr(w, "wrapper_state"):
            w.set_wrapper_state(state)
        else:
            for a, v in state.items():
                setattr(w, a, copy.deepcopy(v))
