"""The paper's Table 4 comes back from runs simulated like the paper's experiment
(valve_env.experiment: temperature steps at constant pressures, x noise 2.4e-3 mm, white
temperature noise 0.01 degC), and the cross-validation of the paper's Fig. 7.

The study takes about 40 s (10 fits of 24 h of 10 s data), so it runs by default. Seeds 0-9
were not used to choose the temperature denoising; on two further sets (seeds 100-109 and
200-209) sigma is covered 8 and 9 times (docs/estimation.md).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
import pandas as pd

from valve_env.ident.mle import MLEstimator
from valve_env.params import ValveParams
from valve_env.valveid.valve_model import ValveModel

TRUE = {k: getattr(ValveParams(), k) for k in ("sigma", "F_hmax", "p_bset")}


def _study(small_run: Callable[..., pd.DataFrame], seeds: list[int], hours: float) -> pd.DataFrame:
    rows = []
    for seed in seeds:
        df = small_run(seed=seed, hours=hours)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = MLEstimator(ValveModel(), n_starts=1, seed=seed).fit(df)
        row = {"seed": seed, "rms": est.rms_["x_mm"], "converged": est.converged_}
        for k in TRUE:
            row[k] = est.params_[k]
            row[f"sd_{k}"] = est.std_[k]
        rows.append(row)
    return pd.DataFrame(rows)


def _check(res: pd.DataFrame, min_cover: int, ratio_tol: float) -> dict[str, tuple[int, float]]:
    out = {}
    for k, v in TRUE.items():
        z = (res[k] - v) / res[f"sd_{k}"]
        cover = int((z.abs() < 2.0).sum())
        ratio = float(res[f"sd_{k}"].mean() / res[k].std(ddof=1))
        out[k] = (cover, ratio)
        assert res[f"sd_{k}"].gt(0).all()
        assert cover >= min_cover, (k, z.round(2).tolist())
        assert 1.0 / ratio_tol <= ratio <= ratio_tol, (k, ratio)
    assert res["converged"].all()
    assert (res["rms"] < 1.25 * 2.4e-3).all()
    return out


def test_table4_ten_seeds(small_run: Callable[..., pd.DataFrame]) -> None:
    """sigma, F_hmax and p_bset within two standard errors in at least 9 of 10 seeds; the mean
    standard error within a factor 1.5 of the spread of the estimates across seeds."""
    res = _study(small_run, list(range(10)), hours=24.0)
    summary = _check(res, min_cover=9, ratio_tol=1.5)
    print("\n" + res.to_string())
    print({k: {"covered_2se": c, "sd_over_spread": round(r, 3)} for k, (c, r) in summary.items()})


def test_cross_validation_like_fig7(small_run: Callable[..., pd.DataFrame]) -> None:
    """Parameters fitted on one run predict an independent run with residuals near the noise level."""
    train = small_run(seed=11, hours=24.0)
    test = small_run(seed=12, hours=24.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = MLEstimator(ValveModel(), n_starts=1).fit(train)
    e = est.residuals(test, standardised=False)["x_mm"].to_numpy()
    rms = float(np.sqrt(np.nanmean(e**2)))
    assert rms < 1.25 * 2.4e-3
    sim = est.simulate(test)["x_mm"].to_numpy()
    rms_sim = float(np.sqrt(np.mean((test["x_mm"].to_numpy() - sim) ** 2)))
    assert rms_sim < 3.0 * 2.4e-3  # pure simulation, never corrected by the measured opening
    z = est.residuals(test)["x_mm"].to_numpy()
    assert abs(np.nanstd(z) - 1.0) < 0.2
