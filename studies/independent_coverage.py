"""Coverage and confusion studies on the independent simulator (docs/uncertainty.md).

Runs the project's current tools, exactly as the commands run them (the run is
written to a CSV holding only the docs/reference.md, section 2 columns and read back with the
loader, so no tool sees the truth), on runs of the independent simulator
(:mod:`valve_env.studies.independent`) and, for comparison, of the project's own
generator (:mod:`valve_env.experiment`):

* ``base``: ``thermovalve fit --ml`` (``valve_env.valveid.fit.fit_run``) and
  ``thermovalve fit``, the default (:func:`valve_env.valveid.eiv.fit_eiv`) on runs
  without effects at 0.01 degC of temperature noise (``--T-noise -1``: drawn per run
  from 0.001-0.02 degC): sigma, F_hmax, p_bset, z = (estimate - truth) / sd, 1-sd and
  2-sd coverage of each candidate sd (``SD_CANDIDATES``: inverse Hessian, HAC sandwich,
  the bias-corrected temperature bootstrap, the default fit's, the EIV state model;
  ``--shipped-only``: the default fit's with its ML fit's inverse Hessian and sandwich).
* ``effects``: ``thermovalve diagnose`` (``valve_env.valveid.diagnose.diagnose``)
  on runs with one named effect each (stiction once per stick-slip variant) and
  runs without: the cause named, and the true effect's parameter against the truth
  (z, coverage, relative error), with the coverage of each of its sds (``EFFECT_SDS``:
  the reported one, the inverse Hessian, the HAC sandwich, the bootstrap alone) and
  its misspecification check.

Study seeds (chosen before any run, never tuned on): base 20261127 (the EIV
study; 20261123 before it), effects 20261124; the project generator's runs use
20261128 (20261125 before) and 20261126. Tuning seeds: 7300 / 7301. The named effects' study
(docs/uncertainty.md, "The studies (`studies/independent_coverage.py`)"): held out 20261201 (effects,
independent), 20261202 (effects, project), 20261205 (base, independent, 0.001-0.02 degC); 4242 for
development. The named effects' pre-processing bracket: development 7700, 7702
(independent), 7701 (project); held out 20261125 (effects, independent) and 20261126 (effects,
project), run once with the final code. The smooth effects per effect: development
20261124, 20261125 (independent), 20261202, 7301 (project); held out 20270213 (independent) and
20270214 (project), run once. ``--summarise`` pools earlier ``--json`` files of a study. Stiction's
band sd (each stiction run's record carries ``band_sd_parts``): development 500, 777,
20261124, 20261201, 20270122, 20270131 (independent), 20261126, 20261202, 20270121, 20270132 (project);
held out 20270211 (independent, 4 runs) and 20270212 (project, 8 runs). A smooth
effect's replicates refitted on TV (each record carries the bootstrap's ``boot_bias``, ``boot_spread``,
``boot_B`` and ``replicates_prepared``, and the summary the ``tv_corrected`` rule): development 20270414,
303 (project), 20270413 (independent); held out 20270614, 20270615 (project), 20270613 (independent).
Run i of a study uses ``numpy.random.default_rng([seed, i])``.

    python studies/independent_coverage.py --study base --runs 30 --eiv-B 8 --workers 2 \
        --json out/held_ind.json
    python studies/independent_coverage.py --study effects --runs 2 --workers 2 --json out/indep_effects.json
    python studies/independent_coverage.py --study effects --only stiction --runs 2 --seed 777 --json out/s.json
    python studies/independent_coverage.py --study base --generator project --runs 20 --json out/held_proj.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
import pandas as pd

from valve_env.outputs import OutputError, OutputSet
from valve_env.studies.independent import COLUMNS, STICTION_VARIANTS, draw_run, simulate_independent

# base: 20261127 / 20261128 held out for the EIV and robust sds (docs/uncertainty.md; the earlier base
# study used 20261123 / 20261125); tuning used 7300 / 7301
SEEDS = {("base", "independent"): 20261127, ("effects", "independent"): 20261124,
         ("base", "project"): 20261128, ("effects", "project"): 20261126}
BASE_NAMES = ("sigma", "F_hmax", "p_bset")
EFFECT_PARAM = {"sensor_lag": "tau_s", "medium_temperature": "beta", "stiction": "band_mm",
                "setpoint_drift": "rate_MPa_per_h"}


def _simulate(case: dict[str, Any]) -> tuple[pd.DataFrame, dict[str, float], dict[str, dict[str, float]]]:
    """The run of a case and its truth (base parameters, effects)."""
    rng = np.random.default_rng([case["seed"], case["i"]])
    conv = tuple(c for c in case.get("conventions", ()) if c != "irregular")
    medium = case.get("medium") or "smooth"
    run = draw_run(rng, case["effect"], T_noise_C=case.get("T_noise_C"),
                   stiction_variant=case.get("variant") or "reset", medium=medium,
                   conventions=conv if case["generator"] == "independent" else ())
    if "irregular" in case.get("conventions", ()):  # jittered times and 5 % of the rows missing
        from dataclasses import replace

        run = replace(run, jitter=0.2, conventions=(*run.conventions, "dropped_5")
                      if case["generator"] == "independent" else run.conventions)
        conv = (*conv, "dropped_5")
    truth = {"sigma": run.valve.sigma, "F_hmax": run.valve.F_hmax, "p_bset": run.valve.p_bset}
    if case["generator"] == "independent":
        df = simulate_independent(run)
    else:
        from valve_env.experiment import simulate_experiment

        df = simulate_experiment(seed=run.seed, duration_h=run.duration_h, dt_s=run.dt_s,
                                 effects={k: dict(v) for k, v in run.effects.items()} or None,
                                 T_noise_C=run.T_noise_C, q_noise_rel=0.015, dp_noise_rel=0.015,
                                 ps_noise_rel=0.015, jitter=run.jitter)
        if conv:
            from valve_env.studies.conventions import apply_convention

            crng = np.random.default_rng([run.seed, 37])
            for name in conv:
                df = apply_convention(df, name, crng, keep_truth=True)
    case.update({"run_seed": run.seed, "duration_h": run.duration_h, "dt_s": run.dt_s, "T_noise_C": run.T_noise_C})
    return df, truth, {k: dict(v) for k, v in run.effects.items()}


def _as_measured(df: pd.DataFrame) -> pd.DataFrame:
    """Write the docs/reference.md, section 2 columns to a CSV and read it back with the project's loader."""
    from valve_env.data_io import load_run

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "run.csv")
        df.loc[:, list(COLUMNS)].to_csv(path, index=False)
        return load_run(path)


