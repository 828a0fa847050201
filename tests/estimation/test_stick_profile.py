"""Stiction's breakaway travel S beside its slip J, the (S, J) profiles of the
open-loop and of the stick-slip filter's likelihood (valve_env.valveid.stick_profile;
valve_env.valveid.bootstrap.breakaway_band; docs/diagnosis.md, "What ``band_mm`` is on a valve with J < S")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from valve_env.studies.independent import COLUMNS, IndependentRun, simulate_independent
from valve_env.valveid.bootstrap import (
    BREAKAWAY_RATIO,
    BREAKAWAY_READ,
    BREAKAWAY_READ_SE,
    Summary,
    breakaway_band,
    breakaway_evident,
    breakaway_unconfirmed,
    calibrated_ratio,
)
from valve_env.valveid.data import RunData
from valve_env.valveid.diagnose import check_run, prepare
from valve_env.valveid.fitting import FitResult, Model
from valve_env.valveid.oe import stick_loglik, stick_simulate
from valve_env.valveid.robust import stick_slip_check
from valve_env.valveid.stick_profile import sj_filter_loglik, sj_profile, spring_rate, stick_simulate_sj
from valve_env.valveid.stiction import jump_band

S_TRUE = 0.035


def _demand_on_substeps() -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, 6 * 3600.0, 2.5)
    x_sub = 1.0 + 0.1 * np.sin(2 * np.pi * t / 5400) + 0.04 * np.sin(2 * np.pi * t / 1300 + 1.0)
    return x_sub, np.arange(0, t.size, 4)


def test_sj_stem_reduces_to_the_diagnosis_stem_at_j_equal_s() -> None:
    """With J = S the (S, J) stem is the diagnosis's (engine.stick_simulate), sample for sample; with J < S it
    lags the demand by (S - J) / 2 while it moves, and its slips are J."""
    x_sub, idx = _demand_on_substeps()
    S = 0.03
    a = stick_simulate_sj(x_sub, idx, S, S, 2.0)
    np.testing.assert_array_equal(a, stick_simulate(x_sub, idx, S, 2.0))
    b = stick_simulate_sj(x_sub, idx, S, S / 3, 2.0)
    steps = np.abs(np.diff(b))
    assert not np.allclose(a, b)
    # the largest sampled steps are J plus the motion of one sample, not S
    assert np.quantile(steps, 0.999) < 0.75 * S
    moving = np.flatnonzero(np.abs(np.diff(b)) > 0)[1:]
    lag = np.abs(b[moving + 1] - x_sub[idx][moving + 1])
    assert abs(float(np.median(lag)) - S / 3) < 0.1 * S


def test_filter_with_a_slip_reads_the_breakaway_and_keeps_j_equal_s() -> None:
    """The stick-slip filter with slips J < S (``slip``; breakaway where the demand is (S + J) / 2 from the
    stem, the (S, J) stem's): on exact (S, J = S / 3) stick-slip its likelihood peaks at the true S / J and gains
    hundreds of log-units over the J = S filter; on (S, S) data the lag only loses. ``slip`` negative or at least
    the band is the diagnosis's filter, bit for bit."""
    x_sub, idx = _demand_on_substeps()
    ts = np.arange(0.0, 6 * 3600.0, 2.5)[idx]
    mask = np.ones(ts.size, dtype=np.bool_)
    rng = np.random.default_rng(3)
    S = 0.03

    def ll(y: np.ndarray, k: float, J: float) -> float:
        B, slip = (0.5 * (k * J + J), J) if k > 1.0 else (J, -1.0)
        return float(stick_loglik(ts, y, x_sub, idx, B, 2.0, 2e-3, 1e-4, 300.0, mask, 0.5, 0.2, slip)[0])

    ks = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
    y = stick_simulate_sj(x_sub, idx, S, S / 3, 2.0) + 2e-3 * rng.standard_normal(ts.size)
    gain = [ll(y, k, S / 3) - ll(y, 1.0, S / 3) for k in ks]
    assert ks[int(np.argmax(gain))] in (2.5, 3.0, 3.5) and max(gain) > 300.0, gain
    y = stick_simulate_sj(x_sub, idx, S, S, 2.0) + 2e-3 * rng.standard_normal(ts.size)
    assert ll(y, 1.5, S) < ll(y, 1.0, S) - 10.0
    ref = stick_loglik(ts, y, x_sub, idx, S, 2.0, 2e-3, 1e-4, 300.0, mask)
    for slip in (-1.0, S, 2 * S):
        got = stick_loglik(ts, y, x_sub, idx, S, 2.0, 2e-3, 1e-4, 300.0, mask, 0.5, 0.2, slip)
        for a, b in zip(ref, got, strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module")
def runs() -> dict[str, tuple[Model, RunData, dict[str, float]]]:
    """12 h at 10 s of the independent simulator's ``force`` (r = 0.5, J = S / 3), ``sj`` (J = S) and ``reset``
    valves with a 0.035 mm band, and the values a fit of the project's model (J = S) takes: J from the slips
    (the ``force`` valve's few measurable slips: its J), the lag (S - J) / 2 in a larger F_hmax."""
    out = {}
    m = Model(("stiction",))
    for variant in ("force", "sj", "reset"):
        df = simulate_independent(IndependentRun(seed=11, duration_h=12.0, dt_s=10.0, T_noise_C=0.005,
                                                 effects={"stiction": {"band_mm": S_TRUE}},
                                                 stiction_variant=variant))
        run = prepare(check_run(df.loc[:, list(COLUMNS)]))
        J = jump_band(run.x, 2.0)[0] if variant != "force" else S_TRUE / 3
        lag = (S_TRUE - J) / 2 if variant == "force" else 0.0
        vals = {"sigma": 6.41, "F_hmax": 1.31 + spring_rate(m, run) * lag, "p_bset": 0.0776, "band_mm": float(J),
                "s_w": 2.4e-3, "s_e": 0.003, "tau_e": 300.0}
        out[variant] = (m, run, vals)
    return out


def test_profile_reads_the_breakaway_of_a_force_valve(runs) -> None:  # type: ignore[no-untyped-def]
    """The force valve's profile puts S / J well above 1 and S within 25 % of the truth; the (S, J = S)
    valve's stays at 1 (S = J, the slips' band)."""
    m, run, vals = runs["force"]
    p = sj_profile(m, run, vals)
    assert p.ratio >= 2.25  # above every J = S valve's open-loop reading (up to 2.0)
    assert abs(p.S_mm - S_TRUE) / S_TRUE < 0.25, p.to_json()
    ll = p.to_json()["profile_loglik"]
    assert isinstance(ll, dict) and ll["1"] == 0.0 and max(ll.values()) > 0.0
    assert 0.0 < p.ratio_sd < p.ratio
    m, run, vals = runs["sj"]
    q = sj_profile(m, run, vals)
    assert q.ratio == 1.0 and q.ratio_sd == 0.0 and q.S_mm == vals["band_mm"], q.to_json()
    with pytest.raises(ValueError, match="ratios"):
        sj_profile(m, run, vals, ratios=(1.5, 2.0))


def _summary(band: float, sd: float) -> Summary:
    k = "band_mm"
    return Summary({k: sd}, {k: 0.0}, {k: (band - 2 * sd, band + 2 * sd)}, {k: band}, {k: False}, {k: sd}, {k: 1.0})


def _fit(vals: dict[str, float]) -> FitResult:
    return FitResult(("stiction",), dict(vals), {}, 0.0, 0, 0, 0.0, True)


def test_filter_profile_tells_force_from_j_equal_s(runs) -> None:  # type: ignore[no-untyped-def]
    """The stick-slip filter's profile puts the force valve (S / J = 3) at or above the threshold,
    its reading within 2 profile sd of 3 and S nearer the truth than the slips' J; the J = S valves stay below it
    (the sj valve's stem stuck longer than it slipped, so only the threshold keeps it; the reset valve's did not,
    and its profile stays at 1). The profile is flat near its peak on this run (2.25 to 3.5 within 7 log-units
    with the Student-t smoother; 2.25 was 4 log-units under 3 with the former IRW smoother), so its reading moves
    by grid steps with the pre-processing: the test asks what the profile's sd says, not a point within 25 %."""
    m, run, vals = runs["force"]
    p = sj_profile(m, run, vals, loglik=sj_filter_loglik)
    assert p.ratio >= BREAKAWAY_RATIO and abs(p.ratio - S_TRUE / p.J_mm) <= 2.0 * p.ratio_sd, p.to_json()
    assert abs(p.S_mm - S_TRUE) < abs(p.J_mm - S_TRUE), p.to_json()
    for variant in ("sj", "reset"):
        m, run, vals = runs[variant]
        q = sj_profile(m, run, vals, loglik=sj_filter_loglik)
        med = stick_slip_check(m, run, _fit(vals), warn=False)["travel_over_slip_median"]
        assert not breakaway_evident(med, q.ratio, q.ratio_sd), (variant, med, q.to_json())
        assert q.ratio < BREAKAWAY_RATIO


def test_breakaway_band_moves_force_and_keeps_reset(runs) -> None:  # type: ignore[no-untyped-def]
    """The bootstrap's band: on the force valve S (nearer the truth than J, its interval covering it: the point
    reading moves by a grid step with the pre-processing, see the test above), its sd the slips' scaled plus the
    profile's width, J reported beside it; on the reset valve (re-sticks after every slip) the slips' band and sd
    exactly as they were."""
    m, run, vals = runs["force"]
    J, sd = vals["band_mm"], 0.1 * vals["band_mm"]
    sm = _summary(J, sd)
    out = breakaway_band(m, run, _fit(vals), sm)
    assert out["applied"] is True
    S = sm.corrected["band_mm"]
    assert abs(S - S_TRUE) < abs(J - S_TRUE)
    assert out["J_mm"] == J and out["S_mm"] == S
    assert sm.std["band_mm"] > out["profile_S_over_J"] * sd  # the (S, J) trade-off widens it
    assert out["S_sd_mm"] == sm.std["band_mm"]
    lo, hi = sm.interval_95["band_mm"]
    assert lo < S_TRUE < hi  # the band's interval covers the true breakaway travel
    # the filter's reading (2.25 here against 3) corrected for its low reading on the fitted valve:
    # S within 25 % of the truth and within its sd, the uncorrected S = 2.25 J was 25 % short
    assert out["S_over_J"] == pytest.approx(out["profile_S_over_J"] / BREAKAWAY_READ)
    assert abs(S - S_TRUE) < 0.25 * S_TRUE and abs(S - S_TRUE) < sm.std["band_mm"], out
    assert abs(S - S_TRUE) < abs(out["profile_S_over_J"] * J - S_TRUE), out
    assert isinstance(out["open_loop"], dict) and "profile_S_over_J" in out["open_loop"]
    m, run, vals = runs["reset"]
    J, sd = vals["band_mm"], 0.05 * vals["band_mm"]
    sm = _summary(J, sd)
    out = breakaway_band(m, run, _fit(vals), sm)
    assert out["applied"] is False
    assert sm.corrected["band_mm"] == J and sm.std["band_mm"] == sd and out["S_mm"] == J
    assert abs(J - S_TRUE) / S_TRUE < 0.1


def test_unconfirmed_breakaway_widens_the_band_sd(runs, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Where the profile reads S > J but the stuck travel does not confirm it (here: the travel threshold raised out of
    reach on the force valve), the band stays the slips' J, and its sd takes half the distance to the calibrated S in
    quadrature: the 2-sd interval reaches that S, and J's own sd is the floor."""
    import valve_env.valveid.bootstrap as B

    monkeypatch.setattr(B, "BREAKAWAY_TRAVEL", 1e9)
    m, run, vals = runs["force"]
    J, sd = vals["band_mm"], 0.1 * vals["band_mm"]
    sm = _summary(J, sd)
    out = breakaway_band(m, run, _fit(vals), sm)
    assert out["applied"] is False and out["profile_S_over_J"] >= BREAKAWAY_RATIO
    S_alt = out["unconfirmed_S_mm"]
    assert S_alt == pytest.approx(out["profile_S_over_J"] / BREAKAWAY_READ * J)
    assert sm.corrected["band_mm"] == J and out["S_mm"] == J
    assert sm.std["band_mm"] == pytest.approx(math.hypot(sd, 0.5 * (S_alt - J))) == out["S_sd_mm"]
    assert J + 2.0 * sm.std["band_mm"] >= S_alt and sm.std["band_mm"] > sd
    lo, hi = sm.interval_95["band_mm"]
    assert lo == pytest.approx(J - 1.96 * sm.std["band_mm"]) and hi == pytest.approx(J + 1.96 * sm.std["band_mm"])


def test_breakaway_unconfirmed_is_the_profile_without_the_travel() -> None:
    assert breakaway_unconfirmed(0.9, BREAKAWAY_RATIO, 0.5)
    assert breakaway_unconfirmed(math.nan, 3.0, 0.5)  # no slip's travel measured: not confirmed
    assert not breakaway_unconfirmed(1.5, BREAKAWAY_RATIO, 0.5)  # confirmed: breakaway_evident's case
    assert not breakaway_unconfirmed(0.9, BREAKAWAY_RATIO - 0.25, 0.1)
    assert not breakaway_unconfirmed(0.9, BREAKAWAY_RATIO, 1.27)  # a flat profile reads nothing


def test_breakaway_evident_needs_both_signs() -> None:
    assert breakaway_evident(1.5, BREAKAWAY_RATIO, 0.5)
    assert not breakaway_evident(1.5, BREAKAWAY_RATIO - 0.25, 0.1)
    assert not breakaway_evident(0.9, 3.0, 0.5)
    assert not breakaway_evident(math.nan, 3.0, 0.5)
    # a flat profile (its reading less than one sd above J = S) is no evidence of J < S
    assert not breakaway_evident(1.5, BREAKAWAY_RATIO, 1.27)


def test_calibrated_ratio_scales_the_reading_and_its_sd() -> None:
    """The filter's reading over the development factor (it read low), its sd the width scaled and the factor's own
    standard error in quadrature: never narrower than either."""
    k, sd = calibrated_ratio(2.0, 0.5)
    assert BREAKAWAY_READ < 1.0 and k == pytest.approx(2.0 / BREAKAWAY_READ)
    assert sd == pytest.approx(math.hypot(0.5 / BREAKAWAY_READ, k * BREAKAWAY_READ_SE))
    assert sd > 0.5 / BREAKAWAY_READ and sd > k * BREAKAWAY_READ_SE
    assert calibrated_ratio(2.0, 0.0)[1] == pytest.approx(k * BREAKAWAY_READ_SE)
