"""The >= 50-run confusion-matrix study and the 24 h bench's diagnoses (slow: `pytest -m slow`).

The bench's speed is a figure it prints (`python benchmarks/diagnosis_speed.py`, `thermovalve bench`),
never a timed assertion here."""

from __future__ import annotations

import importlib

import pytest

from valve_env.experiment import random_cases


@pytest.fixture(scope="module")
def confusion_seed11() -> dict:
    study = importlib.import_module("studies.diagnosis_confusion")
    results = study.run_study(random_cases(50, seed=11), workers=1, progress=False)
    return study.confusion(results)


@pytest.mark.slow
def test_confusion_matrix_no_false_findings(confusion_seed11: dict) -> None:
    c = confusion_seed11
    assert c["n"] >= 50
    assert c["false_rate_on_none"] <= 0.05, c


@pytest.mark.slow
def test_confusion_matrix_correct_rate(confusion_seed11: dict) -> None:
    assert confusion_seed11["correct_rate"] >= 0.95, confusion_seed11


@pytest.mark.slow
def test_bench_24h_diagnoses_its_cases() -> None:
    from valve_env.bench import bench_diagnosis

    r = bench_diagnosis()
    assert r["samples"] == 8641
    assert r["diagnosis_wall_s"] > 0.0  # printed by the bench, not a target here
    assert r["diagnosis_cases"]["sensor_lag"]["cause"] == "sensor_lag"
    assert r["diagnosis_cases"]["none"]["cause"] == "none"
