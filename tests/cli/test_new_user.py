"""A new user's commands as the README and docs/cli.md write them: each one found broken in the
audit of the user-facing surface (docs/cli.md) is held here."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from valve_env.cli import main
from valve_env.outputs import OutputError, OutputSet


def test_outputs_under_out_create_the_missing_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """README: ``thermovalve evaluate ... --json out/sticky.json`` in a fresh checkout (no out/ yet)."""
    monkeypatch.chdir(tmp_path)
    with OutputSet() as outs:
        outs.write_text(outs.add("out/sub/a.json"), "{}\n")
    assert (tmp_path / "out" / "sub" / "a.json").read_text() == "{}\n"
    # outside out/ a missing directory is still a typo to refuse, and nothing is created
    with pytest.raises(OutputError, match="does not exist"):
        OutputSet().add("nodir/a.json")
    assert not (tmp_path / "nodir").exists()
    # out/ that is a file is named
    (tmp_path / "out2").write_text("x")
    monkeypatch.setattr("valve_env.outputs.DEFAULT_OUT_DIR", Path("out2"))
    with pytest.raises(OutputError, match="not a directory"):
        OutputSet().add("out2/a.json")


def test_readme_evaluate_json_under_out_in_a_fresh_checkout(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("THERMOVALVE_NO_PROGRESS", "1")
    code = main(["evaluate", "--env", "ThermoValve-v0", "--controllers", "self_acting", "--episodes", "1",
                 "--env-kwargs", "horizon_h=0.5", "--json", "out/eval.json", "--out", "out/eval"])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((tmp_path / "out" / "eval.json").read_text())
    assert summary["env"] == "ThermoValve-v0" and list(summary["results"]) == ["self_acting"]
    assert (tmp_path / "out" / "eval" / "table.md").exists()


@pytest.mark.parametrize(("spec", "expect"), [
    ("pi:nokey=1", "controller 'pi' has no option(s) ['nokey']; its options: Kp, Ti_s"),
    ("oracle:foo=1", "controller 'oracle' has no option(s) ['foo']; its options: horizon_steps"),
    ("pi:Kp=abc", "controller 'pi' option Kp must be a finite number, got 'abc'"),
    ("pi:Kp=nan", "option Kp must be a finite number"),
    ("pi_compensated:Ti_s=x", "option Ti_s must be a finite number"),
    ("pi_wear:h_max=2.5", "option h_max must be an integer"),
    ("pi:dt_s=-1", "PI dt_s must be a finite sample time > 0 s"),
    ("self_acting:setting_C=500", "self_acting setting_C must be in [10, 120] degC"),
])
def test_a_bad_controller_option_is_one_line_naming_it(spec: str, expect: str, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """``--controllers name:key=value`` with an unknown key, a value that is no number, or a setting no
    action space has: exit 2, one line naming the option (was a Python TypeError's text, a NumPy ufunc
    message, or, for self_acting:setting_C=500, a silently clipped day)."""
    code = main(["evaluate", "--controllers", spec, "--episodes", "1", "--env-kwargs", "horizon_h=0.5",
                 "--json", str(tmp_path / "e.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("thermovalve: error: ")
    assert expect in err, err
    assert not (tmp_path / "e.json").exists()


def test_an_unknown_controller_name_lists_the_built_ins(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A typo (``pi_compensted``) named only the shipped agents (ppo, sac); it now lists the built-ins too."""
    code = main(["evaluate", "--controllers", "pi_compensted", "--episodes", "1", "--json", str(tmp_path / "e.json")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "'pi_compensted'" in err and "self_acting, pi, pi_compensated" in err, err


def test_an_output_directory_left_with_empty_subdirectories_is_reusable(tmp_path: Path) -> None:
    """A failed run may leave its output directory with an empty subdirectory (task-leaderboard makes
    ``figures/`` up front); the next run was refused ('exists and is not empty') though the directory
    holds no file. Files still need --force."""
    d = tmp_path / "tl"
    (d / "figures").mkdir(parents=True)
    assert OutputSet().add_dir(d) == d
    (d / "figures" / "a.png").write_bytes(b"png")
    with pytest.raises(OutputError, match="not empty; use --force"):
        OutputSet().add_dir(d)
    assert OutputSet(force=True).add_dir(d) == d


def test_a_bad_seed_list_names_the_list() -> None:
    """``thermovalve sweep --seeds a-b`` said "invalid literal for int() with base 10: 'a'"; ``5-3`` gave no seeds."""
    from valve_env.cliutil import UsageError, int_list

    assert int_list("0-2,10") == [0, 1, 2, 10]
    for bad in ("a-b", "5-3", "1,x"):
        with pytest.raises(UsageError, match=f"bad integer list '{bad}'"):
            int_list(bad)


def test_a_header_naming_a_column_twice_is_refused(tmp_path: Path, run_csv: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """Two T_tank_C columns: pandas renamed the second (T_tank_C.1) and the fit silently used the first."""
    lines = run_csv.read_text().splitlines()
    bad = tmp_path / "dup.csv"  # every column present, T_tank_C a second time at the end
    bad.write_text("\n".join([lines[0] + ",T_tank_C", *(ln + ",99" for ln in lines[1:])]) + "\n")
    before = bad.read_bytes()
    code = main(["fit", str(bad), "--json", str(tmp_path / "f.json"), "--ml"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "duplicate column(s) ['T_tank_C']" in err, err
    assert bad.read_bytes() == before and not (tmp_path / "f.json").exists()


def test_extra_columns_of_one_name_are_ignored_as_extra_columns_are(tmp_path: Path, run_csv: Path) -> None:
    """Two extra columns of one name (a logger's two ``comment`` columns; two empty names of trailing separators):
    extra columns are ignored (docs/reference.md, section 2), so the run reads as without them (it was refused as a
    duplicate column)."""
    from valve_env.data_io import load_run

    lines = run_csv.read_text().splitlines()
    plain = load_run(run_csv)
    for extra, cells in ((",comment,comment", ",a,b"), (",,", ",,")):
        run = tmp_path / "extra.csv"
        run.write_text("\n".join([lines[0] + extra, *(ln + cells for ln in lines[1:])]) + "\n")
        out = load_run(run)
        pd.testing.assert_frame_equal(out[plain.columns], plain)


def test_an_output_named_twice_into_a_new_directory_is_refused_up_front(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``--json out/ev/table.md --out out/ev`` with out/ev not there yet: the clash was found only while
    committing, after part of the outputs had been renamed into place (a run half written)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("THERMOVALVE_NO_PROGRESS", "1")
    code = main(["evaluate", "--controllers", "self_acting", "--episodes", "1", "--env-kwargs", "horizon_h=0.5",
                 "--json", "out/ev/table.md", "--out", "out/ev"])
    err = capsys.readouterr().err
    assert code == 2 and "named twice" in err, err
    assert not (tmp_path / "out" / "ev").exists() or not any((tmp_path / "out" / "ev").iterdir())
    with pytest.raises(OutputError, match="named twice"):
        outs = OutputSet()
        outs.add_in_dir(tmp_path / "new", ["a.csv"])
        outs.add_in_dir(tmp_path / "new", ["a.csv"])


@pytest.mark.parametrize(("text", "env_id", "expect"), [
    ("valve:\n  sigma: 6.41\n  sigma: 7\n", "ThermoValve-v0", "duplicate key 'sigma'"),
    ("valve:\n  effects:\n    stiction: {band_mm: 5}\n", "ThermoValveStickyValve-v0",
     "c.yaml': valve.effects.stiction.band_mm must be in [0, 1] mm"),
    (None, "ThermoValve-v0", "is a directory, not a YAML file"),
])
def test_a_bad_config_file_is_named(text: str | None, env_id: str, expect: str, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """A key given twice (PyYAML kept the last one silently); a bad value in a file given to a task id
    (the message did not name the file, as it does for the original ids); a directory given as the
    file (said 'does not exist')."""
    cfg = tmp_path / "c.yaml"
    if text is None:
        cfg.mkdir()
    else:
        cfg.write_text(text)
    code = main(["evaluate", "--env", env_id, "--controllers", "pi", "--episodes", "1", "--config", str(cfg)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert expect in err, err


@pytest.mark.parametrize(("args", "expect"), [
    (["--env-kwargs", "config=foo.yaml"], "--env-kwargs config=...: give the file with --config"),
    (["--env-kwargs", "horizon_h=0.5", "horizon_h=1"], "--env-kwargs horizon_h is given twice"),
    (["--env", "ThermoValveDistrictHeating-v0", "--env-kwargs", "tariff=1"],
     "tariff= must be a mapping of the ThermoValveDistrictHeating-v0 tariff's fields, got int 1"),
    (["--env", "ThermoValveStickyValve-v0", "--env-kwargs", "tariff={w_eur: 1}"],
     "ThermoValveStickyValve-v0 has no tariff"),
])
def test_a_bad_env_kwarg_is_named(args: list[str], expect: str, capsys: pytest.CaptureFixture[str]) -> None:
    """config= said "make_config() got multiple values for argument 'config'"; a key given twice kept the last
    silently; tariff=1 said "'int' object is not iterable ..."; a tariff on a task without one was ignored."""
    code = main(["evaluate", "--controllers", "pi", "--episodes", "1", *args])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert expect in err, err


@pytest.mark.parametrize("command", ["evaluate", "demo"])
def test_too_many_episodes_are_refused_up_front(command: str, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """--episodes 1000000 built a million envs side by side (about 400 GB) before stepping one."""
    code = main([command, "--episodes", "1000000", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "--episodes must be <= 1000" in err, err
    from valve_env.evaluation.evaluator import run_episodes

    with pytest.raises(ValueError, match="episodes must be <= 1000"):
        run_episodes(object(), episodes=1001)  # type: ignore[arg-type]


def test_no_command_is_the_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    """``thermovalve`` alone printed the whole help on stdout and exited 2 with no error line."""
    code = main([])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err == "thermovalve: error: a command is required (see thermovalve --help)\n"


def test_a_commit_that_fails_leaves_no_temporary(tmp_path: Path) -> None:
    """A failure inside commit (a refusal found there, or SIGTERM arriving while committing: the cause of a
    '.rep.*.tmp' left by tests/cli/test_outputs.py's SIGTERM test under load) left the staged directory."""
    d = tmp_path / "rep"
    d.mkdir()
    (d / "a.png").write_text("previous")
    outs = OutputSet()
    with pytest.raises(OutputError, match="exists; use --force"), outs:
        staged = outs.stage_dir(d)
        (staged / "a.png").write_text("new")  # not declared: checked (and refused) at commit
    assert (d / "a.png").read_text() == "previous"
    assert [p.name for p in tmp_path.rglob("*") if p.name.endswith(".tmp")] == []


def test_a_reader_that_leaves_the_pipe_ends_the_command_quietly() -> None:
    """``thermovalve tasks | head -1``: the reader closes the pipe before the command has written; the command
    stops with SIGPIPE's status 141 and no error line (it printed ``BrokenPipeError`` as an error before)."""
    import subprocess
    import sys

    code = ("import sys; from valve_env.cli import run_command\n"
            "def cmd(args):\n"
            "    raise BrokenPipeError(32, 'Broken pipe')\n"
            "sys.exit(run_command(cmd, None))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.returncode == 141
    assert p.stderr == ""


def test_fit_warns_on_the_console_that_an_opening_named_in_another_unit_was_not_read(
        tmp_path: Path, short_run_df: pd.DataFrame, capsys: pytest.CaptureFixture[str]) -> None:
    """A rig that logs the opening as ``x_um``: the column is an extra one (x_mm is optional), so the opening is derived
    from the flow; the fit runs, and the console says which column was left unread and how to give it."""
    run = tmp_path / "um.csv"
    short_run_df.assign(x_um=short_run_df.x_mm * 1000.0).drop(columns=["x_mm"]).to_csv(run, index=False)
    code = main(["fit", str(run), "--json", str(tmp_path / "f.json"), "--ml"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert ("warning: no x_mm column: the opening is derived from q_kgh and dp_mbar with the valve characteristic "
            "(docs/reference.md, section 2); the header has 'x_um', x in um: give it as x_mm in mm (divide by 1000), "
            "to read the measured opening instead (the column is not read)") in out.splitlines()
    notes = json.loads((tmp_path / "f.json").read_text())["preprocessing"]
    note = next(n for n in notes if n["what"] == "x_mm_derived")
    assert note["warn"] is True
