"""One scenario registry: every static scenario NAME of valve_env.evaluation.scenarios has
configs/scenarios/NAME.yaml giving the same environment, and no other file exists there."""

from __future__ import annotations

from pathlib import Path

from valve_env.config import make_config
from valve_env.evaluation.scenarios import LEADERBOARD_SCENARIOS, SCENARIOS, STATIC_SCENARIOS, episode_env_kwargs

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "scenarios"


def test_registry_and_config_files_agree() -> None:
    assert sorted(p.stem for p in CONFIGS.glob("*.yaml")) == sorted(STATIC_SCENARIOS)
    for name in STATIC_SCENARIOS:
        assert make_config(str(CONFIGS / f"{name}.yaml")) == make_config(**episode_env_kwargs(name, 0)), name


def test_names_are_unique_and_mean_one_thing() -> None:
    assert len(set(SCENARIOS)) == len(SCENARIOS)
    assert set(LEADERBOARD_SCENARIOS) <= set(SCENARIOS)
    cfgs = {n: make_config(**episode_env_kwargs(n, 0)) for n in STATIC_SCENARIOS}
    names = list(cfgs)
    for i, a in enumerate(names):  # no two names for one environment either
        for b in names[i + 1:]:
            assert cfgs[a] != cfgs[b], (a, b)
    assert cfgs["cold_supply"].scenario.supply_C == 60.0 and cfgs["supply_65C"].scenario.supply_C == 65.0
