"""The output policy under interruption and --force: a killed writer leaves the previous
output intact (and, on SIGTERM, no temporary file); --force replaces; a run that fails after
its outputs were staged leaves none of them."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from valve_env.cli import main
from valve_env.outputs import OutputError, OutputSet

PREVIOUS = '{"previous": "result"}\n'

#: a process that stages a large output slowly, under the CLI's SIGTERM handling
WRITER = r"""
import signal, sys, time
from valve_env.cli import run_command, _on_sigterm
from valve_env.outputs import OutputSet
signal.signal(signal.SIGTERM, _on_sigterm)

def slow(tmp):
    with open(tmp, "w") as fh:
        for i in range(10_000):
            fh.write("x" * 100_000)
            fh.flush()
            if i == 2:
                print("writing", flush=True)
            time.sleep(0.01)

def cmd(args):
    with OutputSet(force=True) as outs:
        outs.stage(sys.argv[1], slow)
    return 0

sys.exit(run_command(cmd, None))
"""


def _temps(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.endswith(".tmp"))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_killed_writer_leaves_previous_output(tmp_path: Path, sig: signal.Signals) -> None:
    out = tmp_path / "out.json"
    out.write_text(PREVIOUS)
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "writing"
    assert _temps(tmp_path)  # the partial file exists, under a temporary name
    proc.send_signal(sig)
    proc.wait(timeout=60)
    assert proc.returncode != 0
    assert out.read_text() == PREVIOUS
    if sig == signal.SIGTERM:  # handled: the staged file is removed
        assert _temps(tmp_path) == []
        assert proc.stderr is not None and "terminated" in proc.stderr.read()
    else:  # SIGKILL cannot be handled: at most a hidden temporary file stays, never a partial out.json
        assert all(n.startswith(".out.json.") for n in _temps(tmp_path))


#: ``thermovalve fit`` with a SIGTERM sent to itself at a chosen point of the output policy (argv[1]:
#: ``stage_dir``, as the report directory is staged, or ``place``, after the first file of the commit is in
#: place): the point is exact, where a signal sent from outside would race the run (it missed the staging
#: window at load 11-13)
FIT_SIGNALLED = r"""
import os, signal, sys
from valve_env import outputs
where = sys.argv[1]
if where == "stage_dir":
    orig_stage_dir = outputs.OutputSet.stage_dir
    def stage_dir(self, directory):
        tmp = orig_stage_dir(self, directory)
        os.kill(os.getpid(), signal.SIGTERM)
        return tmp
    outputs.OutputSet.stage_dir = stage_dir
else:
    orig_place = outputs.OutputSet._place
    def place(self, tmp, final):
        orig_place(self, tmp, final)
        os.kill(os.getpid(), signal.SIGTERM)
    outputs.OutputSet._place = place
from valve_env.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _fit_signalled(where: str, run_csv: Path, out: Path, rep: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "THERMOVALVE_NO_PROGRESS": "1"}
    return subprocess.run([sys.executable, "-c", FIT_SIGNALLED, where, "fit", str(run_csv), "--json", str(out),
                           "--force", "--report", str(rep), "--ml"],
                          capture_output=True, text=True, env=env, timeout=600)


def test_sigterm_during_fit_keeps_previous_result(tmp_path: Path, run_csv: Path) -> None:
    out, rep = tmp_path / "out.json", tmp_path / "rep"
    out.write_text(PREVIOUS)
    proc = _fit_signalled("stage_dir", run_csv, out, rep)
    assert proc.returncode != 0, proc.stderr
    assert "terminated" in proc.stderr
    assert out.read_text() == PREVIOUS
    assert not rep.exists()
    assert [p.name for p in tmp_path.rglob("*") if p.name.endswith(".tmp") or p.name.startswith(".")] == []


def test_sigterm_during_commit_places_every_output(tmp_path: Path, run_csv: Path) -> None:
    """A signal that arrives once the renames have begun waits for them: the outputs are all new (the
    report beside the JSON), never the new JSON beside no report."""
    out, rep = tmp_path / "out.json", tmp_path / "rep"
    out.write_text(PREVIOUS)
    proc = _fit_signalled("place", run_csv, out, rep)
    assert proc.returncode != 0, proc.stderr
    assert "terminated" in proc.stderr
    assert json.loads(out.read_text()) != json.loads(PREVIOUS)
    assert rep.is_dir() and any(rep.iterdir())
    assert [p.name for p in tmp_path.rglob("*") if p.name.endswith(".tmp") or p.name.startswith(".")] == []


