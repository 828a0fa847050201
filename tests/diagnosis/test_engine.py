"""The likelihood engine of the diagnosis: latent temperatures, simulation, filters."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from valve_env.experiment import simulate_experiment
from valve_env.ident.kalman import ou_loglik
from valve_env.valveid.fitting import Model, RunData
from valve_env.valveid.oe import monotone_path, stick_demand, stick_loglik
from valve_env.valveid.temperature import smooth_temperature


@pytest.fixture(scope="module")
def run():  # type: ignore[no-untyped-def]
    return simulate_experiment(seed=21, duration_h=6.0)


def _data(df, truth: bool = False) -> RunData:  # type: ignore[no-untyped-def]
    d = RunData.from_arrays(df["time_s"].to_numpy(), df["T_tank_C"].to_numpy(), df["T_med_C"].to_numpy(),
                            df["x_mm"].to_numpy(), df["dp_mbar"].to_numpy(), df["ps_bar"].to_numpy())
    if truth:  # a run is frozen: the true temperatures make another one
        d = dataclasses.replace(d, T=df["true_T_tank_C"].to_numpy().copy(), M=df["true_T_med_C"].to_numpy().copy(),
                                s_T=1e-4, s_M=1e-4)
    return d


def test_monotone_path_removes_small_reversals_without_lag() -> None:
    t = np.linspace(0, 10, 2001)
    y = np.sin(t)
    rng = np.random.default_rng(0)
    noisy = y + 0.002 * rng.standard_normal(t.size)
    out = monotone_path(noisy, 0.02)
    d = np.diff(out)
    # the direction changes only at the true turning points (pi/2, 3pi/2, 5pi/2)
    changes = np.flatnonzero(np.diff(np.sign(d[np.abs(d) > 0])) != 0)
    assert len(changes) == 3
    assert np.max(np.abs(out - y)) < 0.02
    # level-unbiased, no time shift
    assert abs(np.mean(out - y)) < 1e-3
    # the turning points stay where they are (no lag): the first maximum is at pi/2
    first_max = t[np.argmax(out[: t.size // 3])]
    plateau = t[out == out[np.argmax(out[: t.size // 3])]]
    assert plateau.min() - 0.3 < np.pi / 2 < plateau.max() + 0.3
    assert abs(first_max - np.pi / 2) < 0.5
    assert np.array_equal(monotone_path(y, 0.0), y)


def test_stick_demand_reads_the_noise_off_the_seat() -> None:
    """A demand seated on most samples still has its noise's reversals removed: the noise sd is read off the end
    stops. Read over all samples, the seated ones (exactly 0) made
    the deviation 0 and every reversal of the noise re-stuck the diagnosed stem (seed 20270423 run 8, 72 %
    of the samples seated)."""
    rng = np.random.default_rng(3)
    n_seat, n_free = 700, 300
    ramp = np.r_[np.linspace(0.05, 0.4, n_free // 2), np.linspace(0.4, 0.05, n_free - n_free // 2)]
    x = np.r_[np.zeros(n_seat), ramp + 5e-3 * rng.standard_normal(n_free)]
    idx = np.arange(x.size, dtype=np.int64)
    c = stick_demand(x, idx, 2.0)
    free = c[n_seat:]
    dc = np.diff(free)
    reversals = int(np.sum(dc[1:] * dc[:-1] < 0))
    noisy = int(np.sum(np.diff(x[n_seat:])[1:] * np.diff(x[n_seat:])[:-1] < 0))
    assert noisy > 50  # the raw demand reverses at its noise
    assert reversals <= 2  # one true turn (and at most one at a flat block's edge)
    assert np.all(c[:n_seat] == 0.0)  # the end stops keep their value


def test_smoother_beats_the_noise_and_adds_no_lag(run) -> None:  # type: ignore[no-untyped-def]
    t = run["time_s"].to_numpy()
    level, rate, s_T, _ = smooth_temperature(t, run["T_tank_C"].to_numpy())
    err = level - run["true_T_tank_C"].to_numpy()
    assert s_T == pytest.approx(0.01, rel=0.15)
    assert np.sqrt(np.mean(err**2)) < 0.7 * 0.01
    v = np.gradient(run["true_T_tank_C"].to_numpy(), t)
    # a lag would make the error correlate with the rate
    assert abs(np.corrcoef(err, v)[0, 1]) < 0.2


def test_a_run_is_read_only_and_leaves_the_callers_arrays_writable(run) -> None:  # type: ignore[no-untyped-def]
    x = np.ascontiguousarray(run["x_mm"].to_numpy(dtype=float)).copy()
    t = run["time_s"].to_numpy(dtype=float).copy()
    d = RunData.from_arrays(t, run["T_tank_C"].to_numpy(), run["T_med_C"].to_numpy(), x, run["dp_mbar"].to_numpy(),
                            run["ps_bar"].to_numpy())
    for a in (d.t, d.x, d.T, d.M, d.dp, d.ps, d.T_raw, d.M_raw, d.vT, d.vM):
        assert not a.flags.writeable and a.flags.c_contiguous and a.dtype == np.float64
    with pytest.raises(ValueError, match="read-only"):
        d.x[0] = 0.0
    assert x.flags.writeable and t.flags.writeable  # the caller's own arrays keep their flags
    e = dataclasses.replace(d, T=run["true_T_tank_C"].to_numpy().copy())  # a new run is frozen too
    assert not e.T.flags.writeable


def test_simulation_reproduces_the_generator(run) -> None:  # type: ignore[no-untyped-def]
    d = _data(run, truth=True)
    m = Model(())
    xs, Tg, F = m.simulate(d, {**m.default_start(d), "sigma": 6.41, "F_hmax": 1.31, "p_bset": 0.0776})
    assert np.sqrt(np.mean((xs - run["true_x_mm"].to_numpy()) ** 2)) < 5e-4
    assert np.sqrt(np.mean((F - run["true_F_h_N"].to_numpy()) ** 2)) < 0.02


def test_noisy_temperature_does_not_break_the_dahl_model(run) -> None:  # type: ignore[no-untyped-def]
    """With the noisy channel handled as a latent temperature the simulation stays at the noise level."""
    d = _data(run)
    m = Model(())
    xs, _, _ = m.simulate(d, {**m.default_start(d), "sigma": 6.41, "F_hmax": 1.31, "p_bset": 0.0776})
    assert np.sqrt(np.mean((xs - run["true_x_mm"].to_numpy()) ** 2)) < 2.4e-3


def test_stick_filter_nests_the_base_model(run) -> None:  # type: ignore[no-untyped-def]
    d = _data(run)
    m = Model(("stiction",))
    vals = {**m.default_start(d), "band_mm": 0.0, "s_e": 2e-3, "tau_e": 300.0, "s_w": 2.4e-3}
    vp, e = m._vectors(vals)
    from valve_env.valveid.oe import simulate_valve

    x, _, _, x_sub, idx = simulate_valve(d.t, d.T, d.M, d.dp, d.ps, vp, e, 2.5, m.delta(d), True)
    mask = np.ones(len(d), dtype=np.bool_)
    a = ou_loglik(d.t, d.x - x, 2.4e-3, 2e-3, 300.0, mask)[0]
    b = stick_loglik(d.t, d.x, x_sub, idx, 0.0, 2.0, 2.4e-3, 2e-3, 300.0, mask)[0]
    assert b == pytest.approx(a, rel=1e-9, abs=1e-6)
    # and a positive band on data without stiction costs likelihood
    c = stick_loglik(d.t, d.x, x_sub, idx, 0.02, 2.0, 2.4e-3, 2e-3, 300.0, mask)[0]
    assert c < a


def test_stick_filter_statistic_vanishes_with_the_band(run) -> None:  # type: ignore[no-untyped-def]
    """Each measurement is scored once, under the predictive mixture of the filter's hypotheses: as the
    band vanishes the stiction model's likelihood tends to the base model's (the nested models' LR
    statistic tends to 0). The earlier filter rescored a measurement against the hypothesis that the
    measurement itself had chosen and kept a gain at band 1e-8 mm (18.8 and 76.8 in 2 x log-likelihood
    on two seed-5151 runs of the confusion study)."""
    d = _data(run)
    m = Model(("stiction",))
    vals = {**m.default_start(d), "band_mm": 0.0, "s_e": 2e-3, "tau_e": 300.0, "s_w": 2.4e-3,
            "sigma": 6.41, "F_hmax": 1.31, "p_bset": 0.0776}
    base = m.loglik(d, vals)
    lr = [2.0 * (m.loglik(d, {**vals, "band_mm": b}) - base) for b in (1e-8, 1e-6, 1e-5)]
    assert abs(lr[0]) < 1e-3 and abs(lr[1]) < 0.05 and abs(lr[2]) < 0.5, lr


def test_loglik_terms_sum_to_the_loglik(run) -> None:  # type: ignore[no-untyped-def]
    """Each sample's term (the stick-slip filter's mixture term where it weighed hypotheses) sums to the
    log-likelihood, for the base model and for stiction; the held-out gain is their sum over the held-out part."""
    d = _data(run)
    for effects, extra in (((), {}), (("stiction",), {"band_mm": 0.01})):
        m = Model(effects)
        vals = {**m.default_start(d), "s_e": 2e-3, "tau_e": 300.0, "s_w": 2.4e-3, **extra}
        terms = m.loglik_terms(d, vals)
        assert terms.shape == (len(d),)
        assert float(np.sum(terms)) == pytest.approx(m.loglik(d, vals), rel=1e-9)


def test_slips_show_band_needs_slips_of_the_fitted_band() -> None:
    """Stiction's significance needs the training opening to slip by the fitted band: a stick-slip
    staircase shows its band (and not a third or three times it); a smooth noisy ramp, like a run
    without stiction, shows none."""
    from valve_env.valveid.diagnose import slip_sizes, slips_show_band

    rng = np.random.default_rng(1)
    stroke, band, s_w, n = 1.0, 0.03, 0.002, 3000
    demand = 0.4 + 0.2 * np.sin(np.arange(n) / 300.0)
    stem = np.empty(n)
    y = demand[0]
    for k in range(n):  # (S, J = S): rest until the demand is a band away, then land on it
        if abs(demand[k] - y) >= band:
            y = demand[k]
        stem[k] = y
    x = stem + s_w * rng.standard_normal(n)
    n_sl, med = slip_sizes(x, stroke)
    assert n_sl >= 10 and med == pytest.approx(band, rel=0.2)
    assert slips_show_band(x, stroke, band)
    assert not slips_show_band(x, stroke, band / 3.0)
    assert not slips_show_band(x, stroke, 3.0 * band)
    smooth = demand + s_w * rng.standard_normal(n)
    assert not slips_show_band(smooth, stroke, band)
    assert not slips_show_band(x, stroke, 0.0)


@pytest.mark.parametrize(("significant_at_slips_band", "held_out_shows_it", "held_out_hides_slips"),
                         [(True, True, False), (True, False, False), (False, True, False), (True, False, True),
                          (False, False, True)])
def test_stiction_tests_the_slips_band_where_the_likelihood_band_is_not_shown(
        monkeypatch: pytest.MonkeyPatch, significant_at_slips_band: bool, held_out_shows_it: bool,
        held_out_hides_slips: bool) -> None:
    """docs/diagnosis.md: where the training slips (two or more) do not show the likelihood's band,
    stiction is refitted with the band held at the slips' median; that finding replaces the first only if it
    is significant and the held-out opening's slips show the band too, or the held-out part's sampling hides
    the slips (the model with the band shows fewer than two there) and the held-out gain exceeds
    ``UNRESOLVED_MIN_GAIN``; otherwise the first stays, with the slips' band's statistic recorded."""
    from valve_env.valveid import diagnose as dg

    calls: list[dict] = []

    class Fit:
        def __init__(self, band: float, ll: float) -> None:
            self.params = {"band_mm": band}
            self.loglik = ll

    class Est:
        backend_ = None

        def __init__(self, band: float, ll: float) -> None:
            self.result_ = Fit(band, ll)

    class Data:
        x = np.zeros(4)

    def fake_fit(effects, valve, train, start=None, fixed=None):  # type: ignore[no-untyped-def]
        calls.append({"start": start, "fixed": fixed})
        return Est(fixed["band_mm"] if fixed else 0.012, 100.0)

    def fake_finding(effect, est, *args, slips_stand_in=False):  # type: ignore[no-untyped-def]
        band = est.result_.params["band_mm"]
        shown = dg.band_shown(2, 0.033, band)
        f = dg.Finding.__new__(dg.Finding)
        f.lr_stat, f.estimator, f.validated = (40.0 if band > 0.02 else 280.0), est, True
        f.significant = shown and significant_at_slips_band
        f.training_slips = {"n": 2, "median_mm": 0.033, "show_band": shown}
        f.validation_loglik_gain = 10.0
        return f

    monkeypatch.setattr(dg, "_fit", fake_fit)
    monkeypatch.setattr(dg, "_finding", fake_finding)
    monkeypatch.setattr(dg, "NULL_GUARD", False)  # the null guard is tested in test_diagnose.py
    monkeypatch.setattr(dg, "slips_show_band", lambda x, stroke, band: held_out_shows_it and band == 0.033)
    monkeypatch.setattr(dg, "record_shows_band", lambda parts, stroke, band: False)  # record's slips: test_diagnose.py
    # the model's slips at the held-out samples (none where the sampling hides them) and on its sub-steps
    monkeypatch.setattr(dg, "expected_slips", lambda *a, **k: 0 if held_out_hides_slips else 3)
    monkeypatch.setattr(dg, "slips_below_noise", lambda *a, **k: False)
    valve = type("V", (), {"stroke": 2.0})()
    f = dg._try("stiction", (), Fit(0.0, 0.0), Data(), Data(), (0, 4), valve, 0.001, (0.0, 0.0, 0.0), None, 2.0,
                1.0)
    assert calls[-1]["fixed"] == {"band_mm": 0.033} and calls[-1]["start"]["band_mm"] == 0.033
    if significant_at_slips_band and (held_out_shows_it or held_out_hides_slips):
        assert f.estimator.result_.params["band_mm"] == 0.033 and f.significant and f.validated
        assert f.training_slips["band_from"] == "slips"
        assert f.training_slips["held_out_show_band"] is held_out_shows_it
        assert f.training_slips.get("held_out_resolved", True) is not held_out_hides_slips
        assert f.training_slips["likelihood_band_mm"] == 0.012 and f.training_slips["likelihood_lr"] == 280.0
    else:
        assert f.estimator.result_.params["band_mm"] == 0.012 and not f.significant
        assert f.training_slips["slips_band_lr"] == 40.0
        assert f.training_slips["held_out_show_band"] is held_out_shows_it
        if significant_at_slips_band:  # the model's held-out slips were counted: reported with the first finding
            assert f.training_slips["held_out_expected"] == 3 and "held_out_resolved" not in f.training_slips
