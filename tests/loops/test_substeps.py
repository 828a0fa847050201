"""The valve between the recorded samples (docs/loops.md, "Model"): a historian records interval means of OP, so the
band's fit drives the valve with a mean-preserving sub-sample OP and feeds the process the valve's interval mean; one
substep is the sample-rate valve (nested)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from valve_env.loops.diagnose import diagnose_loop, select_noise_order
from valve_env.loops.model import Settings, fit_process, resolution, scan_paths, subsample_op, valve_path
from valve_env.loops.sim import simulate_loop
from valve_env.physics import stickslip

#: the flow loop of the simulated benchmark's seed 0 (benchmarks/loop_benchmark.py, sim_cases(0, 20)[0]): its limit
#: cycle lasts about five 10 s samples, so the recorded interval means never reach the band's ends
FLOW = {"process": "flow", "S": 2.910885061964363, "J": 1.4229881990975026, "seed": 0}


@pytest.mark.parametrize("m", [2, 4, 8])
def test_subsample_op_keeps_the_recorded_interval_means(m: int) -> None:
    rng = np.random.default_rng(1)
    op = 50.0 + np.cumsum(rng.normal(0.0, 0.8, 300))
    fine = subsample_op(op, m)
    assert fine.size == op.size * m
    np.testing.assert_allclose(fine.reshape(op.size, m).mean(axis=1), op, atol=1e-9)
    # a sharp peak is reconstructed beyond its interval mean (the line through the centres overshoots the mean;
    # two substeps are each half's mean, which for a symmetric peak is the mean itself)
    peak = np.zeros(21)
    peak[10] = 1.0
    assert subsample_op(peak, m).max() > 1.0 + 1e-3 if m >= 4 else subsample_op(peak, m).max() == pytest.approx(1.0)


def test_one_substep_is_the_sample_rate_valve() -> None:
    rng = np.random.default_rng(2)
    op = 50.0 + np.cumsum(rng.normal(0.0, 0.5, 400))
    np.testing.assert_array_equal(subsample_op(op, 1), op)
    for S, J, d0 in ((2.0, 2.0, 1.0), (2.0, 0.0, -1.0), (3.0, 1.0, 1.0)):
        np.testing.assert_array_equal(valve_path(op, S, J, d0, substeps=1), valve_path(op, S, J, d0))
        if d0 > 0:
            np.testing.assert_array_equal(valve_path(op, S, J, d0, substeps=1), stickslip.simulate(op, S, J))
    # the linear valve is the record whatever the substeps (the scan's first path, the bootstrap's null)
    np.testing.assert_array_equal(valve_path(op, 0.0, 0.0, 1.0, substeps=4), op)
    xs, _ = scan_paths(op, substeps=4)
    np.testing.assert_array_equal(xs[0], op)
    # the sampling offset and the scan's floor are the record's resolution, not the substeps'
    assert resolution(op) == pytest.approx(float(np.median(np.abs(np.diff(op)))))
    assert Settings().substeps == 1 and Settings().band_substeps == 4  # the decision's valve, the band's valve


def test_substeps_fit_an_interval_mean_record_better_near_its_band() -> None:
    """On the fast flow loop the sub-sample valve explains the record far better at bands near the truth (the
    recorded OP, an interval mean, is what the valve saw averaged, not what it saw)."""
    loop, _ = simulate_loop(FLOW["process"], S=FLOW["S"], J=FLOW["J"], seed=FLOW["seed"])
    s = select_noise_order(loop)
    S = FLOW["S"] - resolution(loop.op)  # the band the record can show (docs/loops.md, "Band uncertainty")
    J = S * FLOW["J"] / FLOW["S"]

    def ll(m: int) -> float:
        return max(fit_process(loop.pv, valve_path(loop.op, S, J, d0, m), s).loglik for d0 in (1.0, -1.0))

    assert ll(4) > ll(1) + 50.0


@pytest.mark.slow  # the sub-sample valve's nesting and fit stay in the default suite (the tests above)
def test_sub_sample_valve_recovers_the_flow_band() -> None:
    """The band's fit with the valve between the samples recovers the flow loop's band (within 20 %, closer than the
    sample-rate valve's); the linear valve's fit is the same either way."""
    loop, _ = simulate_loop(FLOW["process"], S=FLOW["S"], J=FLOW["J"], seed=FLOW["seed"])
    base = select_noise_order(loop)
    err = {}
    findings = []
    for m in (1, 4):  # the valve without the within-sample jitter (a controller scanning at the record's rate)
        d = diagnose_loop(loop, quantify=True, settings=replace(base, band_substeps=m, scan_s=loop.dt))
        assert d.band_fit is not None
        st = d.result["stiction"]
        err[m] = abs(st["band_pct"] - FLOW["S"]) / FLOW["S"]
        assert d.band_fit.substeps == st["valve_substeps"] == m
        findings.append(d.result["findings"][0])
    assert findings[0] == findings[1]
    assert err[4] < 0.2 and err[4] < err[1]
