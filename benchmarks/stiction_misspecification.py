"""The misspecification check for stiction: its firing rates on stick-slip runs of the project's
generator (the right model) and of the independent simulator's variants ``reset``, ``sj`` and ``force``
(docs/uncertainty.md, "Sandwich standard errors and the misspecification check").

Each run is drawn as ``benchmarks/independent_coverage.py --study effects --only stiction`` draws it (run i
keeps its seed), written to a CSV and read back with the loader, then diagnosed with stiction as the only
candidate and no bootstrap (``diagnose(data, effects=["stiction"], bootstrap_B=0)``: the check runs at the ML
estimate on the training part, as in the full diagnosis). Printed per run: whether stiction was named, its
band against the truth, the whiteness check (the smooth effects' check) and the stick-slip check
(:func:`valve_env.valveid.robust.stick_slip_check`).

    python benchmarks/stiction_misspecification.py --generator project --runs 6 --seed 20261202 --json out/sm_p.json
    python benchmarks/stiction_misspecification.py --generator independent --runs 3 --seed 777 --json out/sm_i.json
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import sys
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from independent_coverage import _as_measured, _simulate, cases  # noqa: E402

from valve_env.outputs import OutputError, OutputSet  # noqa: E402


def diagnose_case(case: dict[str, Any]) -> tuple[dict[str, Any], Any, Any]:
    """The run drawn, read back and diagnosed with stiction the only candidate: (its record, the stiction finding,
    the diagnosis)."""
    from valve_env.valveid.diagnose import diagnose

    df, _truth, effects = _simulate(case)
    data = _as_measured(df)
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose(data, effects=["stiction"], bootstrap_B=0)
    f = d.findings[0]
    out = {k: case[k] for k in ("generator", "seed", "i", "variant", "run_seed", "duration_h", "dt_s", "T_noise_C")}
    out.update({"named": d.cause == "stiction", "true_band": effects["stiction"]["band_mm"],
                "band": float(f.fit.params["band_mm"]), "lr": float(f.lr_stat), "cpu_s": time.process_time() - t0})
    return out, f, d


def add_misspecification(out: dict[str, Any], f: Any, d: Any) -> None:
    """The misspecification checks of the stiction finding ``f`` at its fit, into the record ``out``."""
    from valve_env.valveid.robust import effect_misspecification

    mis = effect_misspecification(f.estimator.backend_, d.train, f.fit, warn=False)
    out["fired"] = bool(mis["misspecified"])
    out["whiteness_fired"] = bool(mis["whiteness"]["misspecified"])  # type: ignore[index]
    out["misspecification"] = mis


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    out, f, d = diagnose_case(case)
    if case.get("dump"):
        with open(os.path.join(case["dump"], f"{case['generator']}_{case['seed']}_{case['i']}.pkl"), "wb") as fh:
            pickle.dump({"model": f.estimator.backend_, "train": d.train, "fit": f.fit, "info": out}, fh)
    add_misspecification(out, f, d)
    return out


def study_main(argv: list[str] | None, doc: str, fn: Callable[[dict[str, Any]], dict[str, Any]],
               report: Callable[[argparse.Namespace, list[dict[str, Any]]], None], generator: str, runs: int,
               add_args: Callable[[argparse.ArgumentParser], None] | None = None,
               select: Callable[[argparse.Namespace, list[dict[str, Any]]], list[dict[str, Any]]] | None = None) -> int:
    """The driver of a stiction study over the stick-slip runs of ``independent_coverage.cases`` (this script's and
    ``stiction_breakaway.py``'s): the common options (``--generator``, default ``generator``; ``--runs``, default
    ``runs``; ``--seed``, ``--workers``, ``--json``, ``--force``) and ``add_args``'s, the output checked before the
    work, ``fn`` on each run (``select``: the runs kept, given the options) in a process pool, ``report`` printed,
    and the JSON written atomically."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--generator", choices=("independent", "project"), default=generator)
    ap.add_argument("--runs", type=int, default=runs, help="runs per stick-slip variant")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", dest="json_out", required=True)
    ap.add_argument("--force", action="store_true", help="replace an existing --json file")
    if add_args is not None:
        add_args(ap)
    a = ap.parse_args(argv)
    if a.runs < 1 or a.workers < 1:
        print("thermovalve: error: --runs and --workers must be at least 1", file=sys.stderr)
        return 2
    outs = OutputSet(force=a.force)
    try:
        json_path = outs.add(a.json_out)
    except OutputError as exc:
        print(f"thermovalve: error: {exc}", file=sys.stderr)
        return 2
    cs = [c for c in cases("effects", a.generator, a.runs, 0, a.seed) if c["effect"] == "stiction"]
    if select is not None:
        cs = select(a, cs)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as ex:
        res = list(ex.map(fn, cs))
    report(a, res)
    out = {"generator": a.generator, "seed": a.seed, "runs": len(cs), "results": res,
           "seconds": time.perf_counter() - t0, "machine": platform.platform(), "command": " ".join(sys.argv)}
    outs.write_text(json_path, json.dumps(out, indent=1, default=float))
    outs.commit()
    return 0


def _report(a: argparse.Namespace, res: list[dict[str, Any]]) -> None:
    for r in res:
        m = r["misspecification"]
        print(f"{r['generator']:11s} {r['i']:3d} {r['variant']!s:6s} dt {r['dt_s']:5.1f} named {r['named']!s:5s} "
              f"band {r['band']:.4f} / {r['true_band']:.4f}  LR {r['lr']:7.1f}  slips {m['n_slips']:3d} "
              f"travel/slip {m['travel_over_slip_median']:5.2f}  stick-slip check {r['fired']!s:5s} "
              f"whiteness {r['whiteness_fired']}")
    for v in sorted({str(r["variant"]) for r in res}):
        rs = [r for r in res if str(r["variant"]) == v]
        print(f"{a.generator} {v}: stick-slip check fired {sum(r['fired'] for r in rs)}/{len(rs)}, "
              f"whiteness {sum(r['whiteness_fired'] for r in rs)}/{len(rs)}, named {sum(r['named'] for r in rs)}")


def main(argv: list[str] | None = None) -> int:
    def dump_arg(ap: argparse.ArgumentParser) -> None:
        ap.add_argument("--dump", default=None, help="directory to pickle each run's stiction fit into (studies)")

    def with_dump(a: argparse.Namespace, cs: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{**c, "dump": a.dump} for c in cs]

    return study_main(argv, __doc__, run_case, _report, "project", 4, dump_arg, with_dump)


if __name__ == "__main__":
    raise SystemExit(main())
