"""Errors in variables for the base fit (valve_env.valveid.eiv): the temperature-noise
bootstrap adds to the Hessian's variance, vanishes without temperature noise, reports its bias."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from valve_env.experiment import simulate_experiment
from valve_env.ident.mle import MLEstimator
from valve_env.valveid.eiv import temperature_bootstrap
from valve_env.valveid.valve_model import ValveModel

NAMES = ("sigma", "F_hmax", "p_bset")


@pytest.fixture(scope="module")
def fitted() -> tuple[MLEstimator, object]:
    df = simulate_experiment(seed=41, duration_h=3.0, dt_s=10.0, T_noise_C=0.01)
    data = df[["time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm"]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = MLEstimator(ValveModel(), n_starts=1, seed=0).fit(data)
    return est, data


def test_bootstrap_adds_the_temperature_noise(fitted: tuple[MLEstimator, object]) -> None:
    est, data = fitted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = temperature_bootstrap(est, data, B=3, seed=1)
    assert r.B == 3 and r.failed == 0 and len(r.replicates) == 3
    assert r.T_noise_C == pytest.approx(0.01, rel=0.3)  # estimated from the data's second differences
    for k in NAMES:
        assert r.std_temperature[k] > 0.0
        assert r.std[k] > r.std_hessian[k]  # var = Hessian + bootstrap (1 + 1/B)
        lw = r.std[k] / r.params[k]
        want = np.sqrt((r.std_hessian[k] / est.params_[k]) ** 2
                       + (1 + 1 / 3) * np.std(np.log(r.replicates[k]), ddof=1) ** 2)
        assert lw == pytest.approx(want, rel=1e-9)
        # bias-corrected estimate: 2 log(theta_hat) - mean log(theta*)
        assert np.log(r.params[k]) == pytest.approx(2 * np.log(est.params_[k]) - np.mean(np.log(r.replicates[k])))
    js = r.to_dict()
    assert set(js["std"]) >= set(NAMES) and "method" in js


def test_no_temperature_noise_no_extra_spread(fitted: tuple[MLEstimator, object]) -> None:
    est, data = fitted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = temperature_bootstrap(est, data, B=2, seed=1, T_noise_C=0.0, T_med_noise_C=0.0)
    # the same input every replicate: every refit lands where the fit did (to the optimiser's tolerance)
    for k in NAMES:
        assert r.std_temperature[k] < 0.05 * r.std_hessian[k]
        assert r.std[k] == pytest.approx(r.std_hessian[k], rel=0.01)


def test_bad_use() -> None:
    with pytest.raises(ValueError, match="fitted"):
        temperature_bootstrap(MLEstimator(ValveModel()), None, B=4)  # type: ignore[arg-type]


def test_quantised_copies_shift_the_grid() -> None:
    """A channel whose noise lies below its 0.1 K step: plain copies are one fixed staircase; copies with
    ``shift_grid`` put the steps elsewhere, keep the step and stay centred on the level. A noisy
    channel's copies do not change."""
    from valve_env.valveid.temperature import channel_noise

    t = np.arange(2000) * 10.0
    level = 60.0 + 0.8 * np.sin(t / 3000.0)
    rec = np.round(level / 0.1) * 0.1
    n = channel_noise(rec)
    assert n.method == "quantisation" and n.quantum == pytest.approx(0.1)
    plain = [n.remeasure(level, n.sd, np.random.default_rng(s)) for s in range(2)]
    assert np.array_equal(plain[0], plain[1])
    shifted = [n.remeasure(level, n.sd, np.random.default_rng(s), shift_grid=True) for s in range(40)]
    assert not np.array_equal(shifted[0], shifted[1])
    for y in shifted[:3]:
        steps = np.abs(np.diff(y))
        assert np.allclose(steps[steps > 1e-9], 0.1, atol=1e-9)  # the channel's step, on a shifted grid
        assert channel_noise(y).quantum == pytest.approx(0.1)
    assert abs(float(np.mean(np.stack(shifted) - level))) < 0.005  # centred: the shift is taken back
    noisy = channel_noise(level + 0.02 * np.random.default_rng(3).standard_normal(level.size))
    assert noisy.method == "mad"
    a = noisy.remeasure(level, noisy.sd, np.random.default_rng(5))
    b = noisy.remeasure(level, noisy.sd, np.random.default_rng(5), shift_grid=True)
    assert np.array_equal(a, b)


def test_quantised_record_is_bias_corrected() -> None:
    """On a record whose temperatures are rounded to 0.1 K, the errors-in-variables fit brackets its
    estimate by the temperature bootstrap's bias correction (half of it applied, its square / 12 added to
    the variance) and says so; the same run with noisy channels is not corrected."""
    from valve_env.params import ValveParams
    from valve_env.valveid.eiv import fit_eiv

    df = simulate_experiment(seed=43, duration_h=4.0, dt_s=10.0, T_noise_C=0.01)
    data = df[["time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm"]].copy()
    q = data.copy()
    for c in ("T_tank_C", "T_med_C"):
        q[c] = np.round(q[c] / 0.1) * 0.1
    truth = ValveParams().sigma
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fq = fit_eiv(q, n_starts=1, B=4, seed=0)
        fn = fit_eiv(data, n_starts=1, B=2, seed=0)
    assert fn.bias_correction is None and fn.to_dict()["bias_correction"] is None
    c = fq.bias_correction["sigma"]
    assert c > 0.03  # the copies' sigma comes out low: the staircase rounds the turning points
    raw = np.exp(0.5 * (np.log(fq.estimates["relaxed"]["sigma"]) + np.log(fq.estimates["tv"]["sigma"])))
    assert fq.params["sigma"] == pytest.approx(raw * np.sqrt(1.0 + c), rel=1e-9)  # the middle of the bracket
    parts = fq.std_parts
    rel2 = (sum(parts[p]["sigma"] ** 2 for p in ("robust", "denoiser"))
            + (1 + 1 / 4) * parts["temperature"]["sigma"] ** 2)
    assert (fq.std["sigma"] / fq.params["sigma"]) ** 2 == pytest.approx(rel2 + np.log1p(c) ** 2 / 12.0, rel=1e-6)
    assert abs(fq.params["sigma"] - truth) < 2.0 * fq.std["sigma"]


def test_quantisation_note() -> None:
    """The console and report.md say what the bracket did: half the bootstrap's correction, per parameter."""
    from valve_env.valveid.report import quantisation_note

    assert quantisation_note({"eiv": {"bias_correction": None}}) is None
    assert quantisation_note({}) is None
    note = quantisation_note({"eiv": {"bias_correction": {"sigma": 0.21, "F_hmax": -0.0}}})
    assert note is not None and "sigma +10.0 %" in note and "F_hmax +0.0 %" in note and "quantised" in note
