"""``thermovalve tasks``: the registered tasks, one line each (id, what makes it hard, action space).

    thermovalve tasks [--all] [--sources]

``--all`` also lists the three original ids; ``--sources`` prints each task's cited parameters.
"""

from __future__ import annotations

import argparse
from typing import Any


def task_lines(include_original: bool = False, sources: bool = False) -> list[str]:
    """The lines that ``thermovalve tasks`` prints."""
    from valve_env.tasks import TASKS

    rows = [t for t in TASKS.values() if include_original or not t.is_original]
    width = max(len(t.id) for t in rows)
    lines = []
    for t in rows:
        lines.append(f"{t.id:<{width}}  {t.hard}  [{t.action_space_text()}]")
        if sources:
            lines += [f"{'':<{width}}    {param}: {src}" for param, src in t.sources.items()]
    return lines


def cmd_tasks(args: argparse.Namespace) -> int:
    print("\n".join(task_lines(args.all, args.sources)))
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("tasks", help="list the benchmark tasks (id, what makes it hard, action space)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--all", action="store_true", help="also list ThermoValve-v0, -Pressure-v0 and -Dual-v0")
    p.add_argument("--sources", action="store_true", help="print the sources of each task's parameters")
    p.set_defaults(func=cmd_tasks)
