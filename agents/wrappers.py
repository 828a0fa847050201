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

import functools
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
I_DRAW = OBS_NAMES.index("draw_l_min")
I_POCKET = OBS_NAMES.index("T_pocket_C")
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
    ``span`` is the residual's half-range in the action's unit; ``kff`` (per l/min, optional)
    a feedforward of the observed hot-water draw (obs draw_l_min), added to the base law: a draw
    empties a small cylinder faster than the outlet error can tell (docs/agents.md).
    """

    low: np.ndarray
    high: np.ndarray
    center: Sequence[float | str]
    span: np.ndarray
    kp: np.ndarray
    ki: np.ndarray
    dt_h: float
    kff: np.ndarray | None = None
    #: ``shut_band`` (K, optional; a temperature setting only): also hold the integrator while the
    #: outlet is above target and the output is more than this below the bulb's pocket temperature.
    #: There the thermostatic valve is shut and a lower setting changes nothing (the tank cools by
    #: its losses alone), so integrating would only wind the setting down, to undershoot later.
    shut_band: float | None = None

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
            kff=vec("kff", 0.0) if "kff" in cfg else None,
            shut_band=_shut_band(cfg),
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
        if self.kff is not None:
            base = base + self.kff * obs[:, I_DRAW, None]
        new_integ = integ + e[:, None] * self.dt_h
        pi = base + self.kp * e[:, None] + self.ki * new_integ + self.span * a
        # conditional integration: do not integrate while the output saturates in the error's direction
        sat = ((pi > self.high) & (e[:, None] * np.sign(self.ki) > 0)) | (
            (pi < self.low) & (e[:, None] * np.sign(self.ki) < 0)
        )
        if self.shut_band is not None:
            sat |= (pi < obs[:, I_POCKET, None] - self.shut_band) & (e[:, None] < 0)
        new_integ = np.where(sat, integ, new_integ)
        u = base + self.kp * e[:, None] + self.ki * new_integ + self.span * a
        return np.clip(u, self.low, self.high), new_integ


def _shut_band(cfg: Mapping[str, Any]) -> float | None:
    if cfg.get("shut_band") is None:
        return None
    band = cfg["shut_band"]
    if isinstance(band, bool) or not isinstance(band, int | float) or not np.isfinite(band) or band < 0:
        raise ValueError(f"residual.shut_band must be a number of kelvin >= 0, got {band!r}")
    return float(band)


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


#: Fixed scaling of a task layer's extra observation columns (docs/tasks.md), by name prefix.
TASK_OBS_SCALING: dict[str, tuple[float, float]] = {
    "price": (80.0, 40.0),  # EUR/MWh: district-heating price now and ahead
    "supply_plan": (75.0, 10.0),  # degC: the operator's supply plan ahead
    "hour_so_far_kW": (0.0, 10.0),  # kW: the power drawn so far in this hour (DistrictHeatingPower)
    "peak_hourly_kW": (0.0, 10.0),  # kW: the highest hourly power of the billing period so far
}


@functools.cache
def _extra_scaling(names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The centre and scale of the 12 plant columns followed by the task layer's ``names``."""
    cs = []
    for n in names:
        hit = [v for k, v in TASK_OBS_SCALING.items() if n.startswith(k)]
        if not hit:
            raise ValueError(f"no fixed scaling for the task observation {n!r} (agents.wrappers.TASK_OBS_SCALING)")
        cs.append(hit[0])
    arr = np.asarray(cs, np.float64).reshape(-1, 2)
    center, scale = np.concatenate([_CENTER, arr[:, 0]]), np.concatenate([_SCALE, arr[:, 1]])
    center.flags.writeable = scale.flags.writeable = False  # cached: shared by every call
    return center, scale


def scale_obs(obs: np.ndarray, extra_names: Sequence[str] = ()) -> np.ndarray:
    """The policy's input features from raw observations (n, 12 + extra) or (12 + extra,):
    the 12 plant columns by OBS_SCALING, a task layer's extra columns (``extra_names``)
    by TASK_OBS_SCALING."""
    o = np.array(obs, dtype=np.float64, copy=True)
    o[..., I_TARGET] = o[..., I_TARGET] - o[..., I_T_OUT]
    center, scale = _extra_scaling(tuple(extra_names)) if extra_names else (_CENTER, _SCALE)
    o -= center
    o /= scale
    return o.astype(np.float32)


