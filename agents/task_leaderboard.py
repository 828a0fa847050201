"""The benchmark tasks' leaderboard: shipped agents against every baseline and the oracle, on
held-out seeds, with the normalised score of ``thermovalve benchmark``.

    thermovalve task-leaderboard [--tasks A,B] [--episodes 10] [--seed 5000] [--scratch out/scratch]
                                 [--oracle-cache out/benchmark/episodes.csv] [--out out/task_leaderboard]
    thermovalve task-leaderboard --docs --force      # regenerate the tracked docs/task_leaderboard.*
    python -m agents.task_leaderboard ...

Per task (default: every current benchmark task, valve_env.CURRENT_TASK_IDS, with a shipped agent in
agents/zoo/<task>/; a superseded task's agent, or an original environment's (ThermoValve-v0, ...), only
when its id is named in --tasks):

* every built-in non-oracle controller (the baselines and compensators that apply to the task),
  each shipped agent and, for a residual agent, its base law alone (``<agent>_base_law``: the
  same controller with the policy off), on the episodes seeded ``--seed .. --seed + episodes - 1``
  (5000-5009 by default: the benchmark's held-out seeds; an agent's own training and checkpoint
  seeds are in its yml: PPO's updates use seeds 0 .. n_envs - 1 and their autoresets and select on
  10000+, CEM the run's seed onwards and its seed + 10000 onwards, never 1000-1009 or 5000-5009);
* the oracle's per-episode results are read from ``--oracle-cache`` (the ``episodes.csv`` of
  ``thermovalve benchmark`` runs, by default out/benchmark/ and out/benchmark_*/; its oracle
  takes 20-300 s per episode), never recomputed here; without them the scores are n/a;
* cost = -return, score = (cost_self_acting - cost) / (cost_self_acting - cost_oracle) on the
  mean costs (valve_env.tasks.benchmark.normalised_scores: 0 = self_acting, 1 = oracle);
* the goal check per agent: the best non-oracle baseline (its own base law included), the share
  of that baseline's gap to the oracle the agent closes, the learned share (the agent's score
  minus its base law's: what the learning adds), paired wins, tdis_Kh against ``pi``'s, wear;
* a generalisation table: each agent run on the other tasks with the same action (observation
  aids computed from the deployment task's scenario), scored with that task's references;
* with ``--scratch DIR`` (the directory of ``python -m agents.scratch``): the standard algorithms
  trained from scratch, from the per-run scores stored in ``DIR/runs.csv`` (scored on the same
  held-out seeds, checked), as the interquartile mean over training seeds with 95 %
  stratified-bootstrap intervals of the gap score (0 = pi, 1 = oracle) and of the cost
  (agents.rliable_summary), beside the engineered agents' rows (gap score with the benchmark's paired
  bootstrap interval over the episodes; what is hand-written named), and a figure of both
  (``figures/task_leaderboard_scratch.png``).

Writes ``task_leaderboard.md``, ``task_leaderboard.json``, ``task_episodes.csv``,
``figures/task_leaderboard.png`` (and with ``--scratch`` ``figures/task_leaderboard_scratch.png``)
into ``--out`` (default out/task_leaderboard; ``--docs``: the tracked docs/), all together and
atomically; existing files are replaced only with ``--force``.
docs/agents.md, "The benchmark tasks".
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from agents.leaderboard import TDIS_TOL_KH

#: the episodes.csv files of ``thermovalve benchmark`` runs (glob patterns; the first with all seeds wins)
DEFAULT_CACHE = "out/benchmark/episodes.csv,out/benchmark_*/episodes.csv"
ORACLE = "oracle"
SELF_ACTING = "self_acting"
REFERENCE = "pi"
#: the goal: the best agent closes at least this share of the best baseline's gap to the oracle
GAP_GOAL = 0.5
KPI_COLUMNS: tuple[str, ...] = ("tdis_Kh", "iae_Kh", "rmse_K", "heat_kWh", "reversals", "travel_mm", "cost_eur")


def task_controllers(task: str, zoo: str | Path | None = None, deploy_on: str | None = None) -> dict[str, Any]:
    """name -> controller: the non-oracle built-ins for ``task`` (none when ``deploy_on`` is given),
    the shipped agents of ``task`` and their base laws. With ``deploy_on`` the agents of ``task``
    are built to run on that task instead (the generalisation table)."""
    from agents.loader import available_agents, load_agent
    from valve_env.controllers import make_controller
    from valve_env.tasks.benchmark import known_controllers

    out: dict[str, Any] = {}
    if deploy_on is None:
        for name in known_controllers(task):
            if name != ORACLE:
                out[name] = make_controller(name, task)
    for name in available_agents(task, zoo):
        ctrl = load_agent(name, task, zoo=zoo, deploy_on=deploy_on)
        out[name] = ctrl
        if ctrl.residual is not None:
            out[f"{name}_base_law"] = ctrl.base_law()
    return out


CACHE_COLUMNS = ("task", "controller", "seed", "return")


def cache_files(cache: Sequence[str | Path]) -> list[Path]:
    """The oracle cache's files that exist (glob patterns expanded, sorted), each checked to be an
    ``episodes.csv`` of ``thermovalve benchmark`` (its header): a file that is not is named (ValueError)."""
    import glob

    files = [Path(f) for pattern in cache for f in (sorted(glob.glob(str(pattern))) or [str(pattern)])]
    out = []
    for p in files:
        if not p.is_file():
            continue
        try:
            columns = set(pd.read_csv(p, nrows=0).columns)
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
            raise ValueError(f"--oracle-cache {p}: not a CSV file ({str(exc).splitlines()[0]})") from None
        if not set(CACHE_COLUMNS) <= columns:
            raise ValueError(f"--oracle-cache {p}: not an episodes.csv of thermovalve benchmark "
                             f"(needs {', '.join(CACHE_COLUMNS)})")
        out.append(p)
    return out


def _stored_episodes(files: Sequence[str | Path], task: str, controller: str,
                     seeds: Sequence[int]) -> pd.DataFrame | None:
    """``controller``'s rows for ``task`` and exactly ``seeds`` (the last row of a seed stored twice) from
    the first of ``files`` that has them all, or None."""
    for p in files:
        df = pd.read_csv(p)
        sub = df[(df["task"] == task) & (df["controller"] == controller) & df["seed"].isin(list(seeds))]
        sub = sub.drop_duplicates("seed", keep="last")
        if len(sub) == len(seeds):
            return sub.drop(columns=["task", "controller"]).sort_values("seed").reset_index(drop=True)
    return None


def oracle_episodes(cache: Sequence[str | Path], task: str, seeds: Sequence[int]) -> pd.DataFrame | None:
    """The oracle's rows for ``task`` and exactly ``seeds`` from the first cache file (glob patterns
    expanded, sorted) that has them all."""
    return _stored_episodes(cache_files(cache), task, ORACLE, seeds)


def reused_episodes(reuse: Sequence[str | Path], task: str, name: str, seeds: Sequence[int]) -> pd.DataFrame | None:
    """A built-in controller's rows for ``task`` and exactly ``seeds`` from an earlier board's
    ``task_episodes.csv`` (``--reuse``), or None."""
    return _stored_episodes(reuse, task, name, seeds)


def run_task(task: str, controllers: Mapping[str, Any], episodes: int, seed: int,
             reuse: Sequence[str | Path] = (), builtin: Sequence[str] = ()) -> dict[str, pd.DataFrame]:
    """Each controller's episodes; a built-in one's (``builtin``: not an agent or a base law) are taken
    from ``reuse`` (earlier boards' task_episodes.csv) when they hold the same task and seeds."""
    from valve_env.evaluation.evaluator import run_episodes

    out = {}
    seeds = list(range(seed, seed + episodes))
    for name, ctrl in controllers.items():
        if name in builtin and (old := reused_episodes(reuse, task, name, seeds)) is not None:
            out[name] = old
            print(f"[task-leaderboard] {task} {name}: reused", file=sys.stderr, flush=True)
            continue
        t0 = time.perf_counter()
        out[name] = run_episodes(ctrl, task, episodes, seed)
        print(f"[task-leaderboard] {task} {name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return out


def kind_of(name: str, agents: Sequence[str]) -> str:
    if name == ORACLE:
        return "oracle"
    if name.endswith("_base_law"):
        return "base law"
    return "agent" if name in agents else "baseline"


def summary_table(per_ep: Mapping[str, pd.DataFrame], agents: Sequence[str]) -> pd.DataFrame:
    """One row per controller: cost (mean, std), the normalised score and the KPI means."""
    from valve_env.tasks.benchmark import normalised_scores

    rows = []
    for name, df in per_ep.items():
        cost = -df["return"].to_numpy(float)
        row: dict[str, Any] = {"controller": name, "kind": kind_of(name, agents),
                               "cost": float(cost.mean()), "cost_std": float(cost.std())}
        for k in KPI_COLUMNS:
            if k in df.columns:
                row[k] = float(df[k].mean())
        rows.append(row)
    table = pd.DataFrame(rows)
    scores = normalised_scores(dict(zip(table["controller"], table["cost"], strict=True)))
    table["score"] = table["controller"].map(scores)
    return table.sort_values("cost").reset_index(drop=True)


def goal_check(per_ep: Mapping[str, pd.DataFrame], table: pd.DataFrame, agent: str) -> dict[str, Any]:
    """The issue's learning goal for one agent (see the module docstring): every non-oracle
    baseline and every agent's base law (not the other agents) is a baseline."""
    cost = dict(zip(table["controller"], table["cost"], strict=True))
    score = dict(zip(table["controller"], table["score"], strict=True))
    kinds = dict(zip(table["controller"], table["kind"], strict=True))
    base = {c: v for c, v in cost.items() if kinds[c] in ("baseline", "base law")}
    best = min(base, key=base.__getitem__)
    law = f"{agent}_base_law"
    out: dict[str, Any] = {"agent": agent, "best_baseline": best, "best_baseline_cost": base[best],
                           "agent_cost": cost[agent]}
    oracle = cost.get(ORACLE, math.nan)
    gap = base[best] - oracle
    out["oracle_cost"] = oracle
    out["gap_closed"] = (base[best] - cost[agent]) / gap if math.isfinite(gap) and gap > 0 else math.nan
    a = per_ep[agent].set_index("seed").sort_index()
    if law in per_ep:
        b = per_ep[law].set_index("seed").sort_index()
        d = (a["return"] - b["return"]).to_numpy(float)
        out["base_law_cost"] = cost[law]
        out["learned_score"] = score[agent] - score[law]  # normalised-score points learning adds
        out["learned_cost"] = cost[law] - cost[agent]
        out["learned_wins"] = int(np.sum(d > 0))
        out["learned_share_of_gap"] = (cost[law] - cost[agent]) / gap if math.isfinite(gap) and gap > 0 else math.nan
    bb = per_ep[best].set_index("seed").sort_index()
    out["wins_vs_best_baseline"] = int(np.sum((a["return"] - bb["return"]).to_numpy(float) > 0))
    out["n"] = len(a)
    if REFERENCE in per_ep:
        out["tdis_Kh"] = float(a["tdis_Kh"].mean())
        out["tdis_Kh_pi"] = float(per_ep[REFERENCE]["tdis_Kh"].mean())
        out["tdis_ok"] = bool(out["tdis_Kh"] <= out["tdis_Kh_pi"] + TDIS_TOL_KH)
        out["reversals_ratio_pi"] = float(a["reversals"].mean() / max(per_ep[REFERENCE]["reversals"].mean(), 1e-9))
    out["goal_met"] = bool(out.get("gap_closed", math.nan) >= GAP_GOAL and out.get("tdis_ok", False))
    return out


def hand_written(cfg: Mapping[str, Any]) -> str:
    """What of an agent's controller is written by hand (its config): the base law of the residual
    and its rules, the observation aids, the frame stack; and how the rest was found."""
    parts = []
    res = cfg.get("residual") or {}
    if res:
        gains = [float(g) for g in (*(res.get("kp") or []), *(res.get("ki") or []))]
        law = (f"base law: PI kp {res.get('kp')} K/K, ki {res.get('ki')} K/(K h) around {res.get('center')}"
               if any(gains) else f"base law: a constant setting {res.get('center')} degC, no PI")
        law += f", residual span +-{res.get('span')}"
        if res.get("kff"):
            law += f", draw feedforward {res['kff']} K per l/min"
        if res.get("shut_band") is not None:
            law += f", shut_band rule {res['shut_band']} K"
        parts.append(law)
    else:
        parts.append("no base law")
    aids = sorted((cfg.get("obs_aids") or {}).keys())
    if aids:
        parts.append("observation aids " + ", ".join(aids))
    if int(cfg.get("frame_stack", 1) or 1) > 1:
        parts.append(f"frame stack {cfg['frame_stack']}")
    search = "CEM on a linear action head" if cfg.get("optimizer") == "cem" else f"{cfg.get('algo', '?')} updates"
    cem = cfg.get("cem") or {}
    if cem.get("init"):
        init = str(cem["init"])
        search += (f", warm-started from {init[init.index('agents/zoo/') + len('agents/zoo/'):]}"
                   if "agents/zoo/" in init else ", warm-started from an earlier run (its yml's warm_start chain)")
    parts.append(f"learned: {search}")
    return "; ".join(parts)


def scratch_rows(runs: pd.DataFrame, seeds: Sequence[int]) -> pd.DataFrame:
    """The rliable summary of the from-scratch runs (agents.rliable_summary.summarise) after checking
    that they were scored on ``seeds``."""
    from agents.rliable_summary import summarise

    want = f"{seeds[0]}-{seeds[-1]}"
    got = sorted(set(runs["eval_seeds"].astype(str)))
    if got != [want]:
        raise ValueError(f"--scratch runs were scored on seeds {', '.join(got)}, the leaderboard on {want}: "
                         f"python -m agents.scratch evaluate --seed {seeds[0]} --episodes {len(seeds)}")
    return summarise(runs)


def engineered_rows(boards: Mapping[str, Any], zoo: str | Path | None = None) -> list[dict[str, Any]]:
    """Per task and shipped agent: its gap score (0 = pi, 1 = oracle) with the benchmark's paired
    bootstrap interval over the held-out episodes, its cost, and what is hand-written."""
    import yaml

    from agents.loader import agent_files
    from valve_env.tasks.benchmark import gap_score_ci, gap_scores

    out = []
    for task, b in boards.items():
        per_ep = b["per_episode"]
        cost = dict(zip(b["table"]["controller"], b["table"]["cost"], strict=True))
        gs, sc = gap_scores(cost), dict(zip(b["table"]["controller"], b["table"]["score"], strict=True))
        per_seed = {n: dict(zip(df["seed"].astype(int), -df["return"].astype(float), strict=True))
                    for n, df in per_ep.items()}
        for g in b["goals"]:
            name = g["agent"]
            ci = gap_score_ci({k: per_seed[k] for k in (name, REFERENCE, ORACLE) if k in per_seed})[name] \
                if ORACLE in per_seed and REFERENCE in per_seed else (math.nan, math.nan)
            cfg = yaml.safe_load(agent_files(name, task, zoo)[1].read_text())
            out.append({"task": task, "agent": name, "gap_score": gs.get(name, math.nan), "gap_score_lo": ci[0],
                        "gap_score_hi": ci[1], "score": sc[name], "cost": cost[name],
                        "hand_written": hand_written(cfg)})
    return out


def scratch_markdown(summary: pd.DataFrame, eng: Sequence[Mapping[str, Any]], meta: Mapping[str, Any]) -> list[str]:
    lines = ["## From scratch against engineered agents", "",
             f"From scratch: SB3 PPO, SAC and TD3 with agents/configs/scratch/<algo>.yml (no base law, no "
             f"observation aids, no reward shaping; VecNormalize), {meta['scratch_budget']} env steps per run on "
             f"the native VecEnv, training seeds {meta['scratch_train_seeds']}; each run's best checkpoint "
             "(periodic evaluation on seeds 10000+) scored on the held-out seeds above; per-run scores in "
             f"{meta['scratch']}/runs.csv (`python -m agents.scratch`). IQM over the training runs with 95 % "
             "stratified-bootstrap intervals (rliable). Gap score 0 = pi, 1 = oracle; score 0 = self_acting, "
             f"1 = oracle; cost = -return. Training: {meta['scratch_runs']} runs, "
             f"{meta['scratch_cpu_min']:.0f} CPU-minutes, "
             f"{meta['scratch_wall_min']:.0f} min of run wall time summed over the runs (several at a time, "
             "nice -n 10, on a shared 2-core machine).", "",
             "| task | controller | runs | gap score IQM [95 % CI] | score IQM [95 % CI] | cost IQM [95 % CI] |",
             "|---|---|---:|---:|---:|---:|"]
    tasks = list(dict.fromkeys([*(e["task"] for e in eng), *summary["task"]]))
    for task in tasks:
        for _, r in summary[summary["task"] == task].iterrows():
            cells = [f"{_f(r[f'{m}_iqm'])} [{_f(r[f'{m}_lo'])}, {_f(r[f'{m}_hi'])}]"
                     if f"{m}_iqm" in r and math.isfinite(r[f"{m}_iqm"]) else "n/a"
                     for m in ("gap_score", "score", "cost")]
            lines.append(f"| {task} | {r['algo']} from scratch | {int(r['n_runs'])} | " + " | ".join(cells) + " |")
        for e in (e for e in eng if e["task"] == task):
            lines.append(f"| {task} | **{e['agent']}** engineered ({e['hand_written']}) | 1 shipped | "
                         f"{_f(e['gap_score'])} [{_f(e['gap_score_lo'])}, {_f(e['gap_score_hi'])}] (over episodes) | "
                         f"{_f(e['score'])} | {_f(e['cost'])} |")
    if meta.get("scratch_step0"):
        lines += ["", "Runs whose best checkpoint on the evaluation seeds was the untrained policy (step 0: its mean "
                  "action is the middle of the setting's range, 60 degC, a constant setting): "
                  f"{meta['scratch_step0']}."]
    lines += ["", "An engineered agent is one shipped run: its interval is the benchmark's paired bootstrap over "
              "the held-out episodes (valve_env.tasks.benchmark.gap_score_ci), not a spread over training seeds.", ""]
    return lines


def plot_scratch(summary: pd.DataFrame, eng: Sequence[Mapping[str, Any]], path: Any) -> None:
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    per_task = summary[summary["task"] != "all tasks"]
    tasks = list(dict.fromkeys([*per_task["task"], *(e["task"] for e in eng)]))
    fig, axes = plt.subplots(1, len(tasks), figsize=(3.6 * len(tasks), 3.4), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        labels, mid, lo, hi, colours = [], [], [], [], []
        for _, r in per_task[per_task["task"] == task].iterrows():
            labels.append(f"{r['algo']} ({int(r['n_runs'])} runs)")
            mid.append(r["gap_score_iqm"])
            lo.append(r["gap_score_lo"])
            hi.append(r["gap_score_hi"])
            colours.append("tab:blue")
        for e in (e for e in eng if e["task"] == task):
            labels.append(f"{e['agent']} (engineered)")
            mid.append(e["gap_score"])
            lo.append(e["gap_score_lo"])
            hi.append(e["gap_score_hi"])
            colours.append("tab:red")
        y = np.arange(len(labels))
        m, lo_, hi_ = (np.asarray(v, float) for v in (mid, lo, hi))
        err = np.vstack([np.nan_to_num(m - lo_), np.nan_to_num(hi_ - m)])
        ax.errorbar(m, y, xerr=err, fmt="none", ecolor="k", capsize=3)
        ax.scatter(m, y, c=colours, zorder=3)
        ax.axvline(0.0, color="0.5", lw=0.8)
        ax.axvline(1.0, color="tab:green", lw=0.8)
        ax.set_yticks(y, labels, fontsize=7)
        ax.invert_yaxis()
        ax.set_title(task.replace("ThermoValve", ""), fontsize=8)
        ax.set_xlabel("gap score (0 = pi, 1 = oracle; symlog): IQM, 95 % CI", fontsize=7)
        ax.set_xscale("symlog", linthresh=1.0)  # from-scratch runs can be thousands of pi's gaps behind
    fig.tight_layout()
    save_figure(fig, path, format="png")


def _f(v: Any, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return f"{v:.{digits}g}" if abs(v) < 1000 else f"{v:.0f}"


def _pct(v: float) -> str:
    return "n/a" if not math.isfinite(v) else f"{100 * v:.1f} %"


def markdown(boards: Mapping[str, Any], gen: Sequence[Mapping[str, Any]], meta: Mapping[str, Any],
             scratch: tuple[pd.DataFrame, Sequence[Mapping[str, Any]]] | None = None) -> str:
    lines = ["# Benchmark tasks: agents against the baselines and the oracle", "",
             f"Generated by `{meta['command']}`. Held-out seeds {meta['seeds'][0]}-{meta['seeds'][1]} "
             "(a shipped agent's training and checkpoint seeds are in its yml, `shipped_from` and `warm_start`; "
             "PPO's updates train on seeds 0 .. n_envs - 1 and select on 10000+, CEM on the run's seed onwards and "
             "its seed + 10000 onwards, and refuses 1000-1009 and 5000-5009). "
             "cost = -return (mean over the episodes); score 0 = self_acting, 1 = oracle "
             "(`thermovalve benchmark`'s normalisation, on the mean costs); the oracle's episodes come from "
             f"the cache {', '.join(meta['oracle_cache'])} (`thermovalve benchmark`).", ""]
    for task, b in boards.items():
        t: pd.DataFrame = b["table"]
        kpis = [k for k in KPI_COLUMNS if k in t.columns and t[k].notna().any()]
        lines += [f"## {task}", "", "| controller | kind | cost | score | " + " | ".join(kpis) + " |",
                  "|---|---|---:|---:|" + "---:|" * len(kpis)]
        for _, r in t.iterrows():
            name = f"**{r['controller']}**" if r["kind"] == "agent" else r["controller"]
            lines.append(f"| {name} | {r['kind']} | {_f(r['cost'])} ± {_f(r['cost_std'], 2)} | {_f(r['score'])} | "
                         + " | ".join(_f(r[k]) for k in kpis) + " |")
        if not b["oracle"]:
            lines += ["", f"No oracle episodes for {task} in the cache: scores n/a "
                      f"(`thermovalve benchmark --tasks {task} --controllers oracle`)."]
        lines += ["", "| agent | best baseline (cost) | agent cost | gap closed | learned: score points (cost, "
                  "wins vs base law) | wins vs best baseline | tdis_Kh agent / pi | reversals / pi | goal met |",
                  "|---|---|---:|---:|---:|---:|---:|---:|:---:|"]
        for g in b["goals"]:
            learned = (f"{_f(g.get('learned_score'))} ({_f(g.get('learned_cost'))}, {g.get('learned_wins', 'n/a')}/"
                       f"{g['n']})" if "learned_score" in g else "n/a (no base law)")
            lines.append(f"| {g['agent']} | {g['best_baseline']} ({_f(g['best_baseline_cost'])}) | "
                         f"{_f(g['agent_cost'])} | {_pct(g['gap_closed'])} | {learned} | "
                         f"{g['wins_vs_best_baseline']}/{g['n']} | "
                         f"{_f(g.get('tdis_Kh'))} / {_f(g.get('tdis_Kh_pi'))} | "
                         f"{_f(g.get('reversals_ratio_pi'), 2)}x | {'yes' if g['goal_met'] else 'no'} |")
        lines += ["", "Goal: gap closed >= 50 % of the best non-oracle baseline's gap to the oracle "
                  "(the agent's own base law counts as a baseline), with tdis_Kh no worse than pi's "
                  f"(+{TDIS_TOL_KH} K h). Learned = the agent's score minus its base law's.", ""]
    if scratch is not None:
        lines += scratch_markdown(scratch[0], scratch[1], meta)
    if gen:
        lines += ["## Generalisation: each agent on the tasks it was not trained on", "",
                  "| agent (trained on) | task | cost | score | pi cost | best baseline (cost) | tdis_Kh | reversals |",
                  "|---|---|---:|---:|---:|---|---:|---:|"]
        for g in gen:
            lines.append(f"| {g['agent']} ({g['trained_on']}) | {g['task']} | {_f(g['cost'])} | {_f(g['score'])} | "
                         f"{_f(g['pi_cost'])} | {g['best_baseline']} ({_f(g['best_baseline_cost'])}) | "
                         f"{_f(g['tdis_Kh'])} | {_f(g['reversals'])} |")
        lines.append("")
    return "\n".join(lines) + "\n"


def plot(boards: Mapping[str, Any], path: Any) -> None:
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    tasks = list(boards)
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.0 * len(tasks), 4.2), squeeze=False)
    colours = {"agent": "tab:red", "base law": "tab:orange", "baseline": "tab:blue", "oracle": "tab:green"}
    for ax, task in zip(axes[0], tasks, strict=True):
        t = boards[task]["table"]
        y = np.arange(len(t))
        ax.barh(y, t["cost"], xerr=t["cost_std"], color=[colours[k] for k in t["kind"]], alpha=0.85)
        ax.set_yticks(y, t["controller"], fontsize=7)
        ax.invert_yaxis()
        for yi, (c, s) in enumerate(zip(t["cost"], t["score"], strict=True)):
            if math.isfinite(s):
                ax.annotate(f"{s:.2f}", (c, yi), xytext=(3, 0), textcoords="offset points", va="center", fontsize=7)
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("cost = -return (normalised score at the bar)")
    fig.tight_layout()
    save_figure(fig, path, format="png")


def build(tasks: Sequence[str], episodes: int, seed: int, cache: Sequence[str], zoo: str | Path | None = None,
          generalisation: bool = True, reuse: Sequence[str | Path] = ()
          ) -> tuple[dict[str, Any], list[dict[str, Any]], pd.DataFrame]:
    from agents.loader import available_agents
    from valve_env.tasks import CURRENT_TASK_IDS
    from valve_env.tasks.benchmark import known_controllers

    seeds = list(range(seed, seed + episodes))
    boards: dict[str, Any] = {}
    frames = []
    for task in tasks:
        per_ep = run_task(task, task_controllers(task, zoo), episodes, seed, reuse, known_controllers(task))
        orc = oracle_episodes(cache, task, seeds)
        if orc is not None:
            per_ep[ORACLE] = orc
        agents = available_agents(task, zoo)
        table = summary_table(per_ep, agents)
        boards[task] = {"table": table, "oracle": orc is not None,
                        "goals": [goal_check(per_ep, table, a) for a in agents], "per_episode": per_ep}
        frames += [df.assign(task=task, controller=name) for name, df in per_ep.items()]
    gen: list[dict[str, Any]] = []
    if generalisation:
        for train_task in tasks:
            for other in CURRENT_TASK_IDS:  # a superseded task is no deployment target
                if other == train_task:
                    continue
                try:
                    ctrls = task_controllers(train_task, zoo, deploy_on=other)
                except ValueError as exc:  # another action or observation: not applicable
                    print(f"[task-leaderboard] {train_task} agents on {other}: n/a ({exc})", file=sys.stderr)
                    continue
                ctrls = {n: c for n, c in ctrls.items() if not n.endswith("_base_law")}
                refs = boards[other]["per_episode"] if other in boards else run_task(
                    other, task_controllers(other, zoo), episodes, seed)
                if other not in boards:
                    orc = oracle_episodes(cache, other, seeds)
                    if orc is not None:
                        refs[ORACLE] = orc
                ref_table = summary_table({n: d for n, d in refs.items() if kind_of(n, []) != "agent"
                                           and n not in available_agents(other, zoo)}, [])
                per_ep = run_task(other, ctrls, episodes, seed)
                frames += [df.assign(task=other, controller=f"{n}@{train_task}") for n, df in per_ep.items()]
                for name, df in per_ep.items():
                    t = summary_table({**{n: refs[n] for n in ref_table["controller"]}, name: df}, [name])
                    row = t[t["controller"] == name].iloc[0]
                    base = ref_table[ref_table["kind"].isin(["baseline"])]
                    best = base.iloc[int(np.argmin(base["cost"].to_numpy()))]
                    gen.append({"agent": name, "trained_on": train_task, "task": other, "cost": float(row["cost"]),
                                "score": float(row["score"]),
                                "pi_cost": float(ref_table.loc[ref_table["controller"] == REFERENCE, "cost"].iloc[0]),
                                "best_baseline": str(best["controller"]), "best_baseline_cost": float(best["cost"]),
                                "tdis_Kh": float(row["tdis_Kh"]), "reversals": float(row["reversals"])})
    return boards, gen, pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _json(boards: Mapping[str, Any], gen: Sequence[Mapping[str, Any]], meta: Mapping[str, Any],
          scratch: tuple[pd.DataFrame, Sequence[Mapping[str, Any]]] | None = None) -> str:
    def clean(v: Any) -> Any:
        if isinstance(v, Mapping):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, (np.floating, np.integer, np.bool_)):
            v = v.item()
        if isinstance(v, float) and not math.isfinite(v):
            return None
        return v

    data = {"meta": meta, "tasks": {t: {"table": b["table"].to_dict(orient="records"), "goals": b["goals"],
                                         "oracle": b["oracle"]} for t, b in boards.items()},
            "generalisation": list(gen)}
    if scratch is not None:
        data["scratch"] = {"summary": scratch[0].to_dict(orient="records"), "engineered": list(scratch[1])}
    return json.dumps(clean(data), indent=1) + "\n"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from valve_env.tasks.benchmark import HELD_OUT_SEED

    p.add_argument("--tasks", default=None, help="comma-separated env ids (default: every current benchmark task "
                   "with a shipped agent; a superseded task or an original environment when named)")
    p.add_argument("--episodes", type=int, default=10, help="episodes per controller (default 10)")
    p.add_argument("--seed", type=int, default=HELD_OUT_SEED, help=f"first seed (default {HELD_OUT_SEED}, held out)")
    p.add_argument("--oracle-cache", default=DEFAULT_CACHE,
                   help="comma-separated episodes.csv files (glob patterns) of thermovalve benchmark runs "
                        f"(default {DEFAULT_CACHE})")
    p.add_argument("--out", default="out/task_leaderboard", help="output directory (default out/task_leaderboard)")
    p.add_argument("--docs", action="store_true", help="write the tracked docs/task_leaderboard.* instead")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.add_argument("--zoo", default=None, help="directory of shipped agents (default agents/zoo)")
    p.add_argument("--no-generalisation", action="store_true", help="skip the generalisation table")
    p.add_argument("--reuse", default=None, metavar="CSV",
                   help="comma-separated task_episodes.csv of earlier boards: the built-in controllers' episodes on "
                        "the same task and seeds are taken from there instead of rerun (agents always run)")
    p.add_argument("--scratch", default=None, metavar="DIR",
                   help="add the from-scratch runs of python -m agents.scratch (DIR/runs.csv, scored on the "
                        "same seeds)")


def run(args: argparse.Namespace) -> int:
    import valve_env
    from agents.loader import available_agents
    from valve_env.outputs import OutputError, OutputSet

    try:
        tasks = ([t for t in args.tasks.split(",") if t] if args.tasks
                 else [t for t in valve_env.CURRENT_TASK_IDS if available_agents(t, args.zoo)])
        for t in tasks:  # a benchmark task, or an original environment named explicitly (its agents, the oracle)
            if t not in valve_env.ALL_ENV_IDS:
                raise ValueError(f"unknown env id {t!r}; known: {', '.join(valve_env.ALL_ENV_IDS)}")
        if not tasks:
            raise ValueError("no benchmark task has a shipped agent (agents/zoo/<task>/)")
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        cache = [c for c in args.oracle_cache.split(",") if c]
        cache_files(cache)  # a file that is not a benchmark's episodes.csv is refused before any episode
        scratch_runs = None
        if args.scratch is not None:
            f = Path(args.scratch) / "runs.csv"
            if not f.is_file():
                raise ValueError(f"--scratch {args.scratch}: no runs.csv (python -m agents.scratch evaluate)")
            scratch_runs = pd.read_csv(f)
            scratch_rows(scratch_runs, list(range(args.seed, args.seed + args.episodes)))  # the seeds checked
        reuse = [c for c in (args.reuse or "").split(",") if c]
        for r in reuse:
            if not Path(r).is_file() or not set(CACHE_COLUMNS) <= set(pd.read_csv(r, nrows=0).columns):
                raise ValueError(f"--reuse {r}: not a task_episodes.csv of thermovalve task-leaderboard")
        outs = OutputSet(force=args.force)
        # --docs: the tracked files (each replaced only with --force); else a directory of its own
        out = Path("docs") if args.docs else outs.add_dir(args.out)
        paths = {n: outs.add(out / n) for n in ("task_leaderboard.md", "task_leaderboard.json", "task_episodes.csv")}
        figdir = out / "figures"
        if not args.docs:
            figdir.mkdir(exist_ok=True)
        fig = outs.add(figdir / "task_leaderboard.png")
        fig_scratch = outs.add(figdir / "task_leaderboard_scratch.png") if scratch_runs is not None else None
    except (ValueError, OutputError) as exc:
        print(f"thermovalve: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    boards, gen, episodes = build(tasks, args.episodes, args.seed, cache, args.zoo, not args.no_generalisation, reuse)
    meta = {"command": "thermovalve task-leaderboard " + shlex.join(sys.argv[2:] if len(sys.argv) > 1
                                                                    and sys.argv[1] == "task-leaderboard"
                                                                    else sys.argv[1:]),
            "seeds": [args.seed, args.seed + args.episodes - 1], "oracle_cache": cache,
            "wall_s": round(time.perf_counter() - t0, 1)}
    scratch = None
    if scratch_runs is not None:
        summary = scratch_rows(scratch_runs, list(range(args.seed, args.seed + args.episodes)))
        scratch = (summary, engineered_rows(boards, args.zoo))
        meta.update({"scratch": str(args.scratch), "scratch_budget": int(scratch_runs["n_timesteps"].max()),
                     "scratch_train_seeds": ", ".join(map(str, sorted(scratch_runs["seed"].unique()))),
                     "scratch_runs": len(scratch_runs),
                     "scratch_step0": ", ".join(
                         f"{a} {int((g['best_checkpoint_step'] == 0).sum())} of {len(g)}"
                         for a, g in scratch_runs.groupby("algo")) if "best_checkpoint_step" in scratch_runs else "",
                     "scratch_cpu_min": float(scratch_runs["train_cpu_s"].fillna(0).sum()) / 60.0,
                     "scratch_wall_min": float(scratch_runs["train_wall_s"].fillna(0).sum()) / 60.0})
    text = markdown(boards, gen, meta, scratch)
    outs.write_text(paths["task_leaderboard.md"], text)
    outs.write_text(paths["task_leaderboard.json"], _json(boards, gen, meta, scratch))
    if scratch is not None and fig_scratch is not None:
        outs.stage(fig_scratch, lambda tmp: plot_scratch(scratch[0], scratch[1], tmp))
    outs.stage(paths["task_episodes.csv"], lambda tmp: episodes.to_csv(tmp, index=False))
    outs.stage(fig, lambda tmp: plot(boards, tmp))
    outs.commit()
    print(text)
    print(outs.summary())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.task_leaderboard", description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
