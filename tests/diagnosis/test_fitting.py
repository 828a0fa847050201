"""Tests of valve_env.valveid.fitting: the maximum-likelihood fit of the base model and its effects."""

from __future__ import annotations

import numpy as np
import pytest

from valve_env.experiment import simulate_experiment
from valve_env.params import I_STROKE
from valve_env.valveid.diagnose import check_run, prepare
from valve_env.valveid.fitting import LOGLIK_RUNS, Model
from valve_env.valveid.oe import stick_loglik, stick_simulate


def test_a_warm_start_is_kept_by_the_grid_scan_and_the_refit_does_not_lose() -> None:
    """The effect's grid scan keeps a start value that beats every grid point (73 s is on no grid),
    and a fit started from a fit ends with at least its likelihood (the scan once dropped the start:
    a refit from a good estimate ended 6 log-likelihood units lower)."""
    df = simulate_experiment(seed=31, duration_h=8.0, dt_s=20.0, effects={"sensor_lag": {"tau_s": 73.0}},
                             T_noise_C=0.005, x_noise_mm=2.0e-3)
    d = prepare(check_run(df))
    m = Model(("sensor_lag",))
    fit = m.fit(d, with_std=False)
    assert abs(fit.params["tau_s"] - 73.0) < 5.0
    p = next(q for q in m.eff_params if q.name == "tau_s")
    assert m._scan(d, fit.params, p, {}, keep_start=True) == {"tau_s": fit.params["tau_s"]}
    again = m.fit(d, start=fit.params, with_std=False)
    assert again.loglik >= fit.loglik - 1e-6


def test_a_drift_scan_turns_about_the_record_middle_and_the_fit_keeps_the_better_path() -> None:
    """setpoint_drift's rate and p_bset trade off along the record: the turned scan moves p_bset with the rate so
    that the set pressure at the record's middle stays (Model._moved), and fit() keeps the better of the held and
    the turned paths (a 10 h run drifting -6e-5 MPa/h had kept the rate at 0 on one machine and found it on
    another: tests/diagnosis/test_diagnose.py's seed 104)."""
    df = simulate_experiment(seed=104, duration_h=10.0, effects={"setpoint_drift": {"rate_MPa_per_h": -6e-5}})
    d = prepare(check_run(df))
    m = Model(("setpoint_drift",))
    p = next(q for q in m.eff_params if q.name == "rate_MPa_per_h")
    vals = {**m.default_start(d), "rate_MPa_per_h": 0.0}
    t_mid_h = 0.5 * (d.t[-1] - d.t[0]) / 3600.0
    turned = m._moved(d, vals, p, -6e-5, {}, True)
    assert turned["p_bset"] + turned["rate_MPa_per_h"] * t_mid_h == pytest.approx(vals["p_bset"], rel=1e-12)
    assert m._moved(d, vals, p, -6e-5, {}, False)["p_bset"] == vals["p_bset"]
    assert m._moved(d, vals, p, -6e-5, {"p_bset": vals["p_bset"]}, True)["p_bset"] == vals["p_bset"]
    fit = m.fit(d, with_std=False)
    paths = [m._fit_path(d, {**vals}, {}, True, 300, turn) for turn in (False, True)]
    assert fit.loglik == pytest.approx(max(q.loglik for q in paths), abs=1e-6)
    assert abs(fit.params["rate_MPa_per_h"] / -6e-5 - 1.0) < 0.25, fit.params


def _fresh_loglik(d, effects: tuple[str, ...], values: dict[str, float]) -> float:  # type: ignore[no-untyped-def]
    """The likelihood from a model that has kept no valve path."""
    return Model(effects).loglik(d, values)


def test_a_kept_valve_path_gives_the_likelihood_of_a_fresh_simulation() -> None:
    """Model._valve_path (docs/diagnosis.md, "Speed"): a finite-difference step in a noise parameter or in
    stiction's band reuses the valve path, a step in a valve parameter or the set point's drift runs the valve anew
    on the kept drive (Model._drive), a step in an effect that shapes the sensed temperature simulates anew, and every
    likelihood equals, to the last bit, that of a model simulating from scratch."""
    df = simulate_experiment(seed=5, duration_h=4.0, dt_s=10.0, effects={"stiction": {"band_mm": 0.02}})
    d = prepare(check_run(df))
    m = Model(("stiction",))
    vals = {**m.default_start(d), "band_mm": 0.02}
    m._paths.clear()  # the start's scan of p_bset has filled it
    steps = [{}, {"s_w": vals["s_w"] * 1.1}, {"tau_e": 400.0}, {"band_mm": 0.03}, {"s_e": 0.02}]
    for s in steps:
        assert m.loglik(d, {**vals, **s}) == _fresh_loglik(d, ("stiction",), {**vals, **s})
    assert len(m._paths) == 1  # the noise and band steps ran the filter on the one path
    m._drives.clear()
    for s in ({"sigma": vals["sigma"] * 1.01}, {"F_hmax": vals["F_hmax"] * 0.9}, {"p_bset": vals["p_bset"] * 1.001}):
        assert m.loglik(d, {**vals, **s}) == _fresh_loglik(d, ("stiction",), {**vals, **s})
    assert len(m._paths) == 4
    assert len(m._drives) == 1  # the valve parameters' steps run the valve on the one kept drive
    lag = Model(("sensor_lag",))
    lv = {**lag.default_start(d), "tau_s": 30.0}
    lag._paths.clear()
    lag._drives.clear()
    assert lag.loglik(d, lv) == _fresh_loglik(d, ("sensor_lag",), lv)
    assert lag.loglik(d, {**lv, "tau_s": 60.0}) == _fresh_loglik(d, ("sensor_lag",), {**lv, "tau_s": 60.0})
    assert len(lag._paths) == 2 and len(lag._drives) == 2  # the lag shapes the demand: a path and a drive each
    # the medium's weight moves the sensed temperature (a drive each); the set point's drift acts after the drive
    for effect, key, a, b in (("medium_temperature", "beta", 0.05, 0.1),
                              ("setpoint_drift", "rate_MPa_per_h", 2e-5, -3e-5)):
        em = Model((effect,))
        ev = em.default_start(d)
        em._drives.clear()
        for value in (a, b):
            assert em.loglik(d, {**ev, key: value}) == _fresh_loglik(d, (effect,), {**ev, key: value})
        assert len(em._drives) == (2 if effect == "medium_temperature" else 1)
    # the stick-slip's demand kept with the path is the one the filter and the stem compute without it
    vp, e = m._vectors(vals)
    _, _, _, x_sub, idx, _ = m._valve_path(d, vp, e, m.delta(d, vals), True)
    mask = np.ones(len(d), dtype=np.bool_)
    stroke = float(vp[I_STROKE])
    own = stick_loglik(d.t, d.x, x_sub, idx, 0.03, stroke, vals["s_w"], vals["s_e"], vals["tau_e"], mask)[0]
    assert m.loglik(d, {**vals, "band_mm": 0.03}) == own
    np.testing.assert_array_equal(m.simulate(d, {**vals, "band_mm": 0.03})[0], stick_simulate(x_sub, idx, 0.03, stroke))
    for i in range(12):  # the oldest paths make room
        m.loglik(d, {**vals, "sigma": vals["sigma"] * (1.0 + 0.01 * i)})
    assert len(m._paths) == 8


