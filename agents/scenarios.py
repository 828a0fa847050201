"""Named evaluation (and sweep) scenarios.

The agents train on ``default`` (gym.make's defaults: EU tapping cycle M,
seeded stochastic draws, 70 degC supply, the paper's valve). The others are
not seen in training:

| name | what changes |
|---|---|
| default | nothing (held-out seeds) |
| profile_L | the EU tapping cycle L (11.655 kWh a day instead of 5.845) |
| cold_supply | district-heating supply at 65 degC instead of 70 |
| valve_random | per episode, sigma, F_hmax and p_bset ~ N(paper Table 4 estimate, its standard error) |

``valve_random`` is per-episode: :func:`episode_env_kwargs` gives the
env keywords of episode seed ``s`` (its own generator, seeded by ``s``, so
every controller meets the same valves).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from valve_env.params import ValveParams

STATIC_SCENARIOS: dict[str, dict[str, Any]] = {
    "default": {},
    "profile_L": {"tapping_profile": "L"},
    "cold_supply": {"supply_C": 65.0},
}
RANDOMISED_SCENARIOS: tuple[str, ...] = ("valve_random",)
SCENARIOS: tuple[str, ...] = (*STATIC_SCENARIOS, *RANDOMISED_SCENARIOS)
DESCRIPTIONS: dict[str, str] = {
    "default": "training scenario (tapping cycle M, supply 70 degC), held-out seeds",
    "profile_L": "unseen: EU tapping cycle L",
    "cold_supply": "unseen: supply 65 degC",
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
    return dict(STATIC_SCENARIOS[name])


def episode_env_kwargs(name: str, seed: int, base: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """gym.make keywords of scenario ``name`` for the episode with seed ``seed``."""
    check_scenario(name)
    kw = dict(base or {})
    if name == "valve_random":
        kw["valve"] = {**dict(kw.get("valve") or {}), **random_valve(seed)}
    else:
        kw.update(STATIC_SCENARIOS[name])
    return kw
