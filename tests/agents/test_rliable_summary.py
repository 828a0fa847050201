"""The from-scratch summary: the interquartile mean with rliable's stratified-bootstrap interval, from
per-run scores stored as a CSV (agents.rliable_summary, agents.scratch, the task leaderboard's --scratch)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from agents.rliable_summary import ALL_TASKS, iqm, iqm_interval, summarise


def test_iqm_of_a_hand_made_case() -> None:
    """Eight runs scoring 1..8: the IQM drops the lowest and the highest two and is (3+4+5+6)/4 = 4.5;
    the interval holds it and stays within the scores."""
    assert iqm(np.arange(1.0, 9.0)) == pytest.approx(4.5)
    point, lo, hi = iqm_interval(np.arange(1.0, 9.0), reps=500)
    assert point == pytest.approx(4.5)
    assert 1.0 <= lo < 4.5 < hi <= 8.0
    assert iqm_interval(np.arange(1.0, 9.0), reps=500) == (point, lo, hi)  # seeded: reproducible


def test_the_bootstrap_is_stratified_by_task() -> None:
    """Two tasks of four runs each, one scoring 0 on every run and one 10: every stratified resample
    keeps four runs of each task, so the IQM is 5 (the middle four of 0,0,0,0,10,10,10,10) and the
    interval is exactly [5, 5]. A bootstrap over the pooled runs would give a wide interval."""
    scores = np.column_stack([np.zeros(4), np.full(4, 10.0)])
    assert iqm_interval(scores, reps=300) == pytest.approx((5.0, 5.0, 5.0))


def test_summary_from_stored_per_run_scores(tmp_path: Path) -> None:
    """runs.csv as agents.scratch stores it -> one row per (algo, task) and one over all tasks."""
    runs = pd.DataFrame({"algo": ["ppo"] * 8, "task": ["A"] * 4 + ["B"] * 4, "seed": [0, 1, 2, 3] * 2,
                         "gap_score": [-1.0, 0.0, 0.5, 9.0, 0.2, 0.4, 0.6, 0.8],
                         "cost": [4.0, 3.0, 2.0, 1.0, 10.0, 20.0, 30.0, 40.0]})
    path = tmp_path / "runs.csv"
    runs.to_csv(path, index=False)
    s = summarise(pd.read_csv(path), reps=300).set_index("task")
    assert s.loc["A", "gap_score_iqm"] == pytest.approx(0.25)  # the middle two of -1, 0, 0.5, 9
    assert s.loc["B", "cost_iqm"] == pytest.approx(25.0)
    assert s.loc["A", "gap_score_lo"] <= 0.25 <= s.loc["A", "gap_score_hi"]
    pooled = np.array([-1.0, 0.0, 0.5, 9.0, 0.2, 0.4, 0.6, 0.8])
    assert s.loc[ALL_TASKS, "gap_score_iqm"] == pytest.approx(np.mean(np.sort(pooled)[2:6]))
    assert s.loc[ALL_TASKS, "n_runs"] == 8 and np.isnan(s.loc[ALL_TASKS, "cost_iqm"])


def test_task_leaderboard_refuses_runs_scored_on_other_seeds() -> None:
    from agents.task_leaderboard import scratch_rows

    runs = pd.DataFrame({"algo": ["td3"] * 2, "task": ["A"] * 2, "seed": [0, 1], "gap_score": [0.1, 0.2],
                         "cost": [1.0, 2.0], "eval_seeds": ["5000-5004"] * 2})
    assert len(scratch_rows(runs, list(range(5000, 5005)))) == 2
    with pytest.raises(ValueError, match="5000-5009"):
        scratch_rows(runs, list(range(5000, 5010)))


def test_the_hundred_times_budget_table_is_what_its_stored_runs_give() -> None:
    """docs/agents.md, "A hundred times the budget (PPO)": each task's gap-score IQM and interval in the table is
    the rliable summary of the stored per-run scores (docs/scratch_ppo_100x_runs.csv), to the printed digits."""
    docs = Path(__file__).resolve().parents[2] / "docs"
    s = summarise(pd.read_csv(docs / "scratch_ppo_100x_runs.csv")).set_index("task")
    text = (docs / "agents.md").read_text(encoding="utf-8").split("### A hundred times the budget (PPO)")[1]
    text = text.split("\n#")[0]  # the section alone
    rows = {line.split("|")[1].strip(): line.split("|")[4] for line in text.splitlines()
            if line.startswith("| ") and "-v" in line}
    assert len(rows) == 5
    for task, cell in rows.items():
        point, lo, hi = (float(v) for v in cell.replace("*", "").replace("[", " ").replace("]", " ")
                         .replace(",", " ").split())
        got = s.loc[f"ThermoValve{task}"]
        assert got["gap_score_iqm"] == pytest.approx(point, rel=5e-3, abs=5e-4)
        assert (got["gap_score_lo"], got["gap_score_hi"]) == pytest.approx((lo, hi), rel=5e-3, abs=5e-4)
