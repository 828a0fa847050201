"""One CLI style: help without markup and with defaults, no RL import to build the parser,
argparse errors in the one-line form."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from valve_env.cli import build_parser, main, strip_markup


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("no sub-commands")


def test_every_help_has_no_markup_and_shows_defaults() -> None:
    parser = build_parser()
    subs = _subparsers(parser)
    assert {"fit", "diagnose", "experiment", "evaluate", "demo", "tune", "bench", "train", "leaderboard",
            "sweep"} <= set(subs)
    for name, sub in subs.items():
        text = sub.format_help()
        for mark in ("``", ":func:", ":class:", ":mod:", "**"):
            assert mark not in text, (name, mark)
        assert "\\" not in sub.format_usage(), name  # the old sweep usage line carried a backslash
        for action in sub._actions:
            if action.option_strings and action.default not in (None, False, argparse.SUPPRESS) \
                    and action.help is not argparse.SUPPRESS:
                assert "default" in (sub._get_formatter()._get_help_string(action) or ""), (name, action.dest)
        writes = any(o in a.option_strings for a in sub._actions for o in ("--json", "--out", "--write", "--ship"))
        assert not writes or any("--force" in a.option_strings for a in sub._actions), name


def test_strip_markup() -> None:
    assert strip_markup("see :func:`valve_env.a.b` and ``x=1`` or `y`") == "see valve_env.a.b and x=1 or y"


def test_parser_builds_without_the_rl_stack() -> None:
    code = ("import sys; from valve_env.cli import build_parser; build_parser(); "
            "bad = [m for m in ('stable_baselines3', 'torch', 'distributed') if m in sys.modules]; "
            "assert not bad, bad")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("argv", [["fit"], ["diagnose", "x.csv"], ["evaluate", "--episodes", "x"],
                                  ["train", "--algo", "a2c"], ["nope"], ["sweep", "--workers"]])
def test_usage_errors_are_one_line_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and err[0].startswith("thermovalve: error: ")
