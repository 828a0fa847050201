"""The benchmark report: every controller on every task over held-out seeds,
with its cost (= -return) and two normalised scores per task: the gap score
(0 = ``pi``, 1 = ``oracle``: the share of pi's optimality gap a controller
closes) and the score (0 = ``self_acting``, 1 = ``oracle``), with 95 %
confidence intervals over the episodes. docs/tasks.md, "The benchmark report".

This module is the core's part (no Dask, no torch): the grid of cells, one
cell's evaluation, the scores and the report files. ``thermovalve
benchmark`` (agents/benchmark.py, in the ``rl`` extra because Dask is)
runs the cells on a Dask cluster.

Seeds: the report's episodes use seeds ``HELD_OUT_SEED .. HELD_OUT_SEED +
episodes - 1`` (5000-5009 by default). The tasks, their parameters and the
report were built looking only at seeds 0-103; 5000+ were not run while
building.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pandas as pd

#: first held-out seed of the report (episodes use HELD_OUT_SEED, HELD_OUT_SEED + 1, ...)
HELD_OUT_SEED = 5000
LOW_REFERENCE = "self_acting"
HIGH_REFERENCE = "oracle"
#: the gap score's reference: 0 = this controller, 1 = the oracle (docs/tasks.md, "The benchmark report")
GAP_REFERENCE = "pi"
#: the confidence level of the intervals over episodes
CI_LEVEL = 0.95
#: bootstrap resamples of the gap score's interval (seeded: the report is reproducible)
N_RESAMPLES = 9999
#: the controller variant that runs pi on a smooth valve (no friction to speak of, no effects)
SMOOTH = "pi@smooth_valve"


def smooth_valve(task_id: str | None = None) -> dict[str, Any]:
    """The ``valve=`` override of a smooth valve on ``task_id``: Dahl friction 1 mN (F_hmax must be
    > 0) and none of the task's named effects (its stiction): each removed by name (``null``; effects
    combine by name, docs/tasks.md, "A valve file on a task")."""
    from valve_env.tasks import get_task

    own = get_task(task_id).sections.get("valve", {}).get("effects", {}) if task_id is not None else {}
    return {"valve": {"F_hmax": 1e-3, "effects": dict.fromkeys(own)}}


@dataclass(frozen=True)
class Cell:
    """One controller on one task over the report's episodes."""

    task: str
    controller: str
    episodes: int = 10
    seed: int = HELD_OUT_SEED
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)

    #: the cell is one of the per-seed cells of a slow controller (its key names its seed)
    split: bool = False

    @property
    def key(self) -> str:
        return f"{self.task}__{self.controller}" + (f"__s{self.seed}" if self.split else "")


def known_controllers(task_id: str, names: Iterable[str] | None = None) -> list[str]:
    """The controllers that :func:`valve_env.controllers.make_controller` can build for ``task_id``:
    ``names`` if given (each checked), else every built-in controller (``CONTROLLERS``: the
    baselines, the compensators and the oracle) that supports the task's action."""
    from valve_env.controllers import CONTROLLERS, make_controller

    candidates = list(names) if names is not None else list(CONTROLLERS)
    out = []
    for name in candidates:
        try:
            make_controller(name, task_id)
        except (ValueError, TypeError, KeyError):  # does not apply to this task's action
            if names is not None:
                raise
            continue
        out.append(name)
    return out


def make_cells(
    tasks: Sequence[str],
    controllers: Sequence[str] | None = None,
    episodes: int = 10,
    seed: int = HELD_OUT_SEED,
    smooth: bool = True,
) -> list[Cell]:
    """The grid: each task x each controller that applies to it (``controllers`` None: every known
    one), plus ``pi`` on a smooth valve (``SMOOTH``) for the valve-matters check. The oracle (slow:
    it plans by simulation) gets a cell per seed, so that its episodes spread over the workers."""
    cells = []
    for task in tasks:
        for name in known_controllers(task, controllers):
            if name == HIGH_REFERENCE:
                cells += [Cell(task, name, 1, int(seed) + i, split=True) for i in range(int(episodes))]
            else:
                cells.append(Cell(task, name, int(episodes), int(seed)))
        if smooth:
            cells.append(Cell(task, SMOOTH, int(episodes), int(seed), smooth_valve(task)))
    return cells