def run_base(case: dict[str, Any]) -> dict[str, Any]:
    """One base run: the default fit (``thermovalve fit``: ML, inverse Hessian, the sandwich, the
    misspecification check), the shipped errors-in-variables fit (``thermovalve fit --eiv``:
    :func:`valve_env.valveid.eiv.fit_eiv`, with the temperature bootstrap of B replicates, whose
    bias-corrected result is the previous "after") and the EIV fit with the temperature error as a
    filter state (``fit_eiv(model="eiv")``)."""
    from valve_env.ident.uncertainty import robust_std, score_contributions
    from valve_env.valveid.eiv import fit_eiv
    from valve_env.valveid.fit import fit_run

    df, truth, _ = _simulate(case)
    data = _as_measured(df)
    out = dict(case)
    if case.get("shipped_only"):
        # only what `thermovalve fit` now runs by default (fit_eiv, B = 8): its relaxed-denoiser ML fit gives
        # the inverse Hessian and the HAC sandwich beside the shipped sd
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            f = fit_eiv(data, model="base", B=case["eiv_B"], seed=case["i"])
        rel = f.estimates["relaxed"]
        out.update({"truth": truth, "estimate": {k: rel[k] for k in BASE_NAMES},
                    "std_hessian": {k: f.estimator.std_[k] for k in BASE_NAMES},
                    "std_hac": {k: f.std_parts["robust"][k] * rel[k] for k in BASE_NAMES},
                    "fit_s": f.fit_time_s, "n": len(data),
                    "base_bracket": {"params": f.params, "std": f.std, "std_parts": f.std_parts,
                                     "estimates": {d: {k: e[k] for k in BASE_NAMES} for d, e in f.estimates.items()},
                                     "misspecified": f.misspecification["misspecified"], "seconds": f.fit_time_s}})
        return out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        est = fit_run(data)  # what `thermovalve fit` runs (n_starts=3, seed=0)
        t_fit = time.perf_counter() - t0
        G = score_contributions(est)
        out.update({"truth": truth, "estimate": {k: est.params_[k] for k in BASE_NAMES},
                    "std_hessian": {k: est.std_[k] for k in BASE_NAMES}, "fit_s": t_fit, "n": len(data)})
        for L in (0, None):
            r = robust_std(est, lags=L, scores=G)
            out["std_hw" if L == 0 else "std_hac"] = {k: r.std[k] for k in BASE_NAMES}
            out["hac_lags"] = r.lags
        for model, B in (("base", case["eiv_B"]), ("eiv", 0)):
            t1 = time.perf_counter()
            f = fit_eiv(data, model=model, B=B, seed=case["i"])
            out[f"{model}_bracket"] = {"params": f.params, "std": f.std, "std_parts": f.std_parts,
                                       "estimates": {d: {k: e[k] for k in BASE_NAMES} for d, e in f.estimates.items()},
                                       "std_hessian": {k: f.estimator.std_[k] for k in BASE_NAMES},
                                       "misspecified": f.misspecification["misspecified"],
                                       "seconds": time.perf_counter() - t1}
            if f.bootstrap is not None:
                eiv = f.bootstrap
                out["estimate_eiv"] = {k: eiv.params[k] for k in BASE_NAMES}
                out["std_eiv"] = {k: eiv.std[k] for k in BASE_NAMES}
                out["std_temperature"] = {k: eiv.std_temperature[k] for k in BASE_NAMES}
                out["eiv_bias"] = {k: eiv.bias[k] for k in BASE_NAMES}
                out["eiv_T_noise_C"] = eiv.T_noise_C
    return out


