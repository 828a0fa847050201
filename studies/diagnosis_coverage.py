"""Coverage study of the diagnosis's parameter uncertainty (docs/diagnosis.md, "Parameter uncertainty: the
coverage study").

Hide one effect at a time in generated runs (effect sizes, sampling intervals, jitter,
record lengths, noise levels and seeds randomised as in the confusion study), run the
full diagnosis, and check the *named* effect's parameter against the truth in units of
its reported standard deviation:

    z = (estimate - truth) / reported sd

For honest uncertainties about 68 % of the |z| lie within 1 and 95 % within 2, the mean
of z (the bias, in sd) is near 0 and the RMS of z (the ratio of the actual to the
reported spread) near 1. Prints a table and writes JSON.

    python studies/diagnosis_coverage.py --runs 40 --seed 101 --workers 2 --json out/coverage.json

Seeds 1, 7 and 11 were used while developing the method; use others for the study.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from valve_env.experiment import STUDY_CLASSES, random_cases, run_cases, simulate_case

EFFECT_CLASSES = STUDY_CLASSES[1:]  # every named effect, no 'none' runs


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    from valve_env.valveid.diagnose import diagnose

    df = simulate_case(case)
    t0 = time.perf_counter()
    d = diagnose(df)
    out = dict(case)
    out.update({"cause": d.cause, "selected": d.selected, "seconds": time.perf_counter() - t0, "n": len(df)})
    # the true effect's fit on top of the base model (named or not)
    f = next(f for f in d.findings if f.effect == case["truth"])
    js = f.to_json()
    out["estimate"] = js["params"]
    out["std"] = js["std"]
    out["std_method"] = js.get("std_method", "")
    out["interval"] = js.get("interval", {})
    unc = js.get("uncertainty") or {}
    out["hessian_std"] = unc.get("hessian_std", {})
    out["bootstrap_std"] = {k: float(v) for k, v in (unc.get("bootstrap_std") or {}).items()}
    if case["truth"] == "stiction":
        out["oracle"] = band_oracle(df, d.settings["n_train"], case, js)
    return out


def band_oracle(df: Any, n_train: int, case: dict[str, Any], finding: dict[str, Any],
                draws: int = 200) -> dict[str, float]:
    """Stiction's band measured against the estimator's own sampling distribution on this run.

    The generated run knows its true opening (``true_x_mm``); the jump estimator applied to it plus
    fresh noise of the run's size (:func:`valve_env.valveid.stiction.band_sampling`, on the
    training part the diagnosis used) gives the estimator's true spread and bias here. The error of
    the reported band then splits into the noise realisation of this run (``z_raw``: the raw estimate
    in its sampling distribution, N(0, 1) by construction) and the error of the bias correction
    (``bias_error``, in sampling sd); ``sd_ratio`` is the reported sd over the sampling sd."""
    from valve_env.params import ValveParams
    from valve_env.valveid.stiction import band_sampling, jump_band

    stroke = float(ValveParams().stroke)
    truth = float(case["effects"]["stiction"]["band_mm"])
    raw, _ = jump_band(df["x_mm"].to_numpy()[:n_train], stroke)
    o = band_sampling(df["true_x_mm"].to_numpy()[:n_train], float(case["x_noise_mm"]), stroke, draws,
                      seed=int(case["seed"]) + 1)
    o = o[np.isfinite(o)]
    m, sd = float(o.mean()), float(o.std(ddof=1))
    unc = finding.get("uncertainty") or {}
    corrected = bool((unc.get("bias_corrected") or {}).get("band_mm", False))
    b_boot = float(unc["bias"]["band_mm"]) if corrected else 0.0
    rep = finding["std"].get("band_mm")
    return {"draws": int(o.size), "raw": float(raw), "mean": m, "sd": sd, "bias": m - truth,
            "bootstrap_bias": b_boot, "z_raw": (raw - m) / sd, "bias_error": (m - truth - b_boot) / sd,
            "sd_ratio": float(rep) / sd if rep is not None and math.isfinite(rep) else float("nan")}


def run_study(cases: list[dict[str, Any]], workers: int = 1, progress: bool = True) -> list[dict[str, Any]]:
    def show(r: dict[str, Any], done: int) -> None:
        k, v = next(iter(r["estimate"].items()))
        true = r["effects"][r["truth"]][k]
        s = r["std"][k]
        print(f"[{done}/{len(cases)}] {r['truth']:<18} cause={r['cause']:<18} {k}={true:.4g} "
              f"est={v:.4g}±{s:.2g} z={(v - true) / s if s else float('nan'):+.2f} dt={r['dt_s']:g}s "
              f"{r['duration_h']:.1f}h {r['seconds']:.1f}s", flush=True)

    return run_cases(run_case, cases, workers, show if progress else None)


def coverage(results: list[dict[str, Any]], named_only: bool = True) -> dict[str, Any]:
    """Per effect: runs, named, bias (mean z and median relative error), within 1/2/3 sd, RMS z."""
    per: dict[str, dict[str, Any]] = {}
    for e in EFFECT_CLASSES:
        rs = [r for r in results if r["truth"] == e]
        if not rs:
            continue
        used = [r for r in rs if (r["cause"] == e or not named_only)]
        z, rel, sd_rel = [], [], []
        for r in used:
            k, v = next(iter(r["estimate"].items()))
            true = r["effects"][e][k]
            s = r["std"][k]
            if s is None or not math.isfinite(s) or s <= 0:
                z.append(float("inf"))
            else:
                z.append((v - true) / s)
            rel.append((v - true) / abs(true))
            sd_rel.append((s or float("nan")) / abs(true))
        za = np.array(z, dtype=float)
        fin = za[np.isfinite(za)]
        per[e] = {
            "runs": len(rs), "named": sum(r["cause"] == e for r in rs), "n": len(used),
            "within_1sd": float(np.mean(np.abs(za) <= 1)) if len(za) else float("nan"),
            "within_2sd": float(np.mean(np.abs(za) <= 2)) if len(za) else float("nan"),
            "within_3sd": float(np.mean(np.abs(za) <= 3)) if len(za) else float("nan"),
            "mean_z": float(np.mean(fin)) if len(fin) else float("nan"),
            "bias_se_z": float(np.std(fin) / math.sqrt(len(fin))) if len(fin) > 1 else float("nan"),
            "rms_z": float(np.sqrt(np.mean(fin**2))) if len(fin) else float("nan"),
            "median_rel_error": float(np.median(rel)) if rel else float("nan"),
            "median_abs_rel_error": float(np.median(np.abs(rel))) if rel else float("nan"),
            "median_rel_sd": float(np.nanmedian(sd_rel)) if sd_rel else float("nan"),
            "methods": sorted({r.get("std_method", "") for r in used}),
        }
        # the oracle is the jump estimator's sampling distribution: only where the band was measured from the
        # slips (at least 4 in the training opening); with fewer the band is the likelihood's (docs/diagnosis.md)
        with_oracle = [r["oracle"] for r in used if "oracle" in r]
        orc = [o for o in with_oracle if math.isfinite(o["raw"])]
        if orc:
            zr = np.array([o["z_raw"] for o in orc])
            be = np.array([o["bias_error"] for o in orc])
            sr = np.array([o["sd_ratio"] for o in orc])
            per[e]["oracle"] = {
                "n": len(orc), "likelihood_band_runs": len(with_oracle) - len(orc),
                "draws_min": int(min(o["draws"] for o in orc)),
                "raw_within_1sd": float(np.mean(np.abs(zr) <= 1)),
                "raw_within_2sd": float(np.mean(np.abs(zr) <= 2)), "rms_z_raw": float(np.sqrt(np.mean(zr**2))),
                "median_sd_ratio": float(np.nanmedian(sr)), "min_sd_ratio": float(np.nanmin(sr)),
                "max_sd_ratio": float(np.nanmax(sr)), "rms_bias_error": float(np.sqrt(np.mean(be**2))),
                "mean_bias_error": float(np.mean(be)),
                # the correction's error against the reported sd, which carries the bootstrap world's bias in
                # quadrature (docs/diagnosis.md, "Parameter uncertainty: the coverage study")
                "rms_bias_error_reported_sd": float(np.sqrt(np.mean((be / sr) ** 2))),
            }
    allz = []
    for r in results:
        if named_only and r["cause"] != r["truth"]:
            continue
        k, v = next(iter(r["estimate"].items()))
        s = r["std"][k]
        allz.append((v - r["effects"][r["truth"]][k]) / s if s and math.isfinite(s) and s > 0 else float("inf"))
    za = np.abs(np.array(allz, dtype=float))
    return {"per_effect": per, "n": len(allz),
            "within_1sd": float(np.mean(za <= 1)) if len(za) else float("nan"),
            "within_2sd": float(np.mean(za <= 2)) if len(za) else float("nan"),
            "seconds_median": float(np.median([r["seconds"] for r in results])) if results else float("nan"),
            "seconds_max": float(np.max([r["seconds"] for r in results])) if results else float("nan")}


def table(c: dict[str, Any]) -> str:
    L = ["| effect | named / runs | within 1 sd | within 2 sd | within 3 sd | mean z (bias, sd units) | "
         "RMS z | median rel. error | median sd / value | sd method |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for e, v in c["per_effect"].items():
        L.append(f"| {e} | {v['named']}/{v['runs']} | {v['within_1sd']:.0%} | {v['within_2sd']:.0%} | "
                 f"{v['within_3sd']:.0%} | {v['mean_z']:+.2f} ± {v['bias_se_z']:.2f} | {v['rms_z']:.2f} | "
                 f"{v['median_rel_error']:+.2%} | {v['median_rel_sd']:.2%} | {', '.join(v['methods'])} |")
    L.append(f"| all | {c['n']} | {c['within_1sd']:.0%} | {c['within_2sd']:.0%} | | | | | | |")
    for e, v in c["per_effect"].items():
        o = v.get("oracle")
        if o:
            L.append(f"\n{e}, against the estimator's own sampling distribution on each named run whose band was "
                     f"measured from the slips ({o['n']} runs; {o['likelihood_band_runs']} with the likelihood's "
                     f"band): "
                     f"the raw estimate lies within 1 / 2 sampling sd in {o['raw_within_1sd']:.0%} / "
                     f"{o['raw_within_2sd']:.0%} (RMS {o['rms_z_raw']:.2f}; the noise realisation, 68 % / 95 % "
                     f"expected); reported sd / sampling sd median {o['median_sd_ratio']:.2f} "
                     f"({o['min_sd_ratio']:.2f}-{o['max_sd_ratio']:.2f}); error of the bias correction "
                     f"RMS {o['rms_bias_error']:.2f}, mean {o['mean_bias_error']:+.2f} sampling sd "
                     f"(RMS {o['rms_bias_error_reported_sd']:.2f} reported sd).")
    return "\n".join(L)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--effects", default=",".join(EFFECT_CLASSES))
    ap.add_argument("--json", default="", help="write the summary and every run as JSON here")
    a = ap.parse_args(argv)
    classes = tuple(s for s in a.effects.split(",") if s)
    cases = random_cases(a.runs, a.seed, classes)
    t0 = time.perf_counter()
    results = run_study(cases, a.workers)
    c = coverage(results)
    cmd = f"python studies/diagnosis_coverage.py --runs {a.runs} --seed {a.seed} --workers {a.workers}"
    print(f"\n{cmd} ({platform.machine()}, Python {platform.python_version()}), "
          f"{time.perf_counter() - t0:.0f} s; diagnosis median {c['seconds_median']:.1f} s, "
          f"max {c['seconds_max']:.1f} s\n")
    print(table(c))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps({"command": cmd, "summary": c, "runs": results}, indent=1,
                                           default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
