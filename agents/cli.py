"""``thermovalve train``, ``thermovalve leaderboard`` and ``thermovalve sweep``
(registered in valve_env.cli's SUBCOMMAND_MODULES)."""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    from agents import leaderboard, sweep, train

    for name, mod, help_text in (
        ("train", train, "train a stable-baselines3 agent (configs/<algo>.yml); --ship copies it into agents/zoo"),
        ("leaderboard", leaderboard, "score shipped agents and baselines on seen and unseen scenarios"),
        ("sweep", sweep, "a sweep of algos x seeds x scenarios on a Dask cluster (resumable)"),
    ):
        p: argparse.ArgumentParser = subparsers.add_parser(name, help=help_text, description=mod.__doc__)
        mod.add_arguments(p)
        p.set_defaults(func=mod.run)