def run_effects(case: dict[str, Any]) -> dict[str, Any]:
    from valve_env.valveid.diagnose import diagnose

    df, truth, effects = _simulate(case)
    data = _as_measured(df)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose(data)
    out = dict(case)
    out.update({"cause": d.cause, "selected": list(d.selected), "seconds": time.perf_counter() - t0,
                "n": len(data), "effects": effects})
    if case["effect"] != "none":
        name = EFFECT_PARAM[case["effect"]]
        f = next(f for f in d.findings if f.effect == case["effect"])
        js = f.to_json()
        unc = js.get("uncertainty") or {}
        mis = js.get("misspecification") or {}
        out.update({"true_value": effects[case["effect"]][name], "estimate_value": js["params"][name],
                    "std_value": js["std"][name], "std_method": js.get("std_method", ""),
                    "named": bool(d.cause == case["effect"] or case["effect"] in d.selected),
                    # the ML estimate (before the bootstrap's bias correction) and the sds side by side
                    "ml_value": (unc.get("uncorrected_estimate") or {}).get(name, js["params"][name]),
                    "std_hessian": (js.get("std_hessian") or {}).get(name, float("nan")),
                    "std_robust": (js.get("std_robust") or {}).get(name, float("nan")),
                    "std_bootstrap": (unc.get("bootstrap_std") or {}).get(name, float("nan")),
                    "std_from": (unc.get("std_from") or {}).get(name, ""),
                    # the bootstrap's parts: bias and spread of the re-estimates about the world's truth, whether
                    # corrected, and how the replicates were prepared
                    "boot_bias": (unc.get("bias") or {}).get(name, float("nan")),
                    "boot_spread": (unc.get("spread") or {}).get(name, float("nan")),
                    "boot_corrected": (unc.get("bias_corrected") or {}).get(name),
                    "replicates_prepared": unc.get("replicates_prepared"), "boot_B": unc.get("replicates"),
                    # the two pre-processings' estimates (the errors-in-variables bracket), where taken
                    "irw_value": ((unc.get("preprocessing") or {}).get("irw") or {}).get(name, float("nan")),
                    "tv_value": ((unc.get("preprocessing") or {}).get("tv") or {}).get(name, float("nan")),
                    "misspecified": mis.get("misspecified"),
                    # stiction's band: the parts of its sd (noise copies, the slips' own, their number)
                    "band_sd_parts": unc.get("band_sd_parts"),
                    # stiction's breakaway travel S beside the slip J (the (S, J) profile)
                    "stick_slip": unc.get("stick_slip"),
                    "ljung_box_p": ((mis.get("outputs") or {}).get("x_mm") or {}).get("ljung_box_p")})
    elif d.cause != "none":
        js = d.findings[0].to_json()
        out["misspecified_false_finding"] = (js.get("misspecification") or {}).get("misspecified")
    return out


