"""Training runs against their own base law, paired by seed (docs/agents.md, "Sweeps on Dask").

    python benchmarks/paired_vs_base_law.py --env ThermoValveStickyValve-v0 --seed 1000 --episodes 10 RUN_DIR...

Each run directory's model (its ``best/`` checkpoint if it has one, else the final model;
agents.loader.load_agent) and the base law of its residual (the policy's action switched off:
the step-0 policy) run the same seeded episodes through the evaluator
(``valve_env.evaluation.evaluate_detailed``). Prints each run's mean return, the per-seed
difference to the base law (mean and standard error over the seeds), on how many seeds it is
better, and its wear (reversals) and tracking (iae_Kh). All runs must share the base law
(the first run's is used).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="training run directories (thermovalve train / sweep cells)")
    p.add_argument("--env", required=True, help="env id the runs were trained on")
    p.add_argument("--seed", type=int, default=1000, help="first evaluation seed (default 1000)")
    p.add_argument("--episodes", type=int, default=10, help="episodes, seeds seed..seed+episodes-1 (default 10)")
    args = p.parse_args(argv)
    missing = [r for r in args.runs if not (Path(r) / "config.yml").is_file()]
    if missing or args.episodes < 2:
        what = f"not a training run directory: {missing[0]}" if missing else "--episodes must be >= 2"
        print(f"thermovalve: error: {what}", file=sys.stderr)
        return 2
    from agents.loader import load_agent
    from valve_env.evaluation import evaluate_detailed

    ctrls = {Path(r).name: load_agent("ppo", args.env, run_dir=r) for r in args.runs}
    ctrls["base_law"] = next(iter(ctrls.values())).base_law()
    summary, per_ep = evaluate_detailed(ctrls, args.env, args.episodes, args.seed, {})
    base = per_ep["base_law"]["return"].to_numpy()
    print(f"{args.env}, seeds {args.seed}-{args.seed + args.episodes - 1}")
    print("| run | return | paired diff vs base law (se) | better on | reversals | iae_Kh |")
    print("|---|---:|---:|---:|---:|---:|")
    for name in ctrls:
        x = per_ep[name]["return"].to_numpy()
        d = x - base
        k = summary["results"][name]["kpis"]
        print(f"| {name} | {x.mean():.4f} | {d.mean():+.4f} ({d.std(ddof=1) / np.sqrt(len(d)):.4f}) | "
              f"{int((d > 0).sum())}/{len(d)} | {k['reversals']['mean']:.0f} | {k['iae_Kh']['mean']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
