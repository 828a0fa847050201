"""The ``thermovalve`` command. Each sub-command lives beside the code it runs;
a module in SUBCOMMAND_MODULES exposes ``register(subparsers)`` which adds its
sub-parser(s) with ``set_defaults(func=...)``; ``func(args)`` returns the exit code."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

SUBCOMMAND_MODULES: tuple[str, ...] = (
    "valve_env.bench",
    "valve_env.diagnosis.cli",
    "valve_env.estimation.cli",
    "valve_env.evaluation.cli",
    "valve_env.tasks.cli",
    "agents.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="thermovalve",
        description="ThermoValve: thermostatic valve environments, controllers and grey-box identification.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("thermovalve: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
