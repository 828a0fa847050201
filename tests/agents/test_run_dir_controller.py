"""A training run directory as a controller: ``thermovalve evaluate`` and ``thermovalve benchmark``
take the directory a ``thermovalve train`` run writes (docs/cli.md, "Controllers")."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from valve_env.cli import main


def test_evaluate_takes_a_run_directory(short_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The run's agent (its best checkpoint) is evaluated under the name given, with the same figures
    as load_agent(run_dir=...) through the Python evaluator."""
    from agents.loader import load_agent
    from valve_env.evaluation import evaluate

    out = tmp_path / "res.json"
    name = str(short_run)
    rc = main(["evaluate", "--env", "ThermoValve-v0", "--controllers", f"{name},pi", "--episodes", "2",
               "--seed", "4", "--json", str(out), "--env-kwargs", "horizon_h=1"])
    assert rc == 0, capsys.readouterr().err
    got = json.loads(out.read_text())["results"]
    assert list(got) == [name, "pi"]
    direct = evaluate({"run": load_agent("run", "ThermoValve-v0", run_dir=short_run)}, "ThermoValve-v0", 2, 4,
                      {"horizon_h": 1.0})["results"]["run"]
    assert got[name]["return"]["mean"] == pytest.approx(direct["return"]["mean"], rel=1e-9)
    assert got[name]["kpis"]["rmse_K"]["mean"] == pytest.approx(direct["kpis"]["rmse_K"]["mean"], rel=1e-9)
    assert got[name]["return"]["mean"] != got["pi"]["return"]["mean"]
    assert f"| {name} |" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda d: d / "nope", "is a path that does not exist"),
        (lambda d: (d / "empty").mkdir() or d / "empty", "is not a training run directory: no config.yml"),
        (lambda d: (d / "f.txt").write_text("x") and d / "f.txt", "is a path that is not a directory"),
    ],
)
def test_a_path_that_is_not_a_run_is_one_line_and_exit_2(
    make: Any, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = make(tmp_path)
    out = tmp_path / "res.json"
    assert main(["evaluate", "--controllers", f"pi,{path}", "--episodes", "1", "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and needle in err and str(path) in err, err
    assert not out.exists()


def test_a_run_of_another_env_is_refused(short_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--env", "ThermoValvePressure-v0", "--controllers", str(short_run), "--episodes", "1",
                 "--json", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "was trained on 'ThermoValve-v0'" in err, err


def test_a_bare_name_is_never_a_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A directory called ``ppo`` in the working directory does not shadow the shipped agent's name."""
    from valve_env.controllers import is_path_name

    (tmp_path / "ppo").mkdir()
    monkeypatch.chdir(tmp_path)
    assert not is_path_name("ppo") and not is_path_name("pi")
    assert is_path_name("./ppo") and is_path_name("out/runs/tiny_ppo") and is_path_name("~/runs/x")


def test_benchmark_takes_a_run_directory(short_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "bench"
    name = str(short_run)
    args = ["benchmark", "--tasks", "ThermoValve-v0", "--controllers", f"{name},self_acting", "--episodes", "2",
            "--seed", "0", "--horizon-h", "1", "--workers", "1", "--no-smooth", "--out", str(out)]
    assert main(args) == 0
    rows = {r["controller"]: r for r in json.loads((out / "results.json").read_text())["table"]}
    assert set(rows) == {name, "self_acting"}
    assert rows[name]["episodes"] == 2 and np.isfinite(rows[name]["cost"])
    assert rows[name]["cost"] != rows["self_acting"]["cost"]
    assert f"| {name} |" in (out / "table.md").read_text()
