"""The leaderboard: shipped agents and the baselines through the one evaluator
(``valve_env.evaluation``), on the training scenario and unseen ones, the same
seeds for every controller.

    thermovalve leaderboard [--envs ThermoValve-v0,...] [--episodes 10] [--seed 1000] [--out out/leaderboard]
    thermovalve leaderboard --docs --force      # regenerate the tracked docs/leaderboard.*
    python -m agents.leaderboard ...

Writes ``leaderboard.md``, ``leaderboard.csv``, ``leaderboard.json`` into
``--out`` (default out/leaderboard; ``--docs`` writes the tracked docs/ instead)
and ``figures/leaderboard_<env>.png`` (tracking versus energy) below it, all
together and atomically; existing files are replaced only with ``--force``.
Scenario names come from the one registry, valve_env.evaluation.scenarios.
The markdown ends with the issue's target check, computed from the
numbers: the best agent (highest mean return on the default scenario) against
``pi``, per scenario, paired by seed.
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

import valve_env
from agents.cem import RANK_SEED
from agents.scenarios import (
    DESCRIPTIONS,
    LEADERBOARD_SCENARIOS,
    SCENARIOS,
    check_scenario,
    episode_env_kwargs,
    is_randomised,
)

BASELINE_NAMES: tuple[str, ...] = ("self_acting", "pi", "pi_compensated")
REFERENCE = "pi"
#: a "loss" on tdis_Kh is a mean increase of more than this (K h per day): the
#: floor shortfall is ~0.03 K h for every controller (the cold start) and tiny
#: numerical differences are not a loss.
TDIS_TOL_KH = 0.005


def controllers_for(
    env_id: str, names: Sequence[str] | None = None, ablation: bool = True, zoo: str | Path | None = None
) -> dict[str, Any]:
    """Controller objects by name: the baselines that support ``env_id``, the
    shipped agents (or ``names``) and, with ``ablation``, each residual
    agent's base law alone (``<agent>_base_law``)."""
    from agents.loader import available_agents, load_agent
    from valve_env.controllers import BASELINES, make_controller

    shipped = available_agents(env_id, zoo)
    if names is None:
        names = [b for b in BASELINE_NAMES if env_id in getattr(BASELINES[b], "supported_env_ids", (env_id,))]
        names += shipped
    out: dict[str, Any] = {}
    for name in names:
        if name not in BASELINES and name not in shipped:
            raise ValueError(f"unknown controller {name!r} for {env_id}; built-in: {', '.join(BASELINES)}; "
                             f"shipped agents: {', '.join(shipped) or 'none'}")
    for name in names:
        if name in BASELINES:
            out[name] = make_controller(name, env_id)
        else:
            ctrl = load_agent(name, env_id, zoo=zoo)
            out[name] = ctrl
            if ablation and ctrl.residual is not None:
                out[f"{name}_base_law"] = ctrl.base_law()
    return out


def score_scenario(
    controllers: Mapping[str, Any],
    env_id: str,
    scenario: str,
    episodes: int,
    seed: int,
    base_kwargs: Mapping[str, Any] | None = None,
) -> tuple[dict[str, Any], dict[str, pd.DataFrame]]:
    """The evaluator's summary and per-episode tables for one scenario.

    A randomised scenario is scored one seed at a time (each seed its own
    valve), then summarised by the evaluator's own ``summarise``."""
    from valve_env.evaluation import evaluate_detailed, summarise

    check_scenario(scenario)
    if not is_randomised(scenario):
        return evaluate_detailed(controllers, env_id, episodes, seed, episode_env_kwargs(scenario, seed, base_kwargs))
    parts: dict[str, list[pd.DataFrame]] = {name: [] for name in controllers}
    for i in range(episodes):
        kw = episode_env_kwargs(scenario, seed + i, base_kwargs)
        _, per_ep = evaluate_detailed(controllers, env_id, 1, seed + i, kw)
        for name, df in per_ep.items():
            parts[name].append(df.assign(episode=i))
    frames = {name: pd.concat(dfs, ignore_index=True) for name, dfs in parts.items()}
    return summarise(frames, env_id), frames


def _energy(df: pd.DataFrame) -> pd.Series:
    """Primary energy, kWh: heat plus 2.5 x pump electricity (the reward's weighting)."""
    return df["heat_kWh"] + 2.5 * df["pump_kWh"]


