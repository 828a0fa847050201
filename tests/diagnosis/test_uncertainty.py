"""Honest uncertainty of the named effect's parameters (docs/diagnosis.md, "Parameter uncertainty: the coverage
study"): the stick band estimator, the
stick-slip filter's bias, and the model-based bootstrap. The >= 30-run coverage study is
studies/diagnosis_coverage.py (slow test below)."""

from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

from valve_env.experiment import random_cases, simulate_experiment
from valve_env.ident.kalman import ou_loglik
from valve_env.params import I_STROKE, ValveParams
from valve_env.valveid.bootstrap import bootstrap
from valve_env.valveid.diagnose import check_run, prepare
from valve_env.valveid.fitting import Model
from valve_env.valveid.oe import simulate_valve, stick_loglik, stick_simulate
from valve_env.valveid.stiction import jump_band


@pytest.mark.parametrize(("band", "dt", "seed"), [(0.012, 5.0, 1), (0.025, 10.0, 2), (0.035, 30.0, 3)])
def test_jump_band_recovers_the_band(band: float, dt: float, seed: int) -> None:
    """Under the (S, J) stick-slip the stem slips once per reversal of the demand: a day holds 10-30 slips."""
    df = simulate_experiment(seed=600 + seed, duration_h=24.0, dt_s=dt, effects={"stiction": {"band_mm": band}},
                             x_noise_mm=2e-3)
    b, n_jumps = jump_band(df["x_mm"].to_numpy(), ValveParams().stroke)
    assert n_jumps >= 10
    assert abs(b / band - 1.0) < 0.1, (b, band)


def test_jump_band_without_jumps_is_nan() -> None:
    rng = np.random.default_rng(0)
    x = 0.5 + 0.002 * rng.standard_normal(500)
    b, n = jump_band(x, 2.0)
    assert math.isnan(b) and n < 10


def test_band_sampling_is_the_estimators_spread_and_the_bootstrap_matches_it() -> None:
    """The slip estimator's sampling distribution on a known opening (``band_sampling``) is centred a
    little below the band (some slips are measured short where the demand slows after the slip) and
    about normal; the bootstrap, which sees only the measured run, finds that spread and that bias.
    Bad noise levels and draw counts are refused."""
    from scipy.stats import shapiro

    from valve_env.valveid.stiction import band_sampling

    band = 0.025
    df = simulate_experiment(seed=631, duration_h=24.0, dt_s=10.0, effects={"stiction": {"band_mm": band}},
                             T_noise_C=0.005, x_noise_mm=2.5e-3)
    stroke = float(ValveParams().stroke)
    o = band_sampling(df["true_x_mm"].to_numpy(), 2.5e-3, stroke, draws=120, seed=1)
    assert np.isfinite(o).all()
    assert 0.85 < o.mean() / band < 1.0 and 0.02 < o.std() / band < 0.12, (o.mean(), o.std())
    assert shapiro(o).pvalue > 1e-3
    d = prepare(check_run(df))
    m = Model(("stiction",))
    fit = m.fit(d, with_std=False)
    b = bootstrap(m, d, fit, B=4, band_B=60, seed=2)
    assert 0.7 <= b.spread["band_mm"] / o.std(ddof=1) <= 1.4, (b.spread, o.std(ddof=1))
    # the reported sd is at least the added-noise spread and the slips' own
    parts = b.band_parts
    assert parts["n_slips"] >= 4 and parts["noise_sd_mm"] == b.spread["band_mm"], parts
    assert b.std["band_mm"] >= max(parts["noise_sd_mm"], parts["slips_sd_mm"]), (b.std, parts)
    js = b.to_json()["band_sd_parts"]
    assert js["slips_sd_mm"] == parts["slips_sd_mm"] and js["n_slips"] == parts["n_slips"]
    assert isinstance(js["n_slips"], int)  # a count, not 16.0 in the JSON
    # the bootstrap's bias against the estimator's true overshoot (here 0.2 sampling sd), within 1 sampling sd
    assert abs(b.bias["band_mm"] - (o.mean() - band)) <= o.std(ddof=1), (b.bias, o.mean() - band)
    with pytest.raises(ValueError, match="noise_sd_mm"):
        band_sampling(df["true_x_mm"].to_numpy(), float("nan"), stroke)
    with pytest.raises(ValueError, match="draws"):
        band_sampling(df["true_x_mm"].to_numpy(), 2.5e-3, stroke, draws=1)


