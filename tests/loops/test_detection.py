"""Detection: the bicoherence test and the OP-PV ellipse on signals whose answer is known, the learned rule's
frozen form, and the rule on simulated loops of seeds it was not fitted on."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from valve_env.loops import detector_coefs
from valve_env.loops.detect import FEATURES, SHAPE_FEATURES, detect, features
from valve_env.loops.detectors import bicoherence, ellipse_area
from valve_env.loops.io import LoopData
from valve_env.loops.sim import random_case, simulate_case


def _loop(op: np.ndarray, pv: np.ndarray, sp: np.ndarray | None = None) -> LoopData:
    n = op.size
    return LoopData(time_s=np.arange(n) * 10.0, sp=np.zeros(n) if sp is None else sp, pv=pv, op=op)


def test_bicoherence_linear_gaussian_against_quadratic_coupling() -> None:
    """A Gaussian AR process is linear (no significant bicoherence peak, excess mean about 0); a signal with
    quadratic phase coupling (f1, f2 and f1 + f2 with phases adding up) is nonlinear."""
    rng = np.random.default_rng(1)
    n = 2048
    g = lfilter([1.0], [1.0, -0.7], rng.normal(size=n))
    lin = bicoherence(_loop(np.zeros(n) + rng.normal(size=n), -g))
    assert not lin["nonlinear"] and abs(lin["ngi"]) < 0.05
    t = np.arange(n)
    p1, p2 = rng.uniform(0, 2 * np.pi, 2)
    f1, f2 = 0.09, 0.14
    x = np.cos(2 * np.pi * f1 * t + p1) + np.cos(2 * np.pi * f2 * t + p2) + np.cos(2 * np.pi * (f1 + f2) * t + p1 + p2)
    nl = bicoherence(_loop(rng.normal(size=n), -(x + 0.3 * rng.normal(size=n))))
    assert nl["nonlinear"] and nl["statistic"] > 0.5 and nl["nli"] > 0.1


def test_band_share_reads_one_cycle() -> None:
    """The oscillation's clarity from the spectrum: one and a half cycles of a sinusoid in noise are clear (their
    share of the spectrum near their frequency is large), white noise is not."""
    from valve_env.loops.detect import band_share

    rng = np.random.default_rng(2)
    n = 720
    t = np.arange(n)
    slow = np.sin(2 * np.pi * 1.5 * t / n) + 0.2 * rng.normal(size=n)
    assert band_share(slow, 1.5 / n) > 0.8
    assert band_share(rng.normal(size=n), 1.5 / n) < 0.05


@pytest.mark.parametrize("phi_deg", [0.0, 30.0, 90.0, 150.0])
def test_ellipse_area_is_sin_of_the_phase(phi_deg: float) -> None:
    """Two sinusoids phi apart trace an ellipse whose normalised area is sin(phi) (0: a line, 1: a circle)."""
    t = np.arange(1200)
    w = 2 * np.pi / 60.0
    op = 3.0 * np.sin(w * t)
    pv = 0.5 * np.sin(w * t - math.radians(phi_deg))
    res = ellipse_area(_loop(op, pv))
    assert abs(res["signed"]) == pytest.approx(math.sin(math.radians(phi_deg)), abs=0.03)
    assert res["period_samples"] == pytest.approx(60.0, rel=0.05)


def test_the_frozen_rule_is_complete_and_fitted_on_other_seeds() -> None:
    """The generated coefficients name every feature, and the seeds they were fitted on are the documented ones (the
    benchmark's default evaluation seeds are not among them)."""
    assert detector_coefs.FEATURES == FEATURES
    assert detector_coefs.CLARITY is None or detector_coefs.CLARITY in FEATURES
    n_terms = 2 * (len(FEATURES) + (len(SHAPE_FEATURES) if detector_coefs.CLARITY is not None else 0))
    assert len(detector_coefs.COEFS) == n_terms + 1
    assert len(detector_coefs.MEANS) == len(detector_coefs.SCALES) == n_terms
    assert all(s > 0 for s in detector_coefs.SCALES) and 0.0 < detector_coefs.THRESHOLD < 1.0
    assert detector_coefs.TRAINING["train_seeds"] == "0-1199"
    assert detector_coefs.TRAINING["validation_seeds"] == "100000-100399"


def test_features_are_finite_and_scale_free() -> None:
    """Every feature is finite, and none changes when PV and OP are rescaled (engineering units)."""
    loop, _ = simulate_case(random_case(910001, kind="stiction"))
    f, _ = features(loop)
    assert set(FEATURES) <= set(f) and all(math.isfinite(v) for v in f.values())
    scaled = LoopData(time_s=loop.time_s, sp=3.0 * loop.sp + 7.0, pv=3.0 * loop.pv + 7.0, op=0.5 * loop.op + 10.0)
    g, _ = features(scaled)
    for k in f:
        assert g[k] == pytest.approx(f[k], rel=1e-6, abs=1e-6), k


@pytest.mark.parametrize(("kind", "named"), [("stiction", True), ("smooth", False)])
def test_rule_on_unseen_simulated_loops(kind: str, named: bool) -> None:
    """On simulated loops of evaluation seeds (never fitted on), a third or more of the sticky loops are named (the
    benchmark's rate is about 60 %: half the generator's sticky loops do not limit-cycle in their record) and at most
    one smooth one in twelve."""
    hits = [detect(simulate_case(random_case(seed, kind=kind))[0], rule="learned")["stiction"]
            for seed in range(920000, 920012)]
    assert (sum(hits) >= 4) if named else (sum(hits) <= 1)


def test_rule_on_limit_cycles_of_the_four_process_set() -> None:
    """On the four-process set (flow, pressure, temperature, level; never fitted on), whose sticky valves (S 3 %,
    J 1.5 %) limit-cycle clearly, at least 10 of 12 sticky loops are named and at most 1 of their 12 smooth twins."""
    from valve_env.loops.sim import simulate_loop

    sticky, smooth = [], []
    for process in ("flow", "pressure", "temperature", "level"):
        for seed in (1, 2, 3):
            sticky.append(detect(simulate_loop(process, S=3.0, J=1.5, seed=seed)[0], rule="learned")["stiction"])
            smooth.append(detect(simulate_loop(process, S=0.0, seed=seed)[0], rule="learned")["stiction"])
    assert sum(sticky) >= 10 and sum(smooth) <= 1


def test_the_default_rule_is_horchs_test_and_the_learned_one_is_reported_beside_it() -> None:
    """loop-diagnose decides by Horch's test as published; the learned rule's probability and verdict are in the
    detection beside it; an unknown rule is refused."""
    from valve_env.loops.detectors import horch

    for seed in (920000, 920001, 920002):
        for kind in ("stiction", "smooth"):
            loop = simulate_case(random_case(seed, kind=kind))[0]
            d = detect(loop)
            assert d["rule"]["name"] == "horch" and d["stiction"] == horch(loop)["stiction"]
            learned = detect(loop, rule="learned")
            assert learned["stiction"] == d["learned_stiction"] == (d["probability"] > d["threshold"])
    with pytest.raises(ValueError, match="rule must be one of"):
        detect(loop, rule="vote")


def _det(rule: str, horch_stiction: bool, phase: float, tau_r: float, tau_l: float, p: float) -> dict:
    from valve_env.loops.detect import THRESHOLD

    learned = p > THRESHOLD
    return {"stiction": horch_stiction if rule == "horch" else learned, "rule": {"name": rule},
            "probability": p, "threshold": THRESHOLD, "learned_stiction": learned,
            "detectors": {"horch": {"statistic": phase, "tau_r": tau_r, "tau_l": tau_l, "stiction": horch_stiction}}}


def test_detection_notes_say_why_horch_gave_no_verdict_and_where_the_rules_disagree() -> None:
    """The notes beside the verdict: a cross-correlation half period under 5 samples (no resolved cycle) or a phase
    between 60 and 120 deg says why Horch's test counted as no stiction, and the other rule's disagreeing verdict is
    named with its statistic; where the rules agree on a resolved cycle nothing is said."""
    from valve_env.loops.detect import THRESHOLD, detection_notes

    assert detection_notes(_det("horch", True, 150.0, 1.0, 9.0, THRESHOLD + 0.1)) == []
    assert detection_notes(_det("horch", False, 20.0, 5.0, 6.0, THRESHOLD - 0.1)) == []
    fast = detection_notes(_det("horch", False, 128.0, 0.5, 3.0, THRESHOLD + 0.03))
    assert fast[0].startswith("Horch's test gives no verdict: the OP-PV cross-correlation's half period is 3.5 samples")
    assert fast[1].startswith("the other detection rule (--rule learned) says stiction (probability")
    middle = detection_notes(_det("horch", False, 90.0, 3.0, 9.0, THRESHOLD - 0.2))
    assert middle == ["Horch's test is undetermined: the OP-PV cross-correlation's phase 90 deg lies between 60 (even: "
                      "no stiction) and 120 (odd: stiction); counted as no stiction"]
    learned = detection_notes(_det("learned", True, 150.0, 1.0, 9.0, THRESHOLD - 0.3))
    assert learned == ["the other detection rule (--rule horch) says stiction (phase 150 deg); the decision is the "
                       "learned rule's (docs/loops.md, \"Which rule\")"]


def test_a_sticky_flow_loop_faster_than_horch_resolves_says_so() -> None:
    """A sticky flow loop whose limit cycle is a few samples long (S 3 %, J 2 %, 10 s sampling): Horch's test, the
    default, resolves no cycle and the cause is not stiction; the notes say why, and that the learned rule names it."""
    from valve_env.loops.diagnose import diagnose_loop
    from valve_env.loops.sim import simulate_loop

    loop, _ = simulate_loop("flow", S=3.0, J=2.0, seed=964311)
    R = diagnose_loop(loop).result
    assert R["cause"] != "stiction"
    assert any(n.startswith("Horch's test gives no verdict") for n in R["notes"])
    assert any(n.startswith("the other detection rule (--rule learned) says stiction") for n in R["notes"])