def time_of_day_s(obs: np.ndarray) -> np.ndarray:
    """The time of day, s in [0, 86400), from the observation's tod_sin / tod_cos columns."""
    o = np.atleast_2d(np.asarray(obs, np.float64))
    ang = np.arctan2(o[:, OBS_NAMES.index("tod_sin")], o[:, OBS_NAMES.index("tod_cos")])
    return np.mod(ang, 2.0 * np.pi) * 86400.0 / (2.0 * np.pi)


def _started_kWh(t_s: np.ndarray, starts_s: np.ndarray, energy_kWh: np.ndarray, sigma_s: float,
                 lo_s: np.ndarray, hi_s: np.ndarray) -> np.ndarray:
    """The habitual draw energy, kWh, expected to start between ``t + lo`` and ``t + hi`` (seconds; rows:
    the times ``t_s``; columns: the windows, ``lo_s``/``hi_s`` (windows,) or (rows, windows)): the
    tabled draws on the day before, the day and the day after, each under a Gaussian start-time jitter
    of sd ``sigma_s`` (0: at its tabled time). Rows with the same times and windows are computed once
    (envs that started together share them)."""
    from scipy.special import ndtr

    n = np.shape(t_s)[0]
    lo = np.broadcast_to(np.asarray(lo_s, np.float64), (n, np.shape(lo_s)[-1]))
    hi = np.broadcast_to(np.asarray(hi_s, np.float64), lo.shape)
    key = np.concatenate([np.asarray(t_s, np.float64)[:, None], lo, hi], axis=1)
    if (key == key[0]).all():  # the common case: every env at the same time and window
        k_u, inv = key[:1], np.zeros(n, np.intp)
    else:
        k_u, inv = np.unique(key, axis=0, return_inverse=True)
    s = (starts_s[None, :] + np.array([-86400.0, 0.0, 86400.0])[:, None])[None]  # (1, 3 days, draws)
    t = k_u[:, :1, None]  # (distinct rows, 1, 1)
    w = lo.shape[1]

    def cdf(x_s: np.ndarray) -> np.ndarray:  # P(the draw starts before t + x) over its jittered start
        x = t + x_s[:, :, None] - s
        return ndtr(x / sigma_s) if sigma_s > 0 else (x >= 0).astype(np.float64)

    out = [((cdf(k_u[:, 1 + w + j:2 + w + j]) - cdf(k_u[:, 1 + j:2 + j])) * energy_kWh).sum(axis=(1, 2))
           for j in range(w)]
    return np.stack(out, axis=1)[inv.reshape(-1)]


def _habit(aid_name: str, scenario: Any) -> tuple[np.ndarray, np.ndarray, float]:
    """The scenario's habitual draws for an aid: the tapping cycle's start times (s) and energies (kWh), and the
    start-time jitter's sd (s; 0 when ``stochastic_draws`` is off)."""
    from valve_env.scenario import tapping_cycle

    if scenario.tapping_profile == "none":
        raise ValueError(f"obs_aids.{aid_name} needs a tapping profile (scenario.tapping_profile is 'none')")
    cyc = tapping_cycle(scenario.tapping_profile)
    sigma = float(scenario.draw_jitter_min) * 60.0 if scenario.stochastic_draws else 0.0
    return cyc["t_start_s"].to_numpy(float), cyc["Qtap_kWh"].to_numpy(float), sigma


def _times_columns(aid_name: str, aid: Mapping[str, Any]) -> tuple[str, ...]:
    """An aid's ``times: [obs column, ...]`` (see :class:`DrawForecast`), checked."""
    times = tuple(str(c) for c in aid.get("times", ()))
    bad = [c for c in times if c not in OBS_SCALING or c == "T_target_C"]
    if bad:
        raise ValueError(f"obs_aids.{aid_name}.times: {bad} are not observation columns with a fixed scaling")
    return times


def _times_products(cols: np.ndarray, obs: np.ndarray, times: tuple[str, ...]) -> np.ndarray:
    """``cols`` followed by ``cols`` times each of the ``times`` columns' physically scaled values."""
    if not times:
        return cols
    o = np.atleast_2d(np.asarray(obs, np.float64))
    prods = [cols * ((o[:, OBS_NAMES.index(c)] - OBS_SCALING[c][0]) / OBS_SCALING[c][1])[:, None] for c in times]
    return np.concatenate([cols, *prods], axis=1)


