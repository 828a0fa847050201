"""The sweep runs on a real Dask LocalCluster (two worker processes, a tiny
grid), resumes (a second run skips finished cells) and records failures."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from agents.sweep import Cell, make_grid, pending, run_cell, run_sweep, write_json_atomic

TINY = ("n_envs=1", "hyperparams.n_steps=64", "hyperparams.batch_size=32", "hyperparams.n_epochs=1")


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