@pytest.mark.xfail(strict=True, reason="known and reported: the filter decides a resting "
                   "stem's slip on each measurement (the measured slip decision, behind the simulated null "
                   "guard of diagnose): it catches the slip at the sample that shows it, but with the slip decided "
                   "by the measurement a smaller band costs only the log of the slip's prior where the stem rests, "
                   "so the likelihood peaks below the band (here at 0.5-0.6 band, the band 13.6 log-units below, "
                   "8.1 below the test grid's lowest point, 0.7 band; the moment-matched filter peaked at 0.85 "
                   "band, the band 86 below). The band is "
                   "measured from the slips, not by this likelihood (docs/diagnosis.md, 'Method').")
def test_stick_filter_nested_and_peaks_at_the_band() -> None:
    """Exact stick-slip data: the filter's likelihood is maximal near the true band (the first-passage
    hazard; a filter that re-applied the slip probability every sub-step peaked at 2.5 times the band),
    and equals the base model's at band 0."""
    df = simulate_experiment(seed=611, duration_h=8.0, dt_s=10.0, T_noise_C=0.0)
    d = prepare(check_run(df))
    m = Model(("stiction",))
    vals = {"sigma": 6.41, "F_hmax": 1.31, "p_bset": m.valve.p_bset, "band_mm": 0.03, "s_w": 2e-3, "s_e": 2e-3,
            "tau_e": 300.0}
    vp, e = m._vectors(vals)
    e[2] = 0.03
    x, _, _, xs, idx = simulate_valve(d.t, d.T, d.M, d.dp, d.ps, vp, e, 1.0, m.delta(d, vals), True)
    rng = np.random.default_rng(1)
    y = stick_simulate(xs, idx, 0.03, float(vp[I_STROKE])) + 2e-3 * rng.standard_normal(len(d))
    mask = np.ones(len(d), dtype=np.bool_)
    fs = np.array([0.7, 0.85, 1.0, 1.15, 1.3, 1.6, 2.0, 2.5])
    ll = [stick_loglik(d.t, y, xs, idx, 0.03 * f, float(vp[I_STROKE]), 2e-3, 2e-3, 300.0, mask)[0] for f in fs]
    # the decision-directed filter (a stem decided to move at slip probability 0.5, overturned by a clear
    # measurement) peaks a little above the band (1.3 times on this run, 7 log-units higher than at the
    # band; with the decision at 0.9 it peaked at the band but missed a stiction run): the band itself is
    # measured from the slips (docs/diagnosis.md)
    best = fs[int(np.argmax(ll))]
    assert 0.85 <= best <= 1.15, dict(zip(fs, np.round(np.array(ll) - max(ll), 1), strict=True))
    assert ll[int(np.flatnonzero(fs == 1.0)[0])] > max(ll) - 10.0
    assert ll[0] < max(ll) - 100.0 and ll[-1] < max(ll) - 100.0
    base = ou_loglik(d.t, y - x, 2e-3, 2e-3, 300.0, mask)[0]
    assert stick_loglik(d.t, y, xs, idx, 0.0, float(vp[I_STROKE]), 2e-3, 2e-3, 300.0, mask)[0] == pytest.approx(base)


@pytest.mark.parametrize(("effect", "param", "value", "seed"), [
    ("sensor_lag", "tau_s", 70.0, 21),
    ("setpoint_drift", "rate_MPa_per_h", -5e-5, 22),
    ("stiction", "band_mm", 0.02, 23),
])
def test_bootstrap_sd_covers_the_truth(effect: str, param: str, value: float, seed: int) -> None:
    """A fit and its bootstrap on a short run: the truth lies within 3 reported sd, and the sd is
    neither zero nor absurdly wide (< 25 % of the value)."""
    df = simulate_experiment(seed=seed, duration_h=8.0, dt_s=20.0, effects={effect: {param: value}},
                             T_noise_C=0.008, x_noise_mm=2.5e-3, jitter=0.2)
    d = prepare(check_run(df))
    m = Model((effect,))
    fit = m.fit(d, with_std=False)
    b = bootstrap(m, d, fit, B=8, seed=seed)
    # the value diagnose reports: bias-corrected where the replicates show a clear bias
    est, sd = b.corrected[param], b.std[param]
    assert 0 < sd < 0.25 * abs(value), (est, sd, value)
    assert abs(est - value) <= 3 * sd, (est, sd, value)


