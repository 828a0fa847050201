"""The wrappers an agent trains with, and their stateless-in-the-wrapper cores
that the deployed controller (agents.loader) replays on raw observations.

Training stack, innermost first::

    gym.make(env_id, **env_kwargs)
    -> Monitor                      (true reward, episode length, KPIs into the monitor CSV)
    -> EnergyPotentialShaping       (optional, training only: potential-based shaping of the energy term)
    -> ResidualAction | RescaleAction   (the agent acts in [-1, 1]; see below)
    -> ScaleObservation             (optional, obs_scaling: physical; fixed scaling, error for target)
    -> FrameStackObservation + FlattenObservation   (history: the friction state is not observed)
    -> DummyVecEnv | SubprocVecEnv -> VecNormalize  (observation and reward normalisation)

or, with ``vec_env: native``, the same wrappers in batched form over the native batched env
(agents.vec_env: ThermoValveVecEnv -> VecKPIInfo + VecMonitor -> VecEnergyShaping ->
VecResidualAction -> VecScaleObservation -> VecHistory -> VecNormalize).

``ResidualAction`` makes the action a bounded correction around a sensible
setting: ``u = clip(base + span * a)`` where ``base`` is either a fixed centre
(the outlet target for a temperature setting) or a PI law on the outlet
error (``center + kp e + ki integral(e dt)``, conditional-integration
anti-windup). With ``a = 0`` the agent *is* that base law, so learning only
has to find the improvement (residual policy learning).

Both the wrapper and the deployed controller call the same ``ResidualCore``
and ``push_history`` code, so training and deployment cannot drift apart.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import FlattenObservation, FrameStackObservation, RescaleAction
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecNormalize

import valve_env  # noqa: F401  (registers the environments)
from agents.train import VEC_KINDS  # the VecEnv kinds of make_vec_env (configs' vec_env, train --vec)
from valve_env.envs.thermovalve import OBS_NAMES

I_T_OUT = OBS_NAMES.index("T_out_C")
I_TARGET = OBS_NAMES.index("T_target_C")
KPI_KEYS: tuple[str, ...] = (
    "rmse_K",
    "iae_Kh",
    "tdis_Kh",
    "unmet_kWh",
    "heat_kWh",
    "pump_kWh",
    "return_C",
    "travel_mm",
    "reversals",
)


# --------------------------------------------------------------------------- cores
@dataclass
class ResidualCore:
    """Maps agent actions in [-1, 1]^m to raw env actions, batched over n envs.

    ``center[j]`` is a number or the string ``"target"`` (the observed outlet
    target, obs index T_target_C); ``kp``/``ki`` (per K and per K h) give the
    PI part on the outlet error e = T_target - T_out (0 for a fixed centre);
    ``span`` is the residual's half-range in the action's unit.
    """

    low: np.ndarray
    high: np.ndarray
    center: Sequence[float | str]
    span: np.ndarray
    kp: np.ndarray
    ki: np.ndarray
    dt_h: float

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], space: gym.spaces.Box, dt_s: float) -> ResidualCore:
        m = int(space.shape[0])

        def vec(key: str, default: float) -> np.ndarray:
            v = cfg.get(key, default)
            arr = np.broadcast_to(np.asarray(v, dtype=np.float64), (m,)).copy()
            return arr

        center = cfg.get("center", ["target"] * m)
        if isinstance(center, (str, int, float)):
            center = [center] * m
        if len(center) != m:
            raise ValueError(f"residual.center needs {m} entries, got {center!r}")
        for c in center:
            if isinstance(c, str) and c != "target":
                raise ValueError(f"residual.center entries are numbers or 'target', got {c!r}")
        span = vec("span", 1.0)
        if np.any(span <= 0):
            raise ValueError(f"residual.span must be > 0, got {span.tolist()}")
        return cls(
            low=np.asarray(space.low, np.float64),
            high=np.asarray(space.high, np.float64),
            center=list(center),
            span=span,
            kp=vec("kp", 0.0),
            ki=vec("ki", 0.0),
            dt_h=float(dt_s) / 3600.0,
        )

    @property
    def n_act(self) -> int:
        return int(self.low.shape[0])

    def initial_state(self, n: int) -> np.ndarray:
        """The PI integrators, (n, m) in K h."""
        return np.zeros((n, self.n_act))

    def step(self, obs: np.ndarray, a: np.ndarray, integ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw actions (n, m) for agent actions ``a`` (n, m) given the raw
        observations ``obs`` (n, obs_dim) the agent acted on; returns the new
        integrator state (the input is not modified)."""
        obs = np.atleast_2d(np.asarray(obs, np.float64))
        a = np.clip(np.atleast_2d(np.asarray(a, np.float64)), -1.0, 1.0)
        target = obs[:, I_TARGET]
        e = target - obs[:, I_T_OUT]
        base = np.empty_like(a)
        for j, c in enumerate(self.center):
            base[:, j] = target if c == "target" else float(c)
        new_integ = integ + e[:, None] * self.dt_h
        pi = base + self.kp * e[:, None] + self.ki * new_integ + self.span * a
        # conditional integration: do not integrate while the output saturates in the error's direction
        sat = ((pi > self.high) & (e[:, None] * np.sign(self.ki) > 0)) | (
            (pi < self.low) & (e[:, None] * np.sign(self.ki) < 0)
        )
        new_integ = np.where(sat, integ, new_integ)
        u = base + self.kp * e[:, None] + self.ki * new_integ + self.span * a
        return np.clip(u, self.low, self.high), new_integ


