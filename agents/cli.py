"""``thermovalve train``, ``thermovalve leaderboard``, ``thermovalve sweep``, ``thermovalve benchmark``,
``thermovalve task-leaderboard`` and ``thermovalve curves``
(registered with the core through the ``thermovalve.cli`` entry point in pyproject.toml, valve_env.plugins)."""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    from agents import benchmark, curves, leaderboard, sweep, task_leaderboard, train

    for name, mod, help_text in (
        ("train", train,
         "train a stable-baselines3 agent (agents/configs/<algo>.yml); --ship copies it into agents/zoo"),
        ("leaderboard", leaderboard, "score shipped agents and baselines on seen and unseen scenarios"),
        ("sweep", sweep, "a sweep of algos x seeds x scenarios on a Dask cluster (resumable)"),
        ("benchmark", benchmark, "every controller on every task over held-out seeds, normalised scores (Dask)"),
        ("task-leaderboard", task_leaderboard,
         "shipped agents on the benchmark tasks: normalised score, learned share, wear, generalisation"),
        ("curves", curves, "learning curves of training runs (one figure per task)"),
    ):
        p: argparse.ArgumentParser = subparsers.add_parser(name, help=help_text, description=mod.__doc__)
        mod.add_arguments(p)
        p.set_defaults(func=mod.run)