def run_cell(cell: Cell) -> dict[str, Any]:
    """Evaluate one cell (runs on a Dask worker): the per-episode rows of the evaluator."""
    import time

    from valve_env.evaluation import evaluate_detailed

    t0 = time.perf_counter()
    name = "pi" if cell.controller == SMOOTH else cell.controller
    _, per_ep = evaluate_detailed([name], cell.task, cell.episodes, cell.seed, dict(cell.env_kwargs))
    df = per_ep[name]
    return {"cell": {**asdict(cell), "key": cell.key}, "wall_s": time.perf_counter() - t0,
            "episodes": df.to_dict(orient="records")}


# -- scores ----------------------------------------------------------------------------


def normalised_scores(
    cost: Mapping[str, float], low: str = LOW_REFERENCE, high: str = HIGH_REFERENCE
) -> dict[str, float]:
    """Each controller's score ``(cost[low] - cost[c]) / (cost[low] - cost[high])``: 0 for ``low``
    (self_acting) and 1 for ``high`` (the oracle) by construction, negative if worse than
    ``low``, above 1 if better than ``high``. NaN for all when a reference is missing or the two
    references cost the same."""
    if low not in cost or high not in cost or not math.isfinite(cost[low] - cost[high]) \
            or cost[low] == cost[high]:
        return {c: math.nan for c in cost}
    span = cost[low] - cost[high]
    return {c: (cost[low] - v) / span for c, v in cost.items()}


def gap_scores(cost: Mapping[str, float], ref: str = GAP_REFERENCE, oracle: str = HIGH_REFERENCE) -> dict[str, float]:
    """Each controller's gap score ``(cost[ref] - cost[c]) / (cost[ref] - cost[oracle])``: the share of
    the reference's (pi's) optimality gap to the oracle that the controller closes; 0 for ``ref``, 1 for
    the oracle, negative if worse than ``ref``. :func:`normalised_scores` with pi as the low reference."""
    return normalised_scores(cost, low=ref, high=oracle)


def mean_ci(x: Sequence[float] | np.ndarray, level: float = CI_LEVEL) -> tuple[float, float]:
    """The t-interval of the mean of ``x`` at ``level`` (two-sided; Student's t with n - 1 degrees of
    freedom, the sample sd); NaN for fewer than two values."""
    from scipy import stats

    a = np.asarray(x, dtype=float)
    if a.size < 2:
        return math.nan, math.nan
    half = float(stats.t.ppf(0.5 + level / 2.0, a.size - 1)) * float(a.std(ddof=1)) / math.sqrt(a.size)
    return float(a.mean()) - half, float(a.mean()) + half


def _gap_statistic(c: np.ndarray, r: np.ndarray, o: np.ndarray, axis: int = -1) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return (r.mean(axis) - c.mean(axis)) / (r.mean(axis) - o.mean(axis))


def gap_score_ci(
    costs: Mapping[str, Mapping[int, float]], ref: str = GAP_REFERENCE, oracle: str = HIGH_REFERENCE,
    level: float = CI_LEVEL, n_resamples: int = N_RESAMPLES, seed: int = 0,
) -> dict[str, tuple[float, float]]:
    """The gap score's interval per controller from per-episode costs (``costs[controller][seed]``):
    a paired percentile bootstrap over episodes (scipy.stats.bootstrap, ``paired=True``): the seeds
    the controller, the reference and the oracle share are resampled together, the gap score of the
    resampled means computed, and its ``level`` percentile interval taken. NaN where a reference is
    missing or fewer than two seeds are shared."""
    from scipy import stats

    out: dict[str, tuple[float, float]] = {}
    for name, per_seed in costs.items():
        out[name] = (math.nan, math.nan)
        if ref not in costs or oracle not in costs:
            continue
        shared = sorted(set(per_seed) & set(costs[ref]) & set(costs[oracle]))
        if len(shared) < 2:
            continue
        c, r, o = (np.array([costs[n][k] for k in shared], float) for n in (name, ref, oracle))
        if name in (ref, oracle):  # 0 and 1 by construction
            v = 0.0 if name == ref else 1.0
            out[name] = (v, v)
            continue
        res = stats.bootstrap((c, r, o), _gap_statistic, paired=True, vectorized=True, n_resamples=n_resamples,
                              confidence_level=level, method="percentile", random_state=np.random.default_rng(seed))
        out[name] = (float(res.confidence_interval.low), float(res.confidence_interval.high))
    return out