@dataclass(frozen=True)
class DrawForecast:
    """Observation aid ``draw_forecast``: the household's *habitual* draws ahead.

    From the time of day alone (the observation's tod_sin / tod_cos) and the
    published tapping cycle of the scenario (EU 814/2013 Annex III, the
    ``scenario.tapping_profile`` of the env's config), the expected tabled
    draw energy, kWh, starting in each window ``[edges[j], edges[j+1])`` hours
    ahead, under the scenario's Gaussian start-time jitter (sd
    ``draw_jitter_min``; 0 when ``stochastic_draws`` is off). It is what a
    thermostat that knows the household's habits can know: it reads neither
    the episode's drawn scenario nor any hidden state (the actual draws are
    jittered and scaled per episode). docs/agents.md, "Observation aids".
    """

    starts_s: np.ndarray
    energy_kWh: np.ndarray
    sigma_s: float
    edges_h: tuple[float, ...]
    #: ``times: [obs column, ...]``: also each window's forecast times that column's physically
    #: scaled value (OBS_SCALING), e.g. T_bottom_C, the cylinder's state of charge: a linear head can
    #: then weigh a draw ahead by how empty the store is (an interaction a linear head cannot form)
    times: tuple[str, ...] = ()

    @classmethod
    def from_config(cls, aid: Mapping[str, Any], env_cfg: Any) -> DrawForecast:
        edges = tuple(float(h) for h in aid.get("edges_h", (0.0, 0.5, 1.0, 2.0, 4.0)))
        if len(edges) < 2 or any(b <= a for a, b in zip(edges, edges[1:], strict=False)) or edges[0] < 0:
            raise ValueError(f"obs_aids.draw_forecast.edges_h must increase from >= 0, got {edges}")
        return cls(*_habit("draw_forecast", env_cfg.scenario), edges, _times_columns("draw_forecast", aid))

    @property
    def names(self) -> tuple[str, ...]:
        win = tuple(f"draw_kWh_{a:g}-{b:g}h" for a, b in zip(self.edges_h, self.edges_h[1:], strict=False))
        return win + tuple(f"{w}*{c}" for c in self.times for w in win)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        e = np.asarray(self.edges_h) * 3600.0
        win = _started_kWh(time_of_day_s(obs), self.starts_s, self.energy_kWh, self.sigma_s, e[:-1], e[1:])
        return _times_products(win, obs, self.times)


