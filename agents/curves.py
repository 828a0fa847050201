"""Learning curves of training runs, one figure per task.

    thermovalve curves out/runs/ThermoValveSmallCylinder-v0/ppo_s0_* [--out out/curves] [--force]
    python -m agents.curves RUN_DIR [RUN_DIR ...]

For each run directory (``thermovalve train``'s): the training episodes' true return (the
monitor CSV; the reward the evaluator sees, not the shaped one) against the env steps, as a
rolling mean over one batch of envs (for a CEM run, agents.cem, the mean policy's and the
elites' returns per generation, ``cem.csv``), and the periodic deterministic evaluations on the fixed
seeds 10000+ (``best/evaluations.npz``; the first is the policy at step 0, i.e. about its
base law). Runs of the same env id share one figure ``<out>/curves_<env id>.png``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml


def read_run(run_dir: str | Path) -> dict[str, Any]:
    """A run's config, its training episodes (steps, return) and its evaluations."""
    r = Path(run_dir)
    cfg_path = r / "config.yml"
    if not cfg_path.is_file():
        raise ValueError(f"{r} is not a training run directory (no config.yml)")
    cfg = yaml.safe_load(cfg_path.read_text())
    frames = [pd.read_csv(f, skiprows=1) for f in sorted((r / "monitor").glob("*.monitor.csv"))]
    frames = [f for f in frames if len(f)]
    ep = pd.concat(frames).sort_values("t") if frames else pd.DataFrame(columns=["r", "l", "t"])
    n_envs = int(cfg.get("n_envs", 1))
    # the episodes end in order of wall time; the step count at an episode's end is about the
    # steps of the episodes ended so far. A desynchronised run (desync: true) cuts each env's first
    # episode short: those count as steps but are not plotted (a part of a day is not a day's return)
    ep = ep.assign(steps=np.cumsum(ep["l"].to_numpy(float)))
    if len(ep):
        ep = ep[ep["l"] == ep["l"].max()]
    cem = pd.read_csv(r / "cem.csv") if (r / "cem.csv").is_file() else None
    evals = None
    npz = r / "best" / "evaluations.npz"
    if npz.is_file():
        d = np.load(npz)
        evals = (d["timesteps"], d["results"].mean(axis=1))
    return {"dir": r, "cfg": cfg, "episodes": ep, "n_envs": n_envs, "evals": evals, "cem": cem}


def plot_runs(runs: Sequence[dict[str, Any]], path: Any, title: str) -> None:
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for i, run in enumerate(runs):
        ep = run["episodes"]
        label = f"{run['cfg'].get('algo')} s{run['cfg'].get('seed')} ({run['dir'].name})"
        if len(ep):
            w = max(1, run["n_envs"])
            ax.plot(ep["steps"] / 1e6, ep["r"].rolling(w, min_periods=1).mean(), color=f"C{i}", alpha=0.7,
                    label=f"{label}: training episodes (mean of {w})")
        cem = run["cem"]
        if cem is not None and len(cem):  # agents.cem: mu and the elites on each generation's training seeds
            ax.plot(cem["env_steps"] / 1e6, cem["mu_return"], color=f"C{i}", alpha=0.7,
                    label=f"{label}: CEM mean policy, training seeds of the generation")
            ax.plot(cem["env_steps"] / 1e6, cem["elite_mean"], ":", color=f"C{i}", alpha=0.7,
                    label=f"{label}: CEM elite mean")
        if run["evals"] is not None:
            ax.plot(run["evals"][0] / 1e6, run["evals"][1], "o--", color=f"C{i}", ms=5,
                    label=f"{label}: deterministic evaluation")
    ax.set_xlabel("env steps (millions)")
    ax.set_ylabel("episode return (true reward)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, format="png")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", help="training run directories (thermovalve train)")
    p.add_argument("--out", default="out/curves", help="output directory (default out/curves)")
    p.add_argument("--force", action="store_true", help="replace existing figures")


def run(args: argparse.Namespace) -> int:
    from valve_env.outputs import OutputError, OutputSet

    try:
        runs = [read_run(r) for r in args.runs]
        by_env: dict[str, list[dict[str, Any]]] = {}
        for r in runs:
            by_env.setdefault(str(r["cfg"]["env_id"]), []).append(r)
        outs = OutputSet(force=args.force)
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise OutputError(f"--out {out} exists and is not a directory")
        out.mkdir(parents=True, exist_ok=True)
        paths = {env: outs.add(out / f"curves_{env}.png") for env in by_env}
    except (ValueError, OutputError) as exc:
        print(f"thermovalve: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    for env, rs in by_env.items():
        def write(tmp: Path, rs: list[dict[str, Any]] = rs, env: str = env) -> None:
            plot_runs(rs, tmp, f"{env}: learning curves")

        outs.stage(paths[env], write)
    outs.commit()
    print(outs.summary())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.curves", description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