def task_table(records: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """Per-episode rows of all cells -> one row per (task, controller): cost (= -return) and KPI
    means and standard deviations, the cost's 95 % t-interval (``cost_ci_lo``, ``cost_ci_hi``), the
    score (0 = self_acting, 1 = oracle), the gap score (0 = pi, 1 = oracle) and its paired bootstrap
    interval (``gap_score_ci_lo``, ``gap_score_ci_hi``), and the number of episodes."""
    rows = []
    for rec in records:
        c = rec["cell"]
        for ep in rec["episodes"]:
            rows.append({"task": c["task"], "controller": c["controller"], **ep})
    df = pd.DataFrame(rows)
    df["cost"] = -df["return"]
    metrics = [m for m in df.columns if m not in ("task", "controller", "episode", "seed", "return")]
    g = df.groupby(["task", "controller"], sort=False)
    means = g[metrics].mean()
    stds = g[metrics].std(ddof=0).add_suffix("_std")
    out = pd.concat([means, stds], axis=1)
    out["episodes"] = g.size()
    out["seeds"] = g["seed"].agg(lambda s: f"{int(s.min())}-{int(s.max())}")
    ci = {key: mean_ci(sub.to_numpy()) for key, sub in g["cost"]}
    out["cost_ci_lo"] = [ci[key][0] for key in out.index]
    out["cost_ci_hi"] = [ci[key][1] for key in out.index]
    out = out.reset_index()
    scores = []
    for task, sub in out.groupby("task", sort=False):
        cost = dict(zip(sub["controller"], sub["cost"], strict=True))
        sc, gap = normalised_scores(cost), gap_scores(cost)
        eps = df[df["task"] == task]
        per_seed = {str(c): dict(zip(e["seed"].astype(int), e["cost"], strict=True))
                    for c, e in eps.groupby("controller", sort=False)}
        gci = gap_score_ci(per_seed)
        scores += [(task, c, sc[c], gap[c], *gci[c]) for c in cost]
    sc_df = pd.DataFrame(scores, columns=["task", "controller", "score", "gap_score", "gap_score_ci_lo",
                                          "gap_score_ci_hi"])
    return out.merge(sc_df, on=["task", "controller"], how="left")


def findings(table: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Per task: the headroom (oracle's cost against the best non-oracle baseline) and whether
    the valve matters (pi's iae_Kh on the task's valve against a smooth valve)."""
    out: dict[str, dict[str, Any]] = {}
    for task, sub in table.groupby("task", sort=False):
        cost = dict(zip(sub["controller"], sub["cost"], strict=True))
        f: dict[str, Any] = {}
        base = {c: v for c, v in cost.items() if c not in (HIGH_REFERENCE, SMOOTH)}
        if base:
            best = min(base, key=base.__getitem__)
            f["best_baseline"] = best
            f["best_baseline_cost"] = base[best]
            if HIGH_REFERENCE in cost:
                f["oracle_cost"] = cost[HIGH_REFERENCE]
                f["headroom_pct"] = 100.0 * (base[best] - cost[HIGH_REFERENCE]) / abs(base[best])
                f["headroom_goal_met"] = bool(f["headroom_pct"] >= 25.0)
        iae = dict(zip(sub["controller"], sub["iae_Kh"], strict=True))
        if "pi" in iae and SMOOTH in iae:
            f["pi_iae_Kh_task_valve"] = iae["pi"]
            f["pi_iae_Kh_smooth_valve"] = iae[SMOOTH]
            f["valve_change_pct"] = 100.0 * (iae["pi"] - iae[SMOOTH]) / iae[SMOOTH]
            f["valve_matters"] = bool(abs(f["valve_change_pct"]) >= 20.0)
        out[str(task)] = f
    return out


#: the setting's action range, K (40-80 degC): the controller output's 0-100 % (valve_env.loops.envloop)
SETTING_RANGE_K = 40.0


def limit_cycle(
    traj: pd.DataFrame, t0_h: float = 2.0, t1_h: float = 5.0, min_jump_mm: float = 0.005
) -> dict[str, float]:
    """The limit cycle of a rollout (valve_env.evaluation.rollout) between ``t0_h`` and ``t1_h`` (a
    window without draws on the M cycle, whose first draw is at 07:00): the stem's break-aways
    (openings by more than ``min_jump_mm`` in a step), their median period (min), and the peak-to-peak
    swings of the setting (the controller output) and of the outlet; and what sets the period: the
    fraction of the time the stem rests on its seat (x < 1 um), the primary flow while it is open
    and the mean flow the heat balance needs (kg/h).

    A stem working mid-stroke often slips in bursts (several openings in consecutive steps), which
    ``period_min`` counts as short periods; ``op_period_min`` is the period of the controller
    output's own cycle (the median spacing of its upward crossings of its window mean, as the
    period of an oscillating loop is read from OP or PV), and ``setting_p2p_pct`` its swing as %
    of the action range (OP %, as the real loops' records report it)."""
    w = traj[(traj["t_h"] > t0_h) & (traj["t_h"] < t1_h)]
    x = w["x_mm"].to_numpy()
    dx = np.diff(x)
    opens = np.flatnonzero(dx > min_jump_mm)
    dt_min = float(np.median(np.diff(w["t_h"].to_numpy()))) * 60.0 if len(w) > 1 else math.nan
    q = w["q_primary_kgh"].to_numpy() if "q_primary_kgh" in w else np.full(len(w), math.nan)
    is_open = x >= 1e-3
    u = w["setting_C"].to_numpy() if len(w) else np.zeros(0)
    up = np.flatnonzero((u[:-1] < u.mean()) & (u[1:] >= u.mean())) if u.size > 1 else np.zeros(0, int)
    return {
        "break_aways": float(opens.size),
        "period_min": float(np.median(np.diff(opens)) * dt_min) if opens.size > 1 else math.nan,
        "setting_p2p_K": float(np.ptp(w["setting_C"])) if len(w) else math.nan,
        "op_period_min": float(np.median(np.diff(up)) * dt_min) if up.size > 1 else math.nan,
        "setting_p2p_pct": 100.0 * float(np.ptp(u)) / SETTING_RANGE_K if u.size else math.nan,
        "outlet_p2p_K": float(np.ptp(w["T_out_C"])) if len(w) else math.nan,
        "seated_frac": float(np.mean(~is_open)) if len(w) else math.nan,
        "q_open_kgh": float(np.median(q[is_open])) if is_open.any() else math.nan,
        "q_mean_kgh": float(np.mean(q)) if len(w) else math.nan,
    }


def limit_cycles(task_id: str, seeds: Iterable[int], controller: str = "pi",
                 env_kwargs: Mapping[str, Any] | None = None) -> dict[str, float]:
    """Median :func:`limit_cycle` figures of ``controller`` on ``task_id`` over ``seeds``."""
    from valve_env.controllers import make_controller
    from valve_env.evaluation import rollout

    figs = [limit_cycle(rollout(make_controller(controller, task_id), task_id, int(s), env_kwargs)) for s in seeds]
    return {k: float(np.nanmedian([f[k] for f in figs])) for k in figs[0]}


# -- the report --------------------------------------------------------------------------

REPORT_KPIS = ("iae_Kh", "tdis_Kh", "heat_kWh", "return_C", "reversals", "travel_mm", "cost_eur")


def _f(v: float, digits: int = 3) -> str:
    if v is None or not math.isfinite(v):
        return "n/a"
    return f"{v:.{digits}g}" if abs(v) < 1000 else f"{v:.0f}"


def _ci(lo: Any, hi: Any) -> str:
    """`` [lo, hi]``, or nothing where the interval is unknown."""
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return ""
    return f" [{_f(lo)}, {_f(hi)}]"


def markdown_report(table: pd.DataFrame, found: Mapping[str, Mapping[str, Any]]) -> str:
    """The report's table (one block per task) and the findings, as markdown."""
    lines = ["# ThermoValve benchmark", ""]
    seeds = sorted(set(table["seeds"]))
    pct = f"{100 * CI_LEVEL:g} %"
    lines += [f"Held-out seeds {', '.join(seeds)} ({int(table['episodes'].max())} episodes per controller). "
              f"cost = -return (mean over episodes, [{pct} t-interval]); "
              f"gap score: 0 = {GAP_REFERENCE}, 1 = oracle ((cost_{GAP_REFERENCE} - cost) / "
              f"(cost_{GAP_REFERENCE} - cost_oracle): the share of {GAP_REFERENCE}'s optimality gap closed; "
              f"[{pct} paired percentile bootstrap over the episodes]); "
              "score: 0 = self_acting, 1 = oracle ((cost_self_acting - cost) / (cost_self_acting - cost_oracle)); "
              f"`{SMOOTH}` is pi on a smooth valve (F_hmax 1 mN, none of the task's effects).", ""]
    for task, sub in table.groupby("task", sort=False):
        kpis = [k for k in REPORT_KPIS if k in sub.columns and sub[k].notna().any()]
        lines += [f"## {task}", "", "| controller | cost [CI] | gap score [CI] | score | " + " | ".join(kpis) + " |",
                  "|---|---:|---:|---:|" + "---:|" * len(kpis)]
        for _, r in sub.iterrows():
            cells = [f"{_f(r['cost'])}{_ci(r.get('cost_ci_lo'), r.get('cost_ci_hi'))}",
                     f"{_f(r.get('gap_score', math.nan))}{_ci(r.get('gap_score_ci_lo'), r.get('gap_score_ci_hi'))}",
                     _f(r["score"])]
            cells += [_f(r[k]) for k in kpis]
            lines.append(f"| {r['controller']} | " + " | ".join(cells) + " |")
        f = found.get(str(task), {})
        lines.append("")
        if "headroom_pct" in f:
            lines.append(f"* headroom: oracle cost {_f(f['oracle_cost'])} against the best baseline "
                         f"({f['best_baseline']}) {_f(f['best_baseline_cost'])}: {f['headroom_pct']:.1f} % "
                         f"({'meets' if f['headroom_goal_met'] else 'misses'} the 25 % goal)")
        else:
            lines.append("* headroom: no oracle in this run (scores n/a)")
        if "limit_cycle" in f:
            lc = f["limit_cycle"]
            lines.append(f"* pi's limit cycle, 02:00-05:00 (median over the seeds): {lc['break_aways']:.0f} "
                         f"break-aways of the stem, period {_f(lc['period_min'])} min between them, "
                         f"{_f(lc.get('op_period_min', math.nan))} min in the setting's cycle, setting swing "
                         f"{_f(lc['setting_p2p_K'])} K ({100 * lc['setting_p2p_K'] / SETTING_RANGE_K:.1f} % of its "
                         f"{SETTING_RANGE_K:g} K range), "
                         f"outlet swing {_f(lc['outlet_p2p_K'])} K; the stem rests on its seat "
                         f"{100 * lc.get('seated_frac', math.nan):.0f} % of the time, passes "
                         f"{_f(lc.get('q_open_kgh', math.nan))} kg/h when open against a mean "
                         f"{_f(lc.get('q_mean_kgh', math.nan))} kg/h")
        if "valve_change_pct" in f:
            lines.append(f"* valve matters: pi iae_Kh {_f(f['pi_iae_Kh_task_valve'])} K h on the task's valve, "
                         f"{_f(f['pi_iae_Kh_smooth_valve'])} on a smooth valve: {f['valve_change_pct']:+.1f} % "
                         f"({'yes' if f['valve_matters'] else 'no'}, goal |change| >= 20 %)")
        lines.append("")
    return "\n".join(lines)


def plot_scores(table: pd.DataFrame, path: Any) -> None:
    """Grouped bars: each task's cost per controller with its confidence interval, the gap score
    (0 = pi, 1 = oracle) at the bars where known, else the score (0 = self_acting, 1 = oracle)."""
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(table["task"]))
    fig, axes = plt.subplots(1, len(tasks), figsize=(4.2 * len(tasks), 3.8), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        sub = table[table["task"] == task]
        y = np.arange(len(sub))
        lo, hi = sub["cost"] - sub["cost_ci_lo"], sub["cost_ci_hi"] - sub["cost"]
        err = np.vstack([lo.fillna(0.0), hi.fillna(0.0)])
        ax.barh(y, sub["cost"], xerr=err, color="tab:blue", alpha=0.8)
        ax.set_yticks(y, sub["controller"])
        ax.invert_yaxis()
        gap = sub["gap_score"] if sub["gap_score"].notna().any() else sub["score"]
        for yi, (c, s) in enumerate(zip(sub["cost"], gap, strict=True)):
            if math.isfinite(s):
                ax.annotate(f"{s:.2f}", (c, yi), xytext=(3, 0), textcoords="offset points", va="center",
                            fontsize=8)
        ax.set_title(task, fontsize=9)
        what = f"gap score, 0 = {GAP_REFERENCE}" if sub["gap_score"].notna().any() else "score, 0 = self_acting"
        ax.set_xlabel(f"cost = -return, {100 * CI_LEVEL:g} % CI ({what}, at the bar)")
    fig.tight_layout()
    save_figure(fig, path, format="png")


def plot_kpis(table: pd.DataFrame, path: Any, kpis: Sequence[str] = ("iae_Kh", "reversals")) -> None:
    """Each task's tracking and wear KPIs per controller (the tradeoff the score hides)."""
    from valve_env.plotting import headless, save_figure

    headless()
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(table["task"]))
    fig, axes = plt.subplots(1, len(tasks), figsize=(4.2 * len(tasks), 3.6), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        sub = table[table["task"] == task]
        ax.scatter(sub[kpis[1]], sub[kpis[0]])
        for _, r in sub.iterrows():
            ax.annotate(r["controller"], (r[kpis[1]], r[kpis[0]]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xlabel(kpis[1])
        ax.set_ylabel(kpis[0])
        ax.set_title(task, fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, format="png")


def report_json(table: pd.DataFrame, found: Mapping[str, Any], meta: Mapping[str, Any]) -> str:
    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, (np.floating, np.integer)):
            return clean(v.item())
        return v

    rows = [{k: clean(v) for k, v in r.items()} for r in table.to_dict(orient="records")]
    def clean_all(v: Any) -> Any:
        return {k: clean_all(x) for k, x in v.items()} if isinstance(v, Mapping) else clean(v)

    data = {"meta": dict(meta), "findings": clean_all(found),
            "table": rows}
    return json.dumps(data, indent=1) + "\n"


__all__ = [
    "CI_LEVEL",
    "GAP_REFERENCE",
    "HELD_OUT_SEED",
    "SMOOTH",
    "Cell",
    "findings",
    "gap_score_ci",
    "gap_scores",
    "known_controllers",
    "limit_cycle",
    "limit_cycles",
    "make_cells",
    "markdown_report",
    "mean_ci",
    "normalised_scores",
    "run_cell",
    "smooth_valve",
    "task_table",
]