def _z(est: float, truth: float, sd: float) -> float:
    return (est - truth) / sd if (sd is not None and math.isfinite(sd) and sd > 0) else float("nan")


def _coverage(z: list[float]) -> dict[str, float]:
    a = np.abs(np.asarray(z, dtype=float))
    ok = a[np.isfinite(a)]
    n = len(a)
    return {"n": n, "n_with_sd": int(len(ok)), "cover_1sd": float(np.sum(ok <= 1.0) / n) if n else float("nan"),
            "cover_2sd": float(np.sum(ok <= 2.0) / n) if n else float("nan"),
            "rms_z": float(np.sqrt(np.mean(ok**2))) if len(ok) else float("nan"),
            "mean_z": float(np.mean(np.asarray(z)[np.isfinite(z)])) if len(ok) else float("nan")}


#: the standard deviations a base study compares: name -> (estimate key, sd key) in a run's record
SD_CANDIDATES: dict[str, str] = {
    "hessian": "ML fit, inverse Hessian (thermovalve fit --ml's std; std_hessian)",
    "hac": "ML fit, HAC sandwich (std_robust)",
    "bootstrap_bc": "temperature bootstrap, bias-corrected (the previous 'after')",
    "eiv": "thermovalve fit, the default (fit_eiv: denoiser bracket + HAC + temperature bootstrap)",
    "eiv_state": "fit_eiv(model='eiv'): temperature error as a filter state, bracket + HAC",
    "eiv_state_hessian": "ValveEIVModel fit alone, inverse Hessian",
}


def _candidate(r: dict[str, Any], name: str, k: str) -> tuple[float, float]:
    if name == "hessian":
        return r["estimate"][k], r["std_hessian"][k]
    if name == "hac":
        return r["estimate"][k], r["std_hac"][k]
    if name == "bootstrap_bc":
        return r.get("estimate_eiv", {}).get(k, float("nan")), r.get("std_eiv", {}).get(k, float("nan"))
    if name == "eiv":
        return r["base_bracket"]["params"][k], r["base_bracket"]["std"][k]
    if name == "eiv_state":
        return r["eiv_bracket"]["params"][k], r["eiv_bracket"]["std"][k]
    return r["eiv_bracket"]["estimates"]["relaxed"][k], r["eiv_bracket"]["std_hessian"][k]


def _has(r: dict[str, Any], name: str) -> bool:
    """Whether a base run's record holds candidate ``name`` (a --shipped-only run holds the default fit's)."""
    need = {"hessian": "std_hessian", "hac": "std_hac", "bootstrap_bc": "std_eiv", "eiv": "base_bracket",
            "eiv_state": "eiv_bracket", "eiv_state_hessian": "eiv_bracket"}
    return need[name] in r


def summarise_base(results: list[dict[str, Any]]) -> dict[str, Any]:
    summ: dict[str, Any] = {}
    for k in BASE_NAMES:
        rel = [r["estimate"][k] / r["truth"][k] - 1.0 for r in results]
        entry: dict[str, Any] = {"mean_rel_err": float(np.mean(rel)), "max_abs_rel_err": float(np.max(np.abs(rel)))}
        for name in SD_CANDIDATES:
            if not all(_has(r, name) for r in results):
                continue
            pairs = [_candidate(r, name, k) for r in results]
            c = _coverage([_z(e, r["truth"][k], s) for (e, s), r in zip(pairs, results, strict=True)])
            c["mean_rel_err"] = float(np.mean([e / r["truth"][k] - 1.0 for (e, _), r in zip(pairs, results,
                                                                                          strict=True)]))
            entry[name] = c
        summ[k] = entry
    state = all("eiv_bracket" in r for r in results)
    summ["_misspecified"] = {"default": int(sum(r["base_bracket"]["misspecified"] for r in results)),
                             "runs": len(results)}
    summ["_seconds_median"] = {"fit": float(np.median([r["fit_s"] for r in results])),
                               "fit_eiv": float(np.median([r["base_bracket"]["seconds"] for r in results])),
                               "n_median": float(np.median([r["n"] for r in results]))}
    if state:
        summ["_misspecified"]["eiv_state"] = int(sum(r["eiv_bracket"]["misspecified"] for r in results))
        summ["_seconds_median"]["fit_eiv_state"] = float(np.median([r["eiv_bracket"]["seconds"] for r in results]))
    return summ


