"""`thermovalve diagnose`: the docs/reference.md, section 4 document, the report, and bad input."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from valve_env.cli import main
from valve_env.experiment import simulate_experiment


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    p = tmp_path_factory.mktemp("runs") / "run.csv"
    simulate_experiment(seed=77, duration_h=6.0, dt_s=20.0,
                        effects={"medium_temperature": {"beta": 0.1}}).to_csv(p, index=False)
    return p


def test_diagnose_writes_spec_json_and_report(good: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = _sha(good)
    out = tmp_path / "out.json"
    code = main(["diagnose", str(good), "--json", str(out)])
    assert code == 0, capsys.readouterr().err
    j = json.loads(out.read_text())
    assert j["cause"] == "medium_temperature"
    assert set(j["base"]) >= {"params", "std", "loglik", "rms_mm"}
    f0 = j["findings"][0]
    assert f0["effect"] == "medium_temperature" and set(f0["params"]) == {"beta"}
    for key in ("loglik", "lr_stat", "p_value", "delta_aic", "delta_bic", "rms_before_mm", "rms_after_mm",
                "validation_rms_before_mm", "validation_rms_after_mm"):
        assert isinstance(f0[key], float)
    assert len(j["findings"]) == 4
    # the named effect's sd come from the model-based bootstrap, and the document says so
    assert f0["std_method"].startswith("model-based bootstrap")
    assert f0["uncertainty"]["replicates"] == 16 and set(f0["uncertainty"]["interval_95"]) == {"beta"}
    u = f0["uncertainty"]
    assert 0 <= u["dropped_replicates"] <= 8 and "band_replicates" not in u
    assert u["split_replicates"] is False
    # the reported sd: the bootstrap's, with the inverse-Hessian/HAC sd as a floor, and the pre-processing
    # bracket (the estimate refitted on TV-denoised temperatures, half the IRW-TV difference added)
    src = u["std_from"]["beta"]
    assert src in ("bootstrap+bracket", "hessian+bracket")
    sd0 = u[f"{src.split('+')[0]}_std"]["beta"]
    assert sd0 == max(u["bootstrap_std"]["beta"], u["hessian_std"]["beta"])
    pre = u["preprocessing"]
    assert f0["params"]["beta"] == pre["tv"]["beta"] and pre["irw"]["beta"] == u["uncorrected_estimate"]["beta"]
    assert f0["std"]["beta"] == pytest.approx(float(np.hypot(sd0, 0.5 * (pre["tv"]["beta"] - pre["irw"]["beta"]))))
    assert 0 < f0["std"]["beta"] < 0.25 * f0["params"]["beta"]
    assert j["findings"][1]["uncertainty"] is None
    report = tmp_path / "out.md"
    text = report.read_text()
    assert "Cause: `medium_temperature`" in text
    assert "model-based bootstrap" in text
    sc = j["simulation_check"]
    assert sc["model"] == "medium_temperature" and sc["passed"] is True
    assert "*Simulation check* (medium_temperature model)" in text and f"{sc['ratio']:.1f} times" in text
    for png in ("out_fit.png", "out_phase.png", "out_residuals.png"):
        assert (tmp_path / png).stat().st_size > 1000
        assert png in text
    assert _sha(good) == before, "the input must never change"


def test_a_report_given_as_a_folder_is_written_into_it(good: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """``--report DIR`` (a path not ending in .md), as fit and loop-diagnose take it: DIR/report.md and its figures,
    the folder made; given again without --force, one line and exit status 2, nothing replaced."""
    d = tmp_path / "rep"
    assert main(["diagnose", str(good), "--json", str(tmp_path / "a.json"), "--report", str(d),
                 "--bootstrap", "0"]) == 0, capsys.readouterr().err
    names = sorted(p.name for p in d.iterdir())
    assert names == ["report.md", "report_fit.png", "report_phase.png", "report_residuals.png"]
    assert "Cause: `medium_temperature`" in (d / "report.md").read_text()
    before = _sha(d / "report.md")
    capsys.readouterr()
    assert main(["diagnose", str(good), "--json", str(tmp_path / "b.json"), "--report", str(d)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "exists; use --force" in err and "report.md" in err
    assert _sha(d / "report.md") == before and not (tmp_path / "b.json").exists()


def test_a_misspecified_effect_is_said_once_on_stdout_not_as_pythons_warning(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A run without x_mm (the opening derived from the flow) whose sensor lag is named with residuals that are not
    white: the console says so on one 'warning:' line; Python's own print of the MisspecificationWarning, with this
    package's file and line, is not also let through (it was, on stderr)."""
    import warnings

    from valve_env.ident.tests import MisspecificationWarning

    run = tmp_path / "run.csv"
    simulate_experiment(seed=41, duration_h=6.0, dt_s=10.0, effects={"sensor_lag": {"tau_s": 90.0}}).drop(
        columns=["x_mm"]).to_csv(run, index=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main(["diagnose", str(run), "--json", str(tmp_path / "d.json"), "--no-report", "--bootstrap", "0"])
    out = capsys.readouterr().out
    assert code == 0
    assert json.loads((tmp_path / "d.json").read_text())["cause"] == "sensor_lag"
    said = [line for line in out.splitlines() if line.startswith("warning: sensor_lag: the one-step residuals")]
    assert len(said) == 1, out
    assert not [w for w in caught if issubclass(w.category, MisspecificationWarning)]


def test_validate_other_run(good: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    other = tmp_path / "other.csv"
    simulate_experiment(seed=78, duration_h=4.0, dt_s=20.0,
                        effects={"medium_temperature": {"beta": 0.1}}).drop(columns=["x_mm"]).to_csv(other, index=False)
    out = tmp_path / "v.json"
    code = main(["diagnose", str(good), "--validate", str(other), "--json", str(out), "--no-report",
                 "--effects", "medium_temperature,stiction"])
    assert code == 0, capsys.readouterr().err
    j = json.loads(out.read_text())
    assert j["cause"] == "medium_temperature"
    assert j["settings"]["validation"] == "independent run"
    assert not (tmp_path / "v.md").exists()


def _bad_files(tmp: Path, good: Path) -> dict[str, tuple[Path, str]]:
    df = pd.read_csv(good)
    cases: dict[str, tuple[Path, str]] = {}

    def put(name: str, frame: pd.DataFrame, expect: str) -> None:
        p = tmp / f"{name}.csv"
        frame.to_csv(p, index=False)
        cases[name] = (p, expect)

    put("missing_column", df.drop(columns=["T_tank_C"]), "missing column")
    d = df.copy()
    d["q_kgh"] = d["q_kgh"].astype(object)
    d.loc[50, "q_kgh"] = "abc"
    put("non_numeric", d, "non-numeric")
    d = df.copy()
    d.loc[60, "time_s"] = np.nan
    put("nan", d, "NaN")
    d = df.copy()
    d.loc[d.index % 4 == 1, "T_med_C"] = np.nan  # one empty cell drops its row; a quarter of the rows is refused
    put("empty_cells", d, "have an empty cell in a measured column")
    d = df.copy()
    d.loc[70, "time_s"] = d.loc[69, "time_s"]
    put("time", d, "increasing")
    put("short", df.iloc[:50], "too short")
    d = df.copy()
    d["T_tank_C"] = 55.0
    put("constant", d, "constant")
    # a flow in l/min without x_mm: the derived opening hardly moves, and l/min is named
    d = df.drop(columns=[c for c in df.columns if c == "x_mm" or c.startswith("true_")])
    put("flow_in_l_per_min", d.assign(q_kgh=d.q_kgh / 60.0), "if q_kgh is in l/min (multiply by 60: the opening would")
    p = tmp / "empty.csv"
    p.write_text("")
    cases["empty"] = (p, "empty")
    p = tmp / "binary.csv"
    p.write_bytes(bytes(range(256)) * 4)
    cases["binary"] = (p, "")
    cases["absent"] = (tmp / "does_not_exist.csv", "no such file")
    return cases


def test_bad_input_one_line_no_traceback(good: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name, (path, expect) in _bad_files(tmp_path, good).items():
        before = _sha(path) if path.exists() else None
        out = tmp_path / f"{name}.json"
        code = main(["diagnose", str(path), "--json", str(out)])
        err = capsys.readouterr().err
        assert code != 0, name
        lines = err.strip().splitlines()
        assert len(lines) == 1, (name, err)
        assert "Traceback" not in err
        assert expect.lower() in err.lower(), (name, err)
        assert not out.exists()
        if before is not None:
            assert _sha(path) == before
    # output directory missing, or the output is the input
    code = main(["diagnose", str(good), "--json", str(tmp_path / "nodir" / "x.json")])
    assert code != 0 and "does not exist" in capsys.readouterr().err
    code = main(["diagnose", str(good), "--json", str(good)])
    assert code == 2 and "refusing to overwrite an input" in capsys.readouterr().err
    # options that cannot hold together: one replicate has no spread (it wrote an sd of 0 and a point interval), and
    # a report asked for and refused in one command (the report was silently not written)
    for extra, says in ((["--bootstrap", "1"], "--bootstrap must be 0 or at least 2, got 1"),
                        (["--no-report", "--report", str(tmp_path / "r.md")], "--no-report and --report exclude"),
                        (["--effects", " , "], "--effects names no effect")):  # it became every effect
        assert main(["diagnose", str(good), "--json", str(tmp_path / "o.json"), *extra]) == 2
        assert says in capsys.readouterr().err
        assert not (tmp_path / "o.json").exists()


def test_entry_point_bad_input_subprocess(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("time_s,T_tank_C\n0,1\n")
    r = subprocess.run([sys.executable, "-m", "valve_env.cli", "diagnose", str(p), "--json", str(tmp_path / "o.json")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "missing column" in r.stderr


def test_a_valve_parameter_on_its_fit_bound_is_said_and_writes_no_valve(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """A flow in g/s read as kg/h, with no x_mm column: the derived opening is 3.6 times too small, and the fit leaves
    F_hmax on its bound (20 N), a number of the search range, not of the valve. The diagnosis says so, with the flow's
    units as a likely cause, and `--valve-out` writes no valve file from it (before, it wrote F_hmax = 20 N)."""
    df = simulate_experiment(seed=20271254, duration_h=3.0, dt_s=20.0)
    df = df[[c for c in df.columns if not c.startswith("true_")]].drop(columns=["x_mm"])
    run = tmp_path / "grams.csv"
    df.assign(q_kgh=df.q_kgh / 3.6).to_csv(run, index=False)
    out, valve = tmp_path / "d.json", tmp_path / "valve.yaml"
    args = ["diagnose", str(run), "--json", str(out), "--no-report", "--bootstrap", "0"]
    code = main([*args, "--valve-out", str(valve)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not out.exists() and not valve.exists()
    assert err[-1].startswith(f"thermovalve: error: {run}: the diagnosed model leaves F_hmax on its fit bound")
    assert "derived from q_kgh and dp_mbar" in err[-1]  # the refusal gives the diagnosis's clue to the units too
    assert main(args) == 0
    printed = capsys.readouterr().out
    note = next(n for n in json.loads(out.read_text())["notes"] if "fit bound" in n)
    assert note.startswith("the diagnosed model leaves F_hmax on its fit bound (20 N)")
    assert "derived from q_kgh and dp_mbar" in note and f"warning: {note}" in printed


def test_the_bound_note_says_how_far_the_flow_lies_from_the_characteristic() -> None:
    """With x_mm measured, the note on a fit bound gives the flow's ratio to the valve characteristic's at the
    opening: 2 for an opening logged as a fraction of the 2 mm stroke; nothing for the valve's own record."""
    from valve_env.valveid.diagnose import unit_clue

    df = simulate_experiment(seed=20271254, duration_h=6.0, dt_s=20.0)
    assert unit_clue(df) == ""
    clue = unit_clue(df.assign(x_mm=df.x_mm / 2.0))
    assert clue.startswith(" The flow q_kgh is 2 times what x_mm and dp_mbar give through the valve characteristic")
    assert clue.endswith("an x_mm in another unit, or a valve of another Kvs.")
    # a measured x_mm with a few empty cells (derived there from the flow) is still a measured opening
    from valve_env.valveid.diagnose import check_run

    gappy = df.assign(x_mm=df.x_mm / 2.0)
    gappy.loc[5:10, "x_mm"] = np.nan
    assert unit_clue(check_run(gappy)).startswith(" The flow q_kgh is 2 times")
    assert unit_clue(check_run(df.drop(columns=["x_mm"]))).startswith(" The opening is derived from q_kgh and dp_mbar")


def test_swapped_temperature_columns_are_suspected(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """T_tank_C and T_med_C swapped in the file: the bulb then follows the column named T_med_C, the diagnosis names
    a medium weight near 1, and a warning says the columns may be swapped (a medium heats a bulb by a few hundredths
    to a quarter)."""
    df = simulate_experiment(seed=20271257, duration_h=6.0, dt_s=20.0)
    run = tmp_path / "swapped.csv"
    df.rename(columns={"T_tank_C": "T_med_C", "T_med_C": "T_tank_C"}).to_csv(run, index=False)
    out = tmp_path / "d.json"
    assert main(["diagnose", str(run), "--json", str(out), "--no-report", "--bootstrap", "0"]) == 0
    printed = capsys.readouterr().out
    j = json.loads(out.read_text())
    assert j["cause"] == "medium_temperature" and j["final"]["params"]["beta"] > 0.5
    note = next(n for n in j["notes"] if n.startswith("the medium weight is "))
    assert "if the two columns are swapped in the file, swap them back" in note and f"warning: {note}" in printed


def test_temperatures_in_degf_within_the_range_are_named_where_the_fit_fails(tmp_path: Path,
                                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Temperatures in degF that stay within the range check's 150 (a tank at 126-140 degF) leave the valve's set point
    unidentified: fit's refusal, diagnose's note and its --valve-out refusal say that the tank's median reads as a
    hot-water tank's in degF (before, they said only that a longer record with wider swings was needed)."""
    df = simulate_experiment(seed=20271273, duration_h=4.0, dt_s=10.0)
    df = df[[c for c in df.columns if not c.startswith("true_")]]
    run = tmp_path / "degf.csv"
    df.assign(T_tank_C=df.T_tank_C * 1.8 + 32.0, T_med_C=(df.T_med_C * 1.8 + 32.0 - 3.0).clip(upper=149.9)).to_csv(
        run, index=False)
    says = "if the temperatures are in degF (the median would be"
    assert main(["fit", str(run), "--json", str(tmp_path / "f.json"), "--bootstrap", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"thermovalve: error: {run}: the record does not identify") and says in err[-1]
    out = tmp_path / "d.json"
    args = ["diagnose", str(run), "--json", str(out), "--no-report", "--bootstrap", "0"]
    assert main([*args, "--valve-out", str(tmp_path / "v.yaml")]) == 2
    assert says in capsys.readouterr().err  # the diagnosis's clue to the units
    assert main(args) == 0
    assert any(says in n for n in json.loads(out.read_text())["notes"])
