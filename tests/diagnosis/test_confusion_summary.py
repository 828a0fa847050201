"""studies/diagnosis_confusion.py's summary: the per-effect relative error counts every correctly named run,
the z-scores only those with an sd (with --bootstrap 0 a stiction band has none)."""

from __future__ import annotations

import importlib
import math


def _run(truth: str, cause: str, true: float, est: float, sd: float) -> dict:
    return {"truth": truth, "cause": cause, "effects": {truth: {"band_mm": true}}, "estimate": {"band_mm": est},
            "std": {"band_mm": sd}, "selected": [cause] if cause != "none" else [], "seconds": 1.0}


def test_relative_error_counts_runs_without_an_sd() -> None:
    study = importlib.import_module("studies.diagnosis_confusion")
    runs = [_run("stiction", "stiction", 0.02, 0.021, 0.001),  # 5 % off, z 1
            _run("stiction", "stiction", 0.02, 0.016, math.nan),  # 20 % off, no sd
            _run("stiction", "stiction", 0.02, 0.019, math.nan),  # 5 % off, no sd
            _run("stiction", "none", 0.02, 0.0, math.nan)]  # not named: not counted
    pe = study.confusion(runs)["per_effect"]["stiction"]
    assert pe["n"] == 3 and pe["n_with_sd"] == 1
    assert math.isclose(pe["median_rel_error"], 0.05) and math.isclose(pe["max_rel_error"], 0.2)
    assert pe["within_3sd"] == 1.0
    assert "relative error median 5.0%, max 20.0% (of 3)" in study.markdown(study.confusion(runs), "cmd", [])