def compare(per_ep: Mapping[str, pd.DataFrame], agent: str, ref: str = REFERENCE) -> dict[str, Any]:
    """Agent minus reference, paired by seed: mean, std and wins per metric."""
    a = per_ep[agent].set_index("seed").sort_index()
    b = per_ep[ref].set_index("seed").sort_index()
    out: dict[str, Any] = {}
    metrics = {
        "return": (a["return"], b["return"], +1),
        "rmse_K": (a["rmse_K"], b["rmse_K"], -1),
        "energy_kWh": (_energy(a), _energy(b), -1),
        "tdis_Kh": (a["tdis_Kh"], b["tdis_Kh"], -1),
        "reversals": (a["reversals"], b["reversals"], -1),  # wear: reported, not part of the target
    }
    for m, (x, y, sign) in metrics.items():
        d = (x - y).to_numpy(dtype=float)
        ref_mean = float(np.mean(y))
        out[m] = {
            "diff_mean": float(np.mean(d)),
            "diff_std": float(np.std(d)),
            "wins": int(np.sum(sign * d > 0)),
            "n": int(d.size),
            "ratio": float(np.mean(x)) / ref_mean if ref_mean else math.nan,
        }
    better_return = out["return"]["diff_mean"] > 0
    better_track = out["rmse_K"]["diff_mean"] < 0
    better_energy = out["energy_kWh"]["diff_mean"] < 0
    tdis_ok = out["tdis_Kh"]["diff_mean"] <= TDIS_TOL_KH
    out["target_met"] = bool(better_return and (better_track or better_energy) and tdis_ok)
    return out


def plot_board(board: Mapping[str, Any], env_id: str, path: Path) -> Path:
    """Tracking (rmse_K) versus primary energy, one panel per scenario, mean +- std."""
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    scen = list(board)
    ncol = 2 if len(scen) > 1 else 1
    nrow = (len(scen) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.6 * ncol, 4.2 * nrow), squeeze=False)
    flat = list(axes.ravel())
    for ax in flat[len(scen):]:
        ax.set_visible(False)
    for ax, s in zip(flat, scen, strict=False):
        per_ep: Mapping[str, pd.DataFrame] = board[s]["per_episode"]
        for i, (name, df) in enumerate(per_ep.items()):
            e = _energy(df)
            agent = name not in BASELINE_NAMES and not name.endswith("_base_law")
            style: dict[str, Any] = {"fmt": "o", "ms": 7, "zorder": 2}
            if agent:
                style = {"fmt": "*", "ms": 13, "zorder": 4}
            elif name.endswith("_base_law"):
                style = {"fmt": "o", "ms": 11, "mfc": "none", "zorder": 3}
            ax.errorbar(
                df["rmse_K"].mean(), e.mean(), xerr=df["rmse_K"].std(ddof=0), yerr=e.std(ddof=0),
                capsize=3, label=name, color=f"C{i}", **style,
            )
        ax.set_xscale("log")
        ax.set_title(f"{s}: {DESCRIPTIONS.get(s, '')}", fontsize=8)
        ax.set_xlabel("outlet RMSE vs target (K, log scale)")
        ax.set_ylabel("primary energy: heat + 2.5 pump (kWh/day)", fontsize=8)
        ax.grid(alpha=0.3, which="both")
    flat[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"{env_id}: tracking vs energy, mean ± std over the episodes", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, path, dpi=100)


def _fmt(mean: float, std: float) -> str:
    if not math.isfinite(mean):
        return "n/a"
    digits = 1 if abs(mean) >= 100 else (2 if abs(mean) >= 1 else 3)
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


TABLE_METRICS: tuple[str, ...] = (
    "return", "rmse_K", "iae_Kh", "tdis_Kh", "heat_kWh", "pump_kWh", "return_C", "travel_mm", "reversals",
)


