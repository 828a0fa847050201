"""The controller's output within a recorded sample (docs/loops.md, "Model"): a controller scanning faster than the
historian records jitters on its measurement noise; the historian's interval mean hides the jitter, but a sticky valve
slips where the jittering output first reaches its band's end. The record's second differences give the jitter's sd,
and the band's valve is driven by it."""

from __future__ import annotations

import numpy as np
import pytest

from valve_env.loops.model import op_jitter, valve_path
from valve_env.loops.sim import random_case, simulate_case


def _within_sample_sd(case: dict) -> tuple[float, np.ndarray]:
    """The true sd of the controller's 1 s output about its recorded interval mean, and the record's OP."""
    fine, _ = simulate_case({**case, "dt": 1.0})  # the same loop recorded at the controller's 1 s step
    loop, _ = simulate_case(case)
    m = int(case["dt"])
    op1 = fine.op[: loop.n * m].reshape(loop.n, m)
    return float((op1 - op1.mean(axis=1, keepdims=True)).std()), loop.op


@pytest.mark.parametrize("seed", [930004, 930009])
def test_op_jitter_reads_the_hidden_within_sample_motion(seed: int) -> None:
    case = random_case(seed)
    true_sd, op = _within_sample_sd(case)
    est = op_jitter(op, case["dt"], 1.0)
    assert true_sd > 0 and 0.6 * true_sd < est < 1.6 * true_sd
    # a controller scanning at the record's rate hides nothing; a held OP shows no jitter
    assert op_jitter(op, case["dt"], case["dt"]) == 0.0
    assert op_jitter(np.repeat(op[:50], 4), case["dt"], 1.0) == 0.0


def test_jitter_valve_nests_the_smooth_one_and_slips_earlier() -> None:
    rng = np.random.default_rng(3)
    op = 50.0 + np.cumsum(rng.normal(0.0, 0.3, 300))
    np.testing.assert_array_equal(valve_path(op, 2.0, 1.0, 1.0, 10, 0.0), valve_path(op, 2.0, 1.0, 1.0, 10))
    # the same draws every call (the candidates' likelihoods compare), and a valve that moves more often with jitter
    a, b = valve_path(op, 2.0, 1.0, 1.0, 10, 0.3), valve_path(op, 2.0, 1.0, 1.0, 10, 0.3)
    np.testing.assert_array_equal(a, b)
    smooth = valve_path(op, 2.0, 1.0, 1.0, 10)
    assert np.mean(np.abs(np.diff(a)) > 1e-9) > np.mean(np.abs(np.diff(smooth)) > 1e-9)


def test_band_of_a_loop_whose_controller_jitters_within_its_samples() -> None:
    """A self-regulating loop of the wide-variety generator (development seed 900054: lag 370 s, 30 s samples, band
    0.64 % of OP; its 1 s output jitters by about 0.14 band within a sample). Driven by the smooth sub-sample OP the
    valve never slips where the jittering one does, and the band's fit reads a quarter of the band; driven by the
    jitter the record shows, the band is found and its sd covers the truth."""
    from dataclasses import replace

    from valve_env.loops.diagnose import diagnose_loop, select_noise_order

    case = random_case(900054)
    loop, _ = simulate_case(case)
    S = case["S"]
    d = diagnose_loop(loop, quantify=True)
    st = d.result["stiction"]
    assert st["op_jitter_pct"] > 0.05 * S and st["valve_substeps"] == 30
    assert abs(st["band_pct"] - S) <= 0.2 * S and abs(st["band_pct"] - S) <= 2.0 * st["std_pct"]
    assert len(st["halves_band_pct"]) == 2
    # the same fit without the jitter (a controller taken to scan at the record's rate)
    smooth = diagnose_loop(loop, quantify=True, settings=replace(select_noise_order(loop), scan_s=loop.dt))
    assert smooth.result["stiction"]["op_jitter_pct"] == 0.0
    assert smooth.result["stiction"]["band_pct"] < 0.5 * S
