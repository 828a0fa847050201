"""The pre-processing bracket of a named smooth effect (valve_env.valveid.bootstrap.apply_bootstrap),
and the effects study's alternative bracket rules (studies/independent_coverage.py).

docs/uncertainty.md, "Errors in variables and robust uncertainty": the TV refit is the estimate and half the
IRW-TV difference enters its sd in quadrature; the study prints the coverage of two other rules beside it (the whole
difference; the midpoint of the two estimates) from the same runs, and pools earlier runs (--summarise).
Stiction's band is not bracketed: it passes through apply_bootstrap exactly as the bootstrap gives it."""

from __future__ import annotations

import importlib
import json
import math
from pathlib import Path

import numpy as np
import pytest

from valve_env.valveid import bootstrap as bs
from valve_env.valveid.fitting import FitResult, Model


def _fit(effects: tuple[str, ...], params: dict[str, float], std: dict[str, float]) -> FitResult:
    return FitResult(effects, dict(params), dict(std), loglik=0.0, n=100, n_free=4, rms_mm=0.01, converged=True)


def _boot(names: list[str], est: dict[str, float], std: dict[str, float],
          corrected: dict[str, float]) -> bs.BootstrapResult:
    return bs.BootstrapResult(names, np.zeros((4, len(names))), est, std, dict.fromkeys(names, 0.0),
                              {k: (v - 2 * std[k], v + 2 * std[k]) for k, v in est.items()}, B=4,
                              corrected=corrected, bias_corrected=dict.fromkeys(names, False))


def test_bracket_estimate_is_the_tv_refit_sd_adds_half_the_difference(monkeypatch: pytest.MonkeyPatch) -> None:
    """beta 0.1000 (IRW-RTS) against 0.1020 (TV): the estimate is the TV refit and its sd
    sqrt(sd_boot^2 + (0.5 x 0.0020)^2), the bootstrap's sd being larger than the Hessian's."""
    monkeypatch.setattr(bs, "preprocessing_refit", lambda model, data, fit, names: {"beta": 0.1020})
    model = Model(("medium_temperature",))
    fit = _fit(model.effects, {"beta": 0.1000}, {"beta": 0.0005})
    b = _boot(["beta"], {"beta": 0.1000}, {"beta": 0.0010}, {"beta": 0.1000})
    source = bs.apply_bootstrap(model, None, fit, b)  # type: ignore[arg-type]  # data only reaches the refit
    assert source == {"beta": "bootstrap+bracket"}
    assert fit.params["beta"] == 0.1020
    assert bs.BRACKET_WEIGHT == 0.5
    assert fit.std["beta"] == pytest.approx(math.hypot(0.0010, 0.5 * 0.0020), rel=1e-12)
    assert fit.extra["irw_beta"] == 0.1000 and fit.extra["tv_beta"] == 0.1020
    assert fit.extra["hessian_std_beta"] == 0.0005


def test_bracket_leaves_stiction_band_as_the_bootstrap_gives_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """Stiction's band is measured from the slips: no TV refit, its estimate the bootstrap's
    bias-corrected one and its sd the bootstrap's (at least the Hessian's), with or without the bracket."""
    calls: list[list[str]] = []
    monkeypatch.setattr(bs, "preprocessing_refit", lambda model, data, fit, names: calls.append(names) or {})
    model = Model(("stiction",))
    for bracket in (None, True, False):
        fit = _fit(model.effects, {"band_mm": 0.030}, {"band_mm": 0.0002})
        b = _boot(["band_mm"], {"band_mm": 0.030}, {"band_mm": 0.0025}, {"band_mm": 0.031})
        source = bs.apply_bootstrap(model, None, fit, b, bracket=bracket)  # type: ignore[arg-type]
        assert source == {"band_mm": "bootstrap"}
        assert fit.params["band_mm"] == 0.031 and fit.std["band_mm"] == 0.0025
        assert "tv_band_mm" not in fit.extra
    assert calls == []