SMOOTH = ("sensor_lag", "medium_temperature", "setpoint_drift")


@pytest.fixture(scope="module")
def coverage_303() -> dict:  # type: ignore[type-arg]
    study = importlib.import_module("studies.diagnosis_coverage")
    results = study.run_study(random_cases(40, seed=303, classes=study.EFFECT_CLASSES), workers=2, progress=False)
    return study.coverage(results)  # type: ignore[no-any-return]


@pytest.mark.slow
def test_coverage_study_targets(coverage_303: dict) -> None:  # type: ignore[type-arg]
    """40 runs (10 per effect) on seed 303, which was not looked at while developing the method.

    Pooled over the named runs of the smooth effects (30), the true parameter lies within 1 reported
    sd in >= 60 % and within 2 sd in >= 90 % of them (the targets). Per effect, 10 runs cannot
    resolve 90 %: with honest sd a run falls outside 2 sd with probability 0.046, so asking 9/10
    per effect would fail an honest method in 7 % of studies per effect. The per-effect bounds
    allow for that sampling error (binomial, about 2-3 % false alarms each): >= 50 % within 1 sd,
    >= 80 % within 2 sd, a mean z within 3 of its standard errors (no bias beyond the sd), and each
    effect named in >= 8 of 10."""
    c = coverage_303
    per = c["per_effect"]
    n = sum(per[e]["n"] for e in SMOOTH)
    w1 = sum(per[e]["within_1sd"] * per[e]["n"] for e in SMOOTH) / n
    w2 = sum(per[e]["within_2sd"] * per[e]["n"] for e in SMOOTH) / n
    assert n >= 27 and w1 >= 0.60 and w2 >= 0.90, per
    for e, v in per.items():
        assert v["named"] >= 8, (e, v)
        if e in SMOOTH:
            if e != "medium_temperature":  # its per-effect bounds: the test below
                assert v["within_1sd"] >= 0.50, (e, v)
                assert v["within_2sd"] >= 0.80, (e, v)
            assert abs(v["mean_z"]) <= 3 * v["bias_se_z"], (e, v)


@pytest.mark.slow
def test_coverage_study_medium_temperature_per_effect(coverage_303: dict) -> None:  # type: ignore[type-arg]
    """medium_temperature's per-effect bounds of :func:`test_coverage_study_targets`: >= 50 % within 1 sd and
    >= 80 % within 2 sd of its 10 runs. Short (4 / 7 of 10, rms z 1.53) where the bootstrap refits its
    replicates on the IRW-RTS temperatures while the estimate is the TV refit, whose own error it never sees; so
    the replicates are refitted on TV too (docs/uncertainty.md, "Errors in variables and robust uncertainty")."""
    v = coverage_303["per_effect"]["medium_temperature"]
    assert v["within_1sd"] >= 0.50 and v["within_2sd"] >= 0.80, v


@pytest.mark.slow
def test_coverage_study_stiction_band_sd_is_its_sampling_sd(coverage_303: dict) -> None:  # type: ignore[type-arg]
    """Stiction's band on seed 303, against the jump estimator's own sampling distribution on each
    named run whose band was measured from the slips (``band_oracle``: the run's true opening plus fresh
    noise of its size, 200 draws). A run with fewer than 4 training slips takes the likelihood's band and
    has no such oracle (on this seed one run, 30 s sampling: band 0.0165 +- 0.0030 mm against a true
    0.0164; its oracle had 46 finite draws of 200, which failed this test's draws check unnoticed in the
    slow suite).

    The reported sd is at least that sampling sd and within a factor of it (it also
    takes the slips' own spread and the bootstrap world's bias, which the oracle's noise draws on one fixed true
    opening do not see; measured median ratio 1.97, range 1.43-4.35). The bootstrap's bias correction is
    made in the project's stick-slip world and errs: RMS 0.96 sampling sd, mean +0.40, on the 9 runs (an
    earlier claim of at most 0.6 no longer holds); the reported sd carries that error (the world's
    bias in quadrature), so against the reported sd it is 0.45 RMS; all 10 estimates lie within 2 reported
    sd (9 within 1). Counting estimates within 1 sd is no test of the method on one seed of 10 runs. Over 68
    named stiction runs of five other held-out seeds (505, 808, 909, 1111, 1212) the z lay within 1 / 2
    reported sd in 65 % / 96 % before the reported sd took the slips' own spread (docs/diagnosis.md, "Parameter
    uncertainty: the coverage study")."""
    v = coverage_303["per_effect"]["stiction"]
    o = v["oracle"]
    assert o["n"] >= 7 and o["n"] + o["likelihood_band_runs"] == v["n"] and o["draws_min"] >= 150, o
    assert 1.0 <= o["median_sd_ratio"] <= 2.5, o
    assert o["min_sd_ratio"] >= 0.8 and o["max_sd_ratio"] <= 5.0, o
    # the correction's error is within the reported sd (not within a fraction of the sampling sd)
    assert o["rms_bias_error_reported_sd"] <= 0.75 and abs(o["mean_bias_error"]) <= 0.6, o
    assert v["within_2sd"] >= 0.80, v