@dataclass(frozen=True)
class DrawOwed:
    """Observation aid ``draw_owed``: the household's habitual draws that have not come yet.

    For each window of the last ``windows_h`` hours: the tabled draw energy, kWh, expected to have
    started in it (the published cycle under the scenario's start-time jitter, as :class:`DrawForecast`)
    less the energy the tank delivered in it (the observed ``draw_l_min`` at the outlet's ``T_out_C``
    above the cold mains), at least 0. A bath later than its habit shows here as energy still owed,
    after the forecast ahead has let it go: what a thermostat that remembers what it saw can know.
    Only the part of a window since the episode began counts. With ``lead_h`` the delivered energy is
    counted from that much earlier, so that a draw that came before its habitual window still pays for it.

    The one aid with memory (``memory_size`` numbers per env, carried by :meth:`ObsFeatures.step`; see
    :meth:`step`). docs/agents.md, "Observation aids"."""

    starts_s: np.ndarray
    energy_kWh: np.ndarray
    sigma_s: float
    windows_h: tuple[float, ...]
    dt_s: float
    #: the water's heat per litre and kelvin, kWh/(l K) (rho cp), and the cold mains, degC (TankParams)
    kWh_per_lK: float
    T_cold_C: float
    #: as :class:`DrawForecast`'s ``times``: also each window's owed energy times these columns
    times: tuple[str, ...] = ()
    #: ``lead_h``: the delivered energy is counted from this much before each window (a draw that came
    #: early, before its habitual window began, still pays for it); 0: the same window
    lead_h: float = 0.0

    @classmethod
    def from_config(cls, aid: Mapping[str, Any], env_cfg: Any) -> DrawOwed:
        win = tuple(float(h) for h in aid.get("windows_h", (1.0, 2.0, 3.0)))
        if not win or any(not h > 0 for h in win) or len(set(win)) != len(win):
            raise ValueError(f"obs_aids.draw_owed.windows_h must be distinct positive hours, got {list(win)}")
        lead = float(aid.get("lead_h", 0.0))
        if not lead >= 0:
            raise ValueError(f"obs_aids.draw_owed.lead_h must be hours >= 0, got {lead}")
        tank = env_cfg.tank
        return cls(*_habit("draw_owed", env_cfg.scenario), win, float(env_cfg.control.dt_s),
                   float(tank.rho) * float(tank.cp) / 3.6e6, float(tank.T_cold), _times_columns("draw_owed", aid), lead)

    @property
    def names(self) -> tuple[str, ...]:
        win = tuple(f"owed_kWh_{h:g}h" for h in self.windows_h)
        return win + tuple(f"{w}*{c}" for c in self.times for w in win)

    @property
    def steps(self) -> int:
        """Control steps in the longest window of delivered energy (with the lead)."""
        return int(np.ceil((max(self.windows_h) + self.lead_h) * 3600.0 / self.dt_s - 1e-9))

    @property
    def memory_size(self) -> int:
        return self.steps + 1 + len(self.windows_h)

    def step(self, obs: np.ndarray, memory: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The owed energy per window for ``obs`` (n, d), and the memory (n, memory_size) after it; rows
        flagged in ``starts`` begin an episode (``obs`` is its first observation: nothing delivered yet).

        The memory is a ring of the energy delivered in the last ``steps`` control steps (step k in slot
        k mod steps), the steps since the episode began, and each window's running sum: a step adds its
        energy to every sum and takes out what left each window, so a step costs the same whatever the
        windows' length."""
        o = np.atleast_2d(np.asarray(obs, np.float64))
        L, W = self.steps, len(self.windows_h)
        fresh = np.asarray(starts, bool)
        new = np.array(memory, np.float64, copy=True)
        new[fresh] = 0.0  # an episode's first observation: nothing delivered yet, no step taken
        kWh = o[:, I_DRAW] * (self.dt_s / 60.0) * self.kWh_per_lK * np.maximum(o[:, I_T_OUT] - self.T_cold_C, 0.0)
        kWh[fresh] = 0.0
        k = new[:, L] + np.where(fresh, 0.0, 1.0)
        new[:, L] = k
        win = np.array([int(round(h * 3600.0 / self.dt_s)) for h in self.windows_h])
        paid = np.minimum(win + int(round(self.lead_h * 3600.0 / self.dt_s)), L)  # the delivered energy's windows
        rows = np.arange(o.shape[0])
        ki = k.astype(np.intp)
        leaving = new[rows[:, None], (ki[:, None] - paid[None, :]) % L]  # slots not yet written this episode hold 0
        sums = new[:, L + 1:L + 1 + W]
        sums += kWh[:, None] - leaving
        new[rows, ki % L] = kWh
        delivered = np.maximum(sums, 0.0)
        since_s = np.minimum(win[None, :].astype(np.float64), k[:, None]) * self.dt_s  # the window since the start
        expected = _started_kWh(time_of_day_s(o), self.starts_s, self.energy_kWh, self.sigma_s, -since_s,
                                np.zeros_like(since_s))
        return _times_products(np.maximum(expected - delivered, 0.0), o, self.times), new


@dataclass(frozen=True)
class TimeOfDay:
    """Observation aid ``time_of_day``: higher harmonics of the time of day, sin and cos of
    ``k`` x 2 pi t / 24 h for each ``k`` in ``harmonics`` (the observation has k = 1 as tod_sin,
    tod_cos). With them a linear head can shape a daily schedule of its correction (a sharper
    morning or evening pre-charge) from the clock alone. docs/agents.md, "Observation aids"."""

    harmonics: tuple[int, ...]

    @classmethod
    def from_config(cls, aid: Mapping[str, Any], env_cfg: Any) -> TimeOfDay:
        ks = tuple(int(k) for k in aid.get("harmonics", (2, 3)))
        if not ks or any(k < 2 for k in ks):
            raise ValueError(f"obs_aids.time_of_day.harmonics must be integers >= 2, got {list(ks)}")
        return cls(ks)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"tod_{f}{k}" for k in self.harmonics for f in ("sin", "cos"))

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        ang = time_of_day_s(obs)[:, None] * (2.0 * np.pi / 86400.0) * np.asarray(self.harmonics, np.float64)
        return np.stack([np.sin(ang), np.cos(ang)], axis=2).reshape(ang.shape[0], -1)


#: the observation aids a config may name (``obs_aids:``), docs/agents.md
OBS_AIDS: dict[str, Any] = {"draw_forecast": DrawForecast, "draw_owed": DrawOwed, "time_of_day": TimeOfDay}


