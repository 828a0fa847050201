"""CLI fuzz: every bad input the CLI audit found (and more) gives exit status 2, exactly one line on
stderr naming the problem, the input byte-for-byte unchanged and an existing output untouched.

Validation cases pass ``--force`` with an existing output, so the test also shows that a
rejected run replaces nothing even when replacing is allowed. The run is short (180 rows):
every case is rejected before any fitting."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.cli.conftest import sha
from valve_env.cli import main

PREVIOUS = '{"previous": "result"}\n'

Mutation = Callable[[pd.DataFrame], pd.DataFrame]


def _set(col: str, row: int, value: object) -> Mutation:
    def f(d: pd.DataFrame) -> pd.DataFrame:
        d = d.copy()
        d[col] = d[col].astype(object)
        d.loc[row, col] = value
        return d
    return f


DATA_CASES: dict[str, tuple[Mutation, str]] = {
    "all_dp_zero": (lambda d: d.assign(dp_mbar=0.0), "column dp_mbar, row 1"),
    "T_tank_1e300": (_set("T_tank_C", 5, 1e300), "column T_tank_C, row 6"),
    "time_last_1e300": (lambda d: d.assign(time_s=np.r_[d.time_s.to_numpy()[:-1], 1e300]), "column time_s"),
    "negative_flow": (_set("q_kgh", 7, -3.0), "column q_kgh, row 8"),
    "negative_static_pressure": (_set("ps_bar", 9, -2.0), "column ps_bar, row 10"),
    "zero_static_pressure": (lambda d: d.assign(ps_bar=0.0), "column ps_bar, row 1"),
    "24h_in_8.6us": (lambda d: d.assign(time_s=np.linspace(0.0, 8.64e-6, len(d))), "sampling interval"),
    "all_q_zero_no_x": (lambda d: d.drop(columns=["x_mm"]).assign(q_kgh=0.0), "column q_kgh is 0 in every row"),
    "T_med_minus_100": (_set("T_med_C", 3, -100.0), "column T_med_C, row 4"),
    "T_tank_inf": (_set("T_tank_C", 2, "inf"), "T_tank_C"),
    "empty_time_cell": (_set("time_s", 4, ""), "column 'time_s' at row 5"),
    # one empty measured cell drops its row (a missed sample); more than 10 % of the rows is refused
    "empty_cells_20_percent": (lambda d: d.assign(T_med_C=d.T_med_C.where(d.index % 5 != 2)),
                               "empty cell in a measured column (the first: 'T_med_C' at row 3"),
    "non_numeric": (_set("q_kgh", 6, "abc"), "non-numeric value 'abc'"),
    "time_not_increasing": (_set("time_s", 10, 0.0), "time_s is not increasing at row 11"),
    "time_gap_2_days": (lambda d: d.assign(time_s=d.time_s + np.where(d.index >= 50, 2 * 86400.0, 0.0)),
                        "a gap of"),
    "huge_dp": (_set("dp_mbar", 1, 1e9), "column dp_mbar, row 2"),
    "missing_column": (lambda d: d.drop(columns=["ps_bar"]), "missing column 'ps_bar'"),
    "too_short": (lambda d: d.iloc[:10], "too short a record"),
    "constant_T": (lambda d: d.assign(T_tank_C=55.0), "constant"),
}


def _write_bad(tmp: Path, df: pd.DataFrame, name: str) -> Path:
    mutate, _ = DATA_CASES[name]
    p = tmp / f"{name}.csv"
    mutate(df).to_csv(p, index=False)
    return p


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse usage errors
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    return code, err


def _assert_one_line(code: int, err: str, needle: str) -> None:
    lines = err.strip().splitlines()
    assert code == 2, (code, err)
    assert len(lines) == 1, err
    assert lines[0].startswith("thermovalve: error: "), err
    assert needle.lower() in lines[0].lower(), (needle, err)
    assert "Traceback" not in err


@pytest.mark.parametrize("command", ["fit", "diagnose"])
@pytest.mark.parametrize("case", sorted(DATA_CASES))
def test_bad_run_rejected_by_fit_and_diagnose_alike(command: str, case: str, tmp_path: Path,
                                                    short_run_df: pd.DataFrame,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    bad = _write_bad(tmp_path, short_run_df, case)
    out = tmp_path / "out.json"
    out.write_text(PREVIOUS)
    before = sha(bad)
    code, err = _run([command, str(bad), "--json", str(out), "--force"], capsys)
    _assert_one_line(code, err, DATA_CASES[case][1])
    assert sha(bad) == before
    assert out.read_text() == PREVIOUS
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([bad.name, out.name])


def _files(tmp: Path, run_csv: Path) -> dict[str, Path]:
    other = tmp / "other.csv"
    other.write_bytes(run_csv.read_bytes())
    link = tmp / "link.csv"
    link.symlink_to(run_csv)
    hard = tmp / "hard.csv"
    os.link(run_csv, hard)
    existing = tmp / "existing.json"
    existing.write_text(PREVIOUS)
    report = tmp / "rep"
    report.mkdir()
    (report / "report.md").write_text(PREVIOUS)
    md = tmp / "out.md"
    md.write_bytes(run_csv.read_bytes())
    (tmp / "d.md").write_text(PREVIOUS)
    return {"run": run_csv, "other": other, "link": link, "hard": hard, "existing": existing, "rep": report,
            "md": md}


#: (argv with {names} of _files, the needle of the one line)
ARG_CASES: dict[str, tuple[list[str], str]] = {
    "fit_json_is_input": (["fit", "{run}", "--json", "{run}"], "is the input"),
    "fit_json_is_input_force": (["fit", "{run}", "--json", "{run}", "--force"], "is the input"),
    "fit_json_symlink_to_input": (["fit", "{run}", "--json", "{link}"], "is the input"),
    "fit_json_hard_link_to_input": (["fit", "{run}", "--json", "{hard}", "--force"], "is the input"),
    "fit_json_is_validate_input": (["fit", "{run}", "--validate", "{other}", "--json", "{other}"], "is the input"),
    "fit_valve_out_is_input": (["fit", "{run}", "--json", "{tmp}/n.json", "--valve-out", "{run}"], "is the input"),
    "fit_report_dir_is_input": (["fit", "{run}", "--json", "{tmp}/n.json", "--report", "{run}"], "is the input"),
    "fit_json_exists": (["fit", "{run}", "--json", "{existing}"], "use --force"),
    "fit_valve_out_exists": (["fit", "{run}", "--json", "{tmp}/n.json", "--valve-out", "{existing}"], "use --force"),
    "fit_report_exists": (["fit", "{run}", "--json", "{tmp}/n.json", "--report", "{rep}"], "use --force"),
    "fit_valve_out_unwritable": (["fit", "{run}", "--json", "{tmp}/n.json", "--valve-out", "{tmp}/nodir/c.yaml"],
                              "does not exist"),
    "fit_json_is_directory": (["fit", "{run}", "--json", "{rep}"], "is a directory"),
    "fit_same_output_twice": (["fit", "{run}", "--json", "{tmp}/n.json", "--valve-out", "{tmp}/n.json"],
                              "named twice"),
    "fit_seed_negative": (["fit", "{run}", "--json", "{tmp}/n.json", "--seed", "-1"], "--seed"),
    "fit_n_starts_zero": (["fit", "{run}", "--json", "{tmp}/n.json", "--n-starts", "0"], "--n-starts"),
    "fit_no_json": (["fit", "{run}"], "--json"),
    "fit_unknown_option": (["fit", "{run}", "--json", "{tmp}/n.json", "--bogus"], "--bogus"),
    "fit_missing_file": (["fit", "{tmp}/absent.csv", "--json", "{tmp}/n.json"], "no such file"),
    "fit_input_is_dir": (["fit", "{rep}", "--json", "{tmp}/n.json"], "directory"),
    "diagnose_report_is_input": (["diagnose", "{run}", "--json", "{tmp}/d.json", "--report", "{run}"],
                                 "is the input"),
    "diagnose_default_report_is_input": (["diagnose", "{md}", "--json", "{tmp}/out.json"], "is the input"),
    "diagnose_json_is_input": (["diagnose", "{run}", "--json", "{run}", "--force"], "is the input"),
    "diagnose_json_exists": (["diagnose", "{run}", "--json", "{existing}"], "use --force"),
    "diagnose_default_report_exists": (["diagnose", "{run}", "--json", "{tmp}/d.json"], "use --force"),
    "diagnose_unknown_effect": (["diagnose", "{run}", "--json", "{tmp}/n.json", "--effects", "nope"], "nope"),
    "diagnose_holdout": (["diagnose", "{run}", "--json", "{tmp}/n.json", "--holdout", "2"], "--holdout"),
    "diagnose_alpha_nan": (["diagnose", "{run}", "--json", "{tmp}/n.json", "--alpha", "nan"], "--alpha"),
    "diagnose_bootstrap_negative": (["diagnose", "{run}", "--json", "{tmp}/n.json", "--bootstrap", "-1"],
                                    "--bootstrap"),
    "diagnose_json_unwritable": (["diagnose", "{run}", "--json", "{tmp}/nodir/d.json"], "does not exist"),
    "experiment_out_exists": (["experiment", "--hours", "0.5", "--out", "{existing}"], "use --force"),
    "experiment_out_is_input_dir": (["experiment", "--hours", "0.5", "--out", "{rep}"], "is a directory"),
    "experiment_seed_negative": (["experiment", "--seed", "-1", "--out", "{tmp}/e.csv"], "--seed"),
    "experiment_hours_zero": (["experiment", "--hours", "0", "--out", "{tmp}/e.csv"], "--hours"),
    "experiment_dt_inf": (["experiment", "--dt", "inf", "--out", "{tmp}/e.csv"], "--dt"),
    "experiment_bad_effect": (["experiment", "--effect", "nope:a=1", "--out", "{tmp}/e.csv"], "nope"),
    "evaluate_json_exists": (["evaluate", "--episodes", "1", "--json", "{existing}"], "use --force"),
    "evaluate_seed_negative": (["evaluate", "--seed", "-1", "--json", "{tmp}/n.json"], "--seed"),
    "evaluate_unknown_env": (["evaluate", "--env", "Nope-v0", "--json", "{tmp}/n.json"], "Nope-v0"),
    "evaluate_unknown_scenario": (["evaluate", "--scenario", "nope", "--json", "{tmp}/n.json"], "nope"),
    "evaluate_episodes_text": (["evaluate", "--episodes", "abc"], "--episodes"),
    "evaluate_config_is_output": (["evaluate", "--config", "{existing}", "--json", "{existing}", "--force"],
                                  "is the input"),
    "demo_seed_negative": (["demo", "--episodes", "1", "--out", "{tmp}/demo", "--seed", "-2"], "--seed"),
    "demo_out_exists": (["demo", "--episodes", "1", "--out", "{tmp}"], "use --force"),
    "bench_json_exists": (["bench", "--quick", "--json", "{existing}"], "use --force"),
    "tune_gains_exists": (["tune", "--write", "--gains", "{existing}"], "use --force"),
    "leaderboard_out_exists": (["leaderboard", "--out", "{tmp}", "--envs", "ThermoValve-v0", "--episodes", "1"],
                               "use --force"),
    "leaderboard_unknown_scenario": (["leaderboard", "--scenarios", "nope", "--out", "{tmp}/lb"], "nope"),
    "train_algo_a2c": (["train", "--algo", "a2c"], "a2c"),
    "sweep_out_not_a_sweep": (["sweep", "--out", "{tmp}"], "use --force"),
    "unknown_command": (["nope"], "nope"),
}


@pytest.mark.parametrize("case", sorted(ARG_CASES))
def test_bad_arguments_and_outputs(case: str, tmp_path: Path, run_csv: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    files = _files(tmp_path, run_csv)
    argv_t, needle = ARG_CASES[case]
    if case == "leaderboard_out_exists":
        (tmp_path / "leaderboard.md").write_text(PREVIOUS)
    if case == "demo_out_exists":
        (tmp_path / "results.json").write_text(PREVIOUS)
    names = {k: str(v) for k, v in files.items()} | {"tmp": str(tmp_path)}
    argv = [a.format(**names) for a in argv_t]
    before = {p: sha(p) for p in tmp_path.rglob("*") if p.is_file() and not p.is_symlink()}
    code, err = _run(argv, capsys)
    _assert_one_line(code, err, needle)
    after = {p: sha(p) for p in tmp_path.rglob("*") if p.is_file() and not p.is_symlink()}
    assert after == before  # no input, no existing output touched, nothing new (no partial output)


@pytest.mark.parametrize("argv", [["train", "--algo", "sac", "--timesteps", "10"],
                                  ["evaluate", "--controllers", "sac", "--episodes", "1"]])
def test_rl_commands_name_the_extra(argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Without stable-baselines3 the RL commands say which extra to install, in one line."""
    import sys

    for mod in [m for m in sys.modules if m == "stable_baselines3" or m.startswith("stable_baselines3.")]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # import stable_baselines3 -> ImportError
    for mod in [m for m in sys.modules if m.startswith("agents.loader") or m.startswith("agents.wrappers")]:
        monkeypatch.delitem(sys.modules, mod)
    code, err = _run([*argv, "--out" if argv[0] == "train" else "--json", str(tmp_path / "o")], capsys)
    lines = err.strip().splitlines()
    assert code != 0 and len(lines) == 1, err
    assert lines[0].startswith("thermovalve: error: ") and "pip install -e '.[rl]'" in lines[0], err
