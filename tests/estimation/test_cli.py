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
    code = main(["fit", str(run_csv), "--json", str(out), "--report", str(rep), "--valve-out", str(cfg),
                 "--n-starts", "1", "--bootstrap", "2"])
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
    assert yaml.safe_load(cfg.read_text())["valve"] == res["params"]  # the valve file (docs/reference.md, section 8)
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


def test_fit_refuses_a_bootstrap_for_the_plain_fit(tmp_path: Path, run_csv: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """``--bootstrap`` sizes the errors-in-variables fit's temperature bootstrap; with ``--ml`` it was silently
    ignored. Refused in one line before any work, as is a bootstrap of one replicate."""
    for extra, says in ((["--ml", "--bootstrap", "4"], "--bootstrap belongs to the errors-in-variables fit"),
                        (["--bootstrap", "1"], "--bootstrap must be 0 or at least 2, got 1")):
        assert main(["fit", str(run_csv), "--json", str(tmp_path / "o.json"), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0]
    assert not (tmp_path / "o.json").exists()


def test_fit_eiv_and_robust_fields(tmp_path: Path, run_csv: Path) -> None:
    """The default fit reports the errors-in-variables estimates and their sd (the one a
    study shows calibrated) with the sandwich, the inverse Hessian and the misspecification check
    beside them; --ml keeps the plain ML fit, labelled as not calibrated."""
    out = tmp_path / "out.json"
    assert main(["fit", str(run_csv), "--json", str(out), "--n-starts", "1", "--bootstrap", "2"]) == 0
    e = json.loads(out.read_text())
    assert set(e["params"]) == {"sigma", "F_hmax", "p_bset"}
    assert e["std_method"].startswith("errors in variables")
    ests = e["eiv"]["estimates"]
    for k in ("sigma", "F_hmax", "p_bset"):  # the midpoint of the two denoisers' fits (log scale)
        lo, hi = sorted((ests["relaxed"][k], ests["tv"][k]))
        assert lo <= e["params"][k] <= hi
        assert e["std"][k] >= e["eiv"]["std_parts"]["robust"][k] * e["params"][k] * 0.999
        assert e["std_hessian"][k] > 0 and e["std_robust"][k] > 0
    assert e["eiv"]["B"] == 2 and set(e["eiv"]["std_parts"]) == {"robust", "denoiser", "temperature"}
    assert e["robust_lags"] > 0
    mis = e["misspecification"]
    assert isinstance(mis["misspecified"], bool) and "x_mm" in mis["outputs"]
    ml_out = tmp_path / "ml.json"
    assert main(["fit", str(run_csv), "--json", str(ml_out), "--n-starts", "1", "--ml"]) == 0
    res = json.loads(ml_out.read_text())
    assert res["std"] == res["std_hessian"]
    assert "not calibrated" in res["std_method"]
    assert set(res["std_robust"]) == {"sigma", "F_hmax", "p_bset"}
    assert res["params"]["sigma"] == pytest.approx(ests["relaxed"]["sigma"], rel=1e-6)
    proc = subprocess.run([sys.executable, "-m", "valve_env.cli", "fit", str(run_csv), "--json",
                           str(tmp_path / "x.json"), "--ml", "--eiv"], capture_output=True, text=True, check=False)
    assert proc.returncode == 2 and "--ml and --eiv" in proc.stderr
