"""The filters and the estimator against ctsmTMB's stored results on its Ornstein2D data
(tests/data/ctsmtmb_ornstein, GPL-3, see SOURCE.md there)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from valve_env.ident.examples import Ornstein1D, Ornstein2D
from valve_env.ident.kalman import run_filter, to_arrays
from valve_env.ident.mle import IdentifiabilityWarning, MLEstimator, negloglik


def _load(ornstein_dir: Path) -> tuple[pd.DataFrame, dict]:
    d = pd.read_csv(ornstein_dir / "Ornstein2D.csv").iloc[:50].rename(columns={"t": "time_s"})
    ref = json.loads((ornstein_dir / "estimate_reference_ornstein2d_first50.json").read_text())["fits"]
    return d, ref


def _natural(par_fixed: dict[str, float]) -> dict[str, float]:
    return {k.removeprefix("log"): (float(np.exp(v)) if k.startswith("log") else float(v))
            for k, v in par_fixed.items()}


@pytest.mark.parametrize(("fit", "method", "foh", "expected"), [
    ("ekf", "ekf", False, 4.83956779),
    ("lkf", "lkf", False, 4.80814948),
    ("ekf_foh", "ekf", True, 1.73650332),
    ("lkf_foh", "lkf", True, None),
])
def test_nll_at_ctsmtmb_parameters(ornstein_dir: Path, fit: str, method: str, foh: bool,
                                   expected: float | None) -> None:
    d, ref = _load(ornstein_dir)
    m = Ornstein2D()
    params = _natural(ref[fit]["par_fixed"])
    value = negloglik(m, params, d, method=method, foh=foh)
    assert value == pytest.approx(ref[fit]["nll"], abs=1e-6)
    if expected is not None:
        assert value == pytest.approx(expected, abs=1e-6)
    if method == "ekf":  # the generic Python EKF gives the same
        assert negloglik(m, params, d, method="ekf", foh=foh, compiled=False) == pytest.approx(value, abs=1e-10)


def test_missing_observations_and_uneven_sampling(ornstein_dir: Path) -> None:
    d, ref = _load(ornstein_dir)
    m = Ornstein2D()
    p = m.param_vector(_natural(ref["ekf"]["par_fixed"]))
    d = d.copy()
    d.loc[[5, 17, 30], "y1"] = np.nan
    d.loc[[17, 40], "y2"] = np.nan
    d = d.drop(index=[8, 9, 22]).reset_index(drop=True)  # uneven sampling
    arr = to_arrays(m, d)
    # one RK4 step over the 0.3-0.4 s gaps is unstable for theta = 6.2 (as in ctsmTMB): sub-steps
    fast = run_filter(m, p, arr, n_sub=4)
    slow = run_filter(m, p, arr, compiled=False, n_sub=4)
    assert not np.isfinite(run_filter(m, p, arr).nll)
    assert np.isfinite(fast.nll)
    assert fast.nll == pytest.approx(slow.nll, abs=1e-10)
    assert np.isnan(fast.innov[d.index[d.y1.isna()], 0]).all()
    # exact discretisation and RK4 with fine sub-steps converge to the same filter
    lin = run_filter(m, p, arr, method="lkf")
    rk = run_filter(m, p, arr, n_sub=20)
    assert lin.nll == pytest.approx(rk.nll, abs=1e-4)


@pytest.mark.parametrize("method", ["ekf", "lkf"])
def test_fit_lands_on_ctsmtmb_estimates(ornstein_dir: Path, method: str) -> None:
    d, ref = _load(ornstein_dir)
    r = ref[method]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)  # sigma_y1 -> 0, as in ctsmTMB (sd 2e4)
        est = MLEstimator(Ornstein2D(), n_starts=2, seed=1, method=method).fit(d)
    assert est.nll_ <= r["nll"] + 1e-6
    assert est.loglik_ == pytest.approx(-r["nll"], abs=1e-5)
    for key, value in r["par_fixed"].items():
        name = key.removeprefix("log")
        if name == "sigma_y1":  # on the boundary: both fits drive it to 0
            assert est.params_["sigma_y1"] < 1e-2
            continue
        ours = est.params_work_[name] if key.startswith("log") else est.params_[name]
        assert abs(ours - value) < r["sd_fixed"][key], name
        assert est.std_work_[name] == pytest.approx(r["sd_fixed"][key], rel=0.05), name
    assert est.corr_.shape == (7, 7)
    assert set(est.tstat_) == set(est.std_)


def test_fixed_parameters_and_nll_method(ornstein_dir: Path) -> None:
    d, ref = _load(ornstein_dir)
    nat = _natural(ref["lkf"]["par_fixed"])
    est = MLEstimator(Ornstein2D(), n_starts=1, method="lkf",
                      fixed={"sigma_y1": nat["sigma_y1"], "theta": nat["theta"]}).fit(d)
    assert est.params_["theta"] == nat["theta"]
    assert "theta" not in est.std_ and est.n_free_ == 5
    assert est.nll(nat) == pytest.approx(ref["lkf"]["nll"], abs=1e-6)


def test_outputs_predict_simulate_smooth_residuals(ornstein_dir: Path) -> None:
    d, ref = _load(ornstein_dir)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        est = MLEstimator(Ornstein2D(), n_starts=1, method="lkf").fit(d)
    pred = est.predict(d)
    assert list(pred.columns) == ["time_s", "y1", "y1_sd", "y2", "y2_sd"]
    sim = est.simulate(d)
    assert (sim["y1_sd"].to_numpy()[5:] > pred["y1_sd"].to_numpy()[5:]).all()
    sm = est.smooth(d)
    fl = est.filter(d)
    assert (sm["x1_sd"] <= fl["x1_sd"] + 1e-12).all()
    res = est.residuals(d)
    assert abs(res["y2"].std() - 1.0) < 0.3


def test_identifiability_message() -> None:
    """A model whose two parameters enter only as a product: flagged, with both names."""
    rng = np.random.default_rng(0)
    n = 200
    t = np.arange(n) * 0.1
    u = rng.standard_normal(n)
    x = np.zeros(n)
    for k in range(1, n):
        x[k] = x[k - 1] + 0.1 * 2.0 * (1.0 + u[k - 1] - x[k - 1]) + 0.1 * rng.standard_normal()
    d = pd.DataFrame({"time_s": t, "u": u, "y": x + 0.05 * rng.standard_normal(n)})

    class Product(Ornstein1D):
        name = "product"
        parameters = (*Ornstein1D.parameters, Ornstein1D.parameters[1].__class__("k", 1.0, 0.1, 10.0, "log"))

        def drift(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
            return np.array([p[0] * (p[1] * p[4] + u[0] - x[0])])

    with pytest.warns(IdentifiabilityWarning, match="mu"):
        est = MLEstimator(Product(), n_starts=1, method="lkf", maxiter=100).fit(d)
    assert any("not identifiable" in m and "k" in m for m in est.identifiability_)
