"""The baselines' acceptance: on the default scenario the tuned PI beats the
self-acting valve on rmse_K and tdis_Kh over 10 seeds; pi_compensated is
measured against pi and reported (docs/baselines.md), not asserted to win."""

from __future__ import annotations

import numpy as np
import pytest

from valve_env.evaluation import evaluate_detailed

SEEDS = 10


@pytest.fixture(scope="module")
def results() -> tuple[dict, dict]:
    return evaluate_detailed(["self_acting", "pi", "pi_compensated"], "ThermoValve-v0", SEEDS, seed=0)


def test_pi_beats_self_acting_on_rmse_and_tdis(results: tuple[dict, dict]) -> None:
    summary, per_ep = results
    sa, pi = summary["results"]["self_acting"]["kpis"], summary["results"]["pi"]["kpis"]
    assert pi["rmse_K"]["mean"] < sa["rmse_K"]["mean"]
    assert pi["tdis_Kh"]["mean"] < sa["tdis_Kh"]["mean"]
    # paired over the same seeds: never worse on rmse, never worse on tdis
    assert np.all(per_ep["pi"]["rmse_K"].to_numpy() < per_ep["self_acting"]["rmse_K"].to_numpy())
    assert np.all(per_ep["pi"]["tdis_Kh"].to_numpy() <= per_ep["self_acting"]["tdis_Kh"].to_numpy() + 1e-12)


def test_pi_compensated_is_measured_against_pi(results: tuple[dict, dict], capsys: pytest.CaptureFixture) -> None:
    _, per_ep = results
    diff = {k: per_ep["pi_compensated"][k].to_numpy() - per_ep["pi"][k].to_numpy()
            for k in ("return", "rmse_K", "iae_Kh", "tdis_Kh", "heat_kWh", "travel_mm", "reversals")}
    with capsys.disabled():
        print("\npi_compensated - pi, paired over seeds 0..9 (mean, min, max):")
        for k, d in diff.items():
            print(f"  {k:10s} {d.mean():+.4g} [{d.min():+.4g}, {d.max():+.4g}]")
    for d in diff.values():
        assert np.all(np.isfinite(d))
