"""The evaluator's KPIs and return against values computed by hand on a short
synthetic trajectory.

Scenario: ThermoValvePressure-v0 with the pump off (dp = 0 mbar, so no primary
flow) and the valve's setting at 40 degC (shut at 50 degC: no stem travel), no
draws, the tank uniform at 50 degC, 1 h. The tank then only loses
heat to 20 degC ambient through UA_loss evenly over its layers, so it stays
uniform and

    T(t) = 20 + 30 exp(-t UA_loss / (m cp)),   m cp = 200 kg * 4180 J/(kg K).

The kernel evaluates the error after each 10 s sub-step (3 per 30 s step), so
the hand computation samples T at t_j = 10 j s, j = 1 .. 360 (the kernel's
explicit Euler sub-steps differ from the exponential by a few 1e-6 K, hence rel=1e-6).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from valve_env.controllers import SelfActing
from valve_env.evaluation import evaluate, run_episodes

ENV_KW = {
    "tapping_profile": "none",
    "T_init_C": 50.0,
    "T_init_spread_K": 0.0,
    "horizon_h": 1.0,
    "setting_C": 40.0,
}
UA, M_CP, T_AMB, T0 = 1.9, 200.0 * 4180.0, 20.0, 50.0
TARGET, FLOOR, DT_SUB = 60.0, 55.0, 10.0


def _by_hand() -> dict[str, float]:
    t = DT_SUB * np.arange(1, 361)
    T = T_AMB + (T0 - T_AMB) * np.exp(-t * UA / M_CP)
    e = T - TARGET
    short = np.maximum(FLOOR - T, 0.0)
    # reward per 30 s step: -(0.04 mean(e^2) + 1.0 mean(short) + 0.02 * 0 kW), three sub-steps each
    ret = -np.sum(0.04 * (e**2).reshape(-1, 3).mean(axis=1) + short.reshape(-1, 3).mean(axis=1))
    return {
        "rmse_K": math.sqrt(np.mean(e**2)),
        "iae_Kh": float(np.sum(np.abs(e)) * DT_SUB / 3600.0),
        "tdis_Kh": float(np.sum(short) * DT_SUB / 3600.0),
        "return": float(ret),
    }


def test_kpis_match_the_hand_computation() -> None:
    ctrl = SelfActing("ThermoValvePressure-v0", dp_mbar=0.0)
    df = run_episodes(ctrl, "ThermoValvePressure-v0", episodes=2, seed=0, env_kwargs=ENV_KW)
    hand = _by_hand()
    # roughly: T falls from 50 to ~49.75 K over the hour, so rmse ~ 10.1 K, iae ~ 10.1 K h, tdis ~ 5.1 K h
    assert hand["rmse_K"] == pytest.approx(10.123, abs=2e-3)
    assert hand["tdis_Kh"] == pytest.approx(5.123, abs=2e-3)
    for _, row in df.iterrows():
        assert row["rmse_K"] == pytest.approx(hand["rmse_K"], rel=1e-6)
        assert row["iae_Kh"] == pytest.approx(hand["iae_Kh"], rel=1e-6)
        assert row["tdis_Kh"] == pytest.approx(hand["tdis_Kh"], rel=1e-6)
        assert row["return"] == pytest.approx(hand["return"], rel=1e-6)  # Monitor rounds to 1e-6
        for k in ("heat_kWh", "pump_kWh", "unmet_kWh", "travel_mm", "reversals"):
            assert row[k] == 0.0, k
        assert math.isnan(row["return_C"])  # no primary flow: undefined


def test_summary_statistics_by_hand() -> None:
    # two controllers with known per-episode values via fixed settings: the
    # evaluator's mean/std are numpy's population statistics of the episodes
    ctrl = SelfActing("ThermoValvePressure-v0", dp_mbar=0.0)
    kw = {**ENV_KW, "T_init_spread_K": 2.0}
    df = run_episodes(ctrl, "ThermoValvePressure-v0", episodes=3, seed=7, env_kwargs=kw)
    summary = evaluate({"off": ctrl}, "ThermoValvePressure-v0", episodes=3, seed=7, env_kwargs=kw)
    res = summary["results"]["off"]
    x = df["rmse_K"].to_numpy()
    assert res["kpis"]["rmse_K"]["mean"] == pytest.approx(x.mean())
    assert res["kpis"]["rmse_K"]["std"] == pytest.approx(math.sqrt(((x - x.mean()) ** 2).mean()))
    assert res["kpis"]["rmse_K"]["std"] > 0  # the seeds differ in their initial temperature
    assert math.isnan(res["kpis"]["return_C"]["mean"])