def summarise_effects(results: list[dict[str, Any]]) -> dict[str, Any]:
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        key = r["effect"] + (f"/{r['variant']}" if r["effect"] == "stiction" else "")
        groups.setdefault(key, []).append(r)
    summ: dict[str, Any] = {}
    for key, rs in groups.items():
        e = rs[0]["effect"]
        entry: dict[str, Any] = {"runs": len(rs), "named_right": sum(r["cause"] == e for r in rs),
                                 "causes": [r["cause"] for r in rs]}
        if e != "none":
            z = [_z(r["estimate_value"], r["true_value"], r["std_value"]) for r in rs]
            entry.update(_coverage(z))
            entry["z"] = z
            entry["rel_err"] = [r["estimate_value"] / r["true_value"] - 1.0 for r in rs]
            entry["by_sd"] = _effect_sd_coverage([r for r in rs if r.get("named")])
            entry["misspecified"] = [r.get("misspecified") for r in rs]
            if e == "stiction":
                # the band as the breakaway travel S (the (S, J) profile) or the slips' J, and J beside it
                ss = [r.get("stick_slip") or {} for r in rs]
                entry["breakaway_applied"] = [s.get("applied") for s in ss]
                # the stick-slip filter's profile of S / J (not the open-loop one, reported for information)
                # and the stick-slip check's statistic, which decide it
                entry["S_over_J"] = [s.get("profile_S_over_J") for s in ss]
                entry["travel_over_slip"] = [s.get("travel_over_slip_median") for s in ss]
                entry["J_rel_err"] = [s["J_mm"] / r["true_value"] - 1.0 if "J_mm" in s else float("nan")
                                      for s, r in zip(ss, rs, strict=True)]
        summ[key] = entry
    n_eff = [r for r in results if r["effect"] != "none"]
    summ["_total"] = {"named_right": sum(r["cause"] == r["effect"] for r in results), "runs": len(results),
                      "false_findings_on_none": sum(r["cause"] != "none" for r in results if r["effect"] == "none"),
                      "wrong_effect": sum(r["cause"] not in ("none", r["effect"]) for r in n_eff),
                      "median_seconds": float(np.median([r["seconds"] for r in results]))}
    summ["_pooled"] = pooled_effects(results)
    return summ


#: the sds of a named effect that the effects study compares (the reported sd is chosen by measured coverage)
EFFECT_SDS: dict[str, str] = {
    "reported": "the JSON's std (smooth effects: the TV refit, max(bootstrap, Hessian/HAC) (+) half the IRW-TV "
                "difference, the bootstrap's replicates refitted on TV; stiction's band: "
                "the bootstrap)",
    "hessian": "inverse Hessian (std_hessian)",
    "robust": "HAC sandwich of the per-sample scores (std_robust)",
    "bootstrap": "the model-based bootstrap alone (uncertainty.bootstrap_std), about the estimate its replicates "
                 "measure: the IRW ML one, or the TV refit where they were refitted on TV (replicates_prepared) "
                 "(stiction's band: about its bias-corrected estimate)",
    "tv_corrected": "the TV refit corrected by its TV-refitted replicates' bias where clear, max(their spread (+) "
                    "the correction's se, Hessian/HAC) (+) half the IRW-TV difference (bootstrap.BRACKET_CORRECT; "
                    "smooth effects)",
    "tv_bootstrap": "the TV refit with the bootstrap's sd alone (no IRW-TV term; smooth effects)",
    "tv_whole_d": "the TV refit, max(bootstrap, Hessian/HAC) (+) the whole IRW-TV difference (smooth effects)",
    "midpoint": "the IRW-TV midpoint, max(bootstrap, Hessian/HAC) (+) half the IRW-TV difference (two "
                "exchangeable pre-processing errors; smooth effects)",
}