#: Fixed physical scaling of the policy's inputs: (obs - center) / scale, per OBS_NAMES.
#: T_target_C (constant in an env) is replaced by the outlet error T_target - T_out.
#: Fixed, not running statistics: constant inputs (target, supply temperature,
#: network dp in ThermoValve-v0) would otherwise be divided by a vanishing
#: running variance and drift as the statistics update, moving the policy.
OBS_SCALING: dict[str, tuple[float, float]] = {
    "T_out_C": (60.0, 5.0),
    "T_pocket_C": (60.0, 5.0),
    "T_bottom_C": (40.0, 15.0),
    "T_supply_C": (70.0, 10.0),
    "T_return_C": (40.0, 15.0),
    "q_primary_kgh": (150.0, 300.0),
    "dp_mbar": (100.0, 100.0),
    "draw_l_min": (0.0, 5.0),
    "tod_sin": (0.0, 1.0),
    "tod_cos": (0.0, 1.0),
    "setting_C": (60.0, 5.0),
    "T_target_C": (0.0, 2.0),  # applied to the error T_target - T_out
}
_CENTER = np.array([OBS_SCALING[n][0] for n in OBS_NAMES])
_SCALE = np.array([OBS_SCALING[n][1] for n in OBS_NAMES])


def scale_obs(obs: np.ndarray) -> np.ndarray:
    """The policy's input features from raw observations (n, 12) or (12,)."""
    o = np.array(obs, dtype=np.float64, copy=True)
    o[..., I_TARGET] = o[..., I_TARGET] - o[..., I_T_OUT]
    return ((o - _CENTER) / _SCALE).astype(np.float32)


