"""thermovalve fit (docs/reference.md, section 7): JSON contract, report, config for the environment, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
import yaml

from valve_env.cli import main
from valve_env.params import ValveParams


@pytest.fixture
def run_csv(tmp_path: Path, small_run: Callable[..., pd.DataFrame]) -> Path:
    path = tmp_path / "run.csv"
    small_run(seed=7, hours=6.0).to_csv(path, index=False)
    return path


def test_fit_json_report_and_config(tmp_path: Path, run_csv: Path) -> None:
    out = tmp_path / "out.json"
    cfg = tmp_path / "valve.yaml"
    rep = tmp_path / "report"
    before = run_csv.read_bytes()
    code = main(["fit", str(run_csv), "--json", str(out), "--report", str(rep), "--config", str(cfg),
                 "--n-starts", "1"])
    assert code == 0
    assert run_csv.read_bytes() == before
    res = json.loads(out.read_text())
    assert set(res["params"]) == {"sigma", "F_hmax", "p_bset"}
    assert set(res["std"]) == {"sigma", "F_hmax", "p_bset"}
    for key, typ in (("loglik", float), ("rms_mm", float), ("n", int)):
        assert isinstance(res[key], typ)
    assert res["n"] == len(pd.read_csv(run_csv))
    assert 1e-3 < res["rms_mm"] < 5e-3
    # params pass straight to the environment's ValveParams
    vp = ValveParams.from_dict(res["params"])
    assert vp.sigma == res["params"]["sigma"]
    assert yaml.safe_load(cfg.read_text()) == {"valve": res["params"]}
    for name in ("fit.png", "phase.png", "whiteness.png", "report.md"):
        assert (rep / name).exists()
    assert "| sigma |" in (rep / "report.md").read_text()


def test_fit_bad_input_exits_nonzero_with_one_line(tmp_path: Path, run_csv: Path) -> None:
    bad = tmp_path / "bad.csv"
    pd.read_csv(run_csv).drop(columns=["T_med_C"]).to_csv(bad, index=False)
    proc = subprocess.run([sys.executable, "-m", "valve_env.cli", "fit", str(bad), "--json", str(tmp_path / "o.json")],
                          capture_output=True, text=True, check=False)
    assert proc.returncode != 0
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "missing column 'T_med_C'" in lines[0]
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "o.json").exists()
