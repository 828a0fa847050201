"""The independent simulator: its physics against the project's physics and the paper, its
stick-slip rules on their defining cases, seeding and the output columns."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from valve_env.params import ConfigError, ValveParams
from valve_env.physics.valve import dahl_update, opening
from valve_env.studies.independent import (
    COLUMNS,
    IndependentRun,
    demanded_opening_mm,
    draw_run,
    setpoint_C,
    simulate_independent,
    stick_force,
    stick_reset,
    stick_sj,
)

VP = ValveParams()
SHORT = IndependentRun(seed=3, duration_h=3.0, dt_s=10.0, T_noise_C=0.0, x_noise_mm=0.0, rel_noise=0.0)


def test_force_balance_matches_the_project_physics_and_the_paper() -> None:
    T = np.linspace(45.0, 62.0, 41)
    F = np.linspace(-1.3, 1.3, 41)
    a = np.clip(demanded_opening_mm(T, F, 100.0, 2.0, VP.p_bset, VP), 0.0, VP.stroke)
    b = opening(T, F, 100.0, 2.0, VP.p_bset, VP.to_array())
    assert np.max(np.abs(a - b)) < 1e-12
    assert setpoint_C(VP) == pytest.approx(57.9, abs=0.05)  # docs/reference.md, section 1: T_SP = 57.9 degC
    gain = -(demanded_opening_mm(58.4, 0.0, 100.0, 2.0, VP.p_bset, VP)
             - demanded_opening_mm(57.4, 0.0, 100.0, 2.0, VP.p_bset, VP))
    assert gain == pytest.approx(0.167, abs=0.01)  # about 0.167 mm/K at the set point


def test_dahl_ode_agrees_with_the_exact_increment_update() -> None:
    df = simulate_independent(SHORT)
    Tg = df["true_T_g_C"].to_numpy()
    F = np.zeros(len(Tg))
    for i in range(1, len(Tg)):
        F[i] = dahl_update(F[i - 1], Tg[i] - Tg[i - 1], VP.to_array())
    Fo = df["true_F_h_N"].to_numpy()
    assert np.max(np.abs(Fo)) <= VP.F_hmax + 1e-6
    assert np.max(np.abs(Fo - F)) < 2e-3  # different integrators, same trajectory
    assert np.ptp(df["true_x_mm"]) > 0.3  # the programme moves the valve


def test_effects_change_the_run_as_specified() -> None:
    base = simulate_independent(SHORT)
    lag = simulate_independent(dataclasses.replace(SHORT, effects={"sensor_lag": {"tau_s": 120.0}}))
    # the bulb lags: T_g - T_tank follows -tau dT/dt
    r = np.gradient(lag["true_T_tank_C"].to_numpy(), lag["time_s"].to_numpy())
    d = lag["true_T_g_C"].to_numpy() - lag["true_T_tank_C"].to_numpy()
    assert np.corrcoef(d[50:], -r[50:])[0, 1] > 0.9
    med = simulate_independent(dataclasses.replace(SHORT, effects={"medium_temperature": {"beta": 0.2}}))
    want = base["true_T_tank_C"] + 0.2 * (base["true_T_med_C"] - base["true_T_tank_C"])
    assert np.allclose(med["true_T_g_C"], want, atol=1e-9)
    drift = simulate_independent(dataclasses.replace(SHORT, effects={"setpoint_drift": {"rate_MPa_per_h": 1e-3}}))
    inner = (base["true_x_mm"] > 0.05) & (base["true_x_mm"] < 1.9)
    shift = (drift["true_x_demand_mm"] - base["true_x_demand_mm"])[inner]
    C = VP.C_v + VP.C_i + VP.C_b + VP.K_f * 0.01
    want_shift = VP.A_b * 1e-3 * base["time_s"][inner] / 3600.0 / C
    assert np.allclose(shift, want_shift, rtol=1e-6, atol=1e-9)


def test_stick_slip_rules_on_a_ramp_and_a_reversal() -> None:
    band = 0.05
    up = np.linspace(0.5, 1.0, 501)  # a slow ramp of 0.5 mm
    xd = np.r_[up, up[::-1][1:]]  # up, then back down
    reset = stick_reset(xd, band, 2.0)
    sj = stick_sj(xd, band, band, 2.0)
    force = stick_force(xd, band, 0.5, 20.0, 2.0)
    # reset: a staircase, about one slip per band of travel on the way up
    slips = np.count_nonzero(np.diff(reset[:501]) != 0.0)
    assert 8 <= slips <= 11
    # (S, J) with J = S: one slip, then it moves with the demand (no re-sticking on a monotone ramp)
    assert np.count_nonzero(np.diff(sj[:501]) == 0.0) < 0.2 * 501
    assert sj[500] == pytest.approx(1.0)
    # after the reversal it rests until the demand has moved S back, then jumps to it
    k = 500 + np.flatnonzero(sj[501:] != sj[500])[0] + 1
    assert xd[500] - xd[k] == pytest.approx(band, abs=2e-3)
    # force: breakaway after band_mm of travel from the reversal, jump (F_s - F_c)/C, lag F_c/C while slipping
    k = 500 + np.flatnonzero(force[501:] != force[500])[0] + 1
    assert xd[500] - xd[k] == pytest.approx(band, abs=2e-3)
    F_s = 20.0 * band / 1.5
    assert force[k] - xd[k] == pytest.approx(0.5 * F_s / 20.0)
    assert force[500] == pytest.approx(1.0 - 0.5 * F_s / 20.0)


@pytest.mark.parametrize("variant", ["reset", "sj", "force"])
def test_stiction_variants_in_a_run(variant: str) -> None:
    run = dataclasses.replace(SHORT, effects={"stiction": {"band_mm": 0.04}}, stiction_variant=variant)
    df = simulate_independent(run)
    x, xd = df["true_x_mm"].to_numpy(), np.clip(df["true_x_demand_mm"].to_numpy(), 0.0, 2.0)
    assert np.max(np.abs(x - xd)) <= 0.04 + 0.005  # the stem never strays more than the band (1 s grid)
    assert np.count_nonzero(np.diff(x) == 0.0) > np.count_nonzero(np.diff(xd) == 0.0)  # it rests


def test_seeded_columns_and_bad_config() -> None:
    rng = np.random.default_rng(7)
    run = draw_run(rng, "stiction", stiction_variant="sj")
    assert 14.0 <= run.duration_h <= 24.0 and 5.0 <= run.dt_s <= 15.0 and 0.001 <= run.T_noise_C <= 0.02
    a = simulate_independent(dataclasses.replace(run, duration_h=2.0))
    b = simulate_independent(dataclasses.replace(run, duration_h=2.0))
    assert list(a.columns[: len(COLUMNS)]) == list(COLUMNS)
    assert {"true_T_tank_C", "true_T_med_C", "true_T_g_C", "true_F_h_N", "true_x_mm"} <= set(a.columns)
    assert a.equals(b)
    with pytest.raises(ConfigError, match="stiction_variant"):
        simulate_independent(dataclasses.replace(run, stiction_variant="karnopp2"))
    with pytest.raises(ConfigError, match="unknown effect"):
        simulate_independent(dataclasses.replace(run, effects={"backlash": {"band_mm": 0.1}}))


def test_the_medium_programmes_and_measurement_conventions() -> None:
    """The independent simulator records the conventions of measured data: a thermostat's or a constant
    medium temperature (the truth), and measurement conventions on the record (valve_env.studies.conventions)."""
    run = dataclasses.replace(SHORT, T_noise_C=0.01, x_noise_mm=2.4e-3, rel_noise=0.015)
    smooth = simulate_independent(run)
    steps = simulate_independent(dataclasses.replace(run, medium="steps"))
    const = simulate_independent(dataclasses.replace(run, medium="constant"))
    # the same plateaus: a thermostat changes between them within about 20 s instead of minutes
    m_s, m_t = smooth["true_T_med_C"].to_numpy(), steps["true_T_med_C"].to_numpy()
    assert np.max(np.abs(np.diff(m_t))) > 3 * np.max(np.abs(np.diff(m_s)))
    assert np.ptp(const["true_T_med_C"].to_numpy()) == 0.0
    np.testing.assert_array_equal(smooth["true_T_tank_C"].to_numpy(), const["true_T_tank_C"].to_numpy())
    rec = simulate_independent(dataclasses.replace(run, medium="steps", conventions=("stepped_medium", "dropped_5")))
    assert len(rec) == pytest.approx(0.95 * len(smooth), abs=2)
    assert np.mean(np.diff(rec["T_med_C"].to_numpy()) == 0) > 0.8  # noiseless, stored on change
    q = simulate_independent(dataclasses.replace(run, conventions=("quantised_0.1",)))
    z = q["T_tank_C"].to_numpy() / 0.1
    assert np.max(np.abs(z - np.round(z))) < 1e-6
    assert q.attrs["conventions"] == ["quantised_0.1"]
    with pytest.raises(ConfigError, match="convention"):
        simulate_independent(dataclasses.replace(run, conventions=("sampled_by_hand",)))
    with pytest.raises(ConfigError, match="medium"):
        simulate_independent(dataclasses.replace(run, medium="wavy"))
