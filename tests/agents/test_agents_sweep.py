"""The sweep runs on a real Dask LocalCluster (two worker processes, a tiny
grid), resumes (a second run skips finished cells) and records failures."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from agents.sweep import Cell, make_grid, pending, run_cell, run_sweep, write_json_atomic

TINY = ("n_envs=1", "hyperparams.n_steps=64", "hyperparams.batch_size=32", "hyperparams.n_epochs=1")


@pytest.mark.slow  # 18 s; the default suite has a Dask LocalCluster (test_agents_benchmark.py) and the retry below
def test_sweep_on_a_local_cluster_and_resume(tmp_path: Path, short: dict[str, Any]) -> None:
    cells = make_grid(["ppo"], [0, 1], ["default"], timesteps=128, eval_episodes=1, overrides=TINY, env_kwargs=short)
    out = tmp_path / "sweep"
    stats = run_sweep(cells, out, workers=2, verbose=False)
    assert stats == {"total": 2, "skipped": 0, "done": 2, "failed": 0}
    for c in cells:
        rec = json.loads((out / "results" / f"{c.key}.json").read_text())
        assert rec["status"] == "done" and rec["cell"]["seed"] == c.seed
        assert len(rec["episodes"]) == 1 and "rmse_K" in rec["kpis"]
        assert (out / "cells" / c.key / "model.zip").is_file()
    assert (out / "summary.csv").is_file() and "ppo" in (out / "summary.md").read_text()
    pids = {json.loads((out / "results" / f"{c.key}.json").read_text())["pid"] for c in cells}
    assert len(pids) >= 1
    # a second run finds every result and starts no cluster
    assert run_sweep(cells, out, workers=2, verbose=False) == {"total": 2, "skipped": 2, "done": 0, "failed": 0}


def test_failed_cell_is_recorded_and_retried(tmp_path: Path, short: dict[str, Any]) -> None:
    bad = Cell("ppo", 0, "default", timesteps=64, eval_episodes=1,
               overrides=("hyperparams.n_steps=-5",), env_kwargs=short)
    rec = run_cell(bad, str(tmp_path))
    assert rec["status"] == "failed" and rec["traceback"]
    assert (tmp_path / "failed" / f"{bad.key}.json").is_file()
    assert not (tmp_path / "results" / f"{bad.key}.json").exists()
    assert pending([bad], tmp_path) == [bad]  # retried on the next run
    # once it succeeds the failure record goes away
    good = Cell("ppo", 0, "default", timesteps=64, eval_episodes=1, overrides=TINY, env_kwargs=short)
    assert good.key == bad.key
    assert run_cell(good, str(tmp_path))["status"] == "done"
    assert not (tmp_path / "failed" / f"{bad.key}.json").exists() and pending([good], tmp_path) == []


def test_atomic_write_leaves_no_partial_file(tmp_path: Path) -> None:
    p = tmp_path / "r.json"
    write_json_atomic(p, {"a": 1})
    try:
        write_json_atomic(p, {"a": object()})  # not serialisable: fails midway
    except TypeError:
        pass
    assert json.loads(p.read_text()) == {"a": 1}
    assert [f.name for f in tmp_path.iterdir()] == ["r.json"]


def test_grid_rejects_unknown_names() -> None:
    import pytest

    with pytest.raises(ValueError, match="unknown algo"):
        make_grid(["dqn"], [0], ["default"])
    with pytest.raises(ValueError, match="per episode"):
        make_grid(["ppo"], [0], ["valve_random"])
    with pytest.raises(ValueError, match="unknown scenario"):
        make_grid(["ppo"], [0], ["mars"])


GRID = """
ThermoValve-v0:
  timesteps: 128
  set: {n_envs: 1, hyperparams.n_steps: 64, hyperparams.batch_size: 32, hyperparams.n_epochs: 1}
  grid:
    hyperparams.learning_rate: [1.0e-4, 3.0e-4]
    hyperparams.policy_kwargs.log_std_init: [-3.0]
