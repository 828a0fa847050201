"""The pre-processing bracket of a named smooth effect (valve_env.estimation.bootstrap.apply_bootstrap),
and the effects study's alternative bracket rules (benchmarks/independent_coverage.py).

docs/uncertainty.md, "Issue 20, eighth round": the TV refit is the estimate and half the IRW-TV difference
enters its sd in quadrature; the study prints the coverage of two other rules beside it (the whole
difference; the midpoint of the two estimates) from the same runs, and pools earlier runs (--summarise).
Stiction's band is not bracketed: it passes through apply_bootstrap exactly as the bootstrap gives it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tests.diagnosis.studies import load_study
from valve_env.diagnosis.fitting import FitResult, Model
from valve_env.estimation import bootstrap as bs


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
    ic = load_study("independent_coverage")
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
