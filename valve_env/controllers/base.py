"""The controller protocol: stable-baselines3's ``predict``.

Every controller, the baselines here and the trained agents of ``agents/``,
answers ``predict(observation, state=None, episode_start=None,
deterministic=True) -> (action, state)`` exactly like an SB3 policy, so one
evaluator scores them all:

* ``observation`` is one observation ``(obs_dim,)`` or a batch
  ``(n_envs, obs_dim)``; the action comes back as ``(act_dim,)`` or
  ``(n_envs, act_dim)`` (float32).
* ``state`` carries the controllers' per-env memory (integrators, filters,
  previous outputs) as a float64 array ``(n_envs, state_size)``; pass back
  what the previous call returned. ``None`` starts every env afresh.
* ``episode_start`` (bool, ``(n_envs,)``) re-initialises the memory of the
  envs whose episode starts with this observation (SB3's convention: the
  ``dones`` of the previous step).

Controllers read only the observation (names in
``valve_env.envs.OBS_NAMES``; a task's extra observations, e.g. forecasts,
follow those 12 and are ignored by controllers that do not use them) and
their own configuration, never the env's hidden state. The batched path is vectorised NumPy (no loop over envs).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from valve_env.env_registry import ALL_ENV_MODES, ENV_MODES
from valve_env.envs.thermovalve import OBS_NAMES

OBS_DIM = len(OBS_NAMES)
I_T_OUT = OBS_NAMES.index("T_out_C")
I_T_POCKET = OBS_NAMES.index("T_pocket_C")
I_SETTING = OBS_NAMES.index("setting_C")
I_DP = OBS_NAMES.index("dp_mbar")
I_T_TARGET = OBS_NAMES.index("T_target_C")
#: the original id of each mode: a task id's controllers are those of its mode's original id
ORIGINAL_ID = {mode: env_id for env_id, mode in ENV_MODES.items()}


def original_id(env_id: str) -> str:
    """``env_id`` if it is one of the original three, else the original id with the same action (mode)."""
    if env_id in ENV_MODES:
        return env_id
    if env_id not in ALL_ENV_MODES:
        raise ValueError(f"unknown env id {env_id!r}; known: {list(ALL_ENV_MODES)}")
    return ORIGINAL_ID[ALL_ENV_MODES[env_id]]


@runtime_checkable
class PredictPolicy(Protocol):
    """Anything with SB3's ``predict`` (baselines, SB3 models, loaded agents)."""

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...


class Controller(ABC):
    """Base class of the baseline controllers (see the module docstring).

    Subclasses set ``name`` and ``supported_env_ids``, ``state_size``, and
    implement :meth:`initial_state` and :meth:`step` on batches.
    """

    name: ClassVar[str] = "controller"
    supported_env_ids: ClassVar[tuple[str, ...]] = tuple(ENV_MODES)

    def __init__(self, env_id: str = "ThermoValve-v0") -> None:
        if env_id not in self.supported_env_ids and original_id(env_id) not in self.supported_env_ids:
            raise ValueError(
                f"controller {self.name!r} does not support env {env_id!r}; it supports {list(self.supported_env_ids)}"
                " and the task ids with their action"
            )
        self.env_id = env_id
        self.mode = ALL_ENV_MODES[env_id]
        self.state_size = 0

    @property
    def act_dim(self) -> int:
        return 2 if self.mode == "dual" else 1

    # -- to implement --------------------------------------------------------
    @abstractmethod
    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        """Memory ``(n, state_size)`` for envs whose episode starts at ``obs`` ``(n, obs_dim)``."""

    @abstractmethod
    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Actions ``(n, act_dim)`` and the new memory for a batch; ``state`` may be updated in place."""

    # -- SB3 interface ---------------------------------------------------------
    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        if obs.shape[-1] < OBS_DIM or obs.ndim not in (1, 2):
            raise ValueError(f"observation must have shape ({OBS_DIM},) or (n_envs, {OBS_DIM}) (a task may append "
                             f"columns), got {obs.shape}")
        obs2 = obs.reshape(-1, obs.shape[-1])
        n = obs2.shape[0]
        if state is None:
            mem = self.initial_state(obs2)
        else:
            mem = np.array(state, dtype=np.float64, copy=True).reshape(n, self.state_size)
            if episode_start is not None:
                start = np.broadcast_to(np.asarray(episode_start, dtype=bool).reshape(-1), (n,))
                if start.any():
                    mem[start] = self.initial_state(obs2[start])
        act, mem = self.step(obs2, mem)
        act = np.asarray(act, dtype=np.float32).reshape(n, self.act_dim)
        return (act[0] if single else act), mem

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """Stateless convenience (memory restarts each call): ``predict(obs)[0]``."""
        return self.predict(observation)[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(env_id={self.env_id!r})"
