"""Standard algorithms from scratch on every current benchmark task: SB3 PPO, SAC and TD3 with the
hyperparameters of ``agents/configs/scratch/<algo>.yml`` (keyed by env id, one env-step budget for
all), several training seeds each, scored on held-out seeds and summarised the way RL benchmarks
report: the interquartile mean over training seeds with a 95 % stratified-bootstrap interval
(``rliable``). docs/agents.md, "From scratch".

    python -m agents.scratch train    [--algos ppo,sac,td3] [--tasks A,B] [--seeds 0,1,2] [--out out/scratch]
    python -m agents.scratch evaluate [--out out/scratch] [--episodes 5] [--seed 5000] [--oracle-cache ...]
    python -m agents.scratch curves   [--out out/scratch] [--figure docs/figures/curves_scratch.png]

``train`` runs ``python -m agents.train`` once per (algo, task, training seed), one process at a
time, into ``<out>/runs/<task>/<algo>_s<seed>/`` (its resolved ``config.yml``, ``command.txt``,
``run.json``, monitor CSVs and the best checkpoint on the evaluation seeds 10000+); a finished run
is skipped. ``evaluate`` loads each run's best checkpoint (agents.loader) and runs it on the held-out
seeds ``--seed .. --seed + episodes - 1`` beside the task's baselines (``pi``, ``self_acting``) and
the oracle's cached episodes (``thermovalve benchmark``'s ``episodes.csv``, else the tracked board's
``docs/task_episodes.csv``, which holds them on 5000-5004; without them it refuses), and writes:

* ``runs.csv`` / ``runs.json``: one row per run: algo, task, training seed, mean cost (= -return)
  over the held-out episodes, its gap score (0 = pi, 1 = oracle: valve_env.tasks.benchmark) and
  score (0 = self_acting, 1 = oracle), tdis_Kh, wall time;
* ``episodes.csv``: the per-episode rows they come from (the baselines' too);
* ``summary.csv`` / ``summary.md``: per (algo, task) the IQM of the gap score and of the cost over
  the training seeds with 95 % stratified-bootstrap intervals, and per algo the IQM of the gap
  score over all tasks (:func:`agents.rliable_summary.summarise`).

Training seeds: 0, 1, 2 (env i of a run starts on seed + i; the periodic evaluation that keeps the
best checkpoint uses seeds 10000+). Held-out evaluation seeds: 5000-5004, never run while training
or choosing anything.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

ALGOS: tuple[str, ...] = ("ppo", "sac", "td3")
TRAIN_SEEDS: tuple[int, ...] = (0, 1, 2)
EVAL_SEED = 5000
EVAL_EPISODES = 5
DEFAULT_OUT = Path("out") / "scratch"
#: the from-scratch hyperparameters (agents/configs/scratch/<algo>.yml)
CONFIG_DIR = Path(__file__).resolve().parent / "configs" / "scratch"
#: the tracked task board's episodes (thermovalve task-leaderboard --docs), which hold the oracle's episodes
#: on the held-out seeds 5000-5004: the last place ``evaluate`` looks for the oracle
BOARD_EPISODES = Path(__file__).resolve().parents[1] / "docs" / "task_episodes.csv"
ORACLE_CACHE = f"out/benchmark/episodes.csv,out/benchmark_*/episodes.csv,{BOARD_EPISODES}"
#: the baselines every run is scored against (the gap score needs pi, the score self_acting)
REFERENCES: tuple[str, ...] = ("pi", "self_acting")


def run_dir(out: str | Path, task: str, algo: str, seed: int) -> Path:
    return Path(out) / "runs" / task / f"{algo}_s{seed}"


def finished(d: Path) -> bool:
    p = d / "run.json"
    return p.is_file() and "finished_utc" in json.loads(p.read_text())


def train_command(algo: str, task: str, seed: int, out: str | Path, timesteps: int | None = None) -> list[str]:
    """The run's ``agents.train`` command; ``timesteps``: a budget in env steps other than the configs' (one for
    every run), evaluated every tenth of it."""
    budget = [] if timesteps is None else ["--timesteps", str(timesteps), "--eval-freq", str(timesteps // 10)]
    return [sys.executable, "-m", "agents.train", "--algo", algo, "--env", task, "--seed", str(seed),
            "--config-dir", str(CONFIG_DIR), "--out", str(run_dir(out, task, algo, seed)), "--no-progress",
            "--force", *budget]


def _children_cpu_s() -> float:
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def claim(d: Path) -> bool:
    """Claim run ``d`` for this process (``<d>.claim`` holding the pid, made atomically), so that two
    sweeps over the same runs share them out; a claim whose process is gone is taken over."""
    path = d.parent / f"{d.name}.claim"
    path.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            try:
                pid = int(path.read_text() or "0")
                os.kill(pid, 0)
                return pid == os.getpid()
            except (ValueError, ProcessLookupError):
                path.unlink(missing_ok=True)  # its process is gone
                continue
        with os.fdopen(fd, "w") as f:
            f.write(str(os.getpid()))
        return True
    return False


def train_all(algos: Sequence[str], tasks: Sequence[str], seeds: Sequence[int], out: str | Path,
              timesteps: int | None = None) -> int:
    """Every run not yet finished and not claimed by another sweep (:func:`claim`), one process at
    a time, seed-major (a cut-short sweep still has every algo and task on its first seeds)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    failed = 0
    for seed in seeds:
        for task in tasks:
            for algo in algos:
                d = run_dir(out, task, algo, seed)
                if finished(d) or not claim(d):
                    continue
                t0, c0 = time.perf_counter(), _children_cpu_s()
                rc = subprocess.call(train_command(algo, task, seed, out, timesteps), env=env)
                wall, cpu = time.perf_counter() - t0, _children_cpu_s() - c0
                if rc == 0:  # the process's wall and CPU time (on a shared machine the CPU time is the cost)
                    (d / "cost.json").write_text(json.dumps({"wall_s": round(wall, 1), "cpu_s": round(cpu, 1)}))
                print(f"[scratch] {task} {algo} seed {seed}: exit {rc}, {wall:.0f} s wall, {cpu:.0f} s CPU",
                      file=sys.stderr, flush=True)
                failed += rc != 0
    return 1 if failed else 0