def board_markdown(env_id: str, board: Mapping[str, Any], episodes: int, seed: int) -> str:
    lines = [f"## {env_id}", ""]
    for s, entry in board.items():
        lines += [f"### {s}: {DESCRIPTIONS.get(s, '')}", ""]
        lines.append("| controller | " + " | ".join(TABLE_METRICS) + " |")
        lines.append("|---|" + "---:|" * len(TABLE_METRICS))
        res = entry["summary"]["results"]
        order = sorted(res, key=lambda n: -res[n]["return"]["mean"])
        for name in order:
            r = res[name]
            cells = [_fmt(r["return"]["mean"], r["return"]["std"])]
            cells += [_fmt(r["kpis"][k]["mean"], r["kpis"][k]["std"]) for k in TABLE_METRICS[1:]]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def target_markdown(env_id: str, best: str | None, checks: Mapping[str, Any]) -> str:
    lines = [f"### Target check, {env_id}", ""]
    if best is None:
        return "\n".join([*lines, f"No shipped agent for {env_id}.", ""])
    if not checks:
        return "\n".join([*lines, f"No `{REFERENCE}` baseline for {env_id}: nothing to compare against.", ""])
    lines += [
        f"Best agent: `{best}` (highest mean return on `default`). Differences agent - `{REFERENCE}`, "
        "paired by seed (mean ± std; wins = seeds where the agent is better). Target: a higher return and a "
        f"lower rmse_K or lower primary energy, with tdis_Kh no worse (by more than {TDIS_TOL_KH} K h). "
        "The last column is the ablation: the agent against its own residual base law (policy off); "
        "a difference near 0 means the gain over the reference comes from the base law, not from learning. "
        "The wear column (stem direction reversals per day, agent / reference) is not part of the target.",
        "",
        "| scenario | Δ return (wins) | Δ rmse_K (wins) | Δ energy kWh (wins) | Δ tdis_Kh | target met "
        "| agent - own base law: Δ return (wins) | wear: reversals agent / reference |",
        "|---|---:|---:|---:|---:|:---:|---:|---:|",
    ]
    for s, c in checks.items():

        def cell(m: str, c: Mapping[str, Any] = c) -> str:
            return f"{c[m]['diff_mean']:+.3f} ± {c[m]['diff_std']:.3f} ({c[m]['wins']}/{c[m]['n']})"

        own = c.get("vs_base_law")
        own_cell = "n/a" if own is None else (
            f"{own['return']['diff_mean']:+.3f} ± {own['return']['diff_std']:.3f} "
            f"({own['return']['wins']}/{own['return']['n']})"
        )
        lines.append(
            f"| {s} | {cell('return')} | {cell('rmse_K')} | {cell('energy_kWh')} | "
            f"{c['tdis_Kh']['diff_mean']:+.4f} | {'yes' if c['target_met'] else 'no'} | {own_cell} | "
            f"{c['reversals']['ratio']:.1f}x |"
        )
    return "\n".join([*lines, ""])


def build_leaderboard(
    env_ids: Sequence[str],
    scenarios: Sequence[str] = LEADERBOARD_SCENARIOS,
    episodes: int = 10,
    seed: int = RANK_SEED,
    names: Sequence[str] | None = None,
    ablation: bool = True,
    zoo: str | Path | None = None,
    out_dir: str | Path = "out/leaderboard",
    command: str | None = None,
    verbose: bool = True,
    base_kwargs: Mapping[str, Any] | None = None,
) -> dict[str, Path]:
    """Score, then write the markdown, CSV, JSON and figures; returns name -> path.

    ``base_kwargs``: gym.make keywords under every scenario (tests use a short horizon)."""
    if episodes < 1:
        raise ValueError("episodes must be >= 1")
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    md = [
        "# Leaderboard",
        "",
        f"Produced by `{command or 'thermovalve leaderboard'}` on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
        f" (valve_env {valve_env.__version__}). Every controller runs the same {episodes} seeded episodes per "
        f"scenario (seeds {seed}..{seed + episodes - 1}, never used in training) through `valve_env.evaluation`; "
        "mean ± std (population std over the episodes). `<agent>_base_law` is the agent's residual base law with "
        "the policy switched off (the ablation: what the learning adds). Energy = heat_kWh + 2.5 pump_kWh.",
        "",
    ]
    rows: list[pd.DataFrame] = []
    js: dict[str, Any] = {
        "episodes": episodes,
        "seeds": list(range(seed, seed + episodes)),
        "scenarios": {s: DESCRIPTIONS[s] for s in scenarios},
        "command": command,
        "envs": {},
    }
    paths: dict[str, Path] = {}
    targets: list[str] = []
    for env_id in env_ids:
        ctrls = controllers_for(env_id, names, ablation, zoo)
        board: dict[str, Any] = {}
        for s in scenarios:
            if verbose:
                print(f"[leaderboard] {env_id} / {s}: {', '.join(ctrls)}", file=sys.stderr, flush=True)
            summary, per_ep = score_scenario(ctrls, env_id, s, episodes, seed, base_kwargs)
            board[s] = {"summary": summary, "per_episode": per_ep}
            for name, df in per_ep.items():
                rows.append(df.assign(env=env_id, scenario=s, controller=name))
        agents = [n for n in ctrls if n not in BASELINE_NAMES and not n.endswith("_base_law")]
        first = board[scenarios[0]]["summary"]["results"]
        best = max(agents, key=lambda n: first[n]["return"]["mean"]) if agents else None
        checks = {}
        if best is not None and REFERENCE in ctrls:
            checks = {s: compare(board[s]["per_episode"], best) for s in scenarios}
            if f"{best}_base_law" in ctrls:  # the ablation: what the learned residual adds
                for s in scenarios:
                    own = compare(board[s]["per_episode"], best, ref=f"{best}_base_law")
                    checks[s]["vs_base_law"] = {k: own[k] for k in ("return", "rmse_K", "energy_kWh", "tdis_Kh")}
        md.append(board_markdown(env_id, board, episodes, seed))
        fig = plot_board(board, env_id, out / "figures" / f"leaderboard_{env_id}.png")
        paths[f"figure_{env_id}"] = fig
        md += [f"![{env_id}: tracking vs energy](figures/{fig.name})", ""]
        targets.append(target_markdown(env_id, best, checks))
        js["envs"][env_id] = {
            "best_agent": best,
            "scenarios": {s: board[s]["summary"] for s in scenarios},
            "target_check": checks,
        }
    md += ["## Target check", "", *targets]
    md.append(f"_Scoring took {time.time() - t0:.0f} s._\n")
    paths["markdown"] = out / "leaderboard.md"
    paths["markdown"].write_text("\n".join(md))
    paths["csv"] = out / "leaderboard.csv"
    pd.concat(rows, ignore_index=True).to_csv(paths["csv"], index=False)
    paths["json"] = out / "leaderboard.json"
    paths["json"].write_text(json.dumps(js, indent=1))
    return paths


