"""A sweep of algorithms x seeds x scenarios on a Dask cluster.

    thermovalve sweep --algos ppo,sac --seeds 0,1,2 --scenarios default,profile_L --timesteps 200000
        --out out/sweep [--workers 2 | --scheduler tcp://host:8786]
    thermovalve sweep --env ThermoValveStickyValve-v0,ThermoValveDistrictHeating-v0 --seeds 0,1
        --out out/sweep_tasks --ship-best ppo --force      # train, select on seeds 1000+, ship
    thermovalve sweep --grid configs/sweeps/sticky_ppo.yml --seeds 0 --eval-episodes 10 --out out/sweep_grid
        # a hyperparameter grid (lists of values per key, keyed by env id) x seeds, ranked on seeds 1000+
    python -m agents.sweep ...

Each cell (algo, seed, scenario) trains an agent on that scenario
(:func:`agents.train.train`) and scores its final model through the
evaluator (``valve_env.evaluation.evaluate_detailed``) on held-out seeds.
Cells are Dask tasks: a ``distributed.LocalCluster`` by default (``--workers``
processes, one thread each), or an existing cluster by its scheduler address
(the workers need this package installed and the output directory on a
shared file system).

Resuming: a cell's result is written atomically (a temporary file, then
``os.replace``) to ``<out>/results/<cell>.json``; a rerun skips every cell
whose result exists. A cell that raised writes ``<out>/failed/<cell>.json``
(the error and traceback) and is retried on the next run; an interrupted
cell leaves no result and is also rerun. A non-empty ``--out`` that is not a
sweep (no ``grid.json``) is refused unless ``--force``. ``<out>/summary.csv`` and
``summary.md`` collect the results after every run.

Hyperparameter grids (``--grid FILE``, docs/agents.md "Sweeps on Dask"): a YAML file keyed
by env id, like agents/configs/<algo>.yml; each env's block has ``grid:`` (a config key, dotted as in
``--set``, to a list of values: the cells are the product of the lists), optionally ``set:``
(key: value overrides for every cell of that env) and ``timesteps:``. Every grid point runs
once per seed; its cells' directories hold the resolved ``config.yml`` and a ``command.txt``
that retrains the cell with ``thermovalve train``, and ``summary.md`` ranks the grid points by
their mean evaluation return on the held-out seeds (``--eval-seed``, 1000+ by default).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shlex
import sys
import tempfile
import time
import traceback
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from agents.cem import RANK_SEED
from valve_env.cliutil import int_list


@dataclass(frozen=True)
class Cell:
    """One training + scoring job of the grid."""

    algo: str
    seed: int
    scenario: str
    env_id: str = "ThermoValve-v0"
    timesteps: int = 100_000
    eval_episodes: int = 5
    eval_seed: int = RANK_SEED
    overrides: tuple[str, ...] = ()
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    #: the grid point's index in its env's grid (-1: not a grid cell) and its ``key=value`` overrides
    grid_point: int = -1
    params: tuple[str, ...] = ()

    @property
    def key(self) -> str:
        g = f"__g{self.grid_point:02d}" if self.grid_point >= 0 else ""
        return f"{self.env_id}__{self.algo}__{self.scenario}{g}__s{self.seed}"

    def train_command(self, run_dir: str | Path) -> str:
        """The ``thermovalve train`` command that retrains this cell into ``run_dir``."""
        args = ["thermovalve", "train", "--algo", self.algo, "--env", self.env_id, "--seed", str(self.seed),
                "--timesteps", str(self.timesteps), "--eval-freq", "0", "--no-progress", "--out", str(run_dir)]
        sets = [*self.overrides, *(f"env_kwargs.{k}={_yaml_value(v)}" for k, v in dict(self.env_kwargs).items())]
        for o in sets:
            args += ["--set", o]
        return shlex.join(args)


def _yaml_value(value: Any) -> str:
    """One-line YAML of a value, read back by ``--set`` (agents.train.apply_overrides) as the same value."""
    import yaml

    text = yaml.safe_dump(value, default_flow_style=True, width=10**6).strip()
    return text[:-4].strip() if text.endswith("\n...") else text


GRID_KEYS = ("grid", "set", "timesteps")


def load_grid(path: str | Path, env_ids: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    """Read and check a grid file (see the module docstring): ``{env_id: {"grid": {key: [values]},
    "set": {key: value}, "timesteps": int | None}}`` for ``env_ids`` (default: every id in the file)."""
    import yaml

    import valve_env

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--grid {p}: no such file")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"--grid {p}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict) or not data:
        raise ValueError(f"--grid {p}: expected a mapping of env ids to grid blocks")
    for env in data:
        if env not in valve_env.ALL_ENV_IDS:
            raise ValueError(f"--grid {p}: unknown env id {env!r}; known: {', '.join(valve_env.ALL_ENV_IDS)}")
    ids = list(data) if env_ids is None else list(env_ids)
    out: dict[str, dict[str, Any]] = {}
    for env in ids:
        if env not in data:
            raise ValueError(f"--grid {p} has no block for {env}; it has {', '.join(data)}")
        block = data[env]
        if not isinstance(block, dict) or not isinstance(block.get("grid"), dict) or not block["grid"]:
            raise ValueError(f"--grid {p}: {env} needs a non-empty 'grid:' mapping of config keys to lists")
        extra = sorted(set(block) - set(GRID_KEYS))
        if extra:
            raise ValueError(f"--grid {p}: {env} has unknown keys {extra}; allowed: {', '.join(GRID_KEYS)}")
        for key, values in block["grid"].items():
            if not isinstance(key, str) or not key or "=" in key:
                raise ValueError(f"--grid {p}: {env}: grid key {key!r} must be a config key like hyperparams.gamma")
            if not isinstance(values, list) or not values:
                raise ValueError(f"--grid {p}: {env}: grid.{key} must be a non-empty list of values, got {values!r}")
        fixed = block.get("set") or {}
        if not isinstance(fixed, dict):
            raise ValueError(f"--grid {p}: {env}: 'set:' must be a mapping of config keys to values")
        steps = block.get("timesteps")
        if steps is not None and (isinstance(steps, bool) or not isinstance(steps, (int, float)) or steps < 1
                                  or float(steps) != int(steps)):
            raise ValueError(f"--grid {p}: {env}: timesteps must be an integer >= 1, got {steps!r}")
        out[env] = {"grid": dict(block["grid"]), "set": dict(fixed),
                    "timesteps": None if steps is None else int(steps)}
    return out


def grid_points(block: Mapping[str, Any]) -> list[tuple[str, ...]]:
    """The ``key=value`` overrides of each point of a grid block (the product of its lists, in file order)."""
    keys = list(block["grid"])
    return [tuple(f"{k}={_yaml_value(v)}" for k, v in zip(keys, combo, strict=True))
            for combo in itertools.product(*(block["grid"][k] for k in keys))]


def make_grid(
    algos: Iterable[str],
    seeds: Iterable[int],
    scenarios: Iterable[str],
    env_id: str = "ThermoValve-v0",
    timesteps: int = 100_000,
    eval_episodes: int = 5,
    eval_seed: int = RANK_SEED,
    overrides: Sequence[str] = (),
    env_kwargs: Mapping[str, Any] | None = None,
    points: Sequence[tuple[str, ...]] | None = None,
) -> list[Cell]:
    """The full grid algos x seeds x scenarios (scenarios: agents.scenarios's static ones), and
    x ``points`` (each a tuple of ``key=value`` overrides applied after ``overrides``; grid_points)."""
    from agents.scenarios import is_randomised
    from agents.train import ALGOS

    cells = []

    def for_algo(algo: str) -> tuple[str, ...]:
        """Overrides for one algo: plain ``key=value`` apply to all, ``algo:key=value`` to that algo."""
        out = []
        for o in overrides:
            head, _, rest = o.partition(":")
            if rest and "=" not in head:
                if head == algo:
                    out.append(rest)
            else:
                out.append(o)
        return tuple(out)

    grid = list(enumerate(points)) if points is not None else [(-1, ())]
    for algo, (gp, params), seed, scen in itertools.product(algos, grid, seeds, scenarios):
        if algo not in ALGOS:
            raise ValueError(f"unknown algo {algo!r}; choose from {', '.join(ALGOS)}")
        if is_randomised(scen):
            raise ValueError(f"scenario {scen!r} changes per episode and cannot be a training scenario")
        cells.append(
            Cell(algo, int(seed), scen, env_id, int(timesteps), int(eval_episodes), int(eval_seed),
                 (*for_algo(algo), *params), dict(env_kwargs or {}), gp, tuple(params))
        )
    return cells


def write_json_atomic(path: Path, data: Mapping[str, Any]) -> None:
    """Write JSON so that a reader sees the old file or the complete new one, never a part."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh, indent=1)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def run_cell(cell: Cell, out_dir: str) -> dict[str, Any]:
    """Train and score one cell (runs on a Dask worker). Writes the result or
    the failure record itself and returns it."""
    from agents.loader import load_agent
    from agents.scenarios import scenario_env_kwargs
    from valve_env.evaluation import evaluate_detailed

    out = Path(out_dir)
    result_path = out / "results" / f"{cell.key}.json"
    failed_path = out / "failed" / f"{cell.key}.json"
    t0 = time.time()
    record: dict[str, Any] = {
        "cell": {**asdict(cell), "key": cell.key},
        "host": os.uname().nodename,
        "pid": os.getpid(),
    }
    try:
        from agents.train import train

        env_kwargs = {**scenario_env_kwargs(cell.scenario), **dict(cell.env_kwargs)}
        run_dir = train(
            cell.algo,
            cell.env_id,
            seed=cell.seed,
            timesteps=cell.timesteps,
            out=out / "cells" / cell.key,
            overrides=cell.overrides,
            env_kwargs=env_kwargs,
            progress_bar=False,
            eval_freq=0,
            command=cell.train_command(out / "cells" / cell.key),
        )
        ctrl = load_agent(cell.algo, cell.env_id, run_dir=run_dir)
        summary, per_ep = evaluate_detailed(
            {cell.algo: ctrl}, cell.env_id, cell.eval_episodes, cell.eval_seed, env_kwargs
        )
        res = summary["results"][cell.algo]
        meta = json.loads((run_dir / "run.json").read_text())
        record.update(
            {
                "status": "done",
                "run_dir": str(run_dir),
                "train_wall_s": meta.get("wall_time_s"),
                "wall_s": round(time.time() - t0, 1),
                "eval": {"episodes": cell.eval_episodes, "seed": cell.eval_seed, "env_kwargs": env_kwargs},
                "return": res["return"],
                "kpis": res["kpis"],
                "episodes": per_ep[cell.algo].to_dict(orient="records"),
            }
        )
        write_json_atomic(result_path, record)
        failed_path.unlink(missing_ok=True)
    except Exception as exc:  # recorded, retried on the next run
        record.update(
            {
                "status": "failed",
                "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(),
                "wall_s": round(time.time() - t0, 1),
            }
        )
        write_json_atomic(failed_path, record)
    return record


def pending(cells: Sequence[Cell], out_dir: str | Path) -> list[Cell]:
    """Cells without a result file (never run, failed or interrupted)."""
    res = Path(out_dir) / "results"
    return [c for c in cells if not (res / f"{c.key}.json").is_file()]


def collect(out_dir: str | Path) -> pd.DataFrame:
    """One row per finished cell: algo, seed, scenario, return and KPI means."""
    rows = []
    for p in sorted((Path(out_dir) / "results").glob("*.json")):
        r = json.loads(p.read_text())
        c = r["cell"]
        row = {"env_id": c["env_id"], "algo": c["algo"], "scenario": c["scenario"], "seed": c["seed"],
               "grid_point": c.get("grid_point", -1), "params": " ".join(c.get("params") or ()),
               "timesteps": c["timesteps"], "eval_seed": c.get("eval_seed"),
               "return": r["return"]["mean"], "return_std": r["return"]["std"]}
        row.update({k: v["mean"] for k, v in r["kpis"].items()})
        row["train_wall_s"] = r.get("train_wall_s")
        rows.append(row)
    return pd.DataFrame(rows)


def write_summary(out_dir: str | Path) -> pd.DataFrame:
    from valve_env.outputs import atomic_path, atomic_write_text

    out = Path(out_dir)
    df = collect(out)
    with atomic_path(out / "summary.csv") as tmp:
        df.to_csv(tmp, index=False)
    lines = ["# Sweep summary", ""]
    if len(df):
        g = df.groupby(["env_id", "algo", "scenario"])
        agg = g.agg(
            cells=("seed", "count"), return_mean=("return", "mean"), return_std=("return", "std"),
            rmse_K=("rmse_K", "mean"), heat_kWh=("heat_kWh", "mean"), tdis_Kh=("tdis_Kh", "mean"),
        ).reset_index()
        lines += ["Means over seeds of each cell's evaluation mean (return_std: across seeds).", ""]
        lines.append("| " + " | ".join(agg.columns) + " |")
        lines.append("|" + "---|" * len(agg.columns))
        for _, r in agg.iterrows():
            lines.append("| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r) + " |")
    grid = df[df["grid_point"] >= 0] if len(df) else df
    if len(grid):
        lines += ["", "## Grid points, ranked by mean evaluation return (best first)", ""]
        for (env, algo, scen), sub in grid.groupby(["env_id", "algo", "scenario"]):
            eval_seed = sub["eval_seed"].iloc[0]
            rank = sub.groupby(["grid_point", "params"]).agg(
                seeds=("seed", "count"), return_mean=("return", "mean"), return_std_seeds=("return", "std"),
                rmse_K=("rmse_K", "mean"), tdis_Kh=("tdis_Kh", "mean"), train_wall_s=("train_wall_s", "mean"),
            ).reset_index().sort_values("return_mean", ascending=False)
            lines += [f"{env}, {algo}, scenario {scen}; evaluated on seeds {eval_seed}+ (held out from training)", "",
                      "| rank | " + " | ".join(rank.columns) + " |", "|" + "---|" * (len(rank.columns) + 1)]
            for i, (_, r) in enumerate(rank.iterrows(), 1):
                lines.append(f"| {i} | " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r) + " |")
            lines.append("")
    failed = sorted(p.stem for p in (out / "failed").glob("*.json")) if (out / "failed").is_dir() else []
    if failed:
        lines += ["", f"Failed cells (retried on the next run): {', '.join(failed)}"]
    atomic_write_text(out / "summary.md", "\n".join(lines) + "\n")
    return df


def check_workers(scheduler: str | None, workers: int) -> None:
    """Refuse a local cluster of no workers (``LocalCluster(n_workers=0)`` waits for ever); with a
    ``scheduler`` the cluster's own workers run the cells."""
    if scheduler is None and workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")


SCHEDULER_TIMEOUT_S = 10.0  # how long --scheduler's address may take to answer


@contextmanager
def dask_client(scheduler: str | None, workers: int) -> Iterator[Any]:
    """A Dask client on ``scheduler``, or on a LocalCluster of ``workers`` single-threaded processes, closed
    (with the cluster) on exit: the runner of the sweep and of ``thermovalve benchmark``."""
    from distributed import Client, LocalCluster

    check_workers(scheduler, workers)
    cluster = None if scheduler else LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                                  dashboard_address=None)
    if scheduler:
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except OSError as exc:  # distributed's connection timeout is an OSError: a traceback and exit 1 before
            raise ValueError(f"--scheduler {scheduler}: no Dask scheduler answered within "
                             f"{SCHEDULER_TIMEOUT_S:g} s ({type(exc).__name__})") from None
    else:
        client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_sweep(
    cells: Sequence[Cell],
    out_dir: str | Path,
    scheduler: str | None = None,
    workers: int = 2,
    verbose: bool = True,
) -> dict[str, Any]:
    """Run the pending cells on Dask; returns counts of done / failed / skipped cells."""
    from distributed import as_completed

    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    todo = pending(cells, out)
    stats: dict[str, Any] = {"total": len(cells), "skipped": len(cells) - len(todo), "done": 0, "failed": 0}
    write_json_atomic(out / "grid.json", {"cells": [{**asdict(c), "key": c.key} for c in cells]})
    if verbose:
        print(f"[sweep] {len(cells)} cells, {stats['skipped']} already done, {len(todo)} to run", file=sys.stderr)
    if todo:
        with dask_client(scheduler, workers) as client:
            futures = {client.submit(run_cell, c, str(out), key=f"cell-{c.key}-{time.time_ns()}", pure=False): c
                       for c in todo}
            for fut in as_completed(futures):
                c = futures[fut]
                try:
                    rec = fut.result()
                except Exception as exc:  # the worker died or the task was lost: record it client-side
                    rec = {"cell": {**asdict(c), "key": c.key}, "status": "failed",
                           "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
                    write_json_atomic(out / "failed" / f"{c.key}.json", rec)
                stats[rec["status"]] = stats.get(rec["status"], 0) + 1
                if verbose:
                    extra = f"return {rec['return']['mean']:.2f}" if rec["status"] == "done" else rec.get("error", "")
                    print(f"[sweep] {c.key}: {rec['status']} {extra}", file=sys.stderr, flush=True)
    write_summary(out)
    return stats


# --------------------------------------------------------------------------- CLI
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--algos", default="ppo", help="comma-separated algorithms, from ppo, sac, td3")
    p.add_argument("--seeds", default="0,1,2", help="comma-separated seeds or ranges, e.g. 0-4 (default 0,1,2)")
    p.add_argument("--scenarios", default="default", help="comma-separated training scenarios (agents.scenarios)")
    p.add_argument("--env", default=None,
                   help="environment id, or comma-separated ids (a grid per id); default ThermoValve-v0, "
                        "or with --grid every id in the grid file")
    p.add_argument("--grid", default=None, metavar="FILE.yml",
                   help="hyperparameter grid, keyed by env id (configs/sweeps/*.yml; see the module docstring)")
    p.add_argument("--timesteps", type=int, default=None,
                   help="training steps per cell (default: the grid file's timesteps:, else 100000)")
    p.add_argument("--eval-episodes", type=int, default=5, help="held-out evaluation episodes per cell")
    p.add_argument("--eval-seed", type=int, default=RANK_SEED, help=f"first evaluation seed (default {RANK_SEED})")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override (as in thermovalve train); ALGO:KEY=VALUE applies to one algo only")
    p.add_argument("--out", default="out/sweep", help="sweep directory (results/, failed/, cells/, summary.*); "
                   "an existing sweep there is resumed")
    p.add_argument("--force", action="store_true", help="use a non-empty --out that is not a sweep")
    p.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    p.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--ship-best", default=None, metavar="NAME",
                   help="after the sweep, ship each env's best cell (highest mean evaluation return on the "
                        "scenario 'default') into agents/zoo/<env>/NAME.* (replacing needs --force)")


