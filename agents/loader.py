"""Load a trained agent as a controller that takes RAW env observations.

``load_agent("ppo", "ThermoValve-v0")`` (``make_controller("ppo")`` through the
``thermovalve.controllers`` entry point, :mod:`valve_env.plugins`) reads ``agents/zoo/ThermoValve-v0/ppo.zip``
with ``ppo.yml`` (the resolved training config) and ``ppo_obs_norm.json``
(VecNormalize's observation statistics) beside it, and returns an
:class:`AgentController` with SB3's interface::

    action, state = ctrl.predict(observation, state=None, episode_start=None, deterministic=True)

``observation`` is what the unwrapped env emits (physical units, shape (12,)
or (n, 12)); ``action`` is in the env's action space (physical units). The
controller replays what the agent was trained with: the observation history
(frame stack), observation normalisation and the residual / rescaled action.
``state`` is a float64 array (n, state_size): the last k (scaled) observations, the memory of
the observation aids that keep one (``draw_owed``) and the residual's PI integrators; rows flagged
in ``episode_start`` (or every row when ``state`` is None) start a new episode.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

from agents.train import ZOO_DIR, algo_class
from agents.wrappers import ObsFeatures, ResidualCore, push_history
from valve_env.envs.thermovalve import OBS_NAMES
from valve_env.plugins import NotProvided


class NoShippedAgent(NotProvided, ValueError):
    """No agent of that name in the zoo for that env id: ``make_controller`` asks its next loader."""


class AgentController:
    """A trained SB3 model wrapped to act on raw observations (see module docstring)."""

    def __init__(
        self,
        model: Any,
        config: dict[str, Any],
        obs_norm: dict[str, Any],
        env_id: str,
        name: str = "agent",
        policy_off: bool = False,
        trained_on: str | None = None,
    ) -> None:
        import valve_env  # noqa: F401

        self.model = model
        self.config = config
        self.name = name
        self.env_id = env_id
        self.trained_on = trained_on or env_id
        self.policy_off = bool(policy_off)
        env = gym.make(env_id, **(config.get("env_kwargs") or {}) if trained_on is None else {})
        space = env.action_space
        assert isinstance(space, gym.spaces.Box)
        self.action_space = space
        self.observation_space = env.observation_space
        dt_s = float(env.unwrapped.cfg.control.dt_s)  # type: ignore[attr-defined]
        if trained_on is not None:  # deployed on another task: the training task's observation columns
            train_env = gym.make(trained_on, **(config.get("env_kwargs") or {}))
            if train_env.action_space.shape != space.shape:
                raise ValueError(f"agent {name!r} ({trained_on}) acts {train_env.action_space.shape}, "
                                 f"{env_id} takes {space.shape}")
            n_train = int(train_env.observation_space.shape[0])  # type: ignore[index]
            names = tuple(getattr(train_env.unwrapped, "obs_names", OBS_NAMES))
            if names != tuple(getattr(env.unwrapped, "obs_names", OBS_NAMES))[:n_train]:
                raise ValueError(f"agent {name!r} observes {names}, which {env_id} does not emit")
            self.observation_space = train_env.observation_space
            train_env.close()
        # observation aids from the deployment task's scenario, the scaling of the training task's columns
        self.features = ObsFeatures.from_config(config, env)
        if trained_on is not None:
            self.features = replace(self.features, extra_names=names[len(OBS_NAMES):])
        env.close()
        #: observation columns the policy reads (the first ones: a task's extra columns follow the plant's)
        self.obs_dim = int(self.observation_space.shape[0])  # type: ignore[index]
        #: the policy's features per frame (the observation, scaled, plus the observation aids)
        self.feat_dim = self.features.size(self.obs_dim)
        self.k = int(config.get("frame_stack", 1) or 1)
        residual = config.get("residual")
        self.residual: ResidualCore | None = ResidualCore.from_config(residual, space, dt_s) if residual else None
        self._low = np.asarray(space.low, np.float64)
        self._high = np.asarray(space.high, np.float64)
        self._norm_cfg = dict(obs_norm)
        self.norm = bool(obs_norm.get("norm_obs", False))
        if self.norm:
            self._mean = np.asarray(obs_norm["mean"], np.float64)
            self._std = np.sqrt(np.asarray(obs_norm["var"], np.float64) + float(obs_norm.get("epsilon", 1e-8)))
            self._clip = float(obs_norm.get("clip_obs", 10.0))
            if self._mean.shape != (self.feat_dim * self.k,):
                raise ValueError(
                    f"{name}: normalisation statistics have shape {self._mean.shape}, "
                    f"expected ({self.feat_dim * self.k},)"
                )

    # -- SB3 interface ----------------------------------------------------------
    @property
    def state_size(self) -> int:
        """Memory per env: the last k observations, the observation aids' memory, then the residual's
        integrators."""
        m = self.residual.n_act if self.residual is not None else 0
        return self.k * self.feat_dim + self.features.memory_size + m

    def predict(
        self,
        observation: np.ndarray,
        state: np.ndarray | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        obs2 = obs.reshape(1, -1) if single else obs
        n, kd = obs2.shape[0], self.k * self.feat_dim
        km = kd + self.features.memory_size
        if self.trained_on != self.env_id and obs2.shape[1] > self.obs_dim:
            obs2 = obs2[:, : self.obs_dim]
        if obs2.shape[1] != self.obs_dim:
            raise ValueError(f"{self.name}: observation must have {self.obs_dim} entries, got shape {obs.shape}")
        state_arr = None if state is None else np.asarray(state, np.float64)
        if state_arr is None or state_arr.shape != (n, self.state_size):
            state_arr = np.zeros((n, self.state_size))
            starts = np.ones(n, bool)
        elif episode_start is None:
            starts = np.zeros(n, bool)
        else:
            starts = np.broadcast_to(np.asarray(episode_start, bool).reshape(-1), (n,))
        feat, memory = self.features.step(obs2, state_arr[:, kd:km], starts)
        hist = push_history(state_arr[:, :kd].reshape(n, self.k, self.feat_dim), feat.astype(np.float64), starts)
        x = hist.reshape(n, kd).astype(np.float32)
        if self.norm:
            x = np.clip((x - self._mean) / self._std, -self._clip, self._clip).astype(np.float32)
        if self.policy_off:  # ablation: the residual's base law alone (agent action 0)
            a = np.zeros((n, self.action_space.shape[0]))  # type: ignore[index]
        else:
            a, _ = self.model.predict(x, deterministic=deterministic)
            a = np.asarray(a, np.float64).reshape(n, -1)
        new_state = np.empty_like(state_arr)
        new_state[:, :kd] = hist.reshape(n, kd)
        new_state[:, kd:km] = memory
        if self.residual is not None:
            integ = np.where(starts[:, None], 0.0, state_arr[:, km:])
            u, new_state[:, km:] = self.residual.step(obs2, a, integ)
        else:
            a = np.clip(a, -1.0, 1.0)
            u = self._low + (a + 1.0) * 0.5 * (self._high - self._low)
        u = u.astype(np.float32)
        return (u[0] if single else u), new_state

    def base_law(self) -> AgentController:
        """The same controller with the policy switched off (agent action 0):
        with a residual config this is the PI base law the agent corrects; the
        ablation that shows what the learning itself contributes."""
        return AgentController(
            self.model, self.config, self._norm_cfg, self.env_id, name=f"{self.name}_base_law", policy_off=True,
            trained_on=None if self.trained_on == self.env_id else self.trained_on,
        )

    def reset(self) -> None:
        """Nothing to do: all memory lives in ``state``."""

    def __repr__(self) -> str:
        return f"AgentController({self.name!r}, env_id={self.env_id!r}, frame_stack={self.k})"


def agent_files(name: str, env_id: str, zoo: str | Path | None = None) -> tuple[Path, Path, Path]:
    """(model zip, config yml, obs_norm json) of a shipped agent."""
    d = Path(zoo or ZOO_DIR) / env_id
    return d / f"{name}.zip", d / f"{name}.yml", d / f"{name}_obs_norm.json"


def available_agents(env_id: str, zoo: str | Path | None = None) -> list[str]:
    d = Path(zoo or ZOO_DIR) / env_id
    return sorted(p.stem for p in d.glob("*.zip") if (d / f"{p.stem}.yml").is_file()) if d.is_dir() else []


def load_from_files(model_path: Path, config_path: Path, norm_path: Path, env_id: str, name: str,
                    deploy_on: str | None = None) -> AgentController:
    """``deploy_on``: run the agent trained on ``env_id`` on another task (the generalisation
    table, docs/agents.md): same action, its observation's first columns, observation aids
    computed from the deployment task's scenario."""
    config = yaml.safe_load(config_path.read_text())
    algo = str(config.get("algo", name)).lower()
    cfg_env = config.get("env_id", env_id)
    if cfg_env != env_id:
        raise ValueError(f"agent {name!r} was trained on {cfg_env!r}, not {env_id!r}")
    model = algo_class(algo).load(str(model_path), device="cpu")
    obs_norm = json.loads(norm_path.read_text()) if norm_path.is_file() else {"norm_obs": False}
    if deploy_on is not None and deploy_on != env_id:
        return AgentController(model, config, obs_norm, deploy_on, name=name, trained_on=env_id)
    return AgentController(model, config, obs_norm, env_id, name=name)