class ScaleObservation(gym.ObservationWrapper[np.ndarray, np.ndarray, np.ndarray]):
    """Applies :func:`scale_obs` (fixed physical scaling, error instead of target)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        shape = env.observation_space.shape
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=shape, dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return scale_obs(observation)


def push_history(hist: np.ndarray, obs: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """The last k observations, oldest first, exactly as gymnasium's
    FrameStackObservation(padding_type="reset") keeps them: ``hist`` (n, k, d),
    ``obs`` (n, d); rows flagged in ``starts`` restart filled with ``obs``."""
    shifted = np.concatenate([hist[:, 1:], obs[:, None, :]], axis=1)
    fresh = np.broadcast_to(obs[:, None, :], hist.shape)
    return np.where(starts[:, None, None], fresh, shifted)


# --------------------------------------------------------------------------- wrappers
class ResidualAction(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """The agent acts in [-1, 1]^m; the env receives ``ResidualCore``'s raw action."""

    def __init__(self, env: gym.Env, cfg: Mapping[str, Any]) -> None:
        super().__init__(env)
        space = env.action_space
        assert isinstance(space, gym.spaces.Box)
        dt_s = float(env.unwrapped.cfg.control.dt_s)  # type: ignore[attr-defined]
        self.core = ResidualCore.from_config(cfg, space, dt_s)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=space.shape, dtype=np.float32)
        self._obs: np.ndarray | None = None
        self._integ = self.core.initial_state(1)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        self._obs = np.asarray(obs)
        self._integ = self.core.initial_state(1)
        return obs, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        u, self._integ = self.core.step(self._obs, np.asarray(action).reshape(1, -1), self._integ)
        obs, r, term, trunc, info = self.env.step(u[0].astype(np.float32))
        self._obs = np.asarray(obs)
        return obs, float(r), term, trunc, info


