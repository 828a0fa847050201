"""Residual diagnostics (statsmodels ACF, Ljung-Box, CCF; cumulated periodogram) and bench figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from valve_env.ident.tests import cumulated_periodogram, residual_report, second_difference_sd
from valve_env.valveid.diagnostics import paper_figure, phase_diagram, whiteness_figure


def test_white_noise_passes_and_ar1_fails(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    e = rng.standard_normal(4000)
    u = pd.DataFrame({"u": rng.standard_normal(4000)})
    rep = residual_report(e, u)
    assert rep.white
    assert rep.summary()["acf_outside_band"] <= 5
    assert "u" in rep.ccf and np.all(np.abs(rep.ccf["u"]) < 0.1)
    ar = np.zeros(4000)
    for k in range(1, 4000):
        ar[k] = 0.5 * ar[k - 1] + e[k]
    rep2 = residual_report(ar)
    assert not rep2.white
    assert rep2.ljung_box["lb_pvalue"].iloc[-1] < 1e-6
    assert rep2.cpgram_max_dev > rep2.cpgram_band
    # residuals that still carry an input: visible in the cross-correlation
    rep3 = residual_report(e + 0.5 * u["u"].to_numpy(), u)
    assert rep3.ccf["u"][0] > 0.3
    # missing values are dropped
    e2 = e.copy()
    e2[::10] = np.nan
    assert residual_report(e2).n == 3600
    whiteness_figure(rep3, tmp_path / "w.png")
    assert (tmp_path / "w.png").stat().st_size > 0


def test_cumulated_periodogram_of_white_noise_is_the_diagonal() -> None:
    rng = np.random.default_rng(1)
    f, c, band = cumulated_periodogram(rng.standard_normal(2000))
    assert f[-1] == 0.5 and c[-1] == 1.0
    assert np.max(np.abs(c - f / 0.5)) < band


def test_figures(tmp_path: Path) -> None:
    t = np.arange(500) * 10.0
    y = np.sin(t / 500.0)
    e = np.random.default_rng(2).standard_normal(500) * 0.01
    paper_figure(t, y + e, y, y, e, tmp_path / "fit.png")
    phase_diagram(50 + y, y + e, tmp_path / "phase.png", simulated=y)
    assert (tmp_path / "fit.png").stat().st_size > 0 and (tmp_path / "phase.png").stat().st_size > 0


def test_bench_fit_returns_flat_figures() -> None:
    from valve_env.bench import bench_fit

    out = bench_fit(hours=2.0, min_time_s=0.1, generic=False)
    assert all(isinstance(v, float) for v in out.values())
    assert out["estimator_nll_evals_per_s"] > 0 and out["estimator_fit_wall_s"] > 0
    assert out["estimator_n_samples"] == 721.0


def test_the_noise_level_from_second_differences() -> None:
    """One definition serves the valve's channels and the loops' (ident.tests): white noise of sd 0.05 on a slow sine is
    read within 5 %; a steady curvature (a parabola) shifts the second differences, which the centred estimate
    ignores and the one about 0 (the loops', for an OP whose curvature averages out) reads as noise."""
    rng = np.random.default_rng(3)
    t = np.arange(5000.0)
    y = np.sin(t / 400.0) + rng.normal(0.0, 0.05, t.size)
    assert abs(second_difference_sd(y) / 0.05 - 1.0) < 0.05
    assert abs(second_difference_sd(y, centred=False) / 0.05 - 1.0) < 0.05
    bent = y + 0.25 * t**2  # second differences shifted by 0.5, four times their sd (0.05 sqrt 6)
    assert abs(second_difference_sd(bent) / 0.05 - 1.0) < 0.05 < second_difference_sd(bent, centred=False) / 0.05 - 1.0
    assert second_difference_sd(y[:2]) == 0.0