def run_dirs(out: str | Path) -> list[tuple[str, str, int, Path]]:
    """(task, algo, seed, directory) of every finished run under ``<out>/runs``."""
    found = []
    for d in sorted((Path(out) / "runs").glob("*/*_s*")):
        if not finished(d):
            continue
        algo, _, s = d.name.rpartition("_s")
        if algo in ALGOS and s.isdigit():
            found.append((d.parent.name, algo, int(s), d))
    return found


def _episodes_cached(d: Path, task: str, algo: str, episodes: int, seed: int) -> Any:
    """The run's held-out episodes (its best checkpoint, agents.loader), kept in the run directory
    as ``heldout_<seed>x<episodes>.csv`` so a second summary does not rerun them."""
    import pandas as pd

    from agents.loader import load_agent
    from valve_env.evaluation.evaluator import run_episodes

    cache = d / f"heldout_{seed}x{episodes}.csv"
    if cache.is_file():
        return pd.read_csv(cache)
    df = run_episodes(load_agent(algo, task, run_dir=d), task, episodes, seed)
    tmp = cache.with_suffix(".tmp")
    df.to_csv(tmp, index=False)
    tmp.replace(cache)
    return df


def evaluate_runs(out: str | Path, episodes: int, seed: int, oracle: Mapping[str, Any]) -> tuple[Any, Any]:
    """(runs, episodes): one row per finished run with its held-out cost, gap score, score and
    training cost; the per-episode rows of the runs and of the references. ``oracle``: each run's task's
    oracle episodes on the same seeds (:func:`oracle_for`)."""
    import pandas as pd

    from agents.task_leaderboard import ORACLE
    from valve_env.controllers import make_controller
    from valve_env.evaluation.evaluator import run_episodes
    from valve_env.tasks.benchmark import gap_scores, normalised_scores

    seeds = list(range(seed, seed + episodes))
    rows, frames, refs = [], [], {}
    for task, algo, s, d in run_dirs(out):
        if task not in refs:
            refs[task] = {n: run_episodes(make_controller(n, task), task, episodes, seed) for n in REFERENCES}
            refs[task][ORACLE] = oracle[task]
            frames += [df.assign(task=task, controller=n, algo="", train_seed=-1) for n, df in refs[task].items()]
        df = _episodes_cached(d, task, algo, episodes, seed)
        frames.append(df.assign(task=task, controller=f"{algo}_s{s}", algo=algo, train_seed=s))
        cost = {n: float(-r["return"].mean()) for n, r in refs[task].items()}
        cost["run"] = float(-df["return"].mean())
        meta = json.loads((d / "run.json").read_text())
        spent = json.loads((d / "cost.json").read_text()) if (d / "cost.json").is_file() else {}
        row = {"algo": algo, "task": task, "seed": s, "cost": cost["run"],
               "gap_score": gap_scores(cost)["run"], "score": normalised_scores(cost)["run"],
               "tdis_Kh": float(df["tdis_Kh"].mean()), "pi_cost": cost["pi"],
               "oracle_cost": cost[ORACLE], "n_timesteps": int(meta["num_timesteps"]),
               # the checkpoint scored: 0 = the untrained policy (its mean action is the middle of the
               # setting's range, 60 degC) was the best on the evaluation seeds 10000+
               "best_checkpoint_step": (meta.get("best_eval") or {}).get("timesteps"),
               "train_wall_s": spent.get("wall_s", meta.get("wall_time_s")), "train_cpu_s": spent.get("cpu_s"),
               "eval_seeds": f"{seeds[0]}-{seeds[-1]}", "run_dir": str(d)}
        (d / "scores.json").write_text(json.dumps(row, indent=1) + "\n")  # the run's own score file
        rows.append(row)
        print(f"[scratch] {task} {algo} s{s}: cost {row['cost']:.4g}, gap score {row['gap_score']:.3g}",
              file=sys.stderr, flush=True)
    return pd.DataFrame(rows), (pd.concat(frames, ignore_index=True) if frames else pd.DataFrame())