#: the alternative bracket rules (EFFECT_SDS): centre ("tv" or the IRW-TV "midpoint") and weight of the difference
BRACKET_RULES: dict[str, tuple[str, float]] = {"tv_whole_d": ("tv", 1.0), "midpoint": ("midpoint", 0.5)}


def _bracket_rule(r: dict[str, Any], name: str) -> tuple[float, float]:
    """Centre and sd of an alternative bracket rule of a smooth effect (:data:`BRACKET_RULES`), from the
    run's two pre-processings' estimates and its bootstrap and Hessian sds (nan where not bracketed)."""
    irw, tv = float(r.get("irw_value", math.nan)), float(r.get("tv_value", math.nan))
    sb = float(np.fmax(r.get("std_bootstrap", math.nan), r.get("std_hessian", math.nan)))
    centre, weight = BRACKET_RULES[name]
    return (tv if centre == "tv" else 0.5 * (tv + irw)), math.hypot(sb, weight * (tv - irw))


def _tv_corrected(r: dict[str, Any]) -> tuple[float, float, float]:
    """Estimate, truth and sd of the ``tv_corrected`` rule (:data:`EFFECT_SDS`; nan without TV-refitted replicates):
    the TV refit less its replicates' bias where the bootstrap calls it clear (more than 2 se of their mean), the sd
    their spread with the correction's se, else their RMS error; at least the Hessian/HAC sd; half the IRW-TV
    difference in quadrature."""
    if r.get("replicates_prepared") != "tv":
        return math.nan, float(r["true_value"]), math.nan
    irw, tv, bias, spread = (float(r[k]) for k in ("irw_value", "tv_value", "boot_bias", "boot_spread"))
    B = int(r.get("boot_B") or 16)
    clear = abs(bias) > 2.0 * spread / math.sqrt(B)
    sd = math.sqrt(spread**2 * (1 + 1 / B)) if clear else math.hypot(spread, bias)
    sd = float(np.fmax(sd, r.get("std_hessian", math.nan)))
    return (tv - bias if clear else tv), float(r["true_value"]), math.hypot(sd, 0.5 * (tv - irw))


def _effect_sd_coverage(rs: list[dict[str, Any]]) -> dict[str, Any]:
    """Coverage of each candidate sd over named runs."""
    key = {"reported": "std_value", "hessian": "std_hessian", "robust": "std_robust", "bootstrap": "std_bootstrap",
           "tv_bootstrap": "std_bootstrap"}
    # the likelihood's sds about the ML estimate; stiction's band has no ML estimate (measured from the slips):
    # its bootstrap is about the bias-corrected estimate (the reported one)
    centre = {"reported": "estimate_value", "hessian": "ml_value", "robust": "ml_value", "bootstrap": "ml_value",
              "tv_bootstrap": "tv_value"}

    def z_of(r: dict[str, Any], name: str) -> float:
        if name == "tv_corrected":
            return _z(*_tv_corrected(r))
        if name == "bootstrap" and r.get("replicates_prepared") == "tv":
            return _z(float(r["tv_value"]), r["true_value"], r.get("std_bootstrap", float("nan")))
        if name in BRACKET_RULES:
            c, sd = _bracket_rule(r, name)
            return _z(c, r["true_value"], sd)
        if r["effect"] == "stiction" and name == "bootstrap":
            return _z(float(r["estimate_value"]), r["true_value"], r.get(key[name], float("nan")))
        return _z(float(r.get(centre[name], r["estimate_value"])), r["true_value"], r.get(key[name], float("nan")))

    return {name: _coverage([z_of(r, name) for r in rs]) for name in EFFECT_SDS}


