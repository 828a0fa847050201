"""Confusion-matrix study of the diagnosis (docs/diagnosis_confusion.md).

Hide an effect (or none) in generated runs, randomised over effects, effect sizes,
sampling intervals, record lengths, noise levels, sampling jitter and seeds; run the
full diagnosis and tabulate the named cause against the truth. Prints the matrix
and writes it to --out (out/diagnosis_confusion.md; --docs for the project's record,
docs/diagnosis_confusion.md) and, with --json, every run as JSON. An existing output is
replaced only with --force (checked before the runs start).

    python studies/diagnosis_confusion.py --runs 60 --seed 1 --workers 1 [--docs --force]

Targets: at least 95 % correct names, no more than 5 % false findings on `none` runs.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from typing import Any

import numpy as np

from valve_env.effects import REGISTRY
from valve_env.experiment import STUDY_CLASSES, random_cases, run_cases, simulate_case
from valve_env.outputs import OutputError, OutputSet

CLASSES = STUDY_CLASSES

#: The randomisation (documented in docs/diagnosis.md): the effects' sizes as the registry draws them
#: (valve_env.effects), the runs' settings as experiment.random_cases draws them.
_KINDS = {"log": "log-uniform", "uniform": "uniform", "signed": "+-uniform"}
RANGES: dict[str, Any] = {
    **{p.name: (_KINDS[p.draw[0]], p.draw[1], p.draw[2]) for e in REGISTRY.values() for p in e.parameters
       if p.draw is not None},
    "dt_s": ("choice", [5.0, 10.0, 20.0, 30.0]),
    "duration_h": ("uniform", 12.0, 30.0),
    "T_noise_C": ("uniform", 0.0, 0.01),
    "x_noise_mm": ("uniform", 1.5e-3, 3.0e-3),
    "jitter": ("choice", [0.0, 0.2]),
}


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    from valve_env.valveid.diagnose import diagnose

    conv = case.get("convention", "")
    if conv == "irregular":  # jittered sample times (20 % of the interval) and 5 % of the rows missing
        case = {**case, "jitter": 0.2}
    df = simulate_case(case)
    if conv:
        from valve_env.studies.conventions import apply_convention

        df = apply_convention(df, "dropped_5" if conv == "irregular" else conv, np.random.default_rng(case["seed"]))
    t0 = time.perf_counter()
    d = diagnose(df, bootstrap_B=int(case.get("bootstrap_B", 16)))
    out = dict(case)
    out.update({"cause": d.cause, "selected": d.selected, "seconds": time.perf_counter() - t0, "n": len(df)})
    # the smallest stick band the record's slips would show (docs/diagnosis.md, "What a `none` cannot see")
    out["stiction_band_shown_mm"] = d.sensitivity.get("stiction_band_mm")
    if d.cause != "none":
        f = d.findings[0]
        out["estimate"] = {k: float(v) for k, v in f.fit.effect_params.items()}
        out["std"] = {k: float(f.fit.std.get(k, float("nan"))) for k in f.fit.effect_params}
        out["lr_stat"] = f.lr_stat
        out["validation_rms_before_mm"] = f.validation_rms_before_mm
        out["validation_rms_after_mm"] = f.validation_rms_after_mm
    best = d.findings[0]
    # the first step's candidates as tested (for studies of the ranking among accepted candidates)
    out["first_step"] = [{"effect": f.effect, "accepted": bool(f.accepted), "lr_stat": float(f.lr_stat),
                          "delta_bic": float(f.delta_bic),
                          "validation_loglik_gain": float(f.validation_loglik_gain),
                          "training_slips": f.training_slips, "null_guard": f.null_guard,
                          "validation_sim_rms_before_mm": float(f.validation_sim_rms_before_mm),
                          "validation_sim_rms_after_mm": float(f.validation_sim_rms_after_mm),
                          "significant": bool(f.significant), "relevant": bool(f.relevant),
                          "validated": bool(f.validated), "effect_size_mm": float(f.effect_size_mm),
                          "s_w": float(f.fit.params["s_w"]),
                          "params": {k: float(v) for k, v in f.fit.effect_params.items()}}
                         for f in d.findings]
    out["simulation_check"] = d.simulation_check
    out["final_fit"] = {"rms_mm": float(d.final.rms_mm), "s_w": float(d.final.params["s_w"]),
                        "s_e": float(d.final.params["s_e"]), "tau_e": float(d.final.params["tau_e"])}
    out["best_candidate"] = best.effect
    out["best_p"] = best.p_value
    return out


def run_study(cases: list[dict[str, Any]], workers: int = 1, progress: bool = True) -> list[dict[str, Any]]:
    def show(r: dict[str, Any], done: int) -> None:
        print(f"[{done}/{len(cases)}] truth={r['truth']:<18} cause={r['cause']:<18} "
              f"dt={r['dt_s']:g}s {r['duration_h']:.1f}h {r['seconds']:.1f}s", flush=True)

    return run_cases(run_case, cases, workers, show if progress else None)


#: the stiction runs' classes by their band b against the smallest band s the record's slips would show
BAND_CLASSES = ("b < s", "s <= b < 1.25 s", "b >= 1.25 s", "s none")


def band_class(band: float, shown: float | None) -> str:
    """The class of :data:`BAND_CLASSES` of a stiction run with true ``band`` and shown band ``shown`` (None: the
    record's slips would show no band up to 0.1 mm)."""
    if shown is None:
        return "s none"
    return "b < s" if band < shown else ("s <= b < 1.25 s" if band < 1.25 * shown else "b >= 1.25 s")


def confusion(results: list[dict[str, Any]]) -> dict[str, Any]:
    labels = list(CLASSES)
    for r in results:
        if r["cause"] not in labels:
            labels.append(r["cause"])
    mat = {t: {p: 0 for p in labels} for t in CLASSES}
    for r in results:
        mat[r["truth"]][r["cause"]] += 1
    n = len(results)
    correct = sum(mat[t][t] for t in CLASSES)
    n_none = sum(mat["none"].values())
    false_none = n_none - mat["none"]["none"]
    # parameter recovery of correctly named effects
    z = []
    per_effect: dict[str, dict[str, list[float]]] = {}
    for r in results:
        if r["truth"] != "none" and r["cause"] == r["truth"]:
            for k, v in r["estimate"].items():
                true = r["effects"][r["truth"]][k]
                s = r["std"][k]
                pe = per_effect.setdefault(r["truth"], {"z": [], "rel": []})
                # the relative error needs no sd: every correctly named run counts (with --bootstrap 0 a stiction
                # band has no sd, and the error used to be summarised over the one run that had one)
                pe["rel"].append(abs(v - true) / abs(true))
                if s and math.isfinite(s) and s > 0:
                    z.append((v - true) / s)
                    pe["z"].append((v - true) / s)
    z_abs = np.abs(np.array(z)) if z else np.zeros(0)
    # stiction runs by their band against the smallest band the record's slips would show
    # (docs/diagnosis.md, "What a `none` cannot see")
    seen: dict[str, list[int]] = {k: [0, 0] for k in BAND_CLASSES}
    for r in results:
        if r["truth"] == "stiction" and "stiction_band_shown_mm" in r:
            k = band_class(r["effects"]["stiction"]["band_mm"], r["stiction_band_shown_mm"])
            seen[k][0] += r["cause"] == "stiction"
            seen[k][1] += 1
    extra = sum(1 for r in results if len(r["selected"]) > (0 if r["truth"] == "none" else 1))
    return {
        "labels": labels, "matrix": mat, "n": n, "correct": correct,
        "correct_rate": correct / n if n else float("nan"),
        "none_runs": n_none, "false_findings_on_none": false_none,
        "false_rate_on_none": false_none / n_none if n_none else float("nan"),
        "param_within_1sd": float(np.mean(z_abs <= 1)) if z else float("nan"),
        "param_within_2sd": float(np.mean(z_abs <= 2)) if z else float("nan"),
        "param_within_3sd": float(np.mean(z_abs <= 3)) if z else float("nan"),
        "n_param": len(z),
        "runs_with_extra_effect": extra,
        "per_effect": {e: {"n": len(v["rel"]), "n_with_sd": len(v["z"]),
                           "within_3sd": float(np.mean(np.abs(v["z"]) <= 3)) if v["z"] else float("nan"),
                           "median_rel_error": float(np.median(v["rel"])), "max_rel_error": float(np.max(v["rel"]))}
                       for e, v in per_effect.items()},
        "stiction_by_band_shown": {k: {"named": v[0], "n": v[1]} for k, v in seen.items()},
        "seconds_median": float(np.median([r["seconds"] for r in results])) if results else float("nan"),
        "seconds_max": float(np.max([r["seconds"] for r in results])) if results else float("nan"),
    }


def markdown(c: dict[str, Any], cmd: str, results: list[dict[str, Any]]) -> str:
    labels = c["labels"]
    L = ["# Diagnosis confusion matrix", "",
         f"Measured with `{cmd}` ({c['n']} generated runs; {platform.machine()}, Python "
         f"{platform.python_version()}).", "",
         "Rows: the effect hidden in the run; columns: the cause named by `thermovalve diagnose`.", "",
         "| truth \\ named | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    for t in CLASSES:
        L.append(f"| {t} | " + " | ".join(str(c["matrix"][t][p]) for p in labels) + " |")
    L += ["", f"- correct names: {c['correct']}/{c['n']} = {c['correct_rate']:.1%} (target >= 95 %)",
          f"- false findings on `none` runs: {c['false_findings_on_none']}/{c['none_runs']} = "
          f"{c['false_rate_on_none']:.1%} (target <= 5 %)",
          f"- runs where forward selection added a second effect that is not there: "
          f"{c['runs_with_extra_effect']}/{c['n']}",
          f"- parameters of correctly named effects within 1/2/3 reported sd: {c['param_within_1sd']:.0%} / "
          f"{c['param_within_2sd']:.0%} / {c['param_within_3sd']:.0%} (of {c['n_param']})",
          "- per effect (correctly named runs): " + "; ".join(
              f"{e}: {v['within_3sd']:.0%} within 3 sd (of {v['n_with_sd']} with an sd), relative error median "
              f"{v['median_rel_error']:.1%}, max {v['max_rel_error']:.1%} (of {v['n']})"
              for e, v in c["per_effect"].items()),
          "- stiction named, by the true band b against the smallest band s the record's slips would show: "
          + "; ".join(f"{k}: {v['named']}/{v['n']}" for k, v in c["stiction_by_band_shown"].items() if v["n"]),
          f"- diagnosis time per run: median {c['seconds_median']:.1f} s, max {c['seconds_max']:.1f} s "
          f"(two runs at a time on the 2-core machine)", "",
          "Randomisation: " + "; ".join(f"{k} {v[0]} {v[1:]}" for k, v in RANGES.items()) + ".", "",
          "## Runs", "", "| # | truth | parameters | dt s | h | T noise | named | selected | estimate ± sd | s |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        truth_p = ", ".join(f"{k}={v:.3g}" for d in r["effects"].values() for k, v in d.items()) or "-"
        est = ", ".join(f"{k}={v:.3g}±{r['std'][k]:.2g}" for k, v in r.get("estimate", {}).items()) or "-"
        L.append(f"| {r['i']} | {r['truth']} | {truth_p} | {r['dt_s']:g} | {r['duration_h']:.1f} | "
                 f"{r['T_noise_C']:.4f} | {r['cause']} | {' -> '.join(r['selected']) or '-'} | {est} | "
                 f"{r['seconds']:.1f} |")
    return "\n".join(L) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=60)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default="out/diagnosis_confusion.md", help="the markdown table ('' for none)")
    ap.add_argument("--docs", action="store_true", help="write the table to docs/diagnosis_confusion.md")
    ap.add_argument("--json", default="", help="also write every run as JSON here")
    ap.add_argument("--force", action="store_true", help="replace existing outputs")
    ap.add_argument("--bootstrap", type=int, default=16,
                    help="bootstrap replicates for the named effects' sd (0: Hessian/HAC sd; the names do not "
                    "depend on it)")
    ap.add_argument("--classes", default="",
                    help="comma-separated truths to draw (default: all, in turn); e.g. 'none' for the null "
                    "distribution of the statistics")
    ap.add_argument("--convention", default="",
                    help="record every run under this convention of measured data (valve_env.studies.conventions, "
                    "e.g. quantised_0.1, stepped_medium, dt_60; or 'irregular': jitter 0.2 and 5 %% of the rows "
                    "dropped)")
    a = ap.parse_args(argv)
    from valve_env.studies.conventions import CONVENTIONS, frame_problem

    if a.convention and a.convention not in (*CONVENTIONS, "irregular"):
        ap.error(f"unknown convention {a.convention!r} (choose from irregular, {', '.join(CONVENTIONS)})")
    if frame_problem([a.convention]):
        ap.error(frame_problem([a.convention]))
    classes = tuple(c for c in a.classes.split(",") if c) or CLASSES
    unknown = [c for c in classes if c not in CLASSES]
    if unknown:
        ap.error(f"unknown class(es) {', '.join(unknown)} (choose from {', '.join(CLASSES)})")
    outs = OutputSet(force=a.force)
    try:  # the project's output policy, checked before the long run
        md_path = outs.add("docs/diagnosis_confusion.md" if a.docs else a.out) if (a.docs or a.out) else None
        json_path = outs.add(a.json) if a.json else None
    except OutputError as exc:
        print(f"thermovalve: error: {exc}", file=sys.stderr)
        return 2
    cases = random_cases(a.runs, a.seed, classes=classes)
    for c in cases:
        c["bootstrap_B"] = a.bootstrap
        c["convention"] = a.convention
    t0 = time.perf_counter()
    results = run_study(cases, a.workers)
    c = confusion(results)
    cmd = f"python studies/diagnosis_confusion.py --runs {a.runs} --seed {a.seed} --workers {a.workers}"
    if a.bootstrap != 16:
        cmd += f" --bootstrap {a.bootstrap}"
    if a.classes:
        cmd += f" --classes {a.classes}"
    if a.convention:
        cmd += f" --convention {a.convention}"
    md = markdown(c, cmd, results)
    print(md)
    print(f"total {time.perf_counter() - t0:.0f} s")
    if md_path is not None:
        outs.write_text(md_path, md)
    if json_path is not None:
        outs.write_text(json_path, json.dumps({"summary": c, "runs": results}, indent=1, default=float))
    outs.commit()
    return 0


if __name__ == "__main__":
    sys.exit(main())
