"""Per-run scores summarised the way RL benchmarks report them (Agarwal et al. 2021, "Deep RL at the
edge of the statistical precipice"): the interquartile mean (IQM: the mean of the middle 50 % of the
runs, ``rliable.metrics.aggregate_iqm``) with a 95 % stratified-bootstrap confidence interval
(``rliable.library.get_interval_estimates``: runs resampled with replacement within each task).

The input is one row per training run (``runs.csv`` of ``python -m agents.scratch evaluate``):
``algo``, ``task``, ``seed`` and the run's metrics on the held-out episodes (``cost``, ``gap_score``,
...). docs/agents.md, "From scratch".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

#: bootstrap resamples (rliable's default is 50000; 2000 keeps a summary under a second)
REPS = 2000
CI_SIZE = 0.95
#: the aggregate row over all tasks
ALL_TASKS = "all tasks"


def iqm(scores: np.ndarray) -> float:
    """The interquartile mean of ``scores`` (any shape; rliable's definition: scipy's 25 % trimmed mean)."""
    from rliable import metrics

    return float(metrics.aggregate_iqm(np.asarray(scores, float)))


def _bootstrap(scores: np.ndarray) -> object:
    """rliable's ``StratifiedBootstrap`` of a (runs x tasks) matrix, through a compatibility shim.
    rliable 1.2.0 hands ``random_state=`` to arch's ``IIDBootstrap``, which arch (7 and 8: the
    project pins 8.0) names ``seed``: arch takes the stray keyword for a data array and refuses it
    (TypeError), so rliable's own constructor cannot run. This subclass sets up the same object
    without that keyword; the resampling (runs within each task, rliable's ``update_indices``, from
    NumPy's global generator) and ``conf_int`` are rliable's and arch's own. rliable is installed
    with ``--no-deps`` for the same reason (it declares arch<8; Makefile ``install``)."""
    from arch.bootstrap import IIDBootstrap
    from rliable import library as rly

    class _Stratified(rly.StratifiedBootstrap):  # type: ignore[misc]
        def __init__(self, data: np.ndarray) -> None:
            IIDBootstrap.__init__(self, data)
            self._args_shape = data.shape
            self._num_tasks = self._args_shape[1]
            self._parameters = [self._num_tasks, False]
            self._task_bootstrap = False
            self._strata_indices = self._get_strata_indices()

    return _Stratified(scores)


def iqm_interval(scores: np.ndarray, reps: int = REPS, seed: int = 0,
                 ci: float = CI_SIZE) -> tuple[float, float, float]:
    """(IQM, lower, upper) of a (runs x tasks) matrix (a vector: one task): the stratified
    bootstrap's percentile interval at ``ci`` (runs resampled within each task, as
    ``rliable.library.get_interval_estimates`` does). rliable draws from NumPy's global generator:
    it is seeded with ``seed`` here and restored after, so a summary is reproducible."""
    from rliable import metrics

    a = np.asarray(scores, float)
    if a.ndim == 1:
        a = a[:, None]
    if a.shape[0] < 1 or not np.all(np.isfinite(a)):
        return math.nan, math.nan, math.nan
    point = float(metrics.aggregate_iqm(a))
    state = np.random.get_state()  # noqa: NPY002  (rliable draws from the legacy global generator)
    try:
        np.random.seed(seed)  # noqa: NPY002
        interval = _bootstrap(a).conf_int(  # type: ignore[attr-defined]
            lambda x: np.array([metrics.aggregate_iqm(x)]), reps=int(reps), size=ci, method="percentile")
    finally:
        np.random.set_state(state)  # noqa: NPY002
    return point, float(interval[0, 0]), float(interval[1, 0])


def summarise(runs: pd.DataFrame, metrics: Sequence[str] = ("gap_score", "score", "cost"), reps: int = REPS,
              seed: int = 0, aggregate: Sequence[str] = ("gap_score", "score")) -> pd.DataFrame:
    """One row per (algo, task): ``n_runs`` and for each metric ``<m>_iqm``, ``<m>_lo``, ``<m>_hi``
    (the IQM over the training runs and its 95 % stratified-bootstrap interval); then one row per
    algo with task ``ALL_TASKS`` for the ``aggregate`` metrics (scale-free ones: a cost's units
    differ between tasks), from the (runs x tasks) matrix of the tasks where the algo has the same
    number of runs (rliable's layout); the other metrics are NaN there."""
    rows = []
    for (algo, task), g in runs.groupby(["algo", "task"], sort=True):
        row: dict[str, object] = {"algo": algo, "task": task, "n_runs": len(g)}
        for m in (m for m in metrics if m in g):
            row[f"{m}_iqm"], row[f"{m}_lo"], row[f"{m}_hi"] = iqm_interval(g[m].to_numpy(float), reps, seed)
        rows.append(row)
    for algo, g in runs.groupby("algo", sort=True):
        counts = g.groupby("task").size()
        n = int(counts.mode().iloc[0])
        tasks = sorted(counts.index[counts == n])
        row = {"algo": algo, "task": ALL_TASKS, "n_runs": n * len(tasks), "n_tasks": len(tasks)}
        for m in (m for m in metrics if m in g):
            if m in aggregate:
                mat = np.column_stack([g[g["task"] == t].sort_values("seed")[m].to_numpy(float) for t in tasks])
                row[f"{m}_iqm"], row[f"{m}_lo"], row[f"{m}_hi"] = iqm_interval(mat, reps, seed)
            else:
                row[f"{m}_iqm"] = row[f"{m}_lo"] = row[f"{m}_hi"] = math.nan
        rows.append(row)
    return pd.DataFrame(rows)


def _f(v: float) -> str:
    if not math.isfinite(v):
        return "n/a"
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def markdown(summary: pd.DataFrame, metrics: Sequence[str] = ("gap_score", "score", "cost")) -> list[str]:
    """The summary as a markdown table: IQM [95 % CI] per metric (those the summary has)."""
    metrics = [m for m in metrics if f"{m}_iqm" in summary]
    lines = ["| algo | task | runs | " + " | ".join(f"{m} IQM [95 % CI]" for m in metrics) + " |",
             "|---|---|---:|" + "---:|" * len(metrics)]
    for _, r in summary.iterrows():
        cells = [f"{_f(r[f'{m}_iqm'])} [{_f(r[f'{m}_lo'])}, {_f(r[f'{m}_hi'])}]"
                 if math.isfinite(r[f"{m}_iqm"]) else "n/a" for m in metrics]
        lines.append(f"| {r['algo']} | {r['task']} | {int(r['n_runs'])} | " + " | ".join(cells) + " |")
    return lines
