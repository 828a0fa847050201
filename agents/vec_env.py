"""A stable-baselines3 ``VecEnv`` over the native batched env, and the
training stack's wrappers in batched form (docs/agents.md, "The native VecEnv").

:class:`ThermoValveVecEnv` steps N ThermoValve envs with one call of the
batched kernel (:class:`valve_env.envs.vector.ThermoValveVectorEnv`, one
process) and speaks SB3's ``VecEnv`` protocol exactly as ``DummyVecEnv`` of
``gym.make(id, ...)`` envs does:

* autoreset in the same step: when env i's episode ends, ``step_wait``
  returns the first observation of its next episode, the last one in
  ``infos[i]["terminal_observation"]`` and the reset's info in
  ``reset_infos[i]``; every info carries ``"TimeLimit.truncated"``
  (``truncated and not terminated``); rewards are float32, dones bool.
* seeds: ``seed(s)`` (SB3) gives env i the seed ``s + i`` at the next
  ``reset()``, as ``DummyVecEnv.seed`` does, and the native env's own
  ``reset(seed=s)`` does the same (``s + i`` for env i), so
  ``ThermoValveVecEnv(id, N).seed(s)`` and ``DummyVecEnv([gym.make(id)] * N).seed(s)``
  draw the same scenarios; an autoreset continues env i's own generator
  (``reset()`` without a seed), in both. Seeds are used once (SB3).
* ``set_options``: the ThermoValve envs take no reset options; options
  are passed on to the native env when they are the same for every env.
* ``get_attr``/``env_method``: per-env quantities (``hidden_state``,
  ``layer_temperatures``, ``step_index``, ``stored_energy_J``,
  ``energy_account``, ``np_random_seed``) are env i's; every other attribute
  is shared by all envs (``cfg``, ``render_mode`` = None; the single env's
  ``observation_space``/``action_space``). The batched env does not render.

The batched training wrappers (:class:`VecKPIInfo`, :class:`VecEnergyShaping`,
:class:`VecResidualAction`, :class:`VecScaleObservation`,
:class:`VecHistory`) are the single-env wrappers of :mod:`agents.wrappers`
applied to all envs at once, built on the same cores (``ResidualCore``,
``scale_obs``, ``push_history``); ``make_vec_env(..., vec="native")`` stacks
them in the same order, and ``tests/agents/test_vec_env.py`` checks both
stacks step by step against each other.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
    VecEnvWrapper,
)

import valve_env
from agents.wrappers import KPI_KEYS, ObsFeatures, ResidualCore, push_history
from valve_env.envs.vector import ThermoValveVectorEnv

#: attributes/methods that differ between envs: answered for env i (see the module docstring)
_PER_ENV_ATTRS: tuple[str, ...] = ("hidden_state", "layer_temperatures", "step_index", "np_random_seed", "np_random")
_PER_ENV_METHODS: tuple[str, ...] = ("stored_energy_J", "energy_account", "kpis")


#: per tuple of info keys, a function building the per-env dicts from one list per key (_rows_builder)
_ROW_BUILDERS: dict[tuple[str, ...], Callable[..., list[dict[str, Any]]]] = {}


def _rows_builder(keys: tuple[str, ...]) -> Callable[..., list[dict[str, Any]]]:
    """``f(col_0, ..., col_m)`` -> ``[{keys[0]: col_0[i], ..., keys[m]: col_m[i]} for i]``, compiled once
    per tuple of keys: a dict display with constant keys is CPython's fastest way to build a small
    dict (at N = 256, 9 keys: 0.27 against 0.37 ms per step for a loop of per-key assignments)."""
    fn = _ROW_BUILDERS.get(keys)
    if fn is None:
        if not all(isinstance(k, str) for k in keys):
            raise TypeError(f"info keys must be strings, got {keys!r}")
        cols = ", ".join(f"c{j}" for j in range(len(keys)))
        vals = ", ".join(f"v{j}" for j in range(len(keys)))
        items = ", ".join(f"{k!r}: v{j}" for j, k in enumerate(keys))
        src = f"def build({cols}):\n    return [{{{items}}} for {vals}{',' if len(keys) == 1 else ''} in zip({cols})]\n"
        ns: dict[str, Any] = {}
        exec(compile(src, f"<info rows {len(keys)}>", "exec"), ns)  # noqa: S102 (keys are repr'd strings)
        fn = _ROW_BUILDERS[keys] = ns["build"]
    return fn


def _unbatch_info(
    info: Mapping[str, Any], n: int, extra: Mapping[str, list[Any]] | None = None
) -> list[dict[str, Any]]:
    """Gymnasium's vectorised info (arrays over envs with ``_key`` masks) as a list
    of per-env dicts of Python scalars: what ``gymnasium.wrappers.vector.DictInfoToList``
    does, with ``tolist`` (the single env's info holds Python floats) and without a
    Python loop per key over the envs where a key is set for all (a step at N = 1024 is a
    few microseconds of kernel: the conversion must not dwarf it). ``extra``: further keys
    set for every env, one list each, after the info's own."""
    keys: list[str] = []
    cols: list[list[Any]] = []
    partial: list[tuple[str, np.ndarray, list[Any]]] = []
    for key, value in info.items():
        if key.startswith("_"):
            continue
        mask = info.get("_" + key)
        vals = _unbatch_info(value, n) if isinstance(value, Mapping) else np.asarray(value).tolist()
        if mask is None or mask.all():
            keys.append(key)
            cols.append(vals)
        else:
            partial.append((key, mask, vals))
    if extra:
        keys.extend(extra)
        cols.extend(extra.values())
    infos = _rows_builder(tuple(keys))(*cols) if keys else [{} for _ in range(n)]
    for key, mask, vals in partial:
        for i in np.flatnonzero(mask).tolist():
            infos[i][key] = vals[i]
    return infos


class ThermoValveVecEnv(VecEnv):
    """SB3 ``VecEnv`` of N ThermoValve envs stepped by the native batched kernel.

    ``ThermoValveVecEnv(env_id, num_envs, **env_kwargs)`` builds
    ``gym.make_vec(env_id, num_envs, vectorization_mode="vector_entry_point", **env_kwargs)``
    (``env_kwargs`` as for ``gym.make``: ``config=``, ``control=``, ...,
    ``max_episode_steps=``); the kernel runs serially unless ``threads=True``
    (then on numba's threads from the native env's ``parallel_threshold``
    envs on); ``ThermoValveVecEnv.from_vector(vec)`` adapts
    an existing :class:`ThermoValveVectorEnv`. See the module docstring.
    """

    def __init__(
        self, env_id: str = "ThermoValve-v0", num_envs: int = 1, threads: bool = False, **env_kwargs: Any
    ) -> None:
        if env_id not in valve_env.ALL_ENV_IDS:
            raise ValueError(f"unknown env id {env_id!r}; known: {', '.join(valve_env.ALL_ENV_IDS)}")
        vec = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **env_kwargs)
        base = vec.unwrapped
        if not threads:
            # one core for the kernel: in training the policy's torch thread needs the other core, and a
            # kernel step waiting for a numba thread that torch (or another process) holds is slow (at
            # N = 1024, PPO learn ran 26k against 15k and 67k against 46k env-steps/s serial vs
            # threaded in two interleaved pairs on the shared 2-core machine; docs/agents.md)
            base.parallel_threshold = num_envs + 1  # type: ignore[attr-defined]
        self._init_from(base)  # type: ignore[arg-type]
        self.env_id = env_id

    @classmethod
    def from_vector(cls, vec: ThermoValveVectorEnv) -> ThermoValveVecEnv:
        self = cls.__new__(cls)
        self._init_from(vec)
        self.env_id = next((k for k, m in valve_env.ENV_MODES.items() if m == vec.mode), "")
        return self

    def _init_from(self, vec: ThermoValveVectorEnv) -> None:
        if not isinstance(vec, ThermoValveVectorEnv):
            raise TypeError(f"expected a ThermoValveVectorEnv, got {type(vec).__name__}")
        self.vector_env = vec
        self.actions: np.ndarray = np.zeros((vec.num_envs, *vec.single_action_space.shape))  # type: ignore[misc]
        #: each env's stored heat after the last step, before any autoreset (J): the potential of
        #: the state the step's reward led to (VecEnergyShaping)
        self.step_stored_energy_J: np.ndarray = np.zeros(vec.num_envs)
        #: desync: the step at which each env's first episode after a reset() is cut (0: not cut)
        self._desync_rng: np.random.Generator | None = None
        self._cut_at: np.ndarray = np.zeros(vec.num_envs, np.int64)
        super().__init__(vec.num_envs, vec.single_observation_space, vec.single_action_space)

    def set_desync(self, seed: int | None) -> None:
        """Spread the envs over the time of day (docs/agents.md, "Desynchronised envs").

        All ThermoValve episodes start at midnight and last the same number of steps, so N envs
        reset together stay in step all day, and a rollout of n_steps < one day shows an update
        only one slice of the day. With a seed, every ``reset()`` from now on cuts env i's first
        episode at a step drawn uniformly from 1..episode_steps (truncated: ``TimeLimit.truncated``
        is True, the value is bootstrapped from ``terminal_observation``, ``info["desync_cut"]``
        marks it, the episode has no KPIs), after which env i runs whole days at its own phase;
        the random-no-op starts of Atari training serve the same purpose. ``None`` turns it off."""
        self._desync_rng = None if seed is None else np.random.default_rng(int(seed))

    @property
    def cfg(self) -> Any:
        return self.vector_env.cfg

    # -- VecEnv API ---------------------------------------------------------------
    def _native_options(self) -> dict[str, Any] | None:
        opts = self._options
        if not any(opts):
            return None
        if any(o != opts[0] for o in opts):
            raise ValueError("the native VecEnv resets all envs with one options dict; set_options gave different ones")
        return dict(opts[0])

    def reset(self) -> VecEnvObs:
        obs, info = self.vector_env.reset(seed=list(self._seeds), options=self._native_options())
        self.reset_infos = _unbatch_info(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        self.step_stored_energy_J = self.vector_env.stored_energy_J()
        if self._desync_rng is not None:
            self._cut_at = self._desync_rng.integers(1, self.vector_env.episode_steps, self.num_envs, endpoint=True)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self.actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        vec = self.vector_env
        obs, rewards, terminated, truncated, info = vec.step(self.actions)
        cut = None
        if self._cut_at.any():  # desync: cut the first episodes (set_desync)
            cut = (self._cut_at > 0) & (vec.step_index >= self._cut_at) & ~(terminated | truncated)
            self._cut_at[(terminated | truncated | cut) & (self._cut_at > 0)] = 0
            truncated = truncated | cut
        dones = terminated | truncated
        if cut is None:
            infos = _unbatch_info(info, self.num_envs, {"TimeLimit.truncated": (truncated & ~terminated).tolist()})
        else:
            infos = _unbatch_info(info, self.num_envs)
            for i in np.flatnonzero(cut).tolist():
                infos[i]["desync_cut"] = True
            for d, trunc in zip(infos, (truncated & ~terminated).tolist(), strict=True):
                d["TimeLimit.truncated"] = trunc
        self.step_stored_energy_J = vec.stored_energy_J()
        if dones.any():
            idx = np.flatnonzero(dones)
            for i in idx.tolist():
                infos[i]["terminal_observation"] = obs[i].copy()
            new_obs, reset_info = vec.reset(options={"reset_mask": dones})
            obs[idx] = new_obs[idx]
            reset_list = _unbatch_info(reset_info, self.num_envs)
            for i in idx.tolist():
                self.reset_infos[i] = reset_list[i]
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.vector_env.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs

    # -- attributes ---------------------------------------------------------------
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        idx = list(self._get_indices(indices))
        vec = self.vector_env
        if attr_name in ("observation_space", "action_space"):
            return [getattr(vec, "single_" + attr_name)] * len(idx)
        if attr_name == "np_random_seed":
            return [vec.np_random_seeds[i] for i in idx]
        if attr_name == "np_random":
            return [vec.np_randoms[i] for i in idx]
        if attr_name in _PER_ENV_ATTRS:
            value = getattr(vec, attr_name)
            if isinstance(value, Mapping):
                return [{k: float(v[i]) for k, v in value.items()} for i in idx]
            return [value[i].copy() if isinstance(value[i], np.ndarray) else value[i].item() for i in idx]
        return [getattr(vec, attr_name)] * len(idx)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        idx = list(self._get_indices(indices))
        if attr_name in _PER_ENV_ATTRS or len(idx) != self.num_envs:
            raise AttributeError(
                f"the native VecEnv's envs share their attributes; cannot set {attr_name!r} for some envs only"
            )
        setattr(self.vector_env, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        idx = list(self._get_indices(indices))
        vec = self.vector_env
        if method_name == "stored_energy_J":
            e = vec.stored_energy_J()
            return [float(e[i]) for i in idx]
        if method_name in ("energy_account", "kpis"):
            return [getattr(vec, method_name)(i) for i in idx]
        method = getattr(vec, method_name)
        if method_name in ("reset", "step"):
            raise AttributeError(f"call {method_name} on the VecEnv, not through env_method")
        return [method(*method_args, **method_kwargs)] * len(idx)

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        """The native env has no wrappers; its built-in sensor noise and dead time
        count as ``SensorNoise``/``ObservationDelay`` where the config enables them."""
        from valve_env.envs.wrappers import ObservationDelay, SensorNoise

        sens = self.cfg.sensors
        wrapped = (wrapper_class is SensorNoise and (sens.noise_K > 0 or sens.flow_noise_rel > 0)) or (
            wrapper_class is ObservationDelay and sens.dead_time_steps > 0
        )
        return [bool(wrapped)] * len(list(self._get_indices(indices)))


# ------------------------------------------------------------------------------ training wrappers
def native_of(venv: VecEnv) -> ThermoValveVecEnv:
    base = venv.unwrapped
    if not isinstance(base, ThermoValveVecEnv):
        raise TypeError(f"expected a stack over ThermoValveVecEnv, got {type(base).__name__}")
    return base


class VecKPIInfo(VecEnvWrapper):
    """agents.wrappers.KPIInfo for all envs: the KPIs as top-level info keys at episode end (for VecMonitor)."""

    def reset(self) -> VecEnvObs:
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        for i in np.flatnonzero(dones).tolist():
            kpis = infos[i].get("kpis")
            infos[i].update({k: float(kpis.get(k, np.nan)) if kpis else float("nan") for k in KPI_KEYS})
        return obs, rewards, dones, infos


class VecEnergyShaping(VecEnvWrapper):
    """agents.wrappers.EnergyPotentialShaping for all envs (training only; see there).
    With ``active=False`` it passes rewards through: the evaluation stack keeps the
    layer so that SB3's ``sync_envs_normalization`` finds its VecNormalize at the
    same depth as the training stack's."""

    def __init__(self, venv: VecEnv, gamma: float, active: bool = True) -> None:
        super().__init__(venv)
        self.active = bool(active)
        base = native_of(venv)
        cfg = base.cfg
        self.gamma = float(gamma)
        self._scale = cfg.control.w_energy / (1000.0 * cfg.control.dt_s)
        self._E_ref = cfg.tank.n_layers * cfg.tank.layer_mass_kg * cfg.tank.cp * cfg.control.T_target_C
        self._base = base
        self._phi = np.zeros(self.num_envs)

    def reset(self) -> VecEnvObs:
        obs = self.venv.reset()
        self._phi = self._scale * (self._base.vector_env.stored_energy_J() - self._E_ref)
        return obs

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        if not self.active:
            return obs, rewards, dones, infos
        phi = self._scale * (self._base.step_stored_energy_J - self._E_ref)
        if dones.any():
            for i in np.flatnonzero(dones).tolist():
                if not infos[i].get("TimeLimit.truncated", False):
                    phi[i] = 0.0  # terminated: no future
        shaped = rewards.astype(np.float64) + self.gamma * phi - self._phi
        if dones.any():  # a reset env's potential is its new episode's
            phi = np.where(dones, self._scale * (self._base.vector_env.stored_energy_J() - self._E_ref), phi)
        self._phi = phi
        return obs, shaped.astype(np.float32), dones, infos


class VecResidualAction(VecEnvWrapper):
    """agents.wrappers.ResidualAction for all envs: agent actions in [-1, 1], raw actions from ResidualCore."""

    def __init__(self, venv: VecEnv, cfg: Mapping[str, Any]) -> None:
        space = venv.action_space
        assert isinstance(space, gym.spaces.Box)
        self.core = ResidualCore.from_config(cfg, space, float(native_of(venv).cfg.control.dt_s))
        super().__init__(venv, action_space=gym.spaces.Box(-1.0, 1.0, shape=space.shape, dtype=np.float32))
        self._obs = np.zeros((self.num_envs, *venv.observation_space.shape))  # type: ignore[misc]
        self._integ = self.core.initial_state(self.num_envs)

    def reset(self) -> VecEnvObs:
        obs = self.venv.reset()
        self._obs = np.asarray(obs)
        self._integ = self.core.initial_state(self.num_envs)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        u, self._integ = self.core.step(self._obs, np.asarray(actions).reshape(self.num_envs, -1), self._integ)
        self.venv.step_async(u.astype(np.float32))

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        self._obs = np.asarray(obs)
        if dones.any():
            self._integ[dones] = 0.0
        return obs, rewards, dones, infos


class VecRescaleAction(VecEnvWrapper):
    """gymnasium's RescaleAction to [-1, 1] for all envs (the stack without a residual)."""

    def __init__(self, venv: VecEnv) -> None:
        space = venv.action_space
        assert isinstance(space, gym.spaces.Box)
        self._low = np.asarray(space.low, np.float64)
        self._high = np.asarray(space.high, np.float64)
        super().__init__(venv, action_space=gym.spaces.Box(-1.0, 1.0, shape=space.shape, dtype=np.float32))

    def reset(self) -> VecEnvObs:
        return self.venv.reset()

    def step_async(self, actions: np.ndarray) -> None:
        a = np.asarray(actions, np.float64)
        u = np.clip(self._low + (self._high - self._low) * ((a + 1.0) / 2.0), self._low, self._high)
        self.venv.step_async(u.astype(np.float32))

    def step_wait(self) -> VecEnvStepReturn:
        return self.venv.step_wait()


class _ObsTransform(VecEnvWrapper):
    """An observation map applied to observations and terminal observations alike."""

    def transform(self, obs: np.ndarray, dones: np.ndarray | None) -> np.ndarray:
        raise NotImplementedError

    def terminal(self, i: int, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def reset(self) -> VecEnvObs:
        return self.transform(np.asarray(self.venv.reset()), None)

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        for i in np.flatnonzero(dones).tolist():
            infos[i]["terminal_observation"] = self.terminal(i, infos[i]["terminal_observation"])
        return self.transform(np.asarray(obs), dones), rewards, dones, infos


class VecScaleObservation(_ObsTransform):
    """agents.wrappers.ScaleObservation for all envs (ObsFeatures: fixed physical scaling,
    error for target, observation aids)."""

    def __init__(self, venv: VecEnv, features: ObsFeatures | None = None) -> None:
        shape = venv.observation_space.shape
        assert shape is not None
        self.features = features or ObsFeatures(True, (), ())
        super().__init__(venv, observation_space=gym.spaces.Box(-np.inf, np.inf, shape=(self.features.size(shape[0]),),
                                                                dtype=np.float32))

        self._memory = self.features.initial_memory(self.num_envs)

    def transform(self, obs: np.ndarray, dones: np.ndarray | None) -> np.ndarray:
        starts = np.ones(self.num_envs, bool) if dones is None else np.asarray(dones, bool)
        feat, self._memory = self.features.step(obs, self._memory, starts)
        return feat

    def terminal(self, i: int, obs: np.ndarray) -> np.ndarray:
        # the episode's last observation, with the memory it ended with (before the reset clears it)
        return self.features.step(np.atleast_2d(obs), self._memory[i:i + 1], np.zeros(1, bool))[0][0]


class VecHistory(_ObsTransform):
    """FrameStackObservation(k, padding_type="reset") + FlattenObservation for all envs:
    the last k observations, oldest first, a new episode padded with its first one
    (SB3's VecFrameStack pads with zeros: not what the deployed controller replays)."""

    def __init__(self, venv: VecEnv, k: int) -> None:
        space = venv.observation_space
        assert isinstance(space, gym.spaces.Box) and space.shape is not None and len(space.shape) == 1
        self.k = int(k)
        self._d = int(space.shape[0])
        stacked = gym.spaces.Box(np.tile(space.low, self.k), np.tile(space.high, self.k), dtype=space.dtype)  # type: ignore[arg-type]
        super().__init__(venv, observation_space=stacked)
        self._hist = np.zeros((self.num_envs, self.k, self._d), space.dtype)

    def transform(self, obs: np.ndarray, dones: np.ndarray | None) -> np.ndarray:
        starts = np.ones(self.num_envs, bool) if dones is None else dones
        push_history(self._hist, obs, starts, in_place=True)
        return self._hist.reshape(self.num_envs, -1).copy()

    def terminal(self, i: int, obs: np.ndarray) -> np.ndarray:
        # the episode's last frame joins the history it ended with (before the reset refills it)
        return np.concatenate([self._hist[i, 1:].reshape(-1), np.asarray(obs, self._hist.dtype)])


def make_native_stack(
    env_id: str,
    cfg: Mapping[str, Any],
    seed: int,
    n_envs: int,
    monitor_file: str | None = None,
    training: bool = True,
    env_kwargs: Mapping[str, Any] | None = None,
) -> VecEnv:
    """agents.wrappers.wrap_env's stack over :class:`ThermoValveVecEnv` (before VecNormalize)."""
    from stable_baselines3.common.vec_env import VecMonitor

    kwargs = dict(cfg.get("env_kwargs") or {}) if env_kwargs is None else dict(env_kwargs)
    venv: VecEnv = ThermoValveVecEnv(env_id, n_envs, **kwargs)
    if training and cfg.get("desync"):
        venv.set_desync(seed)  # type: ignore[attr-defined]
    venv = VecMonitor(VecKPIInfo(venv), filename=monitor_file, info_keywords=KPI_KEYS)
    if cfg.get("energy_shaping"):
        venv = VecEnergyShaping(venv, float((cfg.get("hyperparams") or {}).get("gamma", 0.99)), active=training)
    residual = cfg.get("residual")
    venv = VecResidualAction(venv, residual) if residual else VecRescaleAction(venv)
    features = ObsFeatures.from_config(cfg, native_of(venv))
    if features.active:
        venv = VecScaleObservation(venv, features)
    k = int(cfg.get("frame_stack", 1) or 1)
    if k > 1:
        venv = VecHistory(venv, k)
    venv.action_space.seed(seed)
    venv.seed(seed)
    return venv


__all__ = [
    "ThermoValveVecEnv",
    "VecEnergyShaping",
    "VecHistory",
    "VecKPIInfo",
    "VecRescaleAction",
    "VecResidualAction",
    "VecScaleObservation",
    "make_native_stack",
    "native_of",
]
