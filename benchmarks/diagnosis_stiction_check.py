"""Development study of stiction's decision: the slips' band (docs/diagnosis.md, "Method").

The stiction-only stand-in of the diagnosis (``diagnose(df, effects=["stiction"], bootstrap_B=0)``, whose
base fit the other candidates do not improve, so it is harsher on the null than the full diagnosis) on the
`none` and `stiction` runs of generated studies (:func:`valve_env.experiment.random_cases`). For each run it
records the decision, the LR test, the fitted band and the training slips with the test of the slips'
band (the finding's ``training_slips``).

    python benchmarks/diagnosis_stiction_check.py --set 31:24:none --set 5151:60 --workers 2 --json out/s.json

``--set SEED:RUNS[:CLASSES]`` draws ``RUNS`` cases from ``SEED`` (classes comma-separated with '+', default
all) and keeps the `none` and `stiction` ones. A run whose finding has the slips' band had failed the
slips' check with the likelihood's band, so without the retest at the slips' band its cause is `none`
(printed as ``before``).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from typing import Any

from valve_env.experiment import STUDY_CLASSES, random_cases, run_cases, simulate_case
from valve_env.outputs import OutputError, OutputSet


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    from valve_env.params import ValveParams
    from valve_env.valveid.diagnose import diagnose
    from valve_env.valveid.stiction import slips

    df = simulate_case(case)
    stroke = float(ValveParams().stroke)
    x = df["x_mm"].to_numpy()
    n_train = slips(x[:int(round(len(x) * 0.75))], stroke).size  # diagnose's default hold-out
    if case["few_slips_only"] and not 2 <= n_train <= 3:
        return {"seed_set": case["seed_set"], "i": case["i"], "truth": case["truth"], "skipped": True,
                "training_slips": {"n": int(n_train)}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose(df, effects=["stiction"], bootstrap_B=0)
    f = d.findings[0]
    ts = dict(f.training_slips or {})
    restarted = ts.get("band_from") == "slips"
    if ts.get("n") != n_train:
        raise RuntimeError(f"run {case['i']}: {ts.get('n')} training slips in the diagnosis, {n_train} here")
    return {"seed_set": case["seed_set"], "i": case["i"], "truth": case["truth"], "effects": case["effects"],
            "dt_s": case["dt_s"], "duration_h": case["duration_h"], "cause": d.cause,
            "before": "none" if restarted else d.cause, "restarted": bool(restarted),
            "lr_stat": float(f.lr_stat), "p_value": float(f.p_value), "delta_bic": float(f.delta_bic),
            "significant": bool(f.significant), "relevant": bool(f.relevant), "validated": bool(f.validated),
            "band_mm": float(f.fit.params["band_mm"]), "s_w": float(f.fit.params["s_w"]),
            "training_slips": ts, "null_guard": f.null_guard}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", action="append", required=True, help="SEED:RUNS[:CLASS+CLASS]")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--json", default="", help="write every run as JSON here")
    ap.add_argument("--force", action="store_true", help="replace an existing output")
    ap.add_argument("--few-slips-only", action="store_true",
                    help="diagnose only the runs whose training opening has two or three slips: with fewer the "
                    "slips' band is not tested, with four or more the fit's band is the slips' median already, "
                    "so elsewhere the decision is the same with or without the retest at the slips' band")
    a = ap.parse_args(argv)
    outs = OutputSet(force=a.force)
    try:
        json_path = outs.add(a.json) if a.json else None
    except OutputError as exc:
        print(f"thermovalve: error: {exc}", file=sys.stderr)
        return 2
    cases = []
    for spec in a.set:
        parts = spec.split(":")
        if len(parts) not in (2, 3) or not all(p.isdigit() for p in parts[:2]):
            print(f"thermovalve: error: --set {spec!r}: expected SEED:RUNS[:CLASSES]", file=sys.stderr)
            return 2
        classes = tuple(parts[2].split("+")) if len(parts) == 3 else STUDY_CLASSES
        bad = [c for c in classes if c not in STUDY_CLASSES]
        if bad:
            print(f"thermovalve: error: --set {spec!r}: unknown class(es) {', '.join(bad)}", file=sys.stderr)
            return 2
        for c in random_cases(int(parts[1]), int(parts[0]), classes=classes):
            if c["truth"] in ("none", "stiction"):
                cases.append({**c, "seed_set": int(parts[0]), "few_slips_only": a.few_slips_only})

    def guard(r: dict[str, Any]) -> str:
        g = r.get("null_guard")
        if not g:
            return ""
        return f" null: {g['statistic']:.0f} vs max {max(g['null']):.0f} ({'passed' if g['passed'] else 'stopped'})"

    def show(r: dict[str, Any], done: int) -> None:
        ts = r["training_slips"]
        if r.get("skipped"):
            print(f"[{done}/{len(cases)}] {r['seed_set']}/{r['i']} {r['truth']:<8} skipped ({ts['n']} training slips)",
                  flush=True)
            return
        print(f"[{done}/{len(cases)}] {r['seed_set']}/{r['i']} {r['truth']:<8} -> {r['cause']:<8} "
              f"(before {r['before']}) LR {r['lr_stat']:.0f} band {r['band_mm'] * 1e3:.1f} um slips "
              f"{ts.get('n')} med {1e3 * (ts.get('median_mm') or float('nan')):.1f} dt {r['dt_s']:g}{guard(r)}",
              flush=True)

    results = run_cases(run_case, cases, a.workers, show)
    for truth in ("none", "stiction"):
        rs = [r for r in results if r["truth"] == truth and not r.get("skipped")]
        skipped = sum(1 for r in results if r["truth"] == truth and r.get("skipped"))
        print(f"{truth}: {skipped} runs skipped, {len(rs)} diagnosed, named stiction "
              f"{sum(r['cause'] == 'stiction' for r in rs)} "
              f"(without the retest: {sum(r['before'] == 'stiction' for r in rs)})")
    if json_path is not None:
        outs.write_text(json_path, json.dumps(results, indent=1, default=float))
    outs.commit()
    return 0


if __name__ == "__main__":
    sys.exit(main())
