"""Speed of the diagnosis (issue 6): a full diagnosis of 24 h of 10 s data with every candidate.

``run_bench()`` is wired into ``thermovalve bench``; the target is under 60 s on the
project's 2-core machine.
"""

from __future__ import annotations

import time
from typing import Any

CASES: dict[str, dict[str, dict[str, float]]] = {
    "none": {},
    "sensor_lag": {"sensor_lag": {"tau_s": 60.0}},
    "stiction": {"stiction": {"band_mm": 0.02}},
}


def run_bench(hours: float = 24.0, dt_s: float = 10.0, seed: int = 2024,
              cases: dict[str, dict[str, dict[str, float]]] | None = None) -> dict[str, Any]:
    """Time full diagnoses (all candidates, hold-out validation, forward selection) of generated runs.

    One run per case: no effect (the cheapest: forward selection stops at once), a sensor lag (a
    second selection step) and stiction (the slowest likelihood). ``diagnosis_wall_s`` is the
    slowest of them. Numba compilation is done (and timed) first, separately."""
    import numpy as np

    from valve_env.diagnosis.diagnose import diagnose
    from valve_env.experiment import simulate_experiment

    cases = CASES if cases is None else cases
    t0 = time.perf_counter()
    warm = simulate_experiment(seed=seed + 1, duration_h=3.0, dt_s=dt_s,
                               effects={"stiction": {"band_mm": 0.02}, "sensor_lag": {"tau_s": 30.0}})
    diagnose(warm, max_effects=1)
    compile_s = time.perf_counter() - t0
    per_case: dict[str, Any] = {}
    n = 0
    for name, effects in cases.items():
        df = simulate_experiment(seed=seed, duration_h=hours, dt_s=dt_s, effects=effects or None)
        n = len(df)
        t1 = time.perf_counter()
        d = diagnose(df)
        wall = time.perf_counter() - t1
        per_case[name] = {"wall_s": wall, "cause": d.cause, "selected": list(d.selected),
                          "fits": int(1 + sum(len(s) for s in d.steps))}
    worst = max((c["wall_s"] for c in per_case.values()), default=float("nan"))
    return {
        "diagnosis_wall_s": worst,
        "diagnosis_target_s": 60.0,
        "diagnosis_within_target": bool(worst < 60.0),
        "diagnosis_cases": per_case,
        "samples": int(n),
        "hours": hours,
        "dt_s": dt_s,
        "candidates": 4,
        "warmup_compile_s": compile_s,
        "numpy": np.__version__,
    }


__all__ = ["run_bench", "CASES"]
