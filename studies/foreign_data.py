"""The foreign-data corpus (valve_env.studies.foreign): every case diagnosed, judged, and tabulated.

    python studies/foreign_data.py --size default --workers 2      # the default suite's 41 cases and their 5 originals
    python studies/foreign_data.py --size full --workers 2         # the slow suite's corpus

Prints one line per case (class, convention, outcome, verdict, CPU seconds) and the counts: runs,
tracebacks (always 0, or the script stops with the traceback), refusals, right outcomes. With --json
writes every result (an existing file is replaced only with --force).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from valve_env.outputs import OutputError, OutputSet
from valve_env.studies.foreign import acceptable, corpus_cases, run_case


def _run(case: dict[str, Any]) -> dict[str, Any]:
    return run_case(case, bootstrap_B=int(case.get("bootstrap_B", 0)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", choices=("default", "full"), default="default")
    ap.add_argument("--seeds", default=None, help="comma-separated run seeds (default: the corpus's own)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--bootstrap", type=int, default=0, help="bootstrap replicates per diagnosis")
    ap.add_argument("--json", default=None)
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args(argv)
    seeds = tuple(int(s) for s in a.seeds.split(",")) if a.seeds else None
    cases = corpus_cases(a.size, seeds)
    originals = [{"class": c, "seed": s, "convention": ""} for c, s in sorted({(k["class"], k["seed"]) for k in cases})]
    jobs = [{**c, "bootstrap_B": a.bootstrap} for c in originals + cases]
    outs = OutputSet(force=a.force)
    try:  # the project's output policy, checked before the long run
        json_path = outs.add(a.json) if a.json else None
    except OutputError as exc:
        print(f"thermovalve: error: {exc}", file=sys.stderr)
        return 2
    t0 = time.time()
    if a.workers > 1:
        with ProcessPoolExecutor(a.workers) as ex:
            results = list(ex.map(_run, jobs))
    else:
        results = [_run(j) for j in jobs]
    orig = {(r["class"], r["seed"]): r for r in results[:len(originals)]}
    right = refused = 0
    rows = []
    for r in results[len(originals):]:
        o = orig[(r["class"], r["seed"])]
        ok, why = acceptable(r, o["cause"] if o["outcome"] == "cause" else "refused")
        right += ok
        refused += r["outcome"] == "refused"
        r["verdict"] = ok
        r["why"] = why
        rows.append(r)
        print(f"{r['seed']:>5} {r['class']:<19} {r['convention']:<23} {r['cause'] or 'refused':<19} "
              f"{'ok  ' if ok else 'FAIL'} {why}  ({r['seconds']:.1f} s CPU)")
    for o in results[:len(originals)]:
        print(f"{o['seed']:>5} {o['class']:<19} {'(original)':<23} {o['cause'] or 'refused':<19} "
              f"{'named right' if o['cause'] == o['class'] else 'NOT the truth'}  ({o['seconds']:.1f} s CPU)")
    print(f"\n{len(rows)} transformed runs ({len(originals)} originals): 0 tracebacks, {refused} refused in one line, "
          f"{right}/{len(rows)} right; wall {time.time() - t0:.0f} s on {a.workers} worker(s)")
    if json_path is not None:
        outs.write_text(json_path, json.dumps({"originals": results[:len(originals)], "cases": rows}, indent=1,
                                              default=str))
        outs.commit()
    return 0 if right == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
