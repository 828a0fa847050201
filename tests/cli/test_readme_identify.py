"""The README's "Identify your valve" commands, and the refusal of a run the paper's model does not explain."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from valve_env.cli import main
from valve_env.experiment import simulate_experiment

README = Path(__file__).resolve().parents[2] / "README.md"


def _identify_block() -> list[list[str]]:
    """The thermovalve command lines of the README's bash block under "Identify your valve"."""
    text = README.read_text()
    section = text[text.index("## Identify your valve"):]
    block = re.search(r"```bash\n(.*?)```", section, re.S)
    assert block is not None
    return [line.split("#")[0].split()[1:] for line in block.group(1).splitlines() if line.startswith("thermovalve ")]


def test_a_run_the_papers_model_does_not_explain_is_refused_pointing_to_diagnose(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 60 s sensor lag drives the paper's sigma to its lower bound (a slow friction imitates the lag) and leaves
    the residuals coloured: ``fit`` says the model does not explain the record and names ``diagnose``, in one line
    with exit 2, and writes nothing; it does not blame the record's length."""
    run = tmp_path / "lag.csv"
    df = simulate_experiment(seed=3, duration_h=4.0, dt_s=10.0, effects={"sensor_lag": {"tau_s": 60.0}})
    df[[c for c in df.columns if not c.startswith("true_")]].to_csv(run, index=False)
    out = tmp_path / "fit.json"
    assert main(["fit", str(run), "--json", str(out)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("thermovalve: error:")]
    assert len(err) == 1, err
    assert "the paper's model does not explain this record" in err[0]
    assert "Ljung-Box p" in err[0] and f"thermovalve diagnose {run}" in err[0]
    assert "longer record" not in err[0]
    assert not out.exists()


@pytest.mark.slow
def test_the_readme_identify_commands_run_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Every command of the README's identification block exits 0 in a fresh directory, and ``diagnose`` names the
    sensor lag the README says it names (about 1 min)."""
    monkeypatch.chdir(tmp_path)
    cmds = _identify_block()
    assert [c[0] for c in cmds] == ["experiment", "fit", "experiment", "diagnose"]
    for cmd in cmds:
        assert main(cmd) == 0, cmd
    assert "cause: sensor_lag (tau_s=59.9" in capsys.readouterr().out
    assert (tmp_path / "out" / "valve.yaml").exists() and (tmp_path / "out" / "fit_valve.yaml").exists()