def _run(irw: float, tv: float, sb: float, sh: float, truth: float = 0.1) -> dict[str, object]:
    sd = math.hypot(max(sb, sh), 0.5 * (tv - irw))
    return {"effect": "medium_temperature", "variant": None, "cause": "medium_temperature", "named": True,
            "seconds": 1.0, "true_value": truth, "estimate_value": tv, "std_value": sd, "ml_value": irw,
            "std_hessian": sh, "std_robust": sh, "std_bootstrap": sb, "irw_value": irw, "tv_value": tv,
            "misspecified": False}


def test_effects_study_pools_runs_and_prints_the_other_bracket_rules(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two runs whose TV refit is 2 % low (reported z -2.83): with the whole IRW-TV difference z is -1.79,
    about the midpoint -2.12; the second file's run (TV 0.1 % low) is pooled with the first."""
    ic = importlib.import_module("studies.independent_coverage")
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"study": "effects", "results": [_run(0.0990, 0.0980, 0.0005, 0.0004)]}))
    b.write_text(json.dumps({"study": "effects", "results": [_run(0.1002, 0.0999, 0.0005, 0.0004)]}))
    summ = ic.summarise_effects(json.loads(a.read_text())["results"])["medium_temperature"]["by_sd"]
    assert summ["reported"]["mean_z"] == pytest.approx(-0.002 / math.hypot(0.0005, 0.0005))
    assert summ["tv_whole_d"]["mean_z"] == pytest.approx(-0.002 / math.hypot(0.0005, 0.0010))
    assert summ["midpoint"]["mean_z"] == pytest.approx(-0.0015 / math.hypot(0.0005, 0.0005))
    assert summ["reported"]["cover_2sd"] == 0.0 and summ["tv_whole_d"]["cover_2sd"] == 1.0
    assert ic.main(["--study", "effects", "--summarise", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "pooled from 2 file(s): 2 runs" in out and "named 2/2" in out
    assert "tv_whole_d" in out and "midpoint" in out
    # a file of the other study is refused in one line, exit status 2
    (tmp_path / "c.json").write_text(json.dumps({"study": "base", "results": []}))
    assert ic.main(["--study", "effects", "--summarise", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thermovalve: error:") and "c.json" in err[0]


def test_replicates_are_prepared_as_the_reported_estimate() -> None:
    """A named smooth effect's replicates are refitted on the bracket's denoiser (its reported estimate is the
    TV refit); stiction's band and the base model's parameters keep the IRW-RTS smoother; no bracket, no TV."""
    assert bs.replicate_denoiser(Model(("medium_temperature",)), ["beta"]) == "tv"
    assert bs.replicate_denoiser(Model(("sensor_lag",)), ["tau_s"]) == "tv"
    assert bs.replicate_denoiser(Model(("stiction",)), ["band_mm"]) == "irw"
    assert bs.replicate_denoiser(Model(()), ["sigma", "F_hmax", "p_bset"]) == "irw"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bs, "BRACKET", False)
        assert bs.replicate_denoiser(Model(("medium_temperature",)), ["beta"]) == "irw"


def test_bracket_takes_the_bootstrap_correction_of_the_refit(monkeypatch: pytest.MonkeyPatch) -> None:
    """With TV-refitted replicates the bootstrap carries the run's TV refit (0.1020) and its correction by the
    replicates' clear bias (-0.0015: TV low in the bootstrap's world): the estimate is 0.1035, and no second
    refit is made; the sd is as before (the bootstrap's, the half difference in quadrature)."""
    monkeypatch.setattr(bs, "preprocessing_refit", lambda *a: pytest.fail("refit made twice"))
    model = Model(("medium_temperature",))
    fit = _fit(model.effects, {"beta": 0.1000}, {"beta": 0.0005})
    b = _boot(["beta"], {"beta": 0.1000}, {"beta": 0.0010}, {"beta": 0.1035})
    b.bias, b.bias_corrected, b.denoiser, b.refit = {"beta": -0.0015}, {"beta": True}, "tv", {"beta": 0.1020}
    source = bs.apply_bootstrap(model, None, fit, b)  # type: ignore[arg-type]
    assert source == {"beta": "bootstrap+bracket"}
    assert fit.params["beta"] == 0.1035
    assert fit.extra["irw_beta"] == 0.1000 and fit.extra["tv_beta"] == 0.1020
    assert fit.std["beta"] == pytest.approx(math.hypot(0.0010, 0.5 * 0.0020), rel=1e-12)
    assert b.to_json()["replicates_prepared"] == "tv"


def test_bootstrap_refits_replicates_on_tv_and_corrects_the_refit(monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole bootstrap on a short medium_temperature run: each replicate's refit sees TV-denoised
    temperatures of that replicate's own noisy channels (not the IRW-RTS smoothed ones) and the run's TV refit is
    kept. The replicates' clear bias (TV low by 0.002 in the world) is not a correction (``BRACKET_CORRECT`` off:
    the world's temperatures are the smoothed ones, not the real ones) but part of the sd, their RMS error about
    the world's truth; switched on, it corrects the refit."""
    from valve_env.experiment import simulate_experiment
    from valve_env.valveid.diagnose import check_run, prepare
    from valve_env.valveid.temperature import denoise_temperature

    df = simulate_experiment(seed=31, duration_h=4.0, dt_s=20.0, effects={"medium_temperature": {"beta": 0.1}},
                             T_noise_C=0.008, x_noise_mm=2.5e-3)
    d = prepare(check_run(df))
    m = Model(("medium_temperature",))
    fit = m.fit(d, with_std=False)
    seen: list[bool] = []

    def refit(model: Model, rep: bs.RunData, values: dict[str, float], names: list[str]) -> dict[str, float]:
        seen.append(bool(np.array_equal(rep.T, denoise_temperature(rep.T_raw, rep.t, denoiser="tv")[0])
                         and not np.array_equal(rep.T_raw, d.T_raw)))
        return {**values, "beta": values["beta"] - 0.002 + 1e-4 * len(seen) % 3e-4}

    monkeypatch.setattr(bs, "_refit", refit)
    monkeypatch.setattr(bs, "preprocessing_refit", lambda model, data, fit, names: {"beta": 0.1010})
    b = bs.bootstrap(m, d, fit, B=6, seed=1)
    assert seen == [True] * 6
    assert b.denoiser == "tv" and b.refit == {"beta": 0.1010}
    assert not b.bias_corrected["beta"] and b.corrected["beta"] == 0.1010
    reps = b.replicates[:, 0] - fit.params["beta"]
    assert b.bias["beta"] == pytest.approx(reps.mean()) and b.bias["beta"] < -0.0015
    assert b.std["beta"] == pytest.approx(math.sqrt(reps.var(ddof=1) + reps.mean() ** 2), rel=1e-9)
    monkeypatch.setattr(bs, "BRACKET_CORRECT", True)
    seen.clear()
    b = bs.bootstrap(m, d, fit, B=6, seed=1)
    assert b.bias_corrected["beta"] and b.corrected["beta"] == pytest.approx(0.1010 - b.bias["beta"], rel=1e-12)


def test_effects_study_prints_the_corrected_refit_beside_the_reported() -> None:
    """``tv_corrected`` (the rejected ``BRACKET_CORRECT``): a TV refit 0.0990 whose 16 TV-refitted replicates lie
    0.0008 low with spread 0.0004 (a clear bias, 8 se) becomes 0.0998 +- hypot(0.0004 x sqrt(17/16), 0.0005); a
    run without TV-refitted replicates has no such rule (nan); the bootstrap's own sd is read about the TV refit."""
    ic = importlib.import_module("studies.independent_coverage")
    r = {**_run(0.1000, 0.0990, 0.0009, 0.0002), "boot_bias": -0.0008, "boot_spread": 0.0004, "boot_B": 16,
         "replicates_prepared": "tv"}
    est, truth, sd = ic._tv_corrected(r)
    assert est == pytest.approx(0.0998) and truth == 0.1
    assert sd == pytest.approx(math.hypot(0.0004 * math.sqrt(17 / 16), 0.0005))
    assert math.isnan(ic._tv_corrected(_run(0.1000, 0.0990, 0.0009, 0.0002))[0])
    by_sd = ic.summarise_effects([r])["medium_temperature"]["by_sd"]
    assert by_sd["tv_corrected"]["mean_z"] == pytest.approx(-0.0002 / sd)
    assert by_sd["bootstrap"]["mean_z"] == pytest.approx(-0.0010 / 0.0009)
