"""The ThermoValve environments: a hot-water tank heated through a self-acting
thermostatic valve with Dahl-friction hysteresis.

The env coordinates: it samples a scenario, steps the shared simulator
kernel (valve_env.simulator), builds observations, the reward and the KPIs.
Sensor noise and dead time are wrappers (valve_env.envs.wrappers).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from valve_env import simulator as sim
from valve_env.config import EnvConfig, make_config
from valve_env.params import DP_MAX_MBAR, DRAW_MAX_L_MIN
from valve_env.physics.valve import flow_kgh
from valve_env.scenario import make_scenario

Mode = Literal["setting", "pressure", "dual"]

OBS_NAMES: tuple[str, ...] = (
    "T_out_C",
    "T_pocket_C",
    "T_bottom_C",
    "T_supply_C",
    "T_return_C",
    "q_primary_kgh",
    "dp_mbar",
    "draw_l_min",
    "tod_sin",
    "tod_cos",
    "setting_C",
    "T_target_C",
)
_OUT_TO_OBS = np.array(
    [sim.O_T_TOP, sim.O_T_POCKET, sim.O_T_BOTTOM, sim.O_T_SUP, sim.O_T_RET, sim.O_Q_KGH, sim.O_DP, sim.O_DRAW_LMIN]
)
TEMPERATURE_OBS = (0, 1, 2, 3, 4)
FLOW_OBS = (5, 6)


def primary_flow_bound_kgh(cfg: EnvConfig) -> float:
    """The upper bound of the observed primary flow, kg/h: 5000, or the valve's full
    flow at the largest differential pressure (Kvs at DP_MAX_MBAR) if a larger valve
    can pass more (docs/configuration.md: the observation box)."""
    full = float(flow_kgh(cfg.valve.stroke, DP_MAX_MBAR, cfg.valve.to_array()))
    return max(5000.0, float(np.ceil(full)) + 1.0)


def check_seed(seed: Any, what: str = "seed") -> int | None:
    """A reset seed: an integer >= 0 or None (not a bool, a float or text); else a
    one-line ``ValueError`` naming ``what``."""
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"reset({what}=...) must be an integer >= 0 or None, got {type(seed).__name__} {seed!r}")
    return int(seed)


@dataclass
class SimState:
    """A snapshot of everything that determines the future of an episode."""

    state: np.ndarray
    acc: np.ndarray
    out: np.ndarray
    k: int
    scenario: np.ndarray
    setting_C: float
    dp_mbar: float
    rng_state: dict[str, Any]
    E0_J: float


class ThermoValveEnv(gym.Env[np.ndarray, np.ndarray]):
    """## Description

    A 200 l domestic hot-water tank (8 stratified layers) is heated by a coil
    in its lower half, fed with district-heating water through a self-acting
    thermostatic valve (the seed paper's model: force balance, methanol
    vapour-charged bellows, Dahl friction). The valve's bulb sits in a pocket
    at 70 % of the tank's height and lags it with a 40 s time constant; the
    valve closes as the bulb warms. Hot water is drawn from the top following
    the EU tapping cycle M (a seeded stochastic variant by default); cold
    water enters at the bottom. The agent trims the valve's temperature
    setting (ThermoValve-v0), the differential pressure across it with a
    variable-speed pump (ThermoValvePressure-v0), or both (ThermoValveDual-v0).
    The stem's friction force and position are not observed; they are
    reported in ``info``.

    ## Action space

    | id | shape | meaning | unit | range (ControlParams) |
    |---|---|---|---|---|
    | ThermoValve-v0 | (1,) | valve temperature setting | degC | [40, 80] |
    | ThermoValvePressure-v0 | (1,) | differential pressure across the valve | mbar | [0, 300] |
    | ThermoValveDual-v0 | (2,) | [setting, differential pressure] | degC, mbar | as above |

    Out-of-range actions are clipped to the box (``info["action_clipped"]``);
    a non-finite action or one of the wrong shape raises ``ValueError``. In
    ThermoValve-v0 the differential pressure is the network's (the
    scenario's ``dp_mbar`` with its disturbance); in ThermoValvePressure-v0
    the setting is fixed at ``control.setting_C``.

    ## Observation space

    Box(12,) float32, what a real installation could measure:

    | index | name | unit |
    |---|---|---|
    | 0 | T_out_C: outlet (top layer) temperature | degC |
    | 1 | T_pocket_C: tank temperature at the bulb's pocket | degC |
    | 2 | T_bottom_C: bottom layer temperature | degC |
    | 3 | T_supply_C: primary supply temperature | degC |
    | 4 | T_return_C: primary return temperature (flow-weighted over the step) | degC |
    | 5 | q_primary_kgh: primary flow (mean over the step) | kg/h |
    | 6 | dp_mbar: differential pressure across the valve | mbar |
    | 7 | draw_l_min: hot-water draw from the tank (mean over the step) | l/min |
    | 8, 9 | sin, cos of the time of day | - |
    | 10 | setting_C: the valve setting in force | degC |
    | 11 | T_target_C: the outlet target | degC |

    Bounds: temperatures [-20, 150] degC, primary flow [0, 5000] kg/h (more for a
    valve that passes more at 2000 mbar: Kvs > 3.54 m^3/h), dp [0, 2000] mbar, draw
    [0, 100] l/min, the setting within the action's range. Every accepted config
    keeps its observations inside (docs/configuration.md).

    ## Reward

    Per control step, with sub-step means over the step (n_sub sub-steps):

        r = -( w_track * mean((T_out - T_target)^2)
             + w_floor * mean(max(0, T_floor - T_out))
             + w_energy * (P_heat + 2.5 P_pump) / 1 kW )

    with the defaults w_track = 0.04 / K^2 (an error of 5 K costs 1),
    w_floor = 1 / K, w_energy = 0.02 / kW, P the mean powers over the step
    and 2.5 the primary energy factor of electricity. The KPIs do not depend
    on these weights.

    ## Starting state

    The whole tank at T_init_C (55 degC) plus a seeded uniform spread of
    +-3 K, the bulb in equilibrium, no friction force; midnight.

    ## Episode end

    Truncated after horizon_h (24 h = 2880 steps of 30 s); there is no
    terminal state. The ids are registered with max_episode_steps=2880: for
    another horizon pass both, e.g. ``gym.make(id, horizon_h=48,
    max_episode_steps=5760)`` (the tapping cycle repeats every day). At
    the last step ``info["kpis"]`` holds the docs/reference.md, section 5 KPIs (rmse_K,
    iae_Kh, tdis_Kh, unmet_kWh, heat_kWh, pump_kWh, return_C, travel_mm,
    reversals) and ``info["energy"]`` the first-law account.

    ## Arguments

    ``gym.make("ThermoValve-v0", config=None, render_mode=None, **overrides)``:
    ``config`` a YAML path, a packaged scenario's name (valve_env/data/scenarios), a mapping or an EnvConfig;
    overrides name a section (``valve={"F_hmax": 2.0}``, ``tank=...``,
    ``bulb=...``, ``scenario=...``, ``control=...``, ``sensors=...``) or a
    single scenario or control field (``tapping_profile="L"``,
    ``supply_C=60``). Invalid values raise ``valve_env.ConfigError`` naming
    the field. The valve's named effects (stiction, sensor_lag,
    medium_temperature, setpoint_drift; docs/reference.md sections 3 and 8)
    go in the valve section: ``valve={"effects": {"stiction": {"band_mm":
    0.04}}}`` or a valve file (``config="VALVE.yaml"``, written by
    ``thermovalve fit/diagnose --valve-out``); their hidden states are in
    ``info`` (``stuck``, ``x_demand_mm``, ``p_set_MPa``).

    ## Version history

    * v0: initial release.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}  # noqa: RUF012
    mode: Mode = "setting"

    def __init__(
        self,
        config: Any = None,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        self.cfg: EnvConfig = make_config(config, **overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.render_mode = render_mode
        c = self.cfg.control
        self._n_steps = c.n_steps
        self._vp = self.cfg.valve.to_array()
        self._pp = sim.pack_plant(self.cfg)
        nl = self.cfg.tank.n_layers
        self._work = np.zeros((sim.block_rows(nl), 1))  # a block of one env for sim.plant_step
        self._has_effects = bool(self.cfg.effects)
        lo, hi = [], []
        if self.mode in ("setting", "dual"):
            lo.append(c.setting_min_C)
            hi.append(c.setting_max_C)
        if self.mode in ("pressure", "dual"):
            lo.append(c.dp_min_mbar)
            hi.append(c.dp_max_mbar)
        self.action_space = spaces.Box(np.array(lo, np.float32), np.array(hi, np.float32), dtype=np.float32)
        self._a_lo = np.array(lo, np.float64)
        self._a_hi = np.array(hi, np.float64)
        self._bounds = np.stack([self._a_lo, self._a_hi])
        self._a_shape = self.action_space.shape
        self._a_buf = np.zeros(len(lo))
        self._mode_code = sim.MODE_CODES[self.mode]
        t_hi = 150.0
        obs_lo = np.array([-20, -20, -20, -20, -20, 0, 0, 0, -1, -1, c.setting_min_C, -20], np.float32)
        obs_hi = np.array(
            [t_hi, t_hi, t_hi, t_hi, t_hi, primary_flow_bound_kgh(self.cfg), DP_MAX_MBAR, DRAW_MAX_L_MIN, 1, 1,
             c.setting_max_C, t_hi],
            np.float32,
        )
        self.observation_space = spaces.Box(obs_lo, obs_hi, dtype=np.float32)
        self._tod_step = 2.0 * np.pi * c.dt_s / 86400.0
        # episode buffers, filled by reset()
        self._s = np.zeros(nl + sim.N_STATE_EXTRA)
        self._acc = np.zeros(sim.N_ACC)
        self._out = np.zeros(sim.N_OUT)
        self._scen = np.zeros((self._n_steps, sim.N_SCEN))
        self._k = 0
        self._sd = np.array([c.setting_C, self.cfg.scenario.dp_mbar])  # setting, dp in force
        self._obs_now = np.zeros(sim.N_OBS, np.float32)
        self._dt_s = c.dt_s
        self._E0 = 0.0
        self._hist: np.ndarray | None = None
        self._needs_reset = True

    # -- Gymnasium API ------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=check_seed(seed))
        cfg = self.cfg
        scen = make_scenario(
            cfg.scenario, self.np_random, self._n_steps, cfg.control.dt_s, cfg.tank.T_cold, cfg.tank.cp
        )
        self._scen = scen.as_matrix()
        self._s = sim.initial_state(cfg, scen.T_init_C, float(self._scen[0, 3]))
        self._acc = np.zeros(sim.N_ACC)
        self._k = 0
        self._setting = cfg.control.setting_C
        self._dp = float(self._scen[0, 4])
        sim.reset_outputs(self._out, self._s, self._pp, self._scen[0], self._setting, self._dp)
        sim.fill_obs(self._obs_now, self._out, self._pp, 0, self._setting)
        self._E0 = self.stored_energy_J()
        self._needs_reset = False
        if self.render_mode is not None:
            self._hist = np.full((self._n_steps + 1, 7), np.nan)
            self._record()
        return self._obs(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._needs_reset:
            raise RuntimeError("call reset() before step(), and again after the episode ends")
        # Hot path: validation, clipping, the action, the physics and the
        # observation are one call of the shared numba kernel (simulator.env_step).
        a = self._a_buf
        if type(action) is np.ndarray and action.shape == self._a_shape:
            a[:] = action
        else:
            arr = np.asarray(action, dtype=np.float64).reshape(-1)
            if arr.shape[0] != a.shape[0]:
                raise ValueError(f"action must have shape {self.action_space.shape}, got {np.shape(action)}")
            a[:] = arr
        obs = np.empty(sim.N_OBS, np.float32)
        reward, status = sim.env_step(
            self._s, self._acc, self._out, obs, self._vp, self._pp, self._scen, self._k, a, self._bounds,
            self._mode_code, self._sd, self._work,
        )
        if status < 0:
            raise ValueError(f"action must be finite, got {a.tolist()}")
        self._obs_now = obs
        self._k += 1
        truncated = self._k >= self._n_steps
        info = self._info()
        if status:
            info["action_clipped"] = True
        if truncated:
            self._needs_reset = True
            info["kpis"] = sim.kpis_from_acc(self._acc)
            info["energy"] = self.energy_account()
        if self._hist is not None:
            self._record()
        return obs.copy(), reward, False, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array" or self._hist is None:
            return None
        from valve_env.rendering import render_history

        return render_history(self._hist[: self._k + 1], self.cfg, self.mode)

    # -- helpers --------------------------------------------------------------
    @property
    def _setting(self) -> float:
        """The valve setting in force, degC."""
        return float(self._sd[sim.SD_SET])

    @_setting.setter
    def _setting(self, value: float) -> None:
        self._sd[sim.SD_SET] = value

    @property
    def _dp(self) -> float:
        """The differential pressure in force, mbar."""
        return float(self._sd[sim.SD_DP])

    @_dp.setter
    def _dp(self, value: float) -> None:
        self._sd[sim.SD_DP] = value

    def _obs(self) -> np.ndarray:
        """The current observation (built by simulator.fill_obs, as in the batched env)."""
        return self._obs_now.copy()

    def _info(self) -> dict[str, Any]:
        out = self._out.tolist()
        return {
            "x_mm": out[sim.O_X],
            "F_h_N": out[sim.O_FH],
            "T_g_C": out[sim.O_TG],
            "heat_W": out[sim.O_HEAT_W],
            "pump_W": out[sim.O_PUMP_W],
            "t_s": self._k * self._dt_s,
            **self._effect_info(),
        }

    def _effect_info(self) -> dict[str, float]:
        """The hidden states of the valve's named effects (none without effects)."""
        if not self._has_effects:
            return {}
        st = sim.effect_info(self._s, self.cfg.tank.n_layers, self._pp, self._vp, self._setting)
        return {k: float(v) for k, v in st.items()}

    def _record(self) -> None:
        assert self._hist is not None
        out = self._out
        self._hist[self._k] = (
            self._k * self.cfg.control.dt_s,
            out[sim.O_T_TOP],
            out[sim.O_T_POCKET],
            out[sim.O_T_BOTTOM],
            out[sim.O_X],
            self._setting,
            self._dp,
        )

    # -- state and accounting -------------------------------------------------
    def stored_energy_J(self) -> float:
        """Heat stored in the tank relative to 0 degC, J."""
        t = self.cfg.tank
        return float(self._s[: t.n_layers].sum() * t.layer_mass_kg * t.cp)

    def energy_account(self) -> dict[str, float]:
        """First-law account since reset, J: heat_in = stored + losses + draws."""
        acc = self._acc
        return {
            "heat_in_J": float(acc[sim.A_HEAT]),
            "stored_J": self.stored_energy_J() - self._E0,
            "losses_J": float(acc[sim.A_LOSS]),
            "draws_J": float(acc[sim.A_DRAW]),
        }

    @property
    def hidden_state(self) -> dict[str, float]:
        """The unobserved valve state: friction force (N), stem position (mm), gas temperature (degC), and
        with named effects their states (simulator.effect_info)."""
        nl = self.cfg.tank.n_layers
        return {
            "F_h_N": float(self._s[nl + sim.S_FH]),
            "x_mm": float(self._s[nl + sim.S_X]),
            "T_g_C": float(self._s[nl + sim.S_TG]),
            **self._effect_info(),
        }

    @property
    def layer_temperatures(self) -> np.ndarray:
        return self._s[: self.cfg.tank.n_layers].copy()

    @property
    def step_index(self) -> int:
        return self._k

    def get_state(self) -> SimState:
        """A deep copy of the simulator's state (for MPC and branching rollouts).

        This is the bare env's state only: for an env with wrappers (``gym.make``'s,
        sensor noise and dead time) use :func:`valve_env.envs.wrappers.snapshot` and
        :func:`~valve_env.envs.wrappers.restore`, which include every wrapper's state."""
        return SimState(
            state=self._s.copy(),
            acc=self._acc.copy(),
            out=self._out.copy(),
            k=self._k,
            scenario=self._scen.copy(),
            setting_C=float(self._setting),
            dp_mbar=float(self._dp),
            rng_state=copy.deepcopy(dict(self.np_random.bit_generator.state)),
            E0_J=self._E0,
        )

    def set_state(self, st: SimState) -> None:
        """Restore a snapshot taken by :meth:`get_state` (of an env with the same config)."""
        if st.state.shape != self._s.shape or st.scenario.shape != self._scen.shape:
            raise ValueError("state snapshot does not match this environment's configuration")
        self._s = st.state.copy()
        self._acc = st.acc.copy()
        self._out = st.out.copy()
        self._k = int(st.k)
        self._scen = st.scenario.copy()
        self._setting = float(st.setting_C)
        self._dp = float(st.dp_mbar)
        self.np_random.bit_generator.state = copy.deepcopy(st.rng_state)
        self._E0 = float(st.E0_J)
        self._needs_reset = self._k >= self._n_steps
        sim.fill_obs(self._obs_now, self._out, self._pp, self._k, self._setting)
        if self.render_mode is not None:
            self._hist = np.full((self._n_steps + 1, 7), np.nan)
            self._record()


class ThermoValvePressureEnv(ThermoValveEnv):
    __doc__ = ThermoValveEnv.__doc__
    mode: Mode = "pressure"


class ThermoValveDualEnv(ThermoValveEnv):
    __doc__ = ThermoValveEnv.__doc__
    mode: Mode = "dual"
