"""``thermovalve benchmark``: every controller on every task over held-out seeds, on Dask.

    thermovalve benchmark [--tasks A,B] [--controllers a,b] [--episodes 10] [--seed 5000]
                          [--out out/benchmark] [--force] [--workers 2 | --scheduler tcp://host:8786]
    python -m agents.benchmark ...

Each cell (task, controller) runs the evaluator (valve_env.evaluation) on
``--episodes`` seeded episodes, seeds ``--seed ..`` (5000-5009 by default:
held out, never run while the tasks were built, which used seeds 0-103).
Cells are Dask tasks, on a ``distributed.LocalCluster`` by default
(``--workers`` processes, one thread each) or on an existing cluster
(``--scheduler``; the workers need this package installed). Besides the
controllers, ``pi`` runs on a smooth valve (``pi@smooth_valve``) on every
task: does the valve matter?

Writes into ``--out`` (refused if it holds files, unless ``--force``):
``table.md`` (per task: cost = -return with its 95 % interval, the gap
score 0 = pi, 1 = oracle with its 95 % interval, the score 0 = self_acting,
1 = oracle, KPIs; the headroom and valve findings),
``results.json``, ``episodes.csv``, ``scores.png`` and ``kpis.png``. The
scoring itself is valve_env.tasks.benchmark (core: no Dask); this command
lives in agents/ because Dask is in the ``rl`` extra. docs/tasks.md.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def run_cells(cells: Sequence[Any], scheduler: str | None = None, workers: int = 2,
              verbose: bool = True) -> list[dict[str, Any]]:
    """Run the cells on Dask (a LocalCluster unless ``scheduler``); results in the cells' order."""
    from distributed import as_completed

    from agents.sweep import dask_client
    from valve_env.tasks.benchmark import run_cell

    results: dict[str, dict[str, Any]] = {}
    with dask_client(scheduler, workers) as client:
        futures = {client.submit(run_cell, c, key=f"bench-{c.key}-{time.time_ns()}", pure=False): c for c in cells}
        for fut in as_completed(futures):
            c = futures[fut]
            rec = fut.result()
            results[c.key] = rec
            if verbose:
                print(f"[benchmark] {c.key}: {len(rec['episodes'])} episodes, {rec['wall_s']:.1f} s",
                      file=sys.stderr, flush=True)
    return [results[c.key] for c in cells]


def add_arguments(p: argparse.ArgumentParser) -> None:
    from valve_env.tasks.benchmark import HELD_OUT_SEED

    p.add_argument("--tasks", default=None, help="comma-separated task ids (default: those of `thermovalve tasks`)")
    p.add_argument("--controllers", default=None,
                   help="comma-separated controller names or training run directories given as paths "
                        "(out/runs/tiny_ppo; default: every controller make_controller knows that applies to the task)")
    p.add_argument("--episodes", type=int, default=10, help="episodes per cell (default 10)")
    p.add_argument("--seed", type=int, default=HELD_OUT_SEED, help=f"first seed (default {HELD_OUT_SEED}, held out)")
    p.add_argument("--horizon-h", type=float, default=None, help="episode length, h (default: the task's, 24)")
    p.add_argument("--out", default="out/benchmark", help="output directory (default out/benchmark)")
    p.add_argument("--force", action="store_true", help="replace the files of an earlier report in --out")
    p.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    p.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--no-smooth", action="store_true", help="skip pi on a smooth valve")


def run(args: argparse.Namespace) -> int:
    import valve_env
    from agents.sweep import check_workers
    from valve_env.evaluation.cli import check_episodes
    from valve_env.outputs import OutputError, OutputSet
    from valve_env.params import ConfigError
    from valve_env.tasks import benchmark as bm

    try:
        tasks = [t for t in (args.tasks or ",".join(valve_env.CURRENT_TASK_IDS)).split(",") if t]
        for t in tasks:
            if t not in valve_env.ALL_ENV_IDS:
                raise ValueError(f"unknown task {t!r}; known: {', '.join(valve_env.ALL_ENV_IDS)}")
        check_episodes(args.episodes)
        if args.seed < 0:  # checked here, before the workers start: each would raise it in a traceback
            raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
        check_workers(args.scheduler, args.workers)
        names = [c for c in args.controllers.split(",") if c] if args.controllers else None
        for c in names or ():
            if ":" in c and "/" not in c:  # name:key=value is evaluate's; the board scores each controller as tuned
                raise ValueError(f"--controllers {c!r}: benchmark takes controllers without options (options as "
                                 "name:key=value are for thermovalve evaluate)")
        cells = bm.make_cells(tasks, names, args.episodes, args.seed, smooth=not args.no_smooth)
        if args.horizon_h is not None:
            cells = [bm.Cell(c.task, c.controller, c.episodes, c.seed,
                             {**c.env_kwargs, "horizon_h": float(args.horizon_h)}) for c in cells]
            valve_env.make_config(horizon_h=float(args.horizon_h))  # validates
        outs = OutputSet(force=args.force)
        made = not Path(args.out).exists()
        out = outs.add_dir(args.out)
        paths = {name: outs.add(out / name) for name in
                 ("table.md", "results.json", "episodes.csv", "scores.png", "kpis.png")}
    except (ValueError, ConfigError, OutputError) as exc:
        print(f"thermovalve: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    print(f"[benchmark] {len(cells)} cells: {len(tasks)} tasks, seeds {args.seed}..{args.seed + args.episodes - 1}",
          file=sys.stderr)
    try:
        records = run_cells(cells, args.scheduler, args.workers)
    except BaseException:  # no cluster, a failed cell or an interrupt: leave no empty directory of ours behind
        if made and not any(out.iterdir()):
            out.rmdir()
        raise
    table = bm.task_table(records)
    found = bm.findings(table)
    for task in tasks:  # the limit cycle of pi where the task's valve sticks (plausibility, docs/tasks.md)
        if "stiction" in valve_env.tasks.get_task(task).sections.get("valve", {}).get("effects", {}):
            found.setdefault(task, {})["limit_cycle"] = bm.limit_cycles(
                task, range(args.seed, args.seed + args.episodes),
                env_kwargs=None if args.horizon_h is None else {"horizon_h": float(args.horizon_h)})
    text = bm.markdown_report(table, found)
    import pandas as pd

    episodes = pd.DataFrame([{"task": r["cell"]["task"], "controller": r["cell"]["controller"], **ep}
                             for r in records for ep in r["episodes"]])
    meta = {"command": shlex.join(sys.argv), "seeds": [args.seed, args.seed + args.episodes - 1],
            "held_out": True, "wall_s": round(time.perf_counter() - t0, 1),
            "cells": [{"task": c.task, "controller": c.controller, "env_kwargs": dict(c.env_kwargs)} for c in cells]}
    outs.write_text(paths["table.md"], text)
    outs.write_text(paths["results.json"], bm.report_json(table, found, meta))
    outs.stage(paths["episodes.csv"], lambda tmp: episodes.to_csv(tmp, index=False))
    outs.stage(paths["scores.png"], lambda tmp: bm.plot_scores(table, tmp))
    outs.stage(paths["kpis.png"], lambda tmp: bm.plot_kpis(table, tmp))
    outs.commit()
    print(text)
    print(outs.summary())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.benchmark", description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
