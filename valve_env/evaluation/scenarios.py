"""The one registry of named scenarios, used by ``thermovalve evaluate --scenario``, the
leaderboard, the sweep and the packaged files ``valve_env/data/scenarios/`` (each static scenario NAME
has ``valve_env/data/scenarios/NAME.yaml`` giving the same environment, which ``config="NAME"`` loads;
a test holds them equal).

The agents train on ``default`` (gym.make's defaults: EU tapping cycle M, seeded stochastic
draws, 70 degC supply, the paper's valve). The others are not seen in training:

| name | what changes |
|---|---|
| default | nothing (held-out seeds) |
| profile_L | the EU tapping cycle L (11.655 kWh a day instead of 5.845) |
| supply_65C | district-heating supply at a constant 65 degC instead of 70 |
| cold_supply | supply at 60 degC with a +-5 K daily swing (coldest mid-afternoon) |
| noisy_sensors | the paper's measurement noise (Table 1) and one step of dead time |
| pressure_disturbance | the network dp wanders (Ornstein-Uhlenbeck, 30 mbar sd, 10 min) |
| random_supply | the supply temperature wanders (Ornstein-Uhlenbeck, 5 K sd, 2 h) |
| valve_random | per episode, sigma, F_hmax and p_bset ~ N(paper Table 4 estimate, its standard error) |

Earlier leaderboards' ``cold_supply`` meant a constant 65 degC supply while
``configs/scenarios/cold_supply.yaml`` meant 60 degC with a daily swing; the first is now
``supply_65C`` (the same environment, so its published figures stand under the new name).

``valve_random`` is per-episode: :func:`episode_env_kwargs` gives the env keywords of episode
seed ``s`` (its own generator, seeded by ``s``, so every controller meets the same valves).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from valve_env.params import ValveParams

STATIC_SCENARIOS: dict[str, dict[str, Any]] = {
    "default": {},
    "profile_L": {"scenario": {"tapping_profile": "L"}},
    "supply_65C": {"scenario": {"supply_C": 65.0}},
    "cold_supply": {"scenario": {"supply_C": 60.0, "supply_profile": "daily", "supply_amplitude_K": 5.0}},
    "noisy_sensors": {"sensors": {"noise_K": 0.05, "flow_noise_rel": 0.015, "dead_time_steps": 1}},
    "pressure_disturbance": {"scenario": {"dp_mbar": 100.0, "dp_noise_mbar": 30.0, "dp_tau_s": 600.0}},
    "random_supply": {"scenario": {"supply_profile": "random", "supply_amplitude_K": 5.0, "supply_tau_h": 2.0}},
}
RANDOMISED_SCENARIOS: tuple[str, ...] = ("valve_random",)
SCENARIOS: tuple[str, ...] = (*STATIC_SCENARIOS, *RANDOMISED_SCENARIOS)
#: the leaderboard's default set: the training scenario and three unseen ones
LEADERBOARD_SCENARIOS: tuple[str, ...] = ("default", "profile_L", "supply_65C", "valve_random")
DESCRIPTIONS: dict[str, str] = {
    "default": "training scenario (tapping cycle M, supply 70 degC), held-out seeds",
    "profile_L": "unseen: EU tapping cycle L",
    "supply_65C": "unseen: supply 65 degC constant",
    "cold_supply": "unseen: supply 60 degC with a +-5 K daily swing",
    "noisy_sensors": "unseen: measurement noise (paper Table 1) and one step of dead time",
    "pressure_disturbance": "unseen: network dp wanders (OU, 30 mbar sd, 10 min)",
    "random_supply": "unseen: supply temperature wanders (OU, 5 K sd, 2 h)",
    "valve_random": "unseen: valve sigma, F_hmax, p_bset ~ N(paper, Table 4 sd) per episode",
}


def check_scenario(name: str) -> None:
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")


def random_valve(seed: int) -> dict[str, float]:
    """Valve parameters drawn from N(estimate, standard error) of the paper's Table 4."""
    rng = np.random.default_rng([20_240_707, int(seed)])
    base = ValveParams()
    out = {}
    for name, sd in ValveParams.TABLE4_STD.items():
        mean = float(getattr(base, name))
        out[name] = float(max(rng.normal(mean, sd), 0.05 * mean))
    return out


def is_randomised(name: str) -> bool:
    check_scenario(name)
    return name in RANDOMISED_SCENARIOS


def scenario_env_kwargs(name: str) -> dict[str, Any]:
    """gym.make keywords of a static scenario."""
    check_scenario(name)
    if name in RANDOMISED_SCENARIOS:
        raise ValueError(f"scenario {name!r} changes per episode; use episode_env_kwargs(name, seed)")
    return {k: dict(v) if isinstance(v, dict) else v for k, v in STATIC_SCENARIOS[name].items()}


def episode_env_kwargs(name: str, seed: int, base: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """gym.make keywords of scenario ``name`` for the episode with seed ``seed``."""
    check_scenario(name)
    kw = dict(base or {})
    if name == "valve_random":
        kw["valve"] = {**dict(kw.get("valve") or {}), **random_valve(seed)}
    else:
        for key, value in scenario_env_kwargs(name).items():
            kw[key] = {**dict(kw.get(key) or {}), **value} if isinstance(value, dict) else value
    return kw


__all__ = ["STATIC_SCENARIOS", "RANDOMISED_SCENARIOS", "SCENARIOS", "LEADERBOARD_SCENARIOS", "DESCRIPTIONS",
           "check_scenario", "random_valve", "is_randomised", "scenario_env_kwargs", "episode_env_kwargs"]
