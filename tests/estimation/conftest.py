"""Shared helpers for the estimation tests."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest

from valve_env.experiment import simulate_experiment

DATA = Path(__file__).resolve().parents[1] / "data" / "ctsmtmb_ornstein"


def _small_run(seed: int, hours: float = 4.0, T_noise: float = 0.01, x_noise: float = 2.4e-3,
               **options: float) -> pd.DataFrame:
    """A paper-like run (valve_env.experiment) without the latent-truth columns."""
    df = simulate_experiment(seed=seed, duration_h=hours, T_noise_C=T_noise, x_noise_mm=x_noise, **options)
    return df[[c for c in df.columns if not c.startswith("true_")]]


@pytest.fixture
def small_run() -> Callable[..., pd.DataFrame]:
    return _small_run


@pytest.fixture
def ornstein_dir() -> Path:
    return DATA
