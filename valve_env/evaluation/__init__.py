"""The evaluator: score any controller with SB3's ``predict`` on the KPIs of
docs/reference.md, section 5, over seeded episodes (``thermovalve evaluate``, ``thermovalve demo``)."""

from __future__ import annotations

from valve_env.evaluation.evaluator import (
    DEFAULT_CONTROLLERS,
    evaluate,
    evaluate_detailed,
    make_env,
    markdown_table,
    rollout,
    run_episodes,
    summarise,
    summary_frame,
    write_outputs,
)

__all__ = [
    "DEFAULT_CONTROLLERS",
    "evaluate",
    "evaluate_detailed",
    "make_env",
    "markdown_table",
    "rollout",
    "run_episodes",
    "summarise",
    "summary_frame",
    "write_outputs",
]