class KPIInfo(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """Copies ``info["kpis"]`` into top-level info keys at episode end, so that
    SB3's Monitor (``info_keywords=KPI_KEYS``) writes them into its CSV."""

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, r, term, trunc, info = self.env.step(action)
        if "kpis" in info:
            info = {**info, **{k: float(info["kpis"].get(k, np.nan)) for k in KPI_KEYS}}
        elif term or trunc:  # cut short by a TimeLimit: no KPIs, keep the monitor's columns
            info = {**info, **{k: float("nan") for k in KPI_KEYS}}
        return obs, float(r), term, trunc, info


class EnergyPotentialShaping(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """Potential-based reward shaping (Ng, Harada and Russell 1999), training only.

    The reward charges the heat drawn from the primary side when it flows,
    but heat put into the tank now is heat not needed later: under a discount
    gamma < 1 that makes *postponing* heating look cheap (a myopic bias), and
    the 10 kW bursts during draws dominate the reward's variance. With the
    potential Phi(s) = w_energy * (E_stored(s) - E_ref) / (1 kW * dt) (the
    energy term's units, E_ref the tank at the outlet target) the shaped reward
    r + gamma Phi(s') - Phi(s) credits heat when it is stored. The optimal
    policy is unchanged (a potential-based shaping); Monitor, placed inside
    this wrapper, still logs the true reward, and the evaluator never sees it.
    """

    def __init__(self, env: gym.Env, gamma: float) -> None:
        super().__init__(env)
        u = env.unwrapped
        cfg = u.cfg  # type: ignore[attr-defined]
        self.gamma = float(gamma)
        self._scale = cfg.control.w_energy / (1000.0 * cfg.control.dt_s)
        self._E_ref = cfg.tank.n_layers * cfg.tank.layer_mass_kg * cfg.tank.cp * cfg.control.T_target_C
        self._phi = 0.0

    def _potential(self) -> float:
        return self._scale * (float(self.env.unwrapped.stored_energy_J()) - self._E_ref)  # type: ignore[attr-defined]

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        self._phi = self._potential()
        return obs, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, r, term, trunc, info = self.env.step(action)
        phi = 0.0 if term else self._potential()
        shaped = float(r) + self.gamma * phi - self._phi
        self._phi = phi
        return obs, shaped, term, trunc, info


def wrap_env(
    env: gym.Env,
    cfg: Mapping[str, Any],
    monitor_file: str | None = None,
    monitor: bool = True,
    shape_reward: bool = True,
) -> gym.Env:
    """Apply the single-env part of the training stack described in the module docstring."""
    if monitor:
        env = Monitor(KPIInfo(env), filename=monitor_file, info_keywords=KPI_KEYS)
    if cfg.get("energy_shaping") and shape_reward:
        env = EnergyPotentialShaping(env, gamma=float((cfg.get("hyperparams") or {}).get("gamma", 0.99)))
    residual = cfg.get("residual")
    if residual:
        env = ResidualAction(env, residual)
    else:
        shape: tuple[int, ...] = tuple(env.action_space.shape or (1,))
        env = RescaleAction(env, np.full(shape, -1.0, np.float32), np.full(shape, 1.0, np.float32))
    if cfg.get("obs_scaling") == "physical":
        env = ScaleObservation(env)
    k = int(cfg.get("frame_stack", 1) or 1)
    if k > 1:
        env = FrameStackObservation(env, k, padding_type="reset")
        env = FlattenObservation(env)
    return env


def make_env_fn(
    env_id: str,
    cfg: Mapping[str, Any],
    seed: int,
    rank: int,
    monitor_dir: str | Path | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    training: bool = True,
) -> Callable[[], gym.Env]:
    kwargs = dict(cfg.get("env_kwargs") or {}) if env_kwargs is None else dict(env_kwargs)

    def _init() -> gym.Env:
        env = gym.make(env_id, **kwargs)
        mfile = None if monitor_dir is None else str(Path(monitor_dir) / f"{rank}")
        env = wrap_env(env, cfg, monitor_file=mfile, shape_reward=training)
        env.reset(seed=seed + rank)
        env.action_space.seed(seed + rank)
        return env

    return _init


def make_vec_env(
    env_id: str,
    cfg: Mapping[str, Any],
    seed: int,
    n_envs: int | None = None,
    monitor_dir: str | Path | None = None,
    training: bool = True,
    env_kwargs: Mapping[str, Any] | None = None,
    vec: str | None = None,
) -> VecEnv:
    """The vectorised, normalised training (or evaluation) environment.

    ``vec`` (default: the config's ``vec_env``, else ``dummy``) picks the
    ``VecEnv``: ``native`` the batched kernel with the batched form of this
    module's wrappers (agents.vec_env.make_native_stack; one VecMonitor file
    ``native.monitor.csv`` for all envs), ``dummy``/``subproc`` SB3's
    ``DummyVecEnv``/``SubprocVecEnv`` of single wrapped envs (one Monitor file
    per env). Both give the same episodes on the same seed (env i: seed + i).
    """
    n = int(n_envs if n_envs is not None else cfg.get("n_envs", 1))
    kind = str(vec if vec is not None else cfg.get("vec_env", "dummy"))
    if kind not in VEC_KINDS:
        raise ValueError(f"vec_env must be one of {', '.join(VEC_KINDS)}, got {kind!r}")
    venv: VecEnv
    if kind == "native":
        from agents.vec_env import make_native_stack

        mfile = None if monitor_dir is None else str(Path(monitor_dir) / "native")
        venv = make_native_stack(env_id, cfg, seed, n, monitor_file=mfile, training=training, env_kwargs=env_kwargs)
    else:
        fns = [make_env_fn(env_id, cfg, seed, i, monitor_dir, env_kwargs, training) for i in range(n)]
        if kind == "subproc" and n > 1:
            venv = SubprocVecEnv(fns, start_method="spawn")
        else:
            venv = DummyVecEnv(fns)
        venv.seed(seed)
    norm = cfg.get("normalize") or {}
    if norm:
        venv = VecNormalize(
            venv,
            training=training,
            norm_obs=bool(norm.get("norm_obs", True)),
            norm_reward=bool(norm.get("norm_reward", True)) and training,
            clip_obs=float(norm.get("clip_obs", 10.0)),
            clip_reward=float(norm.get("clip_reward", 10.0)),
            gamma=float(cfg.get("hyperparams", {}).get("gamma", 0.99)),
        )
    return venv
