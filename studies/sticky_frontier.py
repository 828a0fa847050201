"""The iae-reversals trade-off of the stiction compensators on a sticky-valve task (docs/controllers.md).

    python studies/sticky_frontier.py [--task ThermoValveStickyValve-v0] [--seed 0 --episodes 10]
                                         [--plot out/sticky_frontier.png] [--force]

Runs ``pi`` and each compensator over a grid of its own settings (keyword arguments of
``make_controller``) on the sticky task (``--task``: ThermoValveStickyValve-v0, the stem at its seat, or
ThermoValveStickyCirculation-v0, mid-stroke with a circulation loop), 24 h episodes, seeds
``--seed`` .. (the tuning seeds 0-9 by default: the held-out 5000-5009 are for ``thermovalve benchmark`` only),
and prints a markdown table:
iae_Kh and reversals as means and as changes against ``pi`` (the issue's goal: iae -30 % or better
with fewer reversals than ``pi``, tdis_Kh no worse). ``--plot`` also draws the trade-off.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import pandas as pd

from valve_env.controllers import make_controller
from valve_env.evaluation.evaluator import run_episodes
from valve_env.outputs import OutputError, OutputSet

TASK = "ThermoValveStickyValve-v0"
TASKS = ("ThermoValveStickyValve-v0", "ThermoValveStickyCirculation-v0")
GRID: dict[str, list[dict[str, Any]]] = {
    "pi": [{"Kp": k, "Ti_s": t} for k in (5.0, 10.0, 20.0, 40.0) for t in (268.0, 1500.0)],
    "constant_reinforcement": [{"amplitude_band": a} for a in (0.05, 0.1, 0.2, 0.5, 0.8)],
    "knocker": [{"amplitude_band": a, "period_steps": p} for a in (0.5, 1.0) for p in (4, 10)],
    "two_move": [{}],
    "pi_wear": [{}],
    "pi_stiction_tuned": [{}],
    "pi_integral_band": [{"band_factor": f} for f in (0.5, 1.0, 2.0, 4.0)],
    "two_move_position": [{"replace_band": r, "tau_c_factor": f} for f in (1.0, 4.0) for r in (0.2, 0.4, 0.6)]
    + [{"error_band_K": 0.02, "replace_band": 0.4}],
}


def frontier(seed: int, episodes: int, task: str = TASK, grid: dict[str, list[dict[str, Any]]] | None = None
             ) -> pd.DataFrame:
    base = run_episodes(make_controller("pi", task), task, episodes, seed)
    rows = [{"controller": "pi", "settings": "", **base.mean(numeric_only=True)}]
    for name, settings in (GRID if grid is None else grid).items():
        for kw in settings:
            df = run_episodes(make_controller(name, task, **kw), task, episodes, seed)
            rows.append({"controller": name, "settings": ", ".join(f"{k}={v}" for k, v in kw.items()),
                         **df.mean(numeric_only=True)})
    out = pd.DataFrame(rows)
    out["iae_vs_pi_%"] = 100 * (out["iae_Kh"] / base["iae_Kh"].mean() - 1)
    out["reversals_vs_pi_%"] = 100 * (out["reversals"] / base["reversals"].mean() - 1)
    out["iae_x_reversals"] = out["iae_Kh"] * out["reversals"]
    out["goal"] = (out["iae_vs_pi_%"] <= -30) & (out["reversals_vs_pi_%"] < 0) & (
        out["tdis_Kh"] <= base["tdis_Kh"].mean() + 1e-9)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default=TASK, choices=TASKS)
    ap.add_argument("--only", default=None, help="comma-separated controllers of the grid to run (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--plot", default=None, help="write the trade-off figure here (PNG)")
    ap.add_argument("--force", action="store_true", help="replace an existing --plot file")
    a = ap.parse_args()
    outs = OutputSet(force=a.force)
    try:  # the project's output policy, checked before the long run
        plot = outs.add(a.plot) if a.plot else None
    except OutputError as exc:
        print(f"thermovalve: error: {exc}", file=sys.stderr)
        return 2
    grid = None if a.only is None else {k: v for k, v in GRID.items() if k in a.only.split(",")}
    out = frontier(a.seed, a.episodes, a.task, grid)
    cols = ["controller", "settings", "iae_Kh", "reversals", "travel_mm", "tdis_Kh", "iae_vs_pi_%",
            "reversals_vs_pi_%", "iae_x_reversals", "goal"]
    print(f"{a.task}, seeds {a.seed}-{a.seed + a.episodes - 1}, 24 h (means)\n")
    print("| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for _, r in out[cols].iterrows():
        print("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in r) + " |")
    if plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4))
        for name, g in out.groupby("controller", sort=False):
            ax.plot(g["reversals_vs_pi_%"], g["iae_vs_pi_%"], "o", label=name)
        ax.axhline(-30, color="k", lw=0.8, ls="--")
        ax.axvline(0, color="k", lw=0.8, ls="--")
        ax.set_xlabel("stem reversals vs pi, %")
        ax.set_ylabel("iae_Kh vs pi, %")
        ax.set_title("goal: lower left of the dashed lines")
        ax.legend(fontsize=7)
        fig.tight_layout()
        outs.stage(plot, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
        outs.commit()
        print(f"wrote {plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