def test_force_replaces_and_refuses_without(tmp_path: Path) -> None:
    p = tmp_path / "a.json"
    p.write_text(PREVIOUS)
    with pytest.raises(OutputError, match="use --force"):
        OutputSet().add(p)
    with OutputSet(force=True) as outs:
        outs.write_text(outs.add(p), "new\n")
    assert p.read_text() == "new\n"
    assert _temps(tmp_path) == []


def test_force_never_replaces_an_input(tmp_path: Path) -> None:
    inp = tmp_path / "run.csv"
    inp.write_text("data\n")
    link = tmp_path / "hard.csv"
    os.link(inp, link)
    for target in (inp, link):
        with pytest.raises(OutputError, match="is the input"):
            OutputSet(inputs=[inp], force=True).add(target)
    assert inp.read_text() == "data\n"


def test_failure_after_staging_leaves_nothing(tmp_path: Path) -> None:
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    b.write_text(PREVIOUS)
    with pytest.raises(RuntimeError), OutputSet(force=True) as outs:
        outs.write_text(outs.add(a), "new a\n")
        outs.write_text(outs.add(b), "new b\n")
        staged = outs.stage_dir(tmp_path / "figs")
        (staged / "f.png").write_bytes(b"png")
        raise RuntimeError("the report failed")
    assert not a.exists() and b.read_text() == PREVIOUS
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.json"]


def test_staged_directory_commits_together_and_checks_each_file(tmp_path: Path) -> None:
    d = tmp_path / "rep"
    d.mkdir()
    (d / "old.png").write_text("old")
    outs = OutputSet()
    staged = outs.stage_dir(d)
    (staged / "new.png").write_text("new")
    (staged / "old.png").write_text("replaced?")
    with pytest.raises(OutputError, match="old.png exists"):
        outs.commit()
    assert not (d / "new.png").exists() and (d / "old.png").read_text() == "old"
    outs.discard()
    assert sorted(p.name for p in d.iterdir()) == ["old.png"]


