"""The misspecification check of a stick-slip effect (valve_env.valveid.robust.stick_slip_check;
docs/uncertainty.md, "Sandwich standard errors and the misspecification check")."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from valve_env.experiment import simulate_experiment
from valve_env.ident.tests import MisspecificationWarning
from valve_env.studies.independent import stick_force, stick_reset, stick_sj
from valve_env.valveid.diagnose import check_run, prepare
from valve_env.valveid.fitting import Model
from valve_env.valveid.robust import (
    STICK_TOL,
    effect_misspecification,
    stick_slip_check,
    stuck_travel,
)

STROKE = 4.0


def _demand() -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, 12 * 3600.0)
    return t, 1.5 + 0.12 * np.sin(2 * np.pi * t / 5400) + 0.05 * np.sin(2 * np.pi * t / 1300 + 1.0)


@pytest.mark.parametrize("rule", ["reset", "sj", "force"])
def test_stuck_travel_reads_the_slip_rule(rule: str) -> None:
    """Given the true demand, the demand's travel while stuck over the slip's size is 1 for a valve that slips
    onto the demand (the independent simulator's reset and (S, J = S) rules) and (1 + r)/(1 - r) = 3 for the
    force-based rule with F_c = 0.5 F_s, which breaks away after S and slips J = S / 3."""
    t, xd = _demand()
    S = 0.03
    x = {"reset": lambda: stick_reset(xd, S, STROKE), "sj": lambda: stick_sj(xd, S, S, STROKE),
         "force": lambda: stick_force(xd, S, 0.5, 1.0, STROKE)}[rule]()
    idx = np.arange(0, t.size, 10)
    y = x[idx] + 2e-3 * np.random.default_rng(3).standard_normal(idx.size)
    r = stuck_travel(y, xd[idx], STROKE)
    assert r.size >= 15
    med = float(np.median(r))
    if rule == "force":
        assert 2.2 < med < 3.3, med
    else:
        assert 1.0 / 1.15 < med < 1.15, med


@pytest.fixture(scope="module")
def sticky_fit():  # type: ignore[no-untyped-def]
    df = simulate_experiment(seed=78, duration_h=8.0, dt_s=10.0, effects={"stiction": {"band_mm": 0.03}})
    run = prepare(check_run(df))
    m = Model(("stiction",))
    return m, run, m.fit(run)


def test_right_stick_slip_model_passes_the_check(sticky_fit) -> None:  # type: ignore[no-untyped-def]
    """On the model that generated the run the stick-slip check is quiet (and tested: enough slips); the
    whiteness check is kept beside it for information (on the studies' runs it rejected the right model,
    docs/uncertainty.md)."""
    m, run, fit = sticky_fit
    with warnings.catch_warnings():
        warnings.simplefilter("error", MisspecificationWarning)
        r = effect_misspecification(m, run, fit)
    assert r["tested"] is True and r["n_slips"] >= 4
    assert 1.0 / STICK_TOL <= r["travel_over_slip_median"] <= STICK_TOL
    assert r["misspecified"] is False and r["message"] == ""
    assert set(r["whiteness"]["outputs"]["x_mm"]) >= {"ljung_box_p", "cpgram_max_dev", "white"}


def test_the_check_warns_when_the_demand_says_another_rule(sticky_fit) -> None:  # type: ignore[no-untyped-def]
    """A valve whose demand travels far more than its slips while the stem is stuck (the fitted valve's demand
    stretched threefold about the measured opening, as a force-based stick-slip that slips short of the
    demand would have it) is flagged, with the warning."""
    m, run, fit = sticky_fit

    class Doubled(Model):
        def simulate(self, data, values):  # type: ignore[no-untyped-def]
            x, Tg, F = m.simulate(data, values)
            return run.x + 3.0 * (x - run.x), Tg, F

    wrong = Doubled(m.effects, m.valve)
    with pytest.warns(MisspecificationWarning, match="slips follow another rule"):
        r = stick_slip_check(wrong, run, fit)
    assert r["misspecified"] is True and r["travel_over_slip_median"] > STICK_TOL


def test_too_few_slips_are_not_judged(sticky_fit) -> None:  # type: ignore[no-untyped-def]
    m, run, fit = sticky_fit
    r = stick_slip_check(m, run, fit, min_slips=10_000, warn=False)
    assert r["tested"] is False and r["misspecified"] is False
