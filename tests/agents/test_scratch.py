"""The from-scratch sweep (agents.scratch): its configs cover every current task at one budget with nothing
task-specific, and two sweeps share the runs out through claims."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import valve_env
from agents.scratch import ALGOS, CONFIG_DIR, claim, run_dir
from agents.train import load_algo_config


@pytest.mark.parametrize("algo", ALGOS)
def test_every_current_task_has_one_budget_and_no_hand_written_structure(algo: str) -> None:
    cfgs = [load_algo_config(algo, t, CONFIG_DIR) for t in valve_env.CURRENT_TASK_IDS]
    assert len({c["n_timesteps"] for c in cfgs}) == 1
    for c in cfgs:
        assert c["vec_env"] == "native" and not c.get("residual") and not c.get("obs_aids")
        assert not c.get("energy_shaping") and int(c.get("frame_stack", 1)) == 1


def test_a_run_is_claimed_once_and_a_dead_claim_is_taken_over(tmp_path: Path) -> None:
    d = run_dir(tmp_path, "T", "ppo", 0)
    assert claim(d) and claim(d)  # this process holds it
    other = d.parent / "ppo_s1.claim"
    other.write_text(str(os.getppid()))  # held by a live process that is not this one
    assert not claim(run_dir(tmp_path, "T", "ppo", 1))
    dead = d.parent / "ppo_s2.claim"
    dead.write_text("999999999")  # no such process
    assert claim(run_dir(tmp_path, "T", "ppo", 2)) and dead.read_text() == str(os.getpid())


def test_a_budget_other_than_the_configs_is_passed_to_every_run(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from agents.scratch import main, train_command

    cmd = train_command("sac", "ThermoValveStickyValve-v0", 1, tmp_path, 230400)
    assert cmd[cmd.index("--timesteps") + 1] == "230400" and cmd[cmd.index("--eval-freq") + 1] == "23040"
    assert "--timesteps" not in train_command("sac", "ThermoValveStickyValve-v0", 1, tmp_path)
    assert main(["train", "--timesteps", "5", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--timesteps" in err[0]


def test_evaluate_refuses_without_the_oracles_episodes_before_any_episode(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """Without the oracle's held-out episodes every gap score and score would be NaN: `evaluate` refuses in one line
    naming the task and the command that makes them, before it runs an episode or loads a run (the run here has no
    model). The default cache ends with the tracked board's episodes, which hold the oracle on 5000-5004 for every
    current task, so a fresh clone needs no benchmark run for the default seeds."""
    import json

    from agents.scratch import ORACLE_CACHE, main, oracle_for

    d = run_dir(tmp_path, "ThermoValveSmallCylinder-v0", "ppo", 0)
    d.mkdir(parents=True)
    (d / "run.json").write_text(json.dumps({"finished_utc": "2026-12-02T00:00:00Z", "num_timesteps": 10}))
    empty = tmp_path / "none.csv"
    assert main(["evaluate", "--out", str(tmp_path), "--oracle-cache", str(empty)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no oracle episodes on seeds 5000-5004 for ThermoValveSmallCylinder-v0" in err[0]
    assert "thermovalve benchmark --controllers oracle --episodes 5 --seed 5000" in err[0]
    assert not (tmp_path / "runs.csv").exists()
    cache = ORACLE_CACHE.split(",")
    oracle_for(cache, list(valve_env.CURRENT_TASK_IDS), list(range(5000, 5005)))  # found: no error
    with pytest.raises(ValueError, match="no oracle episodes on seeds 6000-6004"):
        oracle_for(cache, ["ThermoValveSmallCylinder-v0"], list(range(6000, 6005)))