def best_cells(out_dir: str | Path, scenario: str = "default") -> dict[str, dict[str, Any]]:
    """Per env id, the finished cell with the highest mean evaluation return on ``scenario``."""
    best: dict[str, dict[str, Any]] = {}
    for path in sorted((Path(out_dir) / "results").glob("*.json")):
        r = json.loads(path.read_text())
        c = r["cell"]
        if c["scenario"] != scenario:
            continue
        if c["env_id"] not in best or r["return"]["mean"] > best[c["env_id"]]["return"]["mean"]:
            best[c["env_id"]] = r
    return best


def check_cells(cells: Sequence[Cell]) -> None:
    """Refuse, before any directory is made or cluster started, what every cell would fail on: an env id
    that is not registered, an algo with no hyperparameters for it, an override that is not ``key=value``."""
    import valve_env
    from agents.train import apply_overrides, load_algo_config

    for c in cells:
        if c.env_id not in valve_env.ALL_ENV_IDS:
            raise ValueError(f"unknown env id {c.env_id!r}; known: {', '.join(valve_env.ALL_ENV_IDS)}")
        try:
            apply_overrides(load_algo_config(c.algo, c.env_id), c.overrides)
        except KeyError as exc:  # the algo's file has no block for this env id
            raise ValueError(str(exc.args[0])) from None