"""


def test_grid_file_parsing(tmp_path: Path) -> None:
    import pytest

    from agents.sweep import grid_points, load_grid

    p = tmp_path / "g.yml"
    p.write_text(GRID)
    block = load_grid(p)["ThermoValve-v0"]
    assert block["timesteps"] == 128 and block["set"]["n_envs"] == 1
    pts = grid_points(block)
    assert pts == [("hyperparams.learning_rate=0.0001", "hyperparams.policy_kwargs.log_std_init=-3.0"),
                   ("hyperparams.learning_rate=0.0003", "hyperparams.policy_kwargs.log_std_init=-3.0")]
    cells = make_grid(["ppo"], [0, 1], ["default"], timesteps=128, points=pts)
    assert len(cells) == 4 and len({c.key for c in cells}) == 4 and cells[2].key.endswith("__g01__s0")
    for text, match in (
        ("NoSuchEnv-v0: {grid: {a: [1]}}", "unknown env id"),
        ("ThermoValve-v0: {grid: {hyperparams.gamma: 0.99}}", "non-empty list"),
        ("ThermoValve-v0: {grid: {hyperparams.gamma: []}}", "non-empty list"),
        ("ThermoValve-v0: {set: {n_envs: 2}}", "non-empty 'grid:'"),
        ("ThermoValve-v0: {grid: {a: [1]}, sett: {}}", "unknown keys"),
        ("ThermoValve-v0: {grid: {a: [1]}, timesteps: -5}", "timesteps"),
        ("ThermoValve-v0: [unclosed", "not valid YAML"),
    ):
        p.write_text(text)
        with pytest.raises(ValueError, match=match):
            load_grid(p)
    p.write_text(GRID)
    with pytest.raises(ValueError, match="no block for ThermoValveDual-v0"):
        load_grid(p, ["ThermoValveDual-v0"])


def test_grid_cell_saves_its_config_and_command(tmp_path: Path, short: dict[str, Any]) -> None:
    """One grid cell run for real: its directory holds the resolved config with the grid point's
    values and a thermovalve train command that resolves to the same config; the summary ranks it."""
    import shlex

    import yaml

    from agents.sweep import grid_points, load_grid, write_summary
    from agents.train import add_arguments, apply_overrides, load_algo_config
    from valve_env.cli import main

    g = tmp_path / "g.yml"
    g.write_text(GRID)
    block = load_grid(g)["ThermoValve-v0"]
    fixed = [f"{k}={v}" for k, v in block["set"].items()]
    cell = make_grid(["ppo"], [0], ["default"], timesteps=128, eval_episodes=1, overrides=fixed,
                     env_kwargs=short, points=grid_points(block))[1]
    rec = run_cell(cell, str(tmp_path / "sw"))
    assert rec["status"] == "done", rec.get("error")
    run_dir = tmp_path / "sw" / "cells" / cell.key
    cfg = yaml.safe_load((run_dir / "config.yml").read_text())
    assert cfg["hyperparams"]["learning_rate"] == 3.0e-4 and cfg["hyperparams"]["policy_kwargs"]["log_std_init"] == -3
    assert cfg["env_kwargs"] == short and (run_dir / "model.zip").is_file()
    argv = shlex.split((run_dir / "command.txt").read_text())
    assert argv[:2] == ["thermovalve", "train"]
    import argparse

    p = argparse.ArgumentParser()
    add_arguments(p)
    a = p.parse_args(argv[2:])
    again = apply_overrides(load_algo_config(a.algo, a.env), a.overrides)
    assert again["hyperparams"] == cfg["hyperparams"] and again["env_kwargs"] == cfg["env_kwargs"]
    assert a.timesteps == 128 and a.seed == 0 and a.out == str(run_dir)
    write_summary(tmp_path / "sw")
    md = (tmp_path / "sw" / "summary.md").read_text()
    assert "ranked by mean evaluation return" in md and "learning_rate=0.0003" in md and "seeds 1000+" in md
    # the CLI refuses a bad grid file with one line
    g.write_text("ThermoValve-v0: {grid: {a: 1}}")
    assert main(["sweep", "--grid", str(g), "--out", str(tmp_path / "sw2")]) == 2
