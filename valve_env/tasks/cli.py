"""``thermovalve tasks``: the registered tasks, one line each (id, what makes it hard, action space).

    thermovalve tasks [--all] [--sources]

The current tasks; ``--all`` also lists the three original ids and the superseded versions (still
registered, bit for bit: ThermoValveDistrictHeating-v0 and -Power-v0, superseded by their v1);
``--sources`` prints each task's cited parameters.
"""

from __future__ import annotations

import argparse
from typing import Any


def task_lines(include_original: bool = False, sources: bool = False) -> list[str]:
    """The lines that ``thermovalve tasks`` prints."""
    from valve_env.tasks import TASKS

    rows = [t for t in TASKS.values()
            if include_original or not (t.is_original or t.superseded_by is not None)]
    width = max(len(t.id) for t in rows)
    lines = []
    for t in rows:
        old = f" (superseded by {t.superseded_by})" if t.superseded_by else ""
        lines.append(f"{t.id:<{width}}  {t.hard}{old}  [{t.action_space_text()}]")
        if sources:
            lines += [f"{'':<{width}}    {param}: {src}" for param, src in t.sources.items()]
    return lines


def cmd_tasks(args: argparse.Namespace) -> int:
    print("\n".join(task_lines(args.all, args.sources)))
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("tasks", help="list the benchmark tasks (id, what makes it hard, action space)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--all", action="store_true",
                   help="also list ThermoValve-v0, -Pressure-v0, -Dual-v0 and the superseded task versions")
    p.add_argument("--sources", action="store_true", help="print the sources of each task's parameters")
    p.set_defaults(func=cmd_tasks)