def run(args: argparse.Namespace) -> int:
    if args.timesteps is not None and args.timesteps < 1:
        raise ValueError(f"--timesteps must be >= 1, got {args.timesteps}")
    check_workers(args.scheduler, args.workers)  # before any directory is made
    env_arg = [e for e in args.env.split(",") if e] if args.env else None
    grids = load_grid(args.grid, env_arg) if args.grid else None
    envs = env_arg or (list(grids) if grids else ["ThermoValve-v0"])
    cells = []
    for env in envs:
        block = grids[env] if grids else None
        steps = args.timesteps or (block or {}).get("timesteps") or 100_000
        fixed = [f"{k}={_yaml_value(v)}" for k, v in (block or {}).get("set", {}).items()]
        cells += make_grid(
            [a for a in args.algos.split(",") if a], int_list(args.seeds), [s for s in args.scenarios.split(",") if s],
            env, steps, args.eval_episodes, args.eval_seed, [*args.overrides, *fixed],
            points=grid_points(block) if block else None,
        )
    check_cells(cells)
    from valve_env.outputs import OutputError, atomic_write_text

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not (out / "grid.json").is_file() and not args.force:
        raise OutputError(f"--out {out} is not empty and holds no sweep (grid.json); use --force to sweep into it")
    import distributed  # noqa: F401  (ImportError here names the extra: pip install -e '.[rl]')

    ship_outs = None
    if args.ship_best:  # checked before the sweep: a shipped agent is replaced only with --force
        from agents.train import ZOO_DIR, ship_files
        from valve_env.outputs import OutputSet

        ship_outs = OutputSet(force=args.force)
        for env in envs:
            ship_outs.add_in_dir(ZOO_DIR / env, ship_files(args.ship_best), "--ship-best")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "command.txt", shlex.join(sys.argv) + "\n")
    stats = run_sweep(cells, out, scheduler=args.scheduler, workers=args.workers)
    print(json.dumps(stats))
    print(f"summary: {out / 'summary.md'}")
    if ship_outs is not None:
        from agents.train import ship

        best = best_cells(out)
        for env, rec in best.items():
            if env in envs:
                ship(rec["run_dir"], outs=ship_outs, name=args.ship_best, commit=False)
                print(f"[sweep] {env}: shipping {rec['cell']['key']} (evaluation return "
                      f"{rec['return']['mean']:.2f} on seeds {rec['eval']['seed']}+)", file=sys.stderr)
        missing = [e for e in envs if e not in best]
        if missing:
            print(f"thermovalve: error: no finished cell to ship for {', '.join(missing)}", file=sys.stderr)
            return 1
        ship_outs.commit()
        print(f"shipped: {ship_outs.summary()}")
    return 0 if stats.get("failed", 0) == 0 else 1


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.sweep", description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
