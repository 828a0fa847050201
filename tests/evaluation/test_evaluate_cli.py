"""``thermovalve evaluate`` and ``thermovalve demo``: the docs/reference.md, section 7 JSON,
clear errors, no silent loss of user files."""

from __future__ import annotations

import json

import pytest

from valve_env.cli import main
from valve_env.simulator import KPI_NAMES


def test_evaluate_writes_the_spec_json(tmp_path, capsys) -> None:
    out = tmp_path / "res.json"
    rc = main(["evaluate", "--env", "ThermoValve-v0", "--controllers", "self_acting,pi", "--episodes", "2",
               "--seed", "3", "--json", str(out), "--env-kwargs", "horizon_h=2", "tapping_profile=L"])
    assert rc == 0
    data = json.loads(out.read_text())
    assert set(data) == {"env", "episodes", "results"}
    assert data["env"] == "ThermoValve-v0" and data["episodes"] == 2
    assert list(data["results"]) == ["self_acting", "pi"]
    for res in data["results"].values():
        assert set(res["return"]) == {"mean", "std"}
        assert set(res["kpis"]) == set(KPI_NAMES)
    assert "| pi |" in capsys.readouterr().out
    # re-running refuses to replace the earlier result without --force, and replaces it with --force
    before = out.read_text()
    assert main(["evaluate", "--controllers", "pi", "--episodes", "1", "--json", str(out),
                 "--env-kwargs", "horizon_h=1"]) == 2
    assert "use --force" in capsys.readouterr().err and out.read_text() == before
    assert main(["evaluate", "--controllers", "pi", "--episodes", "1", "--json", str(out),
                 "--env-kwargs", "horizon_h=1", "--force"]) == 0
    assert list(json.loads(out.read_text())["results"]) == ["pi"]


def test_evaluate_pressure_env_with_out_dir(tmp_path) -> None:
    rc = main(["evaluate", "--env", "ThermoValvePressure-v0", "--episodes", "1", "--json", str(tmp_path / "p.json"),
               "--out", str(tmp_path / "o"), "--env-kwargs", "horizon_h=1"])
    assert rc == 0
    data = json.loads((tmp_path / "p.json").read_text())
    assert list(data["results"]) == ["self_acting", "pi"]  # the baselines that support the pressure env
    assert (tmp_path / "o" / "trajectories.png").is_file()


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--controllers", "pi,nosuchagent"], "nosuchagent"),
        (["--env", "Nope-v0"], "unknown env id"),
        (["--env-kwargs", "nonsense=1"], "nonsense"),
        (["--env-kwargs", "tapping_profile"], "key=value"),
        (["--env-kwargs", "supply_C=-5"], "supply_C"),
        (["--env", "ThermoValvePressure-v0", "--controllers", "pi_compensated"], "does not support"),
        (["--config", "no/such.yaml"], "does not exist"),
    ],
)
def test_bad_input_exits_nonzero_with_one_line(tmp_path, capsys, argv, needle) -> None:
    rc = main(["evaluate", "--episodes", "1", "--json", str(tmp_path / "x.json"), *argv])
    err = capsys.readouterr().err.strip()
    assert rc != 0
    assert len(err.splitlines()) == 1 and needle in err
    assert not (tmp_path / "x.json").exists()


def test_does_not_overwrite_a_foreign_file(tmp_path, capsys) -> None:
    precious = tmp_path / "notes.json"
    precious.write_text('{"mine": true}')
    rc = main(["evaluate", "--controllers", "self_acting", "--episodes", "1", "--json", str(precious),
               "--env-kwargs", "horizon_h=1"])
    assert rc != 0 and "--force" in capsys.readouterr().err
    assert precious.read_text() == '{"mine": true}'


def test_demo_writes_table_and_figures(tmp_path, capsys) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--episodes", "2"]) == 0
    printed = capsys.readouterr().out
    assert "| pi_compensated |" in printed and str(out) in printed
    for name in ("table.md", "results.csv", "episodes.csv", "results.json", "trajectories.png", "tradeoff.png"):
        assert (out / name).is_file(), name
