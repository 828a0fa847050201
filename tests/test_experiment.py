"""The synthetic experiment generator (valve_env.experiment) and `thermovalve experiment`."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from valve_env.experiment import COLUMNS, parse_effect, simulate_experiment
from valve_env.params import ConfigError, ValveParams


@pytest.fixture(scope="module")
def run() -> pd.DataFrame:
    return simulate_experiment(seed=11, duration_h=12.0)


def test_columns_and_shape(run: pd.DataFrame) -> None:
    for c in COLUMNS:
        assert c in run.columns
        assert run[c].dtype == float
    for c in ("true_T_tank_C", "true_T_med_C", "true_T_g_C", "true_F_h_N", "true_x_mm"):
        assert c in run.columns
    assert len(run) == 12 * 360 + 1
    assert np.all(np.diff(run["time_s"]) > 0)
    assert np.isfinite(run.to_numpy()).all()


def test_deterministic_and_seeded() -> None:
    a = simulate_experiment(seed=3, duration_h=3.0)
    b = simulate_experiment(seed=3, duration_h=3.0)
    c = simulate_experiment(seed=4, duration_h=3.0)
    pd.testing.assert_frame_equal(a, b)
    assert not np.allclose(a["T_tank_C"], c["T_tank_C"])


def test_noise_levels(run: pd.DataFrame) -> None:
    assert np.std(run["T_tank_C"] - run["true_T_tank_C"]) == pytest.approx(0.01, rel=0.1)
    assert np.std(run["T_med_C"] - run["true_T_med_C"]) == pytest.approx(0.01, rel=0.1)
    assert np.std(run["x_mm"] - run["true_x_mm"]) == pytest.approx(2.4e-3, rel=0.1)
    quiet = simulate_experiment(seed=11, duration_h=2.0, T_noise_C=0.0, x_noise_mm=0.0)
    assert np.array_equal(quiet["T_tank_C"], quiet["true_T_tank_C"])
    assert np.array_equal(quiet["x_mm"], quiet["true_x_mm"])


def test_paper_like_excitation(run: pd.DataFrame) -> None:
    v = ValveParams()
    x = run["true_x_mm"].to_numpy()
    assert x.min() >= 0.0 and x.max() <= v.stroke
    assert (x < 1e-6).mean() > 0.02, "the valve must close"
    assert x.max() > 1.2, "the valve must open nearly fully"
    F = run["true_F_h_N"].to_numpy()
    assert F.max() > 0.9 * v.F_hmax and F.min() < -0.9 * v.F_hmax, "hysteresis in both directions"
    assert np.all(np.abs(F) <= v.F_hmax + 1e-12)
    # smooth tank temperature (first-order dynamics): no jumps between samples
    assert np.max(np.abs(np.diff(run["true_T_tank_C"]))) < 1.5
    # the medium temperature varies independently
    assert abs(np.corrcoef(run["true_T_med_C"], run["true_T_tank_C"])[0, 1]) < 0.9
    assert np.ptp(run["T_med_C"]) > 10.0
    # constant pressures
    assert np.std(run["dp_mbar"]) / 100.0 < 0.01 and abs(run["ps_bar"].mean() - 2.0) < 0.01


def test_flow_consistent_with_opening(run: pd.DataFrame) -> None:
    from valve_env.physics.valve import opening_from_flow

    x_q = opening_from_flow(run["q_kgh"].to_numpy(), run["dp_mbar"].to_numpy(), ValveParams().to_array())
    assert np.sqrt(np.mean((x_q - run["true_x_mm"]) ** 2)) < 0.01


def test_effects_change_the_truth() -> None:
    kw = {"seed": 5, "duration_h": 6.0, "T_noise_C": 0.0, "x_noise_mm": 0.0}
    base = simulate_experiment(**kw)
    lag = simulate_experiment(effects={"sensor_lag": {"tau_s": 120.0}}, **kw)
    assert np.array_equal(base["true_T_tank_C"], lag["true_T_tank_C"])
    d = lag["true_T_g_C"] - lag["true_T_tank_C"]
    assert np.abs(d).max() > 0.5
    # the lagged gas temperature trails the tank: negative while the tank heats up
    v = np.gradient(lag["true_T_tank_C"], lag["time_s"])
    assert np.corrcoef(d, v)[0, 1] < -0.5
    med = simulate_experiment(effects={"medium_temperature": {"beta": 0.2}}, **kw)
    expect = med["true_T_tank_C"] + 0.2 * (med["true_T_med_C"] - med["true_T_tank_C"])
    assert np.allclose(med["true_T_g_C"], expect, atol=1e-9)
    st = simulate_experiment(effects={"stiction": {"band_mm": 0.03}}, **kw)
    moving = (st["true_x_mm"] > 0.01) & (st["true_x_mm"] < 1.9)
    flat = np.mean(np.diff(st["true_x_mm"])[moving[1:].to_numpy()] == 0.0)
    # the (S, J) stem follows the demand once it has slipped and rests only where the demand reversed
    base_flat = np.mean(np.diff(base["true_x_mm"])[moving[1:].to_numpy()] == 0.0)
    assert flat > base_flat + 0.02, "a sticking stem rests after each reversal of the demand"
    jumps = np.abs(np.diff(st["true_x_mm"]))
    assert jumps[jumps > 0].max() >= 0.03 - 1e-9
    dr = simulate_experiment(effects={"setpoint_drift": {"rate_MPa_per_h": 1e-4}}, **kw)
    assert np.array_equal(dr["true_T_g_C"], base["true_T_g_C"])
    late = dr["time_s"] > 5 * 3600
    gain = (dr["true_x_mm"] - base["true_x_mm"])[late & (base["true_x_mm"] > 0.05) & (base["true_x_mm"] < 1.9)]
    assert gain.mean() > 0.02, "a rising set pressure opens the valve"


def test_uneven_sampling_and_intervals() -> None:
    j = simulate_experiment(seed=2, duration_h=2.0, dt_s=30.0, jitter=0.3)
    dt = np.diff(j["time_s"])
    assert np.all(dt > 0) and dt.std() > 1.0
    f = simulate_experiment(seed=2, duration_h=1.0, dt_s=5.0)
    assert len(f) == 721


@pytest.mark.parametrize(
    "kw",
    [
        {"effects": {"foo": {}}},
        {"effects": {"sensor_lag": {}}},
        {"effects": {"sensor_lag": {"tau_s": -1.0}}},
        {"effects": {"sensor_lag": {"tau": 1.0}}},
        {"dt_s": 0.0},
        {"duration_h": -1.0},
        {"jitter": 0.7},
        {"T_noise_C": -0.1},
        {"nonsense": 1.0},
    ],
)
def test_bad_arguments(kw: dict) -> None:
    with pytest.raises(ConfigError):
        simulate_experiment(seed=0, **kw)


def test_parse_effect() -> None:
    assert parse_effect("sensor_lag:tau_s=60") == ("sensor_lag", {"tau_s": 60.0})
    assert parse_effect("setpoint_drift:rate_MPa_per_h=-2e-5") == ("setpoint_drift", {"rate_MPa_per_h": -2e-5})
    for bad in ("sensor_lag", "sensor_lag:tau_s", "sensor_lag:tau_s=x", "what:a=1"):
        with pytest.raises(ConfigError):
            parse_effect(bad)


def _cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    from valve_env.cli import main

    code = main(list(args))
    return code, capsys.readouterr().err


def test_experiment_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.csv"
    code, err = _cli(capsys, "experiment", "--seed", "7", "--hours", "1", "--dt", "20", "--effect",
                     "sensor_lag:tau_s=60", "--effect", "stiction:band_mm=0.02", "--out", str(out))
    assert code == 0, err
    df = pd.read_csv(out)
    assert list(df.columns[:7]) == list(COLUMNS)
    assert len(df) == 181
    ref = simulate_experiment(seed=7, duration_h=1.0, dt_s=20.0,
                              effects={"sensor_lag": {"tau_s": 60.0}, "stiction": {"band_mm": 0.02}})
    assert np.allclose(df["x_mm"], ref["x_mm"], rtol=1e-8, atol=1e-8)
    before = out.read_bytes()
    code, err = _cli(capsys, "experiment", "--seed", "8", "--hours", "1", "--out", str(out))
    assert code != 0 and "exists" in err and len(err.strip().splitlines()) == 1
    assert out.read_bytes() == before
    code, err = _cli(capsys, "experiment", "--seed", "8", "--hours", "1", "--out", str(out), "--force", "--no-truth")
    assert code == 0 and "true_x_mm" not in pd.read_csv(out).columns
    code, err = _cli(capsys, "experiment", "--effect", "sensor_lag:tau_s=-5", "--out", str(tmp_path / "x.csv"))
    assert code != 0 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.csv").exists()


def test_experiment_cli_subprocess(tmp_path: Path) -> None:
    """The installed entry point: one bad call ends with one line and no traceback."""
    r = subprocess.run([sys.executable, "-m", "valve_env.cli", "experiment", "--effect", "bogus:x=1", "--out",
                        str(tmp_path / "y.csv")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "unknown effect 'bogus'" in r.stderr


def test_study_cases_run_in_order_in_process_and_on_a_pool() -> None:
    """The studies' runner: the same results in the cases' order with one or two workers, each
    reported as it arrives; a case's run is the generator's with the case's settings."""
    from valve_env.experiment import random_cases, run_cases, simulate_case, simulate_experiment

    cases = random_cases(4, seed=5)
    seen: list[int] = []
    one = run_cases(dict, cases, 1, lambda r, k: seen.append(k))
    assert one == run_cases(dict, cases, 2) == [dict(c) for c in cases]
    assert seen == [1, 2, 3, 4]
    c = next(c for c in cases if c["truth"] != "none")
    kw = {k: c[k] for k in ("seed", "duration_h", "dt_s", "effects", "T_noise_C", "x_noise_mm", "jitter")}
    assert simulate_case(c).equals(simulate_experiment(**kw))