@pytest.mark.slow
def test_fit_force_replaces_and_prints_what_it_wrote(tmp_path: Path, run_csv: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out, cfg = tmp_path / "fit.json", tmp_path / "valve.yaml"
    out.write_text(PREVIOUS)
    assert main(["fit", str(run_csv), "--json", str(out), "--valve-out", str(cfg), "--n-starts", "1"]) == 2
    assert out.read_text() == PREVIOUS and not cfg.exists()
    capsys.readouterr()
    assert main(["fit", str(run_csv), "--json", str(out), "--valve-out", str(cfg), "--n-starts", "1", "--force"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}, {cfg}" in printed
    assert "params" in json.loads(out.read_text())


def test_a_file_that_appears_meanwhile_is_not_replaced(tmp_path: Path) -> None:
    """Two runs writing one path: the one that finishes second refuses (no silent loss)."""
    p = tmp_path / "d.json"
    first, second = OutputSet(), OutputSet()
    first.add(p)
    second.add(p)  # both checked while p did not exist
    first.write_text(p, "first\n")
    second.write_text(p, "second\n")
    first.commit()
    with pytest.raises(OutputError, match="appeared while this run was working"):
        second.commit()
    second.discard()
    assert p.read_text() == "first\n"
    assert _temps(tmp_path) == []


def test_json_writer_writes_non_finite_as_null() -> None:
    """No more 'Out of range float values are not JSON compliant: -inf': null instead."""
    import numpy as np

    from valve_env.outputs import json_text

    text = json_text({"loglik": float("-inf"), "sd": np.float64("nan"), "x": np.array([1.0, np.inf]), "n": 3})
    assert json.loads(text) == {"loglik": None, "sd": None, "x": [1.0, None], "n": 3}
    assert "Infinity" not in text and "NaN" not in text


def test_outputs_get_the_mode_a_plain_open_would_give(tmp_path: Path) -> None:
    """An atomically written output is not left at mkstemp's private 0600: it gets 0666 less the umask,
    as any file the user writes."""
    old = os.umask(0o022)
    try:
        with OutputSet() as outs:
            outs.write_text(tmp_path / "a.json", "{}\n")
            outs.stage(tmp_path / "b.csv", lambda tmp: Path(tmp).write_text("x\n"))
    finally:
        os.umask(old)
    for name in ("a.json", "b.csv"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o644, name


def test_an_interrupt_while_a_temporary_is_made_leaves_none(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A signal turned into an exception (Ctrl-C, or SIGTERM through valve_env.cli) between the making of a
    temporary and its clean-up bookkeeping leaves no temporary behind (it once did, under load)."""

    def interrupted(fd: int, mode: int) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fchmod", interrupted)
    outs = OutputSet()
    with pytest.raises(KeyboardInterrupt):
        outs.write_text(outs.add(tmp_path / "a.json"), "new\n")
    outs.discard()
    assert list(tmp_path.iterdir()) == []


def test_a_command_that_ends_early_leaves_no_staged_temporaries(tmp_path: Path) -> None:
    """An error (or SIGTERM) between staging and committing: run_command removes what was staged even
    while the output set is still referenced (in the SIGTERM test above, a set kept alive by a reference
    cycle left its staged report directory behind when the interpreter exited without collecting it)."""
    import argparse

    from valve_env.cli import run_command
    from valve_env.outputs import OutputSet

    alive: list[OutputSet] = []

    def command(args: argparse.Namespace) -> int:
        outs = OutputSet()
        outs.add_in_dir(tmp_path / "rep", ["report.md"])
        (outs.stage_dir(tmp_path / "rep") / "report.md").write_text("partial")
        outs.stage(tmp_path / "out.json", lambda tmp: tmp.write_text("{}"))
        alive.append(outs)  # still referenced: garbage collection cannot clean it up
        raise RuntimeError("the fit failed after staging")

    assert [p for p in tmp_path.iterdir()] == []
    assert run_command(command, argparse.Namespace()) == 1
    assert alive and sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_signal_that_compiled_code_wrapped_still_ends_the_run_as_that_signal(
        capsys: pytest.CaptureFixture[str]) -> None:
    """A signal handled while a compiled kernel returns comes back as ``SystemError: CPUDispatcher(...) returned a
    result with an exception set``, the signal's exception its cause: a SIGTERM during ``diagnose`` printed that
    SystemError and exited 1. It ends the run as the signal does (143, or 130 for Ctrl-C), in one line."""
    from valve_env import cli

    def wrapped(signal_exc: BaseException) -> int:
        def func(args: object) -> int:
            try:
                raise signal_exc
            except BaseException as exc:
                raise SystemError("CPUDispatcher(<function k>) returned a result with an exception set") from exc
        return cli.run_command(func, None)

    assert wrapped(cli._Terminated()) == 143
    assert capsys.readouterr().err.strip() == "thermovalve: terminated; no output was replaced"
    assert wrapped(KeyboardInterrupt()) == 130
    assert capsys.readouterr().err.strip() == "thermovalve: interrupted; no output was replaced"

    def other(args: object) -> int:
        raise SystemError("something else")

    assert cli.run_command(other, None) == 1
    assert "SystemError: something else" in capsys.readouterr().err


def test_stage_progress_ends_full_when_the_run_needs_fewer_stages(capsys: pytest.CaptureFixture[str],
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A diagnosis counts the stages it may need (a bootstrap per named effect); one that needs fewer ended its
    progress at 10/12. The last line now reads the whole count; a run that fails stops where it failed."""
    from valve_env.cliutil import stage_progress

    monkeypatch.delenv("THERMOVALVE_NO_PROGRESS", raising=False)
    with stage_progress(5, "job") as tick:
        tick("a")
        tick("b")
    lines = capsys.readouterr().err.strip().splitlines()
    assert [ln.split(" (")[0] for ln in lines] == ["job: 1/5 a", "job: 2/5 b", "job: 5/5 done"]
    with pytest.raises(RuntimeError), stage_progress(5, "job") as tick:
        tick("a")
        raise RuntimeError("stops")
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith("job: 1/5 a")
