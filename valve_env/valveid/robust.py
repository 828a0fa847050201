"""Misspecification-robust standard errors and the misspecification checks of the valve's fits.

The EKF estimator's sandwich and whiteness check are the core's
(:func:`valve_env.ident.uncertainty.robust_std`, :func:`valve_env.ident.tests.misspecification_check`).

**The output-error likelihood's** (the diagnosis's named effects, :class:`valve_env.valveid.fitting.Model`):
:func:`sandwich_std` (its inverse Hessian and HAC sandwich, from the same
:mod:`valve_env.ident.uncertainty`), :func:`effect_misspecification` (the same whiteness check on its
standardised one-step errors) and :func:`robust_finding` (what a named effect's JSON carries beside its sd).
Their reported sd is the bootstrap's (:mod:`valve_env.valveid.bootstrap`).
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from valve_env.effects import REGISTRY as EFFECTS
from valve_env.ident.tests import ROBUST_ADVICE, MisspecificationWarning, whiteness_check
from valve_env.valveid.stiction import opening_noise, slips

if TYPE_CHECKING:
    from valve_env.valveid.data import RunData
    from valve_env.valveid.fitting import FitResult, Model


def sandwich_std(model: Model, data: RunData, fit: FitResult, fixed: tuple[str, ...] = ("band_mm",)
                 ) -> dict[str, object]:
    """The two likelihood-based sds of a finding's parameters, side by side, at its maximum-likelihood
    estimate ``fit`` (a fit of ``model`` to ``data``): ``std_hessian`` (the inverse Hessian over the
    identified directions) and ``std_robust`` (the Newey-West HAC sandwich of the per-sample scores of
    the output-error likelihood, the residual model's parameters held as a working covariance), both
    from :func:`valve_env.ident.uncertainty.hessian_sandwich_parts`, the one implementation of the
    standard errors (docs/estimation.md). ``fixed`` parameters have neither (stiction's band is
    measured from the slips, not fitted: its sd is the bootstrap's alone). ``lags``: the HAC window."""

    held = {n: fit.params[n] for n in fixed if n in model.names}
    free, zf, _, at, nll = model._objective(data, fit.params, held)
    names, sd_h, sd_r, lags = model.std_parts(data, free, zf, at, nll)
    nan = {n: float("nan") for n in fixed if n in model.names}
    return {"std_hessian": {n: float(sd_h[j]) for j, n in enumerate(names)} | nan,
            "std_robust": {n: float(sd_r[j]) for j, n in enumerate(names)} | nan,
            "lags": int(lags)}


#: what a rejected check means for a bootstrap sd: its replicates are drawn from the fitted model itself
BOOTSTRAP_ADVICE = ("the reported sd is a bootstrap in this model's own world, which assumes the model: read it "
                    "as a lower bound")


#: the stick-slip check fires when the median, over the slips, of the demand's travel while stuck over the slip's
#: size lies outside [1 / STICK_TOL, STICK_TOL] (:func:`stick_slip_check`; calibrated on development runs,
#: docs/uncertainty.md, "Sandwich standard errors and the misspecification check")
STICK_TOL = 1.6
#: the fewest slips the stick-slip check judges (fewer: not tested, it does not fire)
STICK_MIN_SLIPS = 4


def stuck_travel(x: np.ndarray, demand: np.ndarray, stroke: float, rest_sd: float = 3.0) -> np.ndarray:
    """For each slip of the measured opening ``x`` (:func:`valve_env.valveid.stiction.slips`), the demanded
    opening's travel while the stem was stuck over the slip's size (mm / mm; one value per slip).

    The stuck interval runs back from the slip while the opening stays within ``rest_sd`` noise sd of the
    plateau's level; the travel is the demand's, midway between the samples around the slip (where the
    slip's size is measured), beyond its extreme over that interval, in the slip's direction. ``demand``
    is the opening the fitted valve demands at the samples (its stick-slip switched off)."""

    x = np.asarray(x, dtype=float)
    c = np.asarray(demand, dtype=float)
    s = opening_noise(x).sd
    events: list[tuple[int, float, float, float]] = []
    slips(x, stroke, events=events)
    out = []
    for k, sg, lev, size in events:
        j = k - 2
        while j > 0 and abs(x[j - 1] - lev) <= rest_sd * s:
            j -= 1
        seg = sg * c[j:k + 2]
        out.append((0.5 * (seg[-1] + seg[-2]) - float(seg[:-1].min())) / size)
    return np.array(out, dtype=float)


def stick_slip_check(model: Model, data: RunData, fit: FitResult, *, tol: float = STICK_TOL,
                     min_slips: int = STICK_MIN_SLIPS, warn: bool = True, label: str = "stiction valve model",
                     advice: str = ROBUST_ADVICE) -> dict[str, Any]:
    """The misspecification check of a stick-slip effect: does the opening slip the way the fitted model says?

    The project's stick-slip (docs/diagnosis.md; :mod:`valve_env.physics.stickslip` with J = S) says that a
    stuck stem slips when the demanded opening has moved the band from where it stuck and lands on the demand:
    each slip's size equals the demand's travel while the stem was stuck. A valve that slips by another rule
    (a slip J shorter than the breakaway travel S, e.g. the independent simulator's ``force`` variant) breaks
    this. The statistic is the median over the slips of :func:`stuck_travel` (the fitted valve's demand,
    its stick-slip switched off, against the measured slips); the check fires when it lies outside
    ``[1 / tol, tol]`` with at least ``min_slips`` slips (fewer: ``tested`` false, it does not fire).

    Why not the whiteness check: at each slip the stick-slip filter's one-step error is one large error, and
    the filter catches up over a few samples, so its standardised errors are neither Gaussian nor white on
    the right model (Ljung-Box p below 1e-5 on 15 of 15 development runs, slips set aside or not;
    docs/uncertainty.md, "Sandwich standard errors and the misspecification check"). The
    whiteness result is kept beside it for
    information (``whiteness``)."""
    stroke = float(model.valve.stroke)
    demand, _, _ = model.simulate(data, {**fit.params, "band_mm": 0.0})
    r = stuck_travel(data.x, demand, stroke)
    r = r[np.isfinite(r)]
    med = float(np.median(r)) if r.size else float("nan")
    tested = bool(r.size >= min_slips)
    bad = bool(tested and not (1.0 / tol <= med <= tol))
    out: dict[str, Any] = {"check": "stick-slip: the demand's travel while stuck against each slip's size",
                           "n_slips": int(r.size), "travel_over_slip_median": med,
                           "travel_over_slip_iqr": [float(v) for v in np.percentile(r, [25, 75])] if r.size else [],
                           "tolerance": float(tol), "tested": tested, "misspecified": bad}
    out["message"] = (f"the opening's {r.size} slips follow another rule than the model's: the demand travelled "
                      f"{med:.2f} times the slip's size while the stem was stuck (the model says 1, tolerance "
                      f"[{1.0 / tol:.2f}, {tol:.2f}]); the band measures the slips, not the breakaway travel; "
                      f"{advice}") if bad else ""
    if bad and warn:
        warnings.warn(f"{label}: {out['message']}", MisspecificationWarning, stacklevel=3)
    return out


def effect_misspecification(model: Model, data: RunData, fit: FitResult, *, alpha: float = 0.01, nlags: int = 40,
                            warn: bool = True, bootstrap_sd: bool = False) -> dict[str, object]:
    """The misspecification check of a finding: the whiteness of its standardised one-step prediction
    errors (Ljung-Box at ``nlags`` and the cumulated periodogram, level ``alpha``;
    :func:`valve_env.valveid.robust.whiteness_check`, the base fit's check), with a
    :class:`~valve_env.valveid.robust.MisspecificationWarning` when it rejects: the effect's model
    (with its Ornstein-Uhlenbeck model error) does not explain the opening's dynamics, and its sd (the
    bootstrap's world is that model) is not to be trusted. Its rates on the studies' runs are in
    docs/uncertainty.md. ``bootstrap_sd``: the finding's reported sd is the bootstrap's (the warning then
    says so, instead of pointing to the sandwich).

    A model with stiction gets :func:`stick_slip_check` instead (the whiteness of its filter's errors does not
    tell the right stick-slip model from a wrong one), with the whiteness result beside it (``whiteness``)."""
    nu, S = model.prediction_errors(data, fit.params)
    e = np.where(S > 0, nu / np.sqrt(np.where(S > 0, S, 1.0)), np.nan)
    label = ("+".join(model.effects) or "base") + " valve model"
    advice = BOOTSTRAP_ADVICE if bootstrap_sd else ROBUST_ADVICE
    stick_slip = "stiction" in model.effects
    # a stick-slip effect: the whiteness of its filter's errors says nothing (the docstring of stick_slip_check),
    # so only the stick-slip check warns; the whiteness result is kept beside it
    white = whiteness_check({"x_mm": e}, alpha=alpha, nlags=nlags, warn=warn and not stick_slip, label=label,
                            advice=advice)
    if not stick_slip:
        return white
    out = stick_slip_check(model, data, fit, warn=warn, label=label, advice=advice)
    out["whiteness"] = white
    return out


def robust_finding(model: Model, data: RunData, fit: FitResult, *, warn: bool = True,
                   bootstrap_sd: bool = False) -> dict[str, object]:
    """What a named effect's JSON carries beside its ``std`` (docs/uncertainty.md, "Sandwich standard
    errors and the misspecification check"):
    ``std_hessian`` and ``std_robust`` of its effect parameters (:func:`sandwich_std`), ``robust_lags``
    and ``misspecification`` (:func:`effect_misspecification`, which warns)."""

    names = [p.name for e in model.effects for p in EFFECTS[e].parameters]
    sw = sandwich_std(model, data, fit)
    h, r = sw["std_hessian"], sw["std_robust"]
    assert isinstance(h, dict) and isinstance(r, dict)
    return {"std_hessian": {k: float(h.get(k, float("nan"))) for k in names},
            "std_robust": {k: float(r.get(k, float("nan"))) for k in names},
            "robust_lags": sw["lags"],
            "misspecification": effect_misspecification(model, data, fit, warn=warn, bootstrap_sd=bootstrap_sd)}


__all__ = ["effect_misspecification", "robust_finding", "sandwich_std", "stick_slip_check", "stuck_travel"]