def pooled_effects(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Coverage of each candidate sd pooled over the named runs of every effect (and of the smooth
    effects alone, stiction's band being measured, not fitted)."""
    named = [r for r in results if r["effect"] != "none" and r.get("named")]
    smooth = [r for r in named if r["effect"] != "stiction"]
    return {"all_named": _effect_sd_coverage(named), "smooth_named": _effect_sd_coverage(smooth),
            "misspecified_named": int(sum(bool(r.get("misspecified")) for r in named)), "named": len(named)}


def cases(study: str, generator: str, runs: int, eiv_B: int, seed: int, shipped_only: bool = False,
          T_noise_C: float | None = 0.01) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    if study == "base":
        for i in range(runs):
            out.append({"study": study, "generator": generator, "seed": seed, "i": i, "effect": "none",
                        "T_noise_C": T_noise_C, "eiv_B": eiv_B, "shipped_only": shipped_only})
        return out
    classes: list[tuple[str, str | None]] = [("none", None), ("sensor_lag", None), ("medium_temperature", None),
                                             ("setpoint_drift", None)]
    variants = STICTION_VARIANTS if generator == "independent" else ("reset",)
    classes += [("stiction", v) for v in variants]
    i = 0
    for _ in range(runs):
        for effect, variant in classes:
            out.append({"study": study, "generator": generator, "seed": seed, "i": i, "effect": effect,
                        "variant": variant})
            i += 1
    return out


def _print_base(summ: dict[str, Any]) -> None:
    for k in BASE_NAMES:
        e = summ[k]
        print(f"{k}: ML mean rel. error {e['mean_rel_err']:+.2%}, max |rel. error| {e['max_abs_rel_err']:.2%}")
        for name, what in SD_CANDIDATES.items():
            if name not in e:
                continue
            c = e[name]
            print(f"  {name:18s} 1sd {c['cover_1sd']:5.0%}  2sd {c['cover_2sd']:5.0%}  rms z {c['rms_z']:5.2f}  "
                  f"mean z {c['mean_z']:+5.2f}  mean rel err {c['mean_rel_err']:+.2%}  ({what})")
    print(f"misspecification warnings: {summ['_misspecified']}")
    print(f"median seconds per run: {summ['_seconds_median']}")


def _print_effects(summ: dict[str, Any]) -> None:
    for key, e in summ.items():
        if key.startswith("_"):
            continue
        line = f"{key:26s} named {e['named_right']}/{e['runs']}  causes {e['causes']}"
        if "z" in e:
            zs = ", ".join(f"{v:.1f}" for v in e["z"])
            rel = ", ".join(f"{v:+.0%}" for v in e["rel_err"])
            line += f"  z [{zs}]  1sd {e['cover_1sd']:.0%} 2sd {e['cover_2sd']:.0%}  rel err [{rel}]"
            line += f"  misspecified {e['misspecified']}"
            if "breakaway_applied" in e:
                rel_j = ", ".join(f"{v:+.0%}" for v in e["J_rel_err"])
                line += f"  S from the (S, J) profile {e['breakaway_applied']}  J rel err [{rel_j}]"
                if "S_over_J" in e:
                    line += f"  S/J {e['S_over_J']}"
        print(line)
        for name, c in e.get("by_sd", {}).items():
            print(f"    {name:10s} over {c['n']} named: 1sd {c['cover_1sd']:.0%} 2sd {c['cover_2sd']:.0%} "
                  f"rms z {c['rms_z']:.2f}")
    p = summ["_pooled"]
    print(f"pooled over {p['named']} named runs (misspecification warnings {p['misspecified_named']}):")
    for grp in ("all_named", "smooth_named"):
        for name, c in p[grp].items():
            print(f"  {grp:12s} {name:10s} n {c['n']:3d} ({c['n_with_sd']} with sd): 1sd {c['cover_1sd']:.0%} "
                  f"2sd {c['cover_2sd']:.0%} rms z {c['rms_z']:.2f} mean z {c['mean_z']:+.2f}")
    t = summ["_total"]
    print(f"total: named right {t['named_right']}/{t['runs']}, false findings on 'none' "
          f"{t['false_findings_on_none']}, wrong effect {t['wrong_effect']}, median {t['median_seconds']:.0f} s/run")


def _summarise_files(study: str, paths: list[str]) -> int:
    """Print the pooled summary of earlier --json files of ``study`` (exit status 2 naming a bad file)."""
    results: list[dict[str, Any]] = []
    for path in paths:
        try:
            with open(path, encoding="utf-8") as fh:
                doc = json.load(fh)
            if doc.get("study") != study:
                raise ValueError(f"a {doc.get('study')!r} study, not {study!r}")
            results += list(doc["results"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            print(f"thermovalve: error: {path}: {exc}", file=sys.stderr)
            return 2
    print(f"{study} study pooled from {len(paths)} file(s): {len(results)} runs", flush=True)
    summ = summarise_base(results) if study == "base" else summarise_effects(results)
    (_print_base if study == "base" else _print_effects)(summ)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", choices=("base", "effects"), required=True)
    ap.add_argument("--summarise", nargs="+", metavar="JSON", default=None,
                    help="run nothing: pool the results of these earlier --json files of --study and print their "
                    "summary (e.g. several seeds, or candidate sds added since)")
    ap.add_argument("--generator", choices=("independent", "project"), default="independent")
    ap.add_argument("--runs", type=int, default=30, help="base: runs; effects: runs per class")
    ap.add_argument("--eiv-B", type=int, default=8, help="base: temperature-bootstrap replicates of --eiv (0: none)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=None, help="override the study seed (default: the fixed one)")
    ap.add_argument("--json", dest="json_out", default=None)
    ap.add_argument("--only", default="", help="effects study: only the runs of these effects (comma-separated "
                    "names, e.g. stiction: one run per stick-slip variant); run i keeps its seed")
    ap.add_argument("--shipped-only", action="store_true",
                    help="base: only the default `thermovalve fit` (fit_eiv, B = --eiv-B), with its ML fit's inverse "
                    "Hessian and sandwich beside it")
    ap.add_argument("--T-noise", type=float, default=0.01,
                    help="base: temperature noise sd, degC (negative: drawn per run from U(0.001, 0.02))")
    ap.add_argument("--convention", default="",
                    help="record every run under these conventions of measured data (comma-separated names of "
                    "valve_env.studies.conventions, or 'irregular': jitter 0.2 and 5 %% of the rows dropped)")
    ap.add_argument("--medium", default="smooth", choices=("smooth", "steps", "constant"),
                    help="the medium temperature's programme (independent simulator; steps: a thermostat)")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    if args.summarise:
        return _summarise_files(args.study, args.summarise)
    seed = args.seed if args.seed is not None else SEEDS[(args.study, args.generator)]
    outs = OutputSet(force=args.force)
    try:
        json_path = outs.add(args.json_out) if args.json_out else None
    except OutputError as exc:
        print(f"thermovalve: error: {exc}", file=sys.stderr)
        return 2
    cs = cases(args.study, args.generator, args.runs, args.eiv_B, seed, args.shipped_only,
               None if args.T_noise < 0 else args.T_noise)
    for c in cs:
        c["conventions"] = tuple(x for x in args.convention.split(",") if x)
        c["medium"] = args.medium
    if args.only:
        cs = [c for c in cs if c["effect"] in args.only.split(",")]
    fn = run_base if args.study == "base" else run_effects
    t0 = time.perf_counter()
    print(f"{args.study} study on the {args.generator} generator: {len(cs)} runs, seed {seed}, "
          f"{args.workers} workers", flush=True)
    results: list[dict[str, Any]] = []
    if args.workers <= 1:
        results = [fn(c) for c in cs]
    else:
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            for r in pool.map(fn, cs):
                results.append(r)
                print(f"  {len(results)}/{len(cs)} done ({time.perf_counter() - t0:.0f} s): "
                      f"{json.dumps(r, default=float)}", flush=True)
    summ = summarise_base(results) if args.study == "base" else summarise_effects(results)
    (_print_base if args.study == "base" else _print_effects)(summ)
    doc = {"study": args.study, "generator": args.generator, "seed": seed, "runs": len(cs), "eiv_B": args.eiv_B,
           "summary": summ, "results": results, "seconds": time.perf_counter() - t0,
           "machine": platform.platform(), "command": " ".join(sys.argv)}
    if json_path is not None:
        outs.write_text(json_path, json.dumps(doc, indent=1, default=float))
        outs.commit()
        print(outs.summary())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