def load_agent(
    name: str, env_id: str, zoo: str | Path | None = None, run_dir: str | Path | None = None,
    deploy_on: str | None = None,
) -> AgentController:
    """The shipped agent ``name`` (e.g. "ppo") for ``env_id`` as a raw-observation controller.

    ``run_dir`` loads a training run directory instead (its ``best/`` checkpoint
    if there is one, else the final model). ``deploy_on`` runs it on another task
    (see :func:`load_from_files`)."""
    if run_dir is not None:
        r = Path(run_dir)
        if (r / "best" / "best_model.zip").is_file():
            return load_from_files(
                r / "best" / "best_model.zip", r / "config.yml", r / "best" / "obs_norm.json", env_id, name, deploy_on
            )
        return load_from_files(r / "model.zip", r / "config.yml", r / "obs_norm.json", env_id, name, deploy_on)
    model_path, config_path, norm_path = agent_files(name, env_id, zoo)
    if not model_path.is_file() or not config_path.is_file():
        have = available_agents(env_id, zoo)
        raise NoShippedAgent(
            f"no shipped agent {name!r} for {env_id!r} (looked for {model_path}); "
            f"available: {', '.join(have) if have else 'none'}"
        )
    return load_from_files(model_path, config_path, norm_path, env_id, name, deploy_on)
