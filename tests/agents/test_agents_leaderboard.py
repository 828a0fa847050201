"""The leaderboard command: agents and baselines through the one evaluator,
with a randomised scenario, the ablation row, the target check and the figure."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from agents.leaderboard import build_leaderboard, compare
from agents.scenarios import episode_env_kwargs, random_valve
from agents.train import ship


def test_leaderboard_writes_tables_json_and_figure(short_run: Path, tmp_path: Path, short: dict[str, Any]) -> None:
    zoo = tmp_path / "zoo"
    ship(short_run, zoo_dir=zoo)
    out = tmp_path / "docs"
    paths = build_leaderboard(
        ["ThermoValve-v0"], ["default", "valve_random"], episodes=2, seed=1000, zoo=zoo, out_dir=out,
        command="pytest", verbose=False, base_kwargs=short,
    )
    md = paths["markdown"].read_text()
    for name in ("self_acting", "pi", "pi_compensated", "ppo", "ppo_base_law"):
        assert f"| {name} |" in md
    assert "Target check, ThermoValve-v0" in md and "Best agent: `ppo`" in md
    assert paths["figure_ThermoValve-v0"].is_file() and paths["figure_ThermoValve-v0"].stat().st_size > 10_000
    df = pd.read_csv(paths["csv"])
    assert set(df["scenario"]) == {"default", "valve_random"}
    assert (df.groupby(["scenario", "controller"]).size() == 2).all()
    # every controller met the same seeds
    assert set(df["seed"]) == {1000, 1001}
    js = json.loads(paths["json"].read_text())
    entry = js["envs"]["ThermoValve-v0"]
    assert entry["best_agent"] == "ppo"
    assert entry["scenarios"]["default"]["results"]["pi"]["return"]["std"] >= 0
    assert "vs_base_law" in entry["target_check"]["default"]


def test_random_valve_is_seeded_and_near_the_paper() -> None:
    a, b = random_valve(3), random_valve(3)
    assert a == b and a != random_valve(4)
    assert abs(a["sigma"] - 6.41) < 5 * 0.589 and abs(a["p_bset"] - 0.0776) < 5 * 0.000892
    kw = episode_env_kwargs("valve_random", 3, {"control": {"horizon_h": 1.0}})
    assert kw["valve"] == a and kw["control"] == {"horizon_h": 1.0}


def test_compare_is_paired_by_seed() -> None:
    base = {"seed": [1, 2], "return": [-10.0, -20.0], "rmse_K": [0.3, 0.3], "heat_kWh": [7.0, 7.0],
            "pump_kWh": [0.0, 0.0], "tdis_Kh": [0.0, 0.0], "reversals": [10.0, 10.0]}
    agent = {**base, "seed": [2, 1], "return": [-19.0, -9.0], "rmse_K": [0.2, 0.2]}
    c = compare({"a": pd.DataFrame(agent), "pi": pd.DataFrame(base)}, "a")
    assert c["return"]["diff_mean"] == 1.0 and c["return"]["wins"] == 2 and c["target_met"]