def summary_markdown(runs: Any, summary: Any, meta: dict[str, Any]) -> str:
    from agents.rliable_summary import markdown

    lines = ["# From scratch: standard algorithms on the current benchmark tasks", "",
             f"Generated by `{meta['command']}`. SB3 PPO, SAC and TD3 with agents/configs/scratch/<algo>.yml "
             f"(no base law, no observation aids, no shaping), {meta['budget']} env steps per run on the native "
             f"VecEnv, training seeds {meta['train_seeds']}, scored on the held-out seeds {meta['eval_seeds']} "
             "(the run's best checkpoint on the evaluation seeds 10000+). Gap score 0 = pi, 1 = oracle; cost = "
             "-return. IQM over the training runs with 95 % stratified-bootstrap intervals (rliable).", ""]
    lines += markdown(summary)
    step0 = ", ".join(f"{a} {int((g['best_checkpoint_step'] == 0).sum())} of {len(g)}" for a, g in runs.groupby("algo"))
    lines += ["", f"Runs whose best checkpoint was the untrained policy (step 0; a constant setting of 60 degC): "
              f"{step0}."]
    lines += ["", f"Training: {len(runs)} runs, {meta['cpu_min']:.1f} CPU-minutes "
              f"({meta['wall_min']:.1f} min of run wall time summed over the runs: several at a time, nice -n 10, "
              "on a shared 2-core machine).",
              ""]
    return "\n".join(lines) + "\n"


