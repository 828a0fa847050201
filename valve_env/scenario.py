"""Scenarios: hot-water draws, primary supply temperature and differential
pressure, sampled per control step from the env's seeded generator.

Draws follow the EU tapping cycles S, M, L (Regulation 814/2013 Annex III,
transcribed from RWTH-EBC/BESMod; see valve_env/data/PROFILES_SOURCE.md). The
stochastic variant jitters each draw's start time and scales its energy with
a seeded generator, and adds the same day's cycle on top of itself with no
fixed timetable, so every seed gives another day.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from functools import cache
from typing import Any, ClassVar

import numpy as np
import pandas as pd
from numba import njit

from valve_env.data import data_file
from valve_env.params import DP_MAX_MBAR, SUPPLY_LIMITS_C, ConfigError, _from_mapping, check_fields, param

PROFILES = ("S", "M", "L", "none")
SUPPLY_PROFILES = ("constant", "daily", "random", "network")
DP_PROFILES = ("constant", "network")


@dataclass(frozen=True)
class ScenarioParams:
    """What happens around the tank during an episode.

    | field | unit | meaning (default and source) | range (why) |
    |---|---|---|---|
    | tapping_profile | - | "S", "M", "L" (EU 814/2013 tapping cycles) or "none"; "M" (5.845 kWh/day) | {S, M, L, none} |
    | stochastic_draws | - | True: seeded variant (start jitter, energy scaling); False: the cycle as tabled | {true, false} |
    | draw_jitter_min | min | standard deviation of each draw's start-time jitter; 20 | [0, 240] (up to 4 h: a day's habits) |
    | draw_energy_cv | - | coefficient of variation of each draw's energy (lognormal); 0.2 | [0, 2] (a draw 0 .. several times its tabled energy) |
    | supply_C | degC | primary supply temperature; 70 (docs/reference.md, section 5) | [1, 130] (district heating up to 130 degC) |
    | supply_profile | - | "constant", "daily" (sine, coldest at 15:00), "random" (Ornstein-Uhlenbeck) or "network" (supply_plan plus an OU disturbance of sd supply_noise_K) | {constant, daily, random, network} |
    | supply_amplitude_K | K | amplitude of the daily sine or network plan, or sd of the random profile; 5 | [0, 40] (a daily swing; see below) |
    | supply_tau_h | h | correlation time of the random supply profile and of the network profile's disturbance; 2 | [0.01, 1000] (minutes .. weeks) |
    | supply_noise_K | K | standard deviation of the network profile's OU disturbance around its plan; 0 | [0, 20] (kept within the supply limits) |
    | dp_mbar | mbar | the network's dp across the valve when the agent does not set it; 100 (calibration) | [0, 2000] (0 .. 2 bar, DP_MAX_MBAR) |
    | dp_profile | - | "constant" (dp_mbar) or "network" (dp_plan: falls by dp_swing at peak load) | {constant, network} |
    | dp_swing | - | fractional fall of dp at the network's peak load (dp_profile "network"); 0 | [0, 1) (dp stays positive) |
    | dp_noise_mbar | mbar | standard deviation of an Ornstein-Uhlenbeck disturbance on dp; 0 | [0, 1000] (up to 1 bar; the path is kept in [0, 2000]) |
    | dp_tau_s | s | its correlation time; 600 | [1, 1000000] (a second .. 11 days) |
    | ps_bar | bar | static pressure at the valve; 2 (calibration) | [0, 25] (PN25) |
    | T_init_C | degC | initial tank temperature (mean) ; 55 | [1, 99] (liquid water at ambient pressure) |
    | T_init_spread_K | K | seeded uniform spread of the initial temperature, +-; 3 | [0, 20] |

    The supply temperature stays within SUPPLY_LIMITS_C = [0, 140] degC (liquid
    water at district-heating pressures): a daily profile must lie within
    them (supply_C +- supply_amplitude_K), a random one is kept within them.
    """  # noqa: E501

    SECTION: ClassVar[str] = "scenario"

    tapping_profile: str = param("M", kind="choice", choices=PROFILES)
    stochastic_draws: bool = param(True, kind="bool")
    draw_jitter_min: float = param(20.0, 0.0, 240.0, "min", "up to 4 h: a day's habits")
    draw_energy_cv: float = param(0.2, 0.0, 2.0, "-", "a draw 0 .. several times its tabled energy")
    supply_C: float = param(70.0, 1.0, 130.0, "degC", "district heating up to 130 degC")
    supply_profile: str = param("constant", kind="choice", choices=SUPPLY_PROFILES)
    supply_amplitude_K: float = param(5.0, 0.0, 40.0, "K", "a daily swing")
    supply_tau_h: float = param(2.0, 0.01, 1000.0, "h", "minutes .. weeks")
    supply_noise_K: float = param(0.0, 0.0, 20.0, "K", "kept within the supply limits")
    dp_mbar: float = param(100.0, 0.0, DP_MAX_MBAR, "mbar", "0 .. 2 bar")
    dp_profile: str = param("constant", kind="choice", choices=DP_PROFILES)
    dp_swing: float = param(0.0, 0.0, 1.0, "-", "dp stays positive", hi_open=True)
    dp_noise_mbar: float = param(0.0, 0.0, 1000.0, "mbar", "up to 1 bar")
    dp_tau_s: float = param(600.0, 1.0, 1e6, "s", "a second .. 11 days")
    ps_bar: float = param(2.0, 0.0, 25.0, "bar", "PN25")
    T_init_C: float = param(55.0, 1.0, 99.0, "degC", "liquid water at ambient pressure")
    T_init_spread_K: float = param(3.0, 0.0, 20.0, "K", "a spread of the initial temperature")

    def __post_init__(self) -> None:
        check_fields(self)
        lo, hi = SUPPLY_LIMITS_C
        a = self.supply_amplitude_K
        if self.supply_profile in ("daily", "network") and not (lo <= self.supply_C - a and self.supply_C + a <= hi):
            raise ConfigError(
                f"scenario.supply_amplitude_K: a {self.supply_profile} supply of {self.supply_C:g} +- {a:g} degC "
                f"leaves [{lo:g}, {hi:g}] degC (liquid water at district-heating pressures)"
            )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> ScenarioParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@cache
def tapping_cycle(name: str) -> pd.DataFrame:
    """The tabled EU tapping cycle ``name`` (S, M or L) as a DataFrame."""
    if name not in ("S", "M", "L"):
        raise ConfigError(f"unknown tapping profile {name!r}; choose S, M or L")
    with data_file(f"ecodesign_tapping_profile_{name}.csv").open("r") as fh:
        df = pd.read_csv(fh)
    return df


def largest_tap_l_min(profile: str) -> float:
    """The largest tap flow of the tapping cycle ``profile``, l/min (0 for "none")."""
    return 0.0 if profile == "none" else float(tapping_cycle(profile)["f_l_min"].max())


@dataclass
class ScenarioArrays:
    """Per-control-step scenario inputs (length n_steps each).

    draw_W: mean demanded draw power over the step at the draw temperature
    (cp (T_draw - T_cold) times the useful flow); draw_T_C: the draw's required
    temperature; draw_mmax: the tap's full flow, kg/s; supply_C; dp_mbar.
    """

    draw_W: np.ndarray
    draw_T_C: np.ndarray
    draw_mmax: np.ndarray
    supply_C: np.ndarray
    dp_mbar: np.ndarray
    T_init_C: float

    def as_matrix(self) -> np.ndarray:
        """(n_steps, 5) float64 matrix in the order the simulator kernel reads."""
        return np.ascontiguousarray(
            np.stack([self.draw_W, self.draw_T_C, self.draw_mmax, self.supply_C, self.dp_mbar], axis=1)
        )


@njit(cache=True)
def _spread(starts: np.ndarray, durations: np.ndarray, values: np.ndarray, dt: float, n: int) -> np.ndarray:
    """Step averages of pulses: ``values[:, c]`` during [starts, starts + durations).

    Column c of the result is the mean over each step [k dt, (k+1) dt) of the
    sum of the pulses' c-th values (all columns in one pass)."""
    out = np.zeros((n, values.shape[1]))
    for p in range(starts.shape[0]):
        s = starts[p]
        e = s + durations[p]
        k0 = max(int(np.floor(s / dt)), 0)
        k1 = min(int(np.floor(e / dt)), n - 1)
        for k in range(k0, k1 + 1):
            a = max(s, k * dt)
            b = min(e, (k + 1) * dt)
            if b > a:
                w = (b - a) / dt
                for c in range(values.shape[1]):
                    out[k, c] += values[p, c] * w
    return out