def test_residual_blocks_keep_the_memory_of_the_residuals() -> None:
    """The opening's bootstrap noise: white residuals get short blocks, slowly correlated ones long
    blocks, and a resample keeps the slow correlation (the fitted OU model error forgot it)."""
    from statsmodels.tsa.stattools import acf

    from valve_env.ident.bootstrap import block_resample, residual_block_length

    rng = np.random.default_rng(4)
    n = 3000
    white = rng.standard_normal(n)
    slow = np.empty(n)
    slow[0] = 0.0
    for k in range(1, n):
        slow[k] = 0.98 * slow[k - 1] + rng.standard_normal()
    assert residual_block_length(white) <= 5
    L = residual_block_length(slow)
    assert 20 <= L <= n // 4
    draw = block_resample(slow, L, rng)
    assert draw.shape == slow.shape
    assert set(np.round(draw, 12)) <= set(np.round(slow, 12))  # values of the residuals only
    assert acf(draw, nlags=10)[10] > 0.5 * acf(slow, nlags=10)[10] > 0.3


def test_failed_refits_are_set_aside_and_honest_spreads_kept() -> None:
    """A replicate whose refit ran away (here: beta at its bound, the drift far off) is set aside;
    many draws of honest, normal re-estimates lose none; a spread that is mostly ties is left alone."""
    from valve_env.ident.bootstrap import screen_refits

    def failed_refits(reps: np.ndarray) -> np.ndarray:
        return screen_refits(reps)[0]

    rng = np.random.default_rng(5)
    reps = np.column_stack([0.126 + 1e-3 * rng.standard_normal(16), 5e-5 + 2e-6 * rng.standard_normal(16)])
    reps[7] = [0.9, 4e-3]
    bad = failed_refits(reps)
    assert bad.tolist() == [i == 7 for i in range(16)]
    kept = reps[~bad]
    assert kept[:, 0].std(ddof=1) < 2e-3  # the spread without it: that of the honest replicates
    assert reps[:, 0].std(ddof=1) > 0.15  # with it: the absurd sd of seed 303
    honest = sum(int(failed_refits(rng.standard_normal((16, 2))).sum()) for _ in range(500))
    assert honest == 0
    ties = np.zeros((16, 1))
    ties[3] = 1.0  # Qn scale 0: nothing to measure distance in
    assert not failed_refits(ties).any()
    half = np.concatenate([np.zeros(8), 1e3 + rng.standard_normal(8)])[:, None]
    assert not failed_refits(half).any()  # two clusters: no majority to call the other failed


