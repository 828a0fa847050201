"""``thermovalve loop-diagnose``: the JSON of docs/reference.md s. 10, the report, the output policy, bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from valve_env.cli import main
from valve_env.loops.diagnose import CAUSES

DATA = Path(__file__).parents[1] / "data" / "plant_loops"
STICKY = DATA / "2411FIC20102_1008_1552.txt"


def test_diagnose_real_sticky_loop_with_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / STICKY.name
    shutil.copy(STICKY, src)
    before = src.read_bytes()
    out = tmp_path / "out.json"
    rep = tmp_path / "rep"
    assert main(["loop-diagnose", str(src), "--json", str(out), "--report", str(rep)]) == 0
    res = json.loads(out.read_text())
    assert res["cause"] in CAUSES
    assert set(res["oscillation"]["closed_loop"]) == {"controller_fit_r2", "controller_coefs", "modes"}
    assert [f["candidate"] for f in res["findings"]] == ["linear", "backlash", "stiction"]
    for name in ("report.md", "phase.png", "simulation.png", "residuals.png", "profile.png"):
        assert (rep / name).stat().st_size > 0
    assert "Ljung-Box" in (rep / "report.md").read_text()
    assert src.read_bytes() == before


def test_existing_output_needs_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from valve_env.loops.sim import simulate_loop

    loop, _ = simulate_loop("pressure", S=0.0, seed=3, hours=0.7)
    src = tmp_path / "loop.csv"
    src.write_text(loop.to_csv_text())
    out = tmp_path / "out.json"
    out.write_text("old")
    assert main(["loop-diagnose", str(src), "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thermovalve: error:") and "--force" in err[0]
    assert out.read_text() == "old"
    assert main(["loop-diagnose", str(src), "--json", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["loop"]["n_samples"] == loop.n


def test_output_over_input_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "loop.txt"
    shutil.copy(STICKY, src)
    before = src.read_bytes()
    assert main(["loop-diagnose", str(src), "--json", str(src), "--force"]) == 2
    assert "input" in capsys.readouterr().err
    assert src.read_bytes() == before


def test_bad_csv_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "bad.csv"
    t = np.arange(300) * 10.0
    lines = ["time_s,sp,pv,op"] + [f"{v},1,{np.sin(v)},{'nan' if i == 5 else np.cos(v)}" for i, v in enumerate(t)]
    p.write_text("\n".join(lines))
    out = tmp_path / "o.json"
    assert main(["loop-diagnose", str(p), "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "column op has 1 NaN" in err[0]
    assert not out.exists()


def test_bootstrap_test_flag(tmp_path: Path) -> None:
    """--bootstrap-test adds the replicates (p-value, null) to decision.bootstrap and changes nothing else; without
    it the scan's fields are still there and the SPEC s. 10 fields are complete."""
    from valve_env.loops.sim import simulate_loop

    loop, _ = simulate_loop("pressure", S=0.0, seed=3, hours=0.7)
    src = tmp_path / "loop.csv"
    src.write_text(loop.to_csv_text())
    res = {}
    for flag in ([], ["--bootstrap-test"]):
        out = tmp_path / f"out{len(flag)}.json"
        assert main(["loop-diagnose", str(src), "--json", str(out), *flag]) == 0
        res[len(flag)] = json.loads(out.read_text())
    off, on = res[0], res[1]
    assert off["decision"]["bootstrap"]["n_run"] == 0 and off["decision"]["bootstrap"]["p_value"] is None
    assert on["decision"]["bootstrap"]["n_run"] >= 1 and 0.0 < on["decision"]["bootstrap"]["p_value"] <= 1.0
    for r in (off, on):
        assert {"cause", "findings"} <= set(r)
        for f in r["findings"]:
            assert {"loglik", "lr_stat", "p_value", "delta_bic"} <= set(f)
    assert off["decision"]["bootstrap"]["lr_scan"] == on["decision"]["bootstrap"]["lr_scan"]
    on["decision"].pop("bootstrap"), off["decision"].pop("bootstrap")
    assert on == off