@dataclass(frozen=True)
class Draws:
    """An episode's draws as :func:`make_scenario` samples them, one row each."""

    tabled_s: np.ndarray
    """The tabled start (the habit), s."""
    start_s: np.ndarray
    """The actual start, s (jittered; wrapped into the episode where it is a day or longer)."""
    energy_J: np.ndarray
    power_W: np.ndarray
    T_draw_C: np.ndarray
    f_kgs: np.ndarray

    @property
    def duration_s(self) -> np.ndarray:
        return self.energy_J / self.power_W


def sample_draws(params: ScenarioParams, rng: np.random.Generator, n_steps: int, dt_s: float, T_cold: float,
                 cp: float) -> Draws:
    """The episode's draws of the tapping cycle from ``rng``: each day the tabled starts jittered and the energies
    scaled (the stochastic variant), in the order :func:`make_scenario` draws them."""
    if params.tapping_profile == "none":
        raise ValueError("no tapping profile: no draws")
    horizon = n_steps * dt_s
    cyc = tapping_cycle(params.tapping_profile)
    tab = cyc["t_start_s"].to_numpy(dtype=float)
    Q = cyc["Qtap_kWh"].to_numpy(dtype=float) * 3.6e6
    f_kgs = cyc["f_l_min"].to_numpy(dtype=float) / 60.0
    T_d = cyc["T_draw_C"].to_numpy(dtype=float)
    n_days = max(1, int(np.ceil(horizon / 86400.0 - 1e-9)))
    tabled, starts, energies = [], [], []
    for day in range(n_days):  # the cycle repeats every day, each day with its own randomness
        s_d, Q_d = tab + day * 86400.0, Q
        tabled.append(s_d)
        if params.stochastic_draws:
            s_d = s_d + rng.normal(0.0, params.draw_jitter_min * 60.0, size=tab.size)
            if params.draw_energy_cv > 0:
                s2 = np.log1p(params.draw_energy_cv**2)
                Q_d = Q * rng.lognormal(-0.5 * s2, np.sqrt(s2), size=Q.size)
        starts.append(s_d)
        energies.append(Q_d)
    start = np.concatenate(starts)
    f = np.tile(f_kgs, n_days)
    T = np.tile(T_d, n_days)
    power = f * cp * (T - T_cold)
    start = np.mod(start, horizon) if horizon >= 86400.0 else start
    return Draws(np.concatenate(tabled), start, np.concatenate(energies), power, T, f)


