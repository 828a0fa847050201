"""Shared fixtures of the CLI tests: a short measured run (simulated, docs/reference.md, section 2 columns)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pandas as pd
import pytest


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="session")
def short_run_df() -> pd.DataFrame:
    from valve_env.experiment import simulate_experiment

    df = simulate_experiment(seed=3, duration_h=2.0, dt_s=10.0)  # long enough to identify the valve
    return df[[c for c in df.columns if not c.startswith("true_")]]


@pytest.fixture
def run_csv(tmp_path: Path, short_run_df: pd.DataFrame) -> Path:
    p = tmp_path / "run.csv"
    short_run_df.to_csv(p, index=False, float_format="%.9g")
    return p