def plot_curves(out: str | Path, path: Any) -> None:
    """Learning curves of the from-scratch runs, one panel per task: each run's deterministic evaluations
    on its evaluation seeds 10000+ (agents.curves.read_run: the policy at step 0, at the budget's middle
    and at its end), thin lines per training seed, the mean over the seeds per algo thick."""
    import numpy as np

    from agents.curves import read_run
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    runs = run_dirs(out)
    tasks = list(dict.fromkeys(t for t, _, _, _ in runs))
    fig, axes = plt.subplots(1, len(tasks), figsize=(3.6 * len(tasks), 3.3), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for i, algo in enumerate(ALGOS):
            curves = [read_run(d)["evals"] for t, a, _, d in runs if t == task and a == algo]
            curves = [c for c in curves if c is not None]
            for steps, ret in curves:
                ax.plot(steps / 1e3, ret, color=f"C{i}", alpha=0.3, lw=0.8)
            if curves:
                n = min(len(c[0]) for c in curves)
                mean = np.mean([c[1][:n] for c in curves], axis=0)
                ax.plot(curves[0][0][:n] / 1e3, mean, "o-", color=f"C{i}", label=f"{algo} ({len(curves)} seeds)")
        ax.set_yscale("symlog", linthresh=1.0)  # returns from -1 to -10000 on one axis
        ax.set_title(task.replace("ThermoValve", ""), fontsize=8)
        ax.set_xlabel("env steps (thousands)", fontsize=7)
        ax.set_ylabel("evaluation return (seeds 10000+, symlog)", fontsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, path, format="png")


def main(argv: Sequence[str] | None = None) -> int:
    import valve_env

    p = argparse.ArgumentParser(prog="python -m agents.scratch", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train", help="train every (algo, task, seed) not yet finished")
    t.add_argument("--algos", default=",".join(ALGOS))
    t.add_argument("--tasks", default=",".join(valve_env.CURRENT_TASK_IDS))
    t.add_argument("--seeds", default=",".join(map(str, TRAIN_SEEDS)))
    t.add_argument("--out", default=str(DEFAULT_OUT))
    t.add_argument("--timesteps", type=int, default=None,
                   help="every run's budget in env steps instead of the configs' (evaluation every tenth of it)")
    e = sub.add_parser("evaluate", help="score every finished run on the held-out seeds; write the summary")
    e.add_argument("--out", default=str(DEFAULT_OUT))
    e.add_argument("--episodes", type=int, default=EVAL_EPISODES)
    e.add_argument("--seed", type=int, default=EVAL_SEED)
    e.add_argument("--oracle-cache", default=ORACLE_CACHE,
                   help="where the oracle's held-out episodes are read from: thermovalve benchmark's episodes.csv "
                        "files (globs), then the tracked board's docs/task_episodes.csv")
    e.add_argument("--force", action="store_true", help="replace an earlier summary")
    c = sub.add_parser("curves", help="the learning curves of the runs (one figure, a panel per task)")
    c.add_argument("--out", default=str(DEFAULT_OUT))
    c.add_argument("--figure", default=None, help="the figure's path (default <out>/curves_scratch.png)")
    c.add_argument("--force", action="store_true")
    args = p.parse_args(argv)
    if args.cmd == "evaluate":
        return evaluate_main(args)
    if args.cmd == "curves":
        from valve_env.outputs import OutputError, OutputSet

        try:
            if not run_dirs(args.out):
                raise ValueError(f"no finished run under {Path(args.out) / 'runs'}")
            outs = OutputSet(force=args.force)
            fig = outs.add(args.figure or Path(args.out) / "curves_scratch.png")
        except (ValueError, OutputError) as exc:
            print(f"python -m agents.scratch: error: {exc}", file=sys.stderr)
            return 2
        outs.stage(fig, lambda tmp: plot_curves(args.out, tmp))
        outs.commit()
        print(outs.summary())
        return 0
    try:
        algos = [a for a in args.algos.split(",") if a]
        tasks = [x for x in args.tasks.split(",") if x]
        seeds = [int(s) for s in args.seeds.split(",") if s]
        for a in algos:
            if a not in ALGOS:
                raise ValueError(f"unknown algo {a!r}; choose from {', '.join(ALGOS)}")
        for x in tasks:
            if x not in valve_env.CURRENT_TASK_IDS:
                raise ValueError(f"{x!r} is not a current task; current: {', '.join(valve_env.CURRENT_TASK_IDS)}")
        if args.timesteps is not None and args.timesteps < 10:
            raise ValueError(f"--timesteps must be at least 10 env steps, got {args.timesteps}")
    except ValueError as exc:
        print(f"python -m agents.scratch: error: {exc}", file=sys.stderr)
        return 2
    return train_all(algos, tasks, seeds, args.out, args.timesteps)


def oracle_for(cache: Sequence[str], tasks: Sequence[str], seeds: Sequence[int]) -> dict[str, Any]:
    """Each task's oracle episodes on exactly ``seeds``, read once from the cache; refused (ValueError, one line)
    before any episode runs where a task has none: without them every gap score and score is NaN."""
    from agents.task_leaderboard import oracle_episodes

    found = {t: oracle_episodes(cache, t, seeds) for t in tasks}
    lacking = [t for t, df in found.items() if df is None]
    if lacking:
        raise ValueError(f"no oracle episodes on seeds {seeds[0]}-{seeds[-1]} for {', '.join(lacking)} in "
                         f"--oracle-cache {','.join(cache)}: run thermovalve benchmark --controllers oracle "
                         f"--episodes {len(seeds)} --seed {seeds[0]} --out out/benchmark_oracle (its episodes.csv "
                         "is then found)")
    return found


def evaluate_main(args: argparse.Namespace) -> int:
    import shlex

    from agents.rliable_summary import summarise
    from valve_env.outputs import OutputError, OutputSet

    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        found = run_dirs(args.out)
        if not found:
            raise ValueError(f"no finished run under {Path(args.out) / 'runs'} (python -m agents.scratch train)")
        oracle = oracle_for([c for c in args.oracle_cache.split(",") if c], sorted({task for task, *_ in found}),
                            list(range(args.seed, args.seed + args.episodes)))
        outs = OutputSet(force=args.force)
        names = ("runs.csv", "runs.json", "episodes.csv", "summary.csv", "summary.md")
        paths = dict(zip(names, outs.add_in_dir(args.out, names), strict=True))
    except (ValueError, OutputError) as exc:
        print(f"python -m agents.scratch: error: {exc}", file=sys.stderr)
        return 2
    runs, episodes = evaluate_runs(args.out, args.episodes, args.seed, oracle)
    summary = summarise(runs)
    meta = {"command": "python -m agents.scratch " + shlex.join(sys.argv[1:]),
            "budget": int(runs["n_timesteps"].max()), "train_seeds": ", ".join(map(str, sorted(runs["seed"].unique()))),
            "eval_seeds": f"{args.seed}-{args.seed + args.episodes - 1}",
            "cpu_min": float(runs["train_cpu_s"].fillna(0).sum()) / 60.0,
            "wall_min": float(runs["train_wall_s"].fillna(0).sum()) / 60.0}
    outs.stage(paths["runs.csv"], lambda tmp: runs.to_csv(tmp, index=False))
    outs.write_text(paths["runs.json"], json.dumps({"meta": meta, "runs": json.loads(runs.to_json(orient="records"))},
                                                   indent=1) + "\n")
    outs.stage(paths["episodes.csv"], lambda tmp: episodes.to_csv(tmp, index=False))
    outs.stage(paths["summary.csv"], lambda tmp: summary.to_csv(tmp, index=False))
    text = summary_markdown(runs, summary, meta)
    outs.write_text(paths["summary.md"], text)
    outs.commit()
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
