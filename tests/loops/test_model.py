"""The grey-box loop model: the valve is the project's stick-slip, the fit finds a simulated band,
and a smooth valve is not called stiction."""

from __future__ import annotations

import numpy as np
import pytest

from valve_env.loops.diagnose import diagnose_loop
from valve_env.loops.model import valve_path
from valve_env.loops.sim import simulate_loop
from valve_env.physics import stickslip


def test_valve_is_the_project_stick_slip() -> None:
    rng = np.random.default_rng(0)
    op = 50 + np.cumsum(rng.normal(0, 0.5, 400))
    for S, J in ((2.0, 2.0), (2.0, 0.0), (3.0, 1.0)):
        np.testing.assert_array_equal(valve_path(op, S, J), stickslip.simulate(op, S, J))
        # stuck after a downward motion: the mirror image of the same model
        np.testing.assert_allclose(valve_path(op, S, J, -1.0), -stickslip.simulate(-op, S, J), atol=1e-12)
    np.testing.assert_array_equal(valve_path(op, 0.0, 0.0), op)


@pytest.mark.parametrize(("process", "S", "J"), [pytest.param("pressure", 3.0, 1.5, marks=pytest.mark.slow),
                                             ("temperature", 2.5, 2.0)])
def test_sticky_simulated_loop_gives_its_band(process: str, S: float, J: float) -> None:
    loop, truth = simulate_loop(process, S=S, J=J, seed=101)
    d = diagnose_loop(loop, rule="learned")  # the simulated loops' detection is the learned rule's (docs/loops.md)
    assert d.cause == "stiction" and d.result["stiction"]["detected"] is True
    st = d.result["stiction"]
    assert abs(st["band_pct"] - S) < 0.25 * S
    # the sd holds at least the calibrated model-error and sampling terms (docs/loops.md, "Band uncertainty")
    from valve_env.loops.diagnose import BAND_REL_SD, SAMPLING_SD_SHARE

    floor = np.hypot(BAND_REL_SD * st["band_pct"], SAMPLING_SD_SHARE * st["sampling_offset_pct"])
    assert st["std_pct"] >= floor - 1e-12 and st["std_pct"] > 0
    # each valve that could have moved between the samples reads a band; the more likely one gives it, and half
    # their difference enters the sd
    bands = st["valves_band_pct"]
    assert st["band_pct"] in bands.values() and st["std_pct"] >= (max(bands.values()) - min(bands.values())) / 2
    # the band is the stick-slip candidate's, and this slow loop's record resolves it
    # (refitted with the valve between the samples: Settings.band_substeps, tests/loops/test_substeps.py)
    assert d.band_fit is not None and d.band_fit.valve == "stiction"  # MODEL
    assert st["band_fitted_pct"] == pytest.approx(d.band_fit.S) and d.band_fit.substeps == st["valve_substeps"]
    # a step per controller scan where the record shows the output's jitter (tests/loops/test_jitter.py)
    assert st["valve_substeps"] == (round(loop.dt / d.settings.scan_s) if st["op_jitter_pct"] > 0 else 4)
    assert st["band_resolved"] is True
    names = [f["candidate"] for f in d.result["findings"]]
    assert names == ["linear", "stiction"]
    for f in d.result["findings"]:
        assert {"loglik", "lr_stat", "p_value", "delta_bic"} <= set(f)


def test_smooth_simulated_loop_is_not_stiction() -> None:
    loop, _ = simulate_loop("pressure", S=0.0, seed=102)
    d = diagnose_loop(loop, rule="learned")
    assert d.cause != "stiction" and "stiction" not in d.result and d.band_fit is None


def test_scan_nests_the_linear_valve_and_finds_a_simulated_band() -> None:
    """The LR scan's grid holds the linear valve (LR >= 0) and starts at the record's resolution; on a sticky
    simulated loop its best band is near the truth, on the smooth twin the statistic is far smaller."""
    from valve_env.loops.diagnose import select_noise_order
    from valve_env.loops.model import resolution, scan_paths, scan_valve

    sticky, _ = simulate_loop("pressure", S=3.0, J=1.5, seed=101)
    smooth, _ = simulate_loop("pressure", S=0.0, seed=102)
    lrs = []
    for loop in (sticky, smooth):
        xs, params = scan_paths(loop.op)
        np.testing.assert_array_equal(xs[0], loop.op)
        assert min(p[0] for p in params[1:]) == pytest.approx(max(resolution(loop.op), 0.01 * np.ptp(
            np.percentile(loop.op, [1.0, 99.0]))))
        sc = scan_valve(loop.pv, (xs, params), select_noise_order(loop))
        assert sc.lr >= 0.0
        lrs.append(sc)
    assert abs(lrs[0].S - 3.0) < 0.5 * 3.0
    assert lrs[0].lr > 10.0 * max(lrs[1].lr, 1.0)


def test_the_band_sd_holds_half_the_two_valves_difference() -> None:
    """``band_uncertainty``: the record does not say which valve moved between its samples, so half the difference
    of the two valves' bands adds to the sd in quadrature, and a single valve adds nothing."""
    from valve_env.loops.diagnose import band_uncertainty
    from valve_env.loops.model import ValveFit

    fit = ValveFit("stiction", S=1.5, J=0.5, process=None, n_params=4,  # type: ignore[arg-type]
                   profile=[(1.0, -5.0), (1.5, 0.0), (2.0, -5.0)])
    band, sd1, _, _ = band_uncertainty(fit, 0.0, (1.4, 1.6), (1.5,))
    band2, sd2, lo, hi = band_uncertainty(fit, 0.0, (1.4, 1.6), (1.5, 0.9))
    assert band == band2 == 1.5
    assert sd2 == pytest.approx(np.hypot(sd1, 0.3)) and sd2 > sd1
    assert lo <= band - 1.96 * sd2 + 1e-12 and hi >= band + 1.96 * sd2 - 1e-12


def test_the_band_interval_stops_at_zero() -> None:
    """``band_uncertainty``: where the band's sd is wide against the band (two valves far apart), band - 1.96 sd
    lies below 0 and the interval stops at 0, as a band is not negative."""
    from valve_env.loops.diagnose import band_uncertainty
    from valve_env.loops.model import ValveFit

    fit = ValveFit("stiction", S=0.5, J=0.5, process=None, n_params=4,  # type: ignore[arg-type]
                   profile=[(0.4, -5.0), (0.5, 0.0), (0.6, -5.0)])
    band, sd, lo, hi = band_uncertainty(fit, 0.0, None, (0.5, 2.5))
    assert band - 1.96 * sd < 0.0
    assert lo == 0.0 and hi == pytest.approx(band + 1.96 * sd)


def test_the_band_label_keeps_two_significant_digits() -> None:
    """The sd in the band's one label reads 1.0, not 1, so it is not taken for a rounded integer."""
    from valve_env.loops.diagnose import model_label, sd_text

    assert [sd_text(v) for v in (1.0, 0.224, 12.3, 0.00123)] == ["1.0", "0.22", "12", "0.0012"]
    assert "+/- 1.0 % of OP" in model_label({"band_pct": 3.45, "std_pct": 1.0, "jump_pct": 0.855})
