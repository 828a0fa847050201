"""``thermovalve benchmark`` on a real Dask LocalCluster (one worker, one short task), its outputs and its
refusals; ``thermovalve tasks``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from valve_env.cli import main


def test_benchmark_on_a_local_cluster(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bench"
    args = ["benchmark", "--tasks", "ThermoValveStickyValve-v0", "--controllers", "self_acting,pi",
            "--episodes", "2", "--seed", "0", "--horizon-h", "1", "--workers", "1", "--out", str(out)]
    assert main(args) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"table.md", "results.json", "episodes.csv", "scores.png", "kpis.png"}
    data = json.loads((out / "results.json").read_text())
    rows = {r["controller"]: r for r in data["table"]}
    assert set(rows) == {"self_acting", "pi", "pi@smooth_valve"} and rows["pi"]["episodes"] == 2
    assert rows["pi"]["seeds"] == "0-1"
    f = data["findings"]["ThermoValveStickyValve-v0"]
    assert "valve_change_pct" in f and "limit_cycle" in f
    assert "valve matters" in (out / "table.md").read_text()
    # an existing report is not replaced without --force
    assert main(args) == 2
    assert "use --force" in capsys.readouterr().err


def test_benchmark_rejects_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["benchmark", "--tasks", "NoSuchTask-v0", "--out", str(tmp_path / "b")]) == 2
    assert "unknown task" in capsys.readouterr().err
    assert main(["benchmark", "--controllers", "no_such_controller", "--out", str(tmp_path / "b")]) == 2
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())


def test_tasks_lists_one_line_per_task(capsys: pytest.CaptureFixture[str]) -> None:
    import valve_env

    assert main(["tasks"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [ln.split()[0] for ln in lines] == list(valve_env.CURRENT_TASK_IDS)
    assert all("Box(" in ln for ln in lines)


def test_agent_commands_refuse_bad_input_up_front(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Refused before any cluster, directory or episode (a new user's audit: each ran into the work first)."""
    # benchmark --workers 0: LocalCluster(n_workers=0) waited for ever
    assert main(["benchmark", "--workers", "0", "--out", str(tmp_path / "b")]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err
    # a negative seed and too many episodes were raised by every worker, each with its traceback
    for flag, value, says in (("--seed", "-1", "--seed must be a non-negative integer, got -1"),
                              ("--episodes", "1001", "--episodes must be <= 1000, got 1001")):
        assert main(["benchmark", "--tasks", "ThermoValveStickyValve-v0", flag, value,
                     "--out", str(tmp_path / "b")]) == 2
        err = capsys.readouterr().err
        assert err.strip() == f"thermovalve: error: {says}" or err.strip().startswith(f"thermovalve: error: {says} ")
    assert main(["benchmark", "--controllers", "pi:Kp=5", "--out", str(tmp_path / "b")]) == 2
    assert "benchmark takes controllers without options" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()
    # sweep: an unknown env id and a malformed --set failed inside every cell, after making the sweep directory
    sw = tmp_path / "sw"
    assert main(["sweep", "--env", "Nope-v0", "--out", str(sw)]) == 2
    assert "unknown env id 'Nope-v0'" in capsys.readouterr().err
    assert main(["sweep", "--set", "foo", "--out", str(sw)]) == 2
    assert "must look like key=value" in capsys.readouterr().err
    assert main(["sweep", "--workers", "0", "--out", str(sw)]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err
    assert not sw.exists()
    # leaderboard: an unknown name listed only the shipped agents
    assert main(["leaderboard", "--controllers", "pi_compensted", "--out", str(tmp_path / "lb")]) == 2
    err = capsys.readouterr().err
    assert "unknown controller 'pi_compensted'" in err and "pi_compensated" in err and "ppo" in err
    # task-leaderboard: a cache that is not a benchmark's episodes.csv was read only after the episodes
    garbage = tmp_path / "garbage.csv"
    garbage.write_text("a;b\n1;2\n")
    assert main(["task-leaderboard", "--oracle-cache", str(garbage), "--out", str(tmp_path / "tl")]) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("thermovalve: error:")]
    assert len(errors) == 1 and "--oracle-cache" in errors[0] and "garbage.csv" in errors[0]
    assert not (tmp_path / "tl").exists() or not any((tmp_path / "tl").rglob("*.md"))


def test_a_scheduler_that_does_not_answer_is_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """An address with no Dask scheduler behind it: distributed's OSError and exit 1 after 30 s before."""
    import agents.sweep

    monkeypatch.setattr(agents.sweep, "SCHEDULER_TIMEOUT_S", 1.0)
    out = tmp_path / "b"
    assert main(["benchmark", "--tasks", "ThermoValveStickyValve-v0", "--controllers", "pi", "--episodes", "1",
                 "--scheduler", "tcp://127.0.0.1:9", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    assert err.splitlines()[-1].startswith(
        "thermovalve: error: --scheduler tcp://127.0.0.1:9: no Dask scheduler answered within 1 s")
    assert not out.exists()