def draw_columns(draws: Draws, n_steps: int, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The draws averaged over each control step: (power W, draw temperature degC, mass flow kg/s); 45 degC and no
    flow where none is drawn."""
    vals = np.stack([draws.power_W, np.ones_like(draws.power_W), draws.T_draw_C, draws.f_kgs], axis=1)
    spread = _spread(draws.start_s, draws.duration_s, vals, dt_s, n_steps)
    draw_T = np.full(n_steps, 45.0)
    draw_m = np.zeros(n_steps)
    active = spread[:, 1]
    on = active > 0
    draw_T[on] = spread[on, 2] / active[on]
    draw_m[on] = spread[on, 3] / active[on]
    return spread[:, 0].copy(), draw_T, draw_m


def make_scenario(
    params: ScenarioParams, rng: np.random.Generator, n_steps: int, dt_s: float, T_cold: float, cp: float
) -> ScenarioArrays:
    """Sample one episode's scenario from ``rng`` (the env's seeded generator)."""
    if params.tapping_profile != "none":
        draw_W, draw_T, draw_m = draw_columns(sample_draws(params, rng, n_steps, dt_s, T_cold, cp), n_steps, dt_s)
    else:
        draw_W, draw_T, draw_m = np.zeros(n_steps), np.full(n_steps, 45.0), np.zeros(n_steps)
    t = (np.arange(n_steps) + 0.5) * dt_s
    if params.supply_profile == "constant":
        supply = np.full(n_steps, params.supply_C)
    elif params.supply_profile == "daily":
        supply = params.supply_C + params.supply_amplitude_K * np.cos(2 * np.pi * (t - 3 * 3600.0) / 86400.0)
    elif params.supply_profile == "network":
        supply = supply_plan(params, t)
        if params.supply_noise_K > 0:
            supply = supply + ou_path(rng, n_steps, dt_s, params.supply_tau_h * 3600.0, params.supply_noise_K)
    else:
        supply = params.supply_C + ou_path(rng, n_steps, dt_s, params.supply_tau_h * 3600.0, params.supply_amplitude_K)
        supply = np.clip(supply, *SUPPLY_LIMITS_C)  # an unbounded Gaussian path; liquid water stays within
    if params.supply_profile == "network":
        supply = np.clip(supply, *SUPPLY_LIMITS_C)  # the plan plus an unbounded Gaussian disturbance
    dp = dp_plan(params, t)
    if params.dp_noise_mbar > 0:
        dp = np.clip(dp + ou_path(rng, n_steps, dt_s, params.dp_tau_s, params.dp_noise_mbar), 0.0, DP_MAX_MBAR)
    T0 = params.T_init_C + (rng.uniform(-1.0, 1.0) * params.T_init_spread_K if params.T_init_spread_K > 0 else 0.0)
    return ScenarioArrays(draw_W, draw_T, draw_m, supply, dp, float(T0))


def network_load(t_s: np.ndarray | float) -> np.ndarray:
    """A district-heating network's relative load over the day, 0 .. 1 (1 at the morning peak).

    Two peaks, the morning one (07:30, sd 1.5 h) higher than the evening one
    (19:00, sd 2.5 h, 0.7 of it), scaled to 0 at the night minimum: the shape
    of the daily heat-load profiles of residential district heating (the
    morning peak of domestic hot water and the restart after night set-back;
    Gadd and Werner, "Daily heat load variations in Swedish district heating
    systems", Applied Energy 106 (2013) 47-55). Stylised: docs/tasks.md.
    """
    return (_load_raw(np.asarray(t_s, dtype=float) / 3600.0) - _LOAD_MIN) / (_LOAD_MAX - _LOAD_MIN)


def _load_raw(hour: np.ndarray) -> np.ndarray:
    h = np.mod(hour, 24.0)

    def bump(centre: float, sd: float) -> np.ndarray:
        d = np.mod(h - centre + 12.0, 24.0) - 12.0  # the shortest way round the clock
        return np.exp(-0.5 * (d / sd) ** 2)

    return bump(7.5, 1.5) + 0.7 * bump(19.0, 2.5)


_LOAD_GRID = _load_raw(np.linspace(0.0, 24.0, 24 * 60 + 1))
_LOAD_MIN, _LOAD_MAX = float(_LOAD_GRID.min()), float(_LOAD_GRID.max())


def supply_plan(params: ScenarioParams, t_s: np.ndarray | float) -> np.ndarray:
    """The network operator's planned supply temperature at times ``t_s``, degC:
    ``supply_C + supply_amplitude_K (2 load(t + 1 h) - 1)``: the plant raises the
    supply an hour ahead of the load (:func:`network_load`), the transport delay
    of a city network (docs/tasks.md). What an operator would publish as a forecast."""
    return params.supply_C + params.supply_amplitude_K * (2.0 * network_load(np.asarray(t_s) + 3600.0) - 1.0)


def dp_plan(params: ScenarioParams, t_s: np.ndarray | float) -> np.ndarray:
    """The differential pressure the network leaves across the valve at times ``t_s``, mbar:
    ``dp_mbar`` ("constant") or ``dp_mbar (1 - dp_swing load(t))`` ("network": the pressure
    drop in the mains grows with the load, so the dp at a substation falls at peak load)."""
    t = np.asarray(t_s, dtype=float)
    if params.dp_profile == "constant":
        return np.full(t.shape, params.dp_mbar)
    return params.dp_mbar * (1.0 - params.dp_swing * network_load(t))


def ou_path(rng: np.random.Generator, n: int, dt: float | np.ndarray, tau: float, sd: float) -> np.ndarray:
    """Stationary Ornstein-Uhlenbeck path of ``n`` samples (time constant ``tau``, sd ``sd``), sampled exactly at
    steps ``dt``: one step, or the ``n - 1`` intervals of irregular sample times."""
    a = np.broadcast_to(np.exp(-np.asarray(dt, dtype=float) / tau), (max(n - 1, 0),))
    b = sd * np.sqrt(1.0 - a * a)
    z = rng.normal(0.0, 1.0, size=n)
    x = np.empty(n)
    x[0] = sd * z[0]
    # Python floats in the loop: the same IEEE arithmetic, without NumPy's per-element scalar overhead
    al, bl, zl, prev = a.tolist(), b.tolist(), z.tolist(), float(x[0])
    for k in range(1, n):
        prev = al[k - 1] * prev + bl[k - 1] * zl[k]
        x[k] = prev
    return x