def test_a_changed_run_is_a_new_run_and_simulate_hands_out_copies() -> None:
    """A prepared run is frozen, so a kept path can only belong to the run it was simulated from: a run with
    other temperatures is another object, and its likelihood is its own. ``simulate`` returns copies: writing
    into them leaves the kept path as it was."""
    import dataclasses

    df = simulate_experiment(seed=6, duration_h=3.0, dt_s=10.0)
    d = prepare(check_run(df))
    m = Model(())
    vals = m.default_start(d)
    ll = m.loglik(d, vals)
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.T = d.T + 1.0  # type: ignore[misc]
    warmer = dataclasses.replace(d, T=d.T + 0.5, M=d.M + 0.5)
    assert m.loglik(warmer, vals) == _fresh_loglik(warmer, (), vals) != ll
    x, _, _ = m.simulate(d, vals)
    x[:] = -1.0
    assert m._filter(d, vals)[0] == ll  # the kept path, filtered anew (loglik would give its kept value)
    assert m.simulate(d, vals)[0][0] != -1.0
    import pickle

    copied = pickle.loads(pickle.dumps(m))
    assert copied._paths == {} and copied._lls == {}  # a copied model starts without kept paths or values


def test_a_kept_loglik_is_the_filters_value_for_exactly_its_inputs() -> None:
    """Model.loglik keeps the values of its last LOGLIK_CACHE distinct inputs on each of the last LOGLIK_RUNS runs
    evaluated (docs/diagnosis.md, "Speed"): a repeated point returns the filter's value without running it, any input
    that changes the value (a parameter, the mask, the slip, the filter's band spread) is another entry whose value is
    the filter's own, and a fifth run makes room by dropping the first."""
    df = simulate_experiment(seed=5, duration_h=3.0, dt_s=10.0, effects={"stiction": {"band_mm": 0.02}})
    d = prepare(check_run(df))
    m = Model(("stiction",))
    vals = {**m.default_start(d), "band_mm": 0.02}
    m._lls.clear()
    half = np.arange(len(d)) < len(d) // 2
    cases = [({}, None, -1.0), ({"s_w": vals["s_w"] * 1.1}, None, -1.0), ({}, half, -1.0), ({}, ~half, -1.0),
             ({}, None, 0.01)]
    for s, mask, slip in cases:
        assert m.loglik(d, {**vals, **s}, mask, slip) == m._filter(d, {**vals, **s}, mask, slip)[0]
    assert len(m._lls) == 1 and len(m._lls[id(d)][1]) == len(cases)
    calls = []
    real = m._filter
    m._filter = lambda *a: calls.append(a) or real(*a)  # type: ignore[method-assign]
    for s, mask, slip in cases:  # kept: the filter does not run
        assert m.loglik(d, {**vals, **s}, None if mask is None else mask.copy(), slip) == real(d, {**vals, **s},
                                                                                              mask, slip)[0]
    assert calls == []
    m.band_spread *= 2.0
    first = next(iter(m._lls[id(d)][1].values()))[1]
    assert m.loglik(d, vals) == real(d, vals)[0] != first
    assert len(calls) == 1
    # the values of the last LOGLIK_RUNS runs are kept, each run held by its entry: a model evaluated on many runs
    # (null and bootstrap copies) holds a few of them, not each
    import dataclasses

    others = [dataclasses.replace(d, T=d.T + 0.1 * (i + 1), M=d.M + 0.1 * (i + 1)) for i in range(LOGLIK_RUNS)]
    for o in others:
        assert m.loglik(o, vals) == real(o, vals)[0]
    held = [run for run, _ in m._lls.values()]
    assert len(held) == LOGLIK_RUNS and all(a is b for a, b in zip(held, others, strict=True))  # the first made room
    m.forget_paths()
    assert m._lls == {}
