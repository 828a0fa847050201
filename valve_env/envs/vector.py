"""The native batched ThermoValve environments (Gymnasium ``VectorEnv``).

``gym.make_vec("ThermoValve-v0", num_envs=N)`` (or with
``vectorization_mode="vector_entry_point"``) returns a
:class:`ThermoValveVectorEnv`: N independent copies of the single env stepped
by one call of the shared numba kernel :func:`valve_env.simulator.env_step_batch`
(threads over ranges of envs), which runs the same ``apply_action`` and block
kernel ``plant_step`` as the single env's :func:`valve_env.simulator.env_step`
(the single env is a block of one column, this env a block of N). There is
one model; the batched env is not a second copy of it.

It behaves like ``gymnasium.vector.SyncVectorEnv`` over ``gym.make(id, ...)``
with the same seed, to floating-point rounding:

* ``reset(seed=s)`` seeds env i with ``s + i`` (a list gives one seed each,
  ``None`` fresh entropy); env i's scenario is drawn from its own generator by
  :func:`valve_env.scenario.make_scenario`, exactly as the single env's reset;
  ``options={"reset_mask": mask}`` resets only some envs.
* autoreset in Gymnasium's default ``NEXT_STEP`` mode: the step after an
  episode ends resets that env (its action is ignored, its reward is 0, its
  info is the reset info).
* episodes are truncated after ``min(control.n_steps, max_episode_steps)``
  steps (``gym.make``'s TimeLimit; ``make_vec`` passes the registered 2880);
  at the env's own last step ``info["kpis"]`` and ``info["energy"]`` carry
  the KPIs and the first-law account, as in the single env.
* info is Gymnasium's vectorised dict: every key an array over envs plus a
  boolean mask ``"_key"``; nested dicts (``kpis``, ``energy``) likewise.
* actions are validated (finite, right shape: ``ValueError``) and clipped to
  the box (``info["action_clipped"]``) like the single env's.
* the sensor wrappers of the single env's factory (``sensors.noise_K``,
  ``flow_noise_rel``, ``dead_time_steps``) are applied the same way, each env
  drawing its noise from its own generator.

Memory: each env's scenario is stored run-length encoded (a row per change
of the scenario inputs, not per step): N = 4096 day-long envs take about
30 MB instead of the 470 MB of dense (n_steps, 5) scenarios; a scenario that
changes every step (``supply_profile="random"``) costs what a dense one would.
"""

from __future__ import annotations

import copy
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from valve_env import simulator as sim
from valve_env.config import EnvConfig, make_config
from valve_env.envs.thermovalve import (
    Mode,
    SimState,
    ThermoValveDualEnv,
    ThermoValveEnv,
    ThermoValvePressureEnv,
    check_seed,
)
from valve_env.scenario import make_scenario

_SINGLE: dict[str, type[ThermoValveEnv]] = {
    "setting": ThermoValveEnv,
    "pressure": ThermoValvePressureEnv,
    "dual": ThermoValveDualEnv,
}
_INFO_KEYS: tuple[tuple[str, int], ...] = (
    ("x_mm", sim.O_X),
    ("F_h_N", sim.O_FH),
    ("T_g_C", sim.O_TG),
    ("heat_W", sim.O_HEAT_W),
    ("pump_W", sim.O_PUMP_W),
)
_ENERGY_KEYS: tuple[str, ...] = ("heat_in_J", "stored_J", "losses_J", "draws_J")


def _aligned_zeros(shape: int | tuple[int, ...], dtype: Any = np.float64, align: int = 4096) -> np.ndarray:
    """``np.zeros(shape, dtype)`` whose data start on an ``align``-byte boundary."""
    dt = np.dtype(dtype)
    size = int(np.prod(shape)) * dt.itemsize
    buf = np.zeros(size + align, np.uint8)
    off = -buf.ctypes.data % align
    return buf[off : off + size].view(dt).reshape(shape)


class ThermoValveVectorEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """N ThermoValve envs (mode ``setting``) stepped together; see the module docstring.

    ``ThermoValveVectorEnv(num_envs=N, config=None, max_episode_steps=None,
    render_mode=None, **overrides)`` takes the single env's arguments
    (``config`` a YAML path, mapping or EnvConfig; overrides as in
    ``gym.make``). Observations ``(N, 12)`` float32, rewards ``(N,)`` float64.
    """

    metadata: dict[str, Any] = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
    mode: ClassVar[Mode] = "setting"
    #: from this many envs on, the kernel runs on numba's threads (below, a serial loop): on the
    #: 2-core machine of docs/speed.md, with the threads spinning briefly between steps
    #: (GOMP_SPINCOUNT, valve_env/__init__.py), env.step at 512 envs ran 4.5-5.4 M env-steps/s
    #: on threads against 4.4 M serially, and at 256 envs 3.7 against 4.1 M
    parallel_threshold: ClassVar[int] = 512
    #: envs per range of columns handed to a thread: 256 stepped 512 to 4096 envs 5-15 % faster than
    #: 512 in interleaved A/B runs (equal at 16 384); 128 was no better
    block_size: ClassVar[int] = 256
    _SCEN_CAPACITY: ClassVar[int] = 128

    def __init__(
        self,
        num_envs: int = 1,
        config: Any = None,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if render_mode is not None:
            raise ValueError(
                "the batched ThermoValve env does not render; use the single env (render_mode='rgb_array')"
            )
        if max_episode_steps is not None and (int(max_episode_steps) != max_episode_steps or max_episode_steps < 1):
            raise ValueError(f"max_episode_steps must be an integer >= 1 or None, got {max_episode_steps!r}")
        self.cfg: EnvConfig = make_config(config, **overrides)
        # the single env's own setup: spaces, packed parameters, action box (one source)
        proto = _SINGLE[self.mode](config=self.cfg)
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.metadata = dict(type(self).metadata)
        self.single_observation_space = proto.observation_space
        self._plant_obs_space = proto.observation_space  # the plant's 12 observations (the sensor noise's bounds)
        self.single_action_space = proto.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._vp = proto._vp
        self._pp = proto._pp
        self._a_lo = proto._a_lo
        self._a_hi = proto._a_hi
        self._mode_code = proto._mode_code
        c = self.cfg.control
        self._n_steps = c.n_steps
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self._limit = self._n_steps if max_episode_steps is None else min(self._n_steps, int(max_episode_steps))
        self._dt_s = c.dt_s
        n, nl = self.num_envs, self.cfg.tank.n_layers
        self._nl = nl
        # all envs live in one block (structure of arrays: a column per env) that the
        # kernel steps in place; _S, _ACC and _OUT are (N, ...) views of it. The kernel writes
        # the observations into _OBS (N, 12) as they are returned (a transposed copy of a
        # (12, N) array cost 5 us per step at N = 1024)
        ns = nl + sim.N_STATE_EXTRA
        # page-aligned, so that the threads' column ranges (multiples of 16 envs) share no
        # cache line in any row (no measurable change on its own in one A/B run; it costs nothing)
        self._Z = _aligned_zeros((sim.block_rows(nl), n))
        self._OBS = _aligned_zeros((n, sim.N_OBS), np.float32)
        self._S = self._Z[:ns].T
        self._ACC = self._Z[sim.acc_row(nl) : sim.acc_row(nl) + sim.N_ACC].T
        self._OUT = self._Z[sim.out_row(nl) : sim.out_row(nl) + sim.N_OUT].T
        self._R = self._Z[ns + sim.Z_REWARD]
        self._K = _aligned_zeros(n, np.int64)
        self._SD = _aligned_zeros((n, 2))
        self._CUR = _aligned_zeros(n, np.int64)
        # the scenario row in force and the step where the next run starts: the kernel reads
        # these compact rows at every step and RK/RV (an env's runs are 5 kB apart) only
        # when a run changes; reading RV at every step cost 50 ns per env-step in misses
        self._ROW = _aligned_zeros((n, sim.N_SCEN))
        self._NEXT = _aligned_zeros(n, np.int64)
        self._NRUN = np.ones(n, np.int64)
        self._RK = np.zeros((n, self._SCEN_CAPACITY), np.int64)
        self._RV = np.zeros((n, self._SCEN_CAPACITY, sim.N_SCEN))
        self._E0 = np.zeros(n)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._seeds: list[int | None] = [None] * n
        self._autoreset = np.zeros(n, bool)
        self._started = np.zeros(n, bool)
        self._all_envs = np.ones(n, bool)
        self._any_autoreset = False
        self._all_started = False
        self._A = np.zeros((n, self._a_lo.shape[0]))
        self._clipped = np.zeros(n, bool)
        self._bounds = proto._bounds
        self._INFO = _aligned_zeros((len(_INFO_KEYS) + 1, n))
        self._info_cols = np.array([col for _, col in _INFO_KEYS])
        self._info_names = [key for key, _ in _INFO_KEYS] + ["t_s"]
        self._mask_names = ["_" + key for key in self._info_names]
        self._all_idx = np.arange(n)
        self._no_envs = np.zeros(0, np.int64)
        sens = self.cfg.sensors
        self._noise = sens.noise_K > 0 or sens.flow_noise_rel > 0
        self._delay = sens.dead_time_steps
        self._delay_buf = np.zeros((n, self._delay + 1, sim.N_OBS), np.float32) if self._delay > 0 else None
        self._bulb_layer = int(self._pp[sim.P_BULB_LAYER])
        self._has_effects = bool(self.cfg.effects)

    # -- Gymnasium API ------------------------------------------------------
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (list, tuple)):
            if len(seed) != n:
                raise ValueError(f"reset(seed=[...]) must give num_envs = {n} seeds, got {len(seed)}")
            seeds = [check_seed(s, f"seed[{i}]") for i, s in enumerate(seed)]
        else:
            first = check_seed(seed)
            assert first is not None
            seeds = [first + i for i in range(n)]
        if options is not None and "reset_mask" in options:
            mask = options["reset_mask"]
            if not isinstance(mask, np.ndarray):
                raise TypeError(f"`options['reset_mask']` must be a numpy array, got {type(mask)}")
            if mask.shape != (n,):
                raise ValueError(f"`options['reset_mask']` must have shape `({n},)`, got {mask.shape}")
            if mask.dtype != np.bool_:
                raise TypeError(f"`options['reset_mask']` must have `dtype=np.bool_`, got {mask.dtype}")
            if not np.any(mask):
                raise ValueError(
                    "`options['reset_mask']` must contain a boolean array with at least one True value, "
                    f"got reset_mask={mask}"
                )
            idx = np.flatnonzero(mask)
        else:
            idx = np.arange(n)
        for i in idx:
            self._reset_env(int(i), seeds[i])
        self._autoreset[idx] = False
        self._any_autoreset = bool(self._autoreset.any())
        self._started[idx] = True
        self._all_started = bool(self._started.all())
        stepped = np.zeros(n, bool)
        obs = self._observe(stepped, idx)
        return obs, self._base_info(idx)

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._all_started:
            raise RuntimeError("call reset() before step()")
        n, adim = self.num_envs, self._a_lo.shape[0]
        A_in = np.asarray(actions, dtype=np.float64)
        if A_in.size != n * adim or (A_in.ndim >= 1 and A_in.shape[0] != n):
            raise ValueError(f"actions must have shape {self.action_space.shape}, got {np.shape(actions)}")
        resetting = self._autoreset
        any_reset = self._any_autoreset
        stepping = ~resetting if any_reset else self._all_envs
        A_in = A_in.reshape(n, adim)
        clipped = self._clipped
        bad = self._kernel_step(A_in, stepping)
        truncated = self._K >= self._limit
        if any_reset:
            truncated &= stepping
        any_end = bool(truncated.any())
        ended_info = None
        if any_end:
            finished = np.flatnonzero(truncated & (self._K >= self._n_steps))
            if finished.size:
                ended_info = self._end_info(finished)
        rewards = self._R.copy()
        if any_reset:
            reset_idx = np.flatnonzero(resetting)
            for i in reset_idx:
                self._reset_env(int(i), None)
            rewards[resetting] = 0.0
            obs = self._observe(stepping, reset_idx)
        else:
            obs = self._observe(stepping, self._no_envs)
        if any_reset:  # the reset envs' info columns are their reset's
            self._INFO[:-1, reset_idx] = self._OUT[reset_idx][:, self._info_cols].T
            self._INFO[-1, reset_idx] = 0.0
        info = self._base_info(self._all_idx, self._INFO.copy())
        if bad == -2:  # some action was clipped
            info["action_clipped"] = clipped.copy()
            info["_action_clipped"] = clipped.copy()
        if ended_info is not None:
            info.update(ended_info)
        self._autoreset = truncated
        self._any_autoreset = any_end
        return obs, rewards, np.zeros(n, bool), truncated.copy(), info

    def plan_step(self, actions: Any) -> tuple[np.ndarray, np.ndarray]:
        """A planner's step (valve_env.controllers.oracle): every env steps once by the same
        kernel as :meth:`step`, without autoreset, info or sensor noise. Returns the kernel's
        plant observations (N, 12) and rewards (N,) as views (valid until the next step).
        Every env must be mid-episode (after :meth:`set_state` with k < the episode's steps)."""
        n, adim = self.num_envs, self._a_lo.shape[0]
        A_in = np.asarray(actions, dtype=np.float64).reshape(n, adim)
        if bool((self._K >= self._limit).any()):
            raise RuntimeError("plan_step: some env's episode has ended; load a snapshot with set_state()")
        self._kernel_step(A_in, self._all_envs)
        return self._OBS, self._R

    def _kernel_step(self, A_in: np.ndarray, stepping: np.ndarray) -> int:
        """One kernel call on the envs ``stepping`` with actions ``A_in`` (n, act_dim): the kernel's
        flag (-1 fine, -2 some action clipped); a non-finite action raises."""
        args = (
            self._Z, self._OBS, self._INFO, self._vp, self._pp, self._RK, self._RV, self._CUR, self._NRUN, self._ROW,
            self._NEXT, self._K,
            A_in, self._bounds, self._A, self._clipped, self._mode_code, self._SD, stepping,
        )
        if self.num_envs >= self.parallel_threshold:
            # blocks of ``block_size`` envs, scheduled statically: each thread gets
            # the same blocks every step, so their rows stay in its core's cache
            # (dynamic scheduling moved blocks between cores: 5-10 % slower)
            bad = sim.env_step_batch(*args, self.block_size)
        else:
            bad = sim.env_step_batch_serial(*args, self.block_size)
        if bad >= 0:
            raise ValueError(f"action must be finite, got {A_in[bad].tolist()} for env {bad}")
        return int(bad)

    def render(self) -> None:
        return None

    # -- seeding ------------------------------------------------------------
    @property
    def np_random_seeds(self) -> tuple[int | None, ...]:
        """The seed of each env's generator (as ``SyncVectorEnv.np_random_seed``)."""
        return tuple(self._seeds)

    @property
    def np_randoms(self) -> tuple[np.random.Generator | None, ...]:
        """Each env's own generator (scenario and sensor noise come from env i's)."""
        return tuple(self._rngs)

    # -- per-env state and accounting ------------------------------------------
    def stored_energy_J(self) -> np.ndarray:
        """Heat stored in each tank relative to 0 degC, J (N,)."""
        t = self.cfg.tank
        return self._S[:, : self._nl].sum(axis=1) * t.layer_mass_kg * t.cp

    def kpis(self, i: int) -> dict[str, float]:
        """The KPIs of env i's episode so far (docs/reference.md, section 5)."""
        return sim.kpis_from_acc(self._ACC[i])

    def energy_account(self, i: int) -> dict[str, float]:
        """First-law account of env i since its reset, J (as the single env's)."""
        t = self.cfg.tank
        acc = self._ACC[i]
        return {
            "heat_in_J": float(acc[sim.A_HEAT]),
            "stored_J": float(self._S[i, : self._nl].sum() * t.layer_mass_kg * t.cp) - float(self._E0[i]),
            "losses_J": float(acc[sim.A_LOSS]),
            "draws_J": float(acc[sim.A_DRAW]),
        }

    @property
    def hidden_state(self) -> dict[str, np.ndarray]:
        """The unobserved valve state of every env: friction force (N), stem position (mm), gas temperature (degC)."""
        nl = self._nl
        return {
            "F_h_N": self._S[:, nl + sim.S_FH].copy(),
            "x_mm": self._S[:, nl + sim.S_X].copy(),
            "T_g_C": self._S[:, nl + sim.S_TG].copy(),
            **sim.effect_info(self._S, nl, self._pp, self._vp, self._SD[:, sim.SD_SET]),
        }

    @property
    def layer_temperatures(self) -> np.ndarray:
        return self._S[:, : self._nl].copy()

    @property
    def step_index(self) -> np.ndarray:
        return self._K.copy()

    @property
    def episode_steps(self) -> int:
        """Steps per episode: min(control.n_steps, max_episode_steps)."""
        return self._limit

    @property
    def n_steps(self) -> int:
        """The env's own horizon in steps (control.n_steps); KPIs come at this step."""
        return self._n_steps

    # -- snapshots (the single env's SimState) ----------------------------------
    def get_state(self, i: int) -> SimState:
        """A deep copy of env i's state, as the single env's :meth:`ThermoValveEnv.get_state`
        gives it (the same :class:`SimState`, interchangeable between the two)."""
        i = int(i)
        rng = self._rngs[i]
        if rng is None:
            raise RuntimeError("call reset() before get_state()")
        runs = int(self._NRUN[i])
        starts = np.append(self._RK[i, :runs], self._n_steps)
        scen = np.repeat(self._RV[i, :runs], np.diff(starts), axis=0)
        return SimState(
            state=self._S[i].copy(),
            acc=self._ACC[i].copy(),
            out=self._OUT[i].copy(),
            k=int(self._K[i]),
            scenario=scen,
            setting_C=float(self._SD[i, sim.SD_SET]),
            dp_mbar=float(self._SD[i, sim.SD_DP]),
            rng_state=copy.deepcopy(dict(rng.bit_generator.state)),
            E0_J=float(self._E0[i]),
        )

    def set_state(self, st: SimState, envs: Any = None, rng: bool = True) -> None:
        """Load the snapshot ``st`` (from this env's or the single env's ``get_state``, same
        configuration) into the envs ``envs`` (indices, a boolean mask or a slice; all by
        default): each continues exactly as the snapshotted env would, stepped by the same
        kernel. This is how a model-predictive controller branches N rollouts from one state
        (valve_env.controllers.oracle)."""
        idx = self._all_idx[envs] if envs is not None else self._all_idx
        if st.state.shape != (self._S.shape[1],) or st.scenario.shape != (self._n_steps, sim.N_SCEN):
            raise ValueError("state snapshot does not match this environment's configuration")
        k = int(st.k)
        scen = st.scenario
        cached = getattr(self, "_runs_of", None)
        if cached is not None and cached[0] is scen:  # the same snapshot again (a planner's iterations)
            starts = cached[1]
        else:
            change = np.flatnonzero((scen[1:] != scen[:-1]).any(axis=1)) + 1
            starts = np.concatenate(([0], change))
            self._runs_of = (scen, starts)
        m = starts.size
        if m > self._RK.shape[1]:
            # grow the run tables through the one place that does it
            self._store_scenario(int(idx[0]), scen)
        self._RK[idx, :m] = starts
        self._RV[idx, :m] = scen[starts]
        self._NRUN[idx] = m
        self._CUR[idx] = max(int(np.searchsorted(starts, k, side="right")) - 1, 0)
        self._NEXT[idx] = 0  # the next step loads the run in force into _ROW
        self._S[idx] = st.state
        self._ACC[idx] = st.acc
        self._OUT[idx] = st.out
        self._K[idx] = k
        self._autoreset[idx] = False  # a loaded env continues its episode
        self._any_autoreset = bool(self._autoreset.any())
        self._SD[idx, sim.SD_SET] = st.setting_C
        self._SD[idx, sim.SD_DP] = st.dp_mbar
        self._E0[idx] = st.E0_J
        # the generators (sensor noise, the next reset's scenario); ``rng=False`` leaves them, for a
        # planner whose plan_step never draws from them (valve_env.controllers.oracle)
        for i in idx if rng else ():  # the state setter copies the values (the snapshot's dict is not kept)
            gen = self._rngs[i]
            if gen is None:
                self._rngs[i], self._seeds[i] = seeding.np_random()
                gen = self._rngs[i]
            assert gen is not None
            gen.bit_generator.state = st.rng_state
        obs = np.zeros(sim.N_OBS, np.float32)
        sim.fill_obs(obs, st.out, self._pp, k, st.setting_C)
        self._OBS[idx] = obs
        if self._delay_buf is not None:
            self._delay_buf[idx] = obs
        done = k >= self._limit
        self._autoreset[idx] = done
        self._any_autoreset = bool(self._autoreset.any())
        self._started[idx] = True
        self._all_started = bool(self._started.all())

    # -- helpers --------------------------------------------------------------
    def _reset_env(self, i: int, seed: int | None) -> None:
        """Env i's reset, as ThermoValveEnv.reset does it."""
        if seed is not None:
            self._rngs[i], self._seeds[i] = seeding.np_random(seed)
        elif self._rngs[i] is None:
            self._rngs[i], self._seeds[i] = seeding.np_random()
        rng = self._rngs[i]
        assert rng is not None
        cfg = self.cfg
        arrays = make_scenario(cfg.scenario, rng, self._n_steps, cfg.control.dt_s, cfg.tank.T_cold, cfg.tank.cp)
        scen = arrays.as_matrix()
        self._store_scenario(i, scen)
        self._S[i] = sim.initial_state(cfg, arrays.T_init_C, float(scen[0, 3]))
        self._ACC[i] = 0.0
        self._K[i] = 0
        self._CUR[i] = 0
        self._NEXT[i] = 0  # the first step loads run 0 into _ROW
        sd = self._SD[i]
        sd[sim.SD_SET] = cfg.control.setting_C
        sd[sim.SD_DP] = float(scen[0, 4])
        sim.reset_outputs(self._OUT[i], self._S[i], self._pp, scen[0], sd[sim.SD_SET], sd[sim.SD_DP])
        sim.fill_obs(self._OBS[i], self._OUT[i], self._pp, 0, sd[sim.SD_SET])
        t = cfg.tank
        self._E0[i] = float(self._S[i, : self._nl].sum() * t.layer_mass_kg * t.cp)

    def _store_scenario(self, i: int, scen: np.ndarray) -> None:
        """Run-length encode env i's (n_steps, 5) scenario into RK/RV (growing them if needed)."""
        change = np.flatnonzero((scen[1:] != scen[:-1]).any(axis=1)) + 1
        starts = np.concatenate(([0], change))
        m = starts.size
        cap = self._RK.shape[1]
        if m > cap:
            new_cap = max(m, 2 * cap)
            rk = np.zeros((self.num_envs, new_cap), np.int64)
            rv = np.zeros((self.num_envs, new_cap, sim.N_SCEN))
            rk[:, :cap] = self._RK
            rv[:, :cap] = self._RV
            self._RK, self._RV = rk, rv
        self._RK[i, :m] = starts
        self._RV[i, :m] = scen[starts]
        self._NRUN[i] = m

    def _observe(self, stepped: np.ndarray, reset: np.ndarray) -> np.ndarray:
        """The observations returned to the agent: the kernel's (``stepped`` a
        mask of the envs that stepped, ``reset`` the indices of those reset),
        through the sensor wrappers' noise and dead time as make_thermovalve
        stacks them."""
        obs = self._OBS.copy()
        if self._noise:
            for i in np.union1d(np.flatnonzero(stepped), reset):
                obs[i] = self._noisy(int(i), obs[i])
        buf = self._delay_buf
        if buf is not None:
            if stepped.any():
                buf[stepped, :-1] = buf[stepped, 1:]
                buf[stepped, -1] = obs[stepped]
            if reset.size:
                buf[reset] = obs[reset][:, None, :]
            obs = buf[:, 0].copy()
        return obs

    def _noisy(self, i: int, observation: np.ndarray) -> np.ndarray:
        """valve_env.envs.wrappers.SensorNoise.observation for env i, from env i's generator."""
        from valve_env.envs.wrappers import noisy_observation

        rng = self._rngs[i]
        assert rng is not None
        sens = self.cfg.sensors
        space = self._plant_obs_space
        assert isinstance(space, gym.spaces.Box)
        return noisy_observation(observation, rng, sens.noise_K, sens.flow_noise_rel, space.low, space.high)

    def _base_info(self, idx: np.ndarray, vals: np.ndarray | None = None) -> dict[str, Any]:
        """The single env's per-step info keys for envs ``idx``, vectorised with masks;
        ``vals`` (6, N) the info columns if the kernel has filled them."""
        n = self.num_envs
        nk = len(_INFO_KEYS) + 1
        if vals is None:
            vals = np.empty((nk, n))
            vals[:-1] = self._OUT[:, self._info_cols].T
            np.multiply(self._K, self._dt_s, out=vals[-1])
        if idx.size == n:
            masks = np.ones((nk, n), bool)
        else:
            masks = np.zeros((nk, n), bool)
            masks[:, idx] = True
            vals[:, ~masks[0]] = 0.0
        info = dict(zip(self._info_names, vals, strict=True))
        info.update(zip(self._mask_names, masks, strict=True))
        if self._has_effects:  # the hidden states of the valve's named effects
            for key, arr in sim.effect_info(self._S, self._nl, self._pp, self._vp, self._SD[:, sim.SD_SET]).items():
                arr[~masks[0]] = 0.0
                info[key] = arr
                info["_" + key] = masks[0].copy()
        return info

    def _end_info(self, idx: np.ndarray) -> dict[str, Any]:
        """``kpis`` and ``energy`` for the envs whose episode ended, vectorised with masks."""
        n = self.num_envs
        mask = np.zeros(n, bool)
        mask[idx] = True
        kpis = {name: np.zeros(n) for name in sim.KPI_NAMES}
        energy = {name: np.zeros(n) for name in _ENERGY_KEYS}
        for i in idx:
            for name, v in sim.kpis_from_acc(self._ACC[i]).items():
                kpis[name][i] = v
            for name, v in self.energy_account(int(i)).items():
                energy[name][i] = v
        k_info: dict[str, Any] = {}
        for name, arr in kpis.items():
            k_info[name] = arr
            k_info["_" + name] = mask.copy()
        e_info: dict[str, Any] = {}
        for name, arr in energy.items():
            e_info[name] = arr
            e_info["_" + name] = mask.copy()
        return {"kpis": k_info, "_kpis": mask.copy(), "energy": e_info, "_energy": mask.copy()}


class ThermoValvePressureVectorEnv(ThermoValveVectorEnv):
    __doc__ = ThermoValveVectorEnv.__doc__
    mode: ClassVar[Mode] = "pressure"


class ThermoValveDualVectorEnv(ThermoValveVectorEnv):
    __doc__ = ThermoValveVectorEnv.__doc__
    mode: ClassVar[Mode] = "dual"


VECTOR_CLASSES: dict[str, type[ThermoValveVectorEnv]] = {
    "setting": ThermoValveVectorEnv,
    "pressure": ThermoValvePressureVectorEnv,
    "dual": ThermoValveDualVectorEnv,
}

__all__ = ["ThermoValveVectorEnv", "ThermoValvePressureVectorEnv", "ThermoValveDualVectorEnv", "VECTOR_CLASSES"]