def test_split_replicates_are_not_bias_corrected() -> None:
    """Half of the refits ran away to one far value (a bound): the re-estimates have split, none is
    set aside, and the estimate is not moved by a 'bias' that is the gap between the two groups; a
    clear bias of honest replicates is still corrected."""
    from valve_env.ident.bootstrap import screen_refits, summarise

    rng = np.random.default_rng(11)
    est = 6e-5
    near = est * (1 + 0.01 * rng.standard_normal(8))
    far = 60 * est * (1 + 1e-3 * rng.standard_normal(8))
    reps = np.concatenate([near, far])
    failed, split = screen_refits(reps[:, None])
    assert split and not failed.any()
    names = ["drift"]
    sm = summarise(names, {"drift": est}, {"drift": reps}, no_correction={"drift"})
    assert sm.corrected["drift"] == est and not sm.bias_corrected["drift"]
    assert sm.std["drift"] > 20 * est  # the sd shows the split: root-mean-square error about the estimate
    # without either guard the same replicates would have moved the estimate far below zero
    moved = summarise(names, {"drift": est}, {"drift": reps}, normal_p=0.0)
    assert moved.bias_corrected["drift"] and moved.corrected["drift"] < -20 * est
    # the normality check alone also refuses to correct by the mean of two groups
    assert summarise(names, {"drift": est}, {"drift": reps}).corrected["drift"] == est
    # honest replicates with a clear bias (the mean about 6 se off): no split, corrected
    honest = est + 1e-6 * (1.5 + rng.standard_normal(16))
    assert not screen_refits(honest[:, None])[1]
    sm = summarise(names, {"drift": est}, {"drift": honest})
    assert sm.bias_corrected["drift"] and sm.corrected["drift"] < est


def test_scattered_runaways_are_not_bias_corrected() -> None:
    """Half of the refits ran away and scattered over two decades: the robust screen does not see a
    split (the runaways widen the robust sd itself), but the re-estimates are far from normal, so the
    estimate is not moved by their mean and the sd (RMS error about the estimate) shows the spread.
    Normal re-estimates with a clear bias are still corrected (the check refuses about 1 draw in 1000)."""
    from valve_env.ident.bootstrap import screen_refits, summarise

    rng = np.random.default_rng(12)
    est = 6e-5
    reps = np.concatenate([est * (1 + 0.01 * rng.standard_normal(8)),
                           est * np.exp(rng.uniform(np.log(10.0), np.log(1000.0), 8))])
    failed, split = screen_refits(reps[:, None])
    assert not split and failed.sum() < 8  # the screen alone lets most of them through
    sm = summarise(["drift"], {"drift": est}, {"drift": reps[~failed]})
    assert sm.normality_p["drift"] < 1e-3
    assert not sm.bias_corrected["drift"] and sm.corrected["drift"] == est
    assert sm.std["drift"] > 10 * est
    moved = summarise(["drift"], {"drift": est}, {"drift": reps[~failed]}, normal_p=0.0)
    assert moved.corrected["drift"] < -5 * est  # what the mean would have done
    # a bias of 2 sd (8 se of the mean of 16): clear in every draw, refused only by the normality check
    kept = [summarise(["b"], {"b": 0.0}, {"b": 2.0 + rng.standard_normal(16)}).bias_corrected["b"]
            for _ in range(2000)]
    assert np.mean(kept) > 0.995


@pytest.mark.parametrize("seed", [13, 14])
def test_jump_band_reads_slips_against_the_noise_at_their_opening(seed: int) -> None:
    """Noise that grows with the opening (a flow meter's relative error, in an opening derived from the flow) is
    found by level, and the slips are judged against the noise at their own opening: the band comes back where
    one sd for the record (too small at large openings) took noise steps for slips (seed 13: 46 slips, 0.0037 mm
    against 0.03; seed 14 read 0.026 either way). White noise of the same rms keeps one sd (the code path of every
    measured opening before)."""
    from valve_env.valveid.stiction import opening_noise

    df = simulate_experiment(seed=seed, duration_h=12.0, dt_s=10.0, effects={"stiction": {"band_mm": 0.03}},
                             x_noise_mm=0.0)
    x_true = df["true_x_mm"].to_numpy()
    rng = np.random.default_rng(seed)
    g = x_true / np.sqrt(np.mean(x_true**2))
    relative = x_true + 1.3e-3 * g * rng.standard_normal(x_true.size)
    white = x_true + 1.3e-3 * rng.standard_normal(x_true.size)
    stroke = ValveParams().stroke
    on = opening_noise(relative)
    assert on.level_sd is not None and max(on.level_sd) > 2.5 * min(on.level_sd)
    assert on.describe()["noise_sd_by_level_mm"] == list(on.level_sd)
    b, n = jump_band(relative, stroke)
    assert n >= 8 and abs(b / 0.03 - 1.0) < 0.3, (b, n)
    assert opening_noise(white).level_sd is None
    assert abs(jump_band(white, stroke)[0] / 0.03 - 1.0) < 0.2