# --------------------------------------------------------------------------- CLI
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--envs", default=None, help="comma-separated env ids (default: every env id with a shipped agent)")
    p.add_argument("--controllers", default=None, help="comma-separated names (default: baselines + shipped agents)")
    p.add_argument("--scenarios", default=",".join(LEADERBOARD_SCENARIOS),
                   help=f"comma-separated, from {', '.join(SCENARIOS)}")
    p.add_argument("--episodes", type=int, default=10, help="seeded episodes per scenario (default 10)")
    p.add_argument("--seed", type=int, default=RANK_SEED, help=f"first evaluation seed (default {RANK_SEED})")
    p.add_argument("--out", default="out/leaderboard", help="output directory")
    p.add_argument("--docs", action="store_true", help="write the tracked docs/leaderboard.* (with --force to replace)")
    p.add_argument("--force", action="store_true", help="replace existing output files (never an input)")
    p.add_argument("--zoo", default=None, help="directory of shipped agents (default agents/zoo)")
    p.add_argument("--no-ablation", action="store_true", help="leave out the <agent>_base_law rows")


def _command_line() -> str:
    """The command as typed, for the record (``thermovalve ...`` or ``python -m agents.<module> ...``)."""
    prog = Path(sys.argv[0]).name
    if prog == "thermovalve":
        return shlex.join(["thermovalve", *sys.argv[1:]])
    return shlex.join(["python", "-m", f"agents.{Path(prog).stem}", *sys.argv[1:]])


def run(args: argparse.Namespace) -> int:
    from agents.loader import available_agents

    envs = args.envs.split(",") if args.envs else [e for e in valve_env.ENV_IDS if available_agents(e, args.zoo)]
    if not envs:
        envs = ["ThermoValve-v0"]
    scenarios = [s for s in args.scenarios.split(",") if s]
    for s in scenarios:
        check_scenario(s)
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    names = args.controllers.split(",") if args.controllers else None
    cmd = _command_line()
    from valve_env.outputs import OutputSet

    out_dir = Path("docs") if args.docs else Path(args.out)
    outs = OutputSet(force=args.force)
    outs.add_in_dir(out_dir, ["leaderboard.md", "leaderboard.csv", "leaderboard.json",
                              *[f"figures/leaderboard_{e}.png" for e in envs]], "--out")
    with outs:
        build_leaderboard(envs, scenarios, args.episodes, args.seed, names, not args.no_ablation, args.zoo,
                          outs.stage_dir(out_dir), cmd)
    print(outs.summary())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.leaderboard", description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())