@dataclass(frozen=True)
class ObsFeatures:
    """The policy's input features from raw observations: :func:`scale_obs` (``obs_scaling:
    physical``; else the raw columns) followed by the columns of the observation aids
    (``obs_aids:``). The training wrappers and the deployed controller call this one map."""

    scaled: bool
    extra_names: tuple[str, ...]
    aids: tuple[Any, ...]

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], env: gym.Env | Any) -> ObsFeatures:
        """``env``: the (wrapped) single env or the native VecEnv, for its config and observation names."""
        base: Any = getattr(env, "vector_env", None) or getattr(env, "unwrapped", env)
        env_cfg = base.cfg
        names = tuple(getattr(base, "obs_names", OBS_NAMES))[len(OBS_NAMES):]
        aids = []
        for name, spec in (cfg.get("obs_aids") or {}).items():
            if name not in OBS_AIDS:
                raise ValueError(f"unknown observation aid {name!r}; known: {', '.join(OBS_AIDS)}")
            aids.append(OBS_AIDS[name].from_config(spec or {}, env_cfg))
        return cls(cfg.get("obs_scaling") == "physical", names, tuple(aids))

    @property
    def active(self) -> bool:
        return self.scaled or bool(self.aids)

    def size(self, obs_dim: int) -> int:
        return obs_dim + sum(len(a.names) for a in self.aids)

    @property
    def memory_size(self) -> int:
        """Numbers per env that the aids with memory (:class:`DrawOwed`) carry from step to step."""
        return sum(int(getattr(a, "memory_size", 0)) for a in self.aids)

    def initial_memory(self, n: int) -> np.ndarray:
        return np.zeros((n, self.memory_size))

    def step(self, obs: np.ndarray, memory: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The features of ``obs`` (n, d) or (d,), with the aids' ``memory`` (n, memory_size) carried;
        rows flagged in ``starts`` (n,) begin an episode. Returns (features, the memory after them).
        Every caller (the training wrappers, CEM's batched policies, the deployed controller) steps
        this one map, so training and deployment see the same features."""
        o = np.asarray(obs)
        x = scale_obs(o, self.extra_names) if self.scaled else o.astype(np.float32)
        if not self.aids:
            return x, memory
        o2 = np.atleast_2d(o)
        cols, mems, i = [], [], 0
        for a in self.aids:
            m = int(getattr(a, "memory_size", 0))
            if m:
                c, new = a.step(o2, memory[:, i:i + m], np.asarray(starts, bool).reshape(-1))
                mems.append(new)
                i += m
            else:
                c = a(o2)
            cols.append(c)
        feat = np.concatenate([np.atleast_2d(x), np.concatenate(cols, axis=1).astype(np.float32)], axis=1)
        return feat.reshape(*x.shape[:-1], -1), (np.concatenate(mems, axis=1) if mems else memory)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """The features of aids without memory (:meth:`step` carries the memory of those with it)."""
        if self.memory_size:
            raise TypeError("an observation aid with memory (draw_owed) needs ObsFeatures.step(obs, memory, starts)")
        o = np.asarray(obs)
        return self.step(o, np.zeros((np.atleast_2d(o).shape[0], 0)), np.zeros(np.atleast_2d(o).shape[0], bool))[0]


class ScaleObservation(gym.ObservationWrapper[np.ndarray, np.ndarray, np.ndarray]):
    """Applies :class:`ObsFeatures` (fixed physical scaling, error instead of target; observation aids)."""

    def __init__(self, env: gym.Env, features: ObsFeatures | None = None) -> None:
        super().__init__(env)
        self.features = features or ObsFeatures(True, (), ())
        shape = env.observation_space.shape
        assert shape is not None
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.features.size(shape[0]),),
                                                dtype=np.float32)
        self._memory = self.features.initial_memory(1)
        self._start = True

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        self._start = True
        return super().reset(**kwargs)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        feat, self._memory = self.features.step(np.atleast_2d(observation), self._memory, np.array([self._start]))
        self._start = False
        return feat[0]


def push_history(hist: np.ndarray, obs: np.ndarray, starts: np.ndarray, in_place: bool = False) -> np.ndarray:
    """The last k observations, oldest first, exactly as gymnasium's
    FrameStackObservation(padding_type="reset") keeps them: ``hist`` (n, k, d),
    ``obs`` (n, d); rows flagged in ``starts`` restart filled with ``obs``. A new array,
    or with ``in_place`` ``hist`` itself updated (its dtype kept; no per-step allocation)."""
    if not in_place:
        shifted = np.concatenate([hist[:, 1:], obs[:, None, :]], axis=1)
        fresh = np.broadcast_to(obs[:, None, :], hist.shape)
        return np.where(starts[:, None, None], fresh, shifted)
    hist[:, :-1] = hist[:, 1:]  # numpy buffers the overlapping copy
    hist[:, -1] = obs
    if starts.any():
        hist[starts] = obs[starts][:, None, :]
    return hist


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
    features = ObsFeatures.from_config(cfg, env)
    if features.active:
        env = ScaleObservation(env, features)
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
