"""Loop diagnoses' decisions per record, stored and compared: a speed change must not change them (docs/loops.md,
"Decision").

    python benchmarks/loop_decisions.py --out before.json --sim 7000:20 --env seat:0-3 \
        --real dev --data /path/to/plant_loops
    python benchmarks/loop_decisions.py --compare before.json after.json

For each record (simulated loops of ``loop_benchmark.sim_cases``, all four kinds; real loops of a split set,
``--data``; env records, ``seat`` on ThermoValveStickyValve-v0 or ``mid`` on ThermoValveStickyCirculation-v0 with
``--kp 5 --ti 1500``, sticky and smooth) it stores the cause, the band and its sd when named, the seat of the
nonlinear valves, the scan's band and the CPU time of ``diagnose``, in one JSON file (written atomically; never over
an existing one without ``--force``). ``--compare`` prints the records whose cause differs or whose band moved by more
than ``--tol`` of its sd, and the CPU time before and after; it exits 1 when a decision differs.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from valve_env.cli import int_list
from valve_env.outputs import OutputError, atomic_write_text, check_output

KINDS = ("sticky", "smooth", "ext_smooth", "ext_sticky")
ENV_SETS = {"seat": ("ThermoValveStickyValve-v0", None, None), "mid": ("ThermoValveStickyCirculation-v0", 5.0, 1500.0)}


def _record(job: tuple) -> dict:
    """Diagnose one record of ``job`` = (source, key, spec) and return its decision and CPU time."""
    from valve_env.loops.diagnose import diagnose

    source, key, spec = job
    if source == "sim":
        from loop_benchmark import sim_record

        loop = sim_record(*spec)
    elif source == "real":
        from valve_env.loops.io import read_loop

        loop = read_loop(Path(spec))
    else:
        from valve_env.loops.envloop import record_env_loop

        env_id, kp, ti, band, seed = spec
        loop = record_env_loop(band, seed=seed, env_id=env_id, Kp=kp, Ti_s=ti)
    c0 = time.process_time()
    res = diagnose(loop).result
    cpu = time.process_time() - c0
    st = res.get("stiction")
    seat = res["decision"]["seat"]
    return {"key": key, "cause": res["cause"], "band_pct": st["band_pct"] if st else None,
            "std_pct": st["std_pct"] if st else None, "seat_nonlinear_pct": seat["nonlinear_pct"],
            "seat_linear_pct": seat["linear_pct"], "S_scan_pct": res["decision"]["bootstrap"]["S_scan_pct"],
            "n": loop.n, "cpu_s": cpu}


def jobs_for(args: argparse.Namespace) -> list[tuple]:
    from loop_benchmark import SPLIT, sim_cases

    jobs: list[tuple] = []
    for spec in args.sim:
        seed0, n = (int(v) for v in spec.split(":"))
        for c in sim_cases(seed0, n):
            jobs += [("sim", f"sim {c['seed']} {k}", (c, k)) for k in KINDS]
    if args.real:
        for r in csv.DictReader(open(SPLIT)):
            if r["set"] == args.real:
                jobs.append(("real", f"real {r['file']}", str(args.data / r["label"] / r["file"])))
    for spec in args.env:
        name, seeds = spec.split(":")
        env_id, kp, ti = ENV_SETS[name]
        for seed in int_list(seeds):
            for band in (0.1, 0.0):
                jobs.append(("env", f"env {name} {seed} {band:g}", (env_id, kp, ti, band, seed)))
    return jobs


def compare(old: dict, new: dict, tol: float) -> int:
    bad = 0
    cpu_old, cpu_new = [], []
    for key, a in old.items():
        b = new.get(key)
        if b is None:
            continue
        cpu_old.append(a["cpu_s"] / a["n"] * 720)
        cpu_new.append(b["cpu_s"] / b["n"] * 720)
        moved = (a["band_pct"] is not None and b["band_pct"] is not None
                 and abs(a["band_pct"] - b["band_pct"]) > tol * a["std_pct"])
        if a["cause"] != b["cause"] or moved:
            bad += 1
            print(f"DIFFERS {key}: {a['cause']} {a['band_pct']} +/- {a['std_pct']} -> {b['cause']} {b['band_pct']} "
                  f"+/- {b['std_pct']}")
        elif a["band_pct"] is not None and a["band_pct"] != b["band_pct"]:
            print(f"band moved {key}: {a['band_pct']:.4f} -> {b['band_pct']:.4f} "
                  f"({abs(a['band_pct'] - b['band_pct']) / a['std_pct']:.3f} sd)")
    print(f"{len(cpu_old)} records in both, {bad} decisions differ (cause, or band by more than {tol:g} sd)")
    if cpu_old:
        print(f"CPU per 720 samples: before mean {np.mean(cpu_old):.2f} s, max {np.max(cpu_old):.2f} s; "
              f"after mean {np.mean(cpu_new):.2f} s, max {np.max(cpu_new):.2f} s")
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path)
    ap.add_argument("--force", action="store_true", help="replace an existing --out")
    ap.add_argument("--sim", action="append", default=[], help="simulated cases SEED0:N (repeatable)")
    ap.add_argument("--real", choices=("dev",), default=None, help="the real loops' development half (--data)")
    ap.add_argument("--data", type=Path, default=None, help="the plant_loops folder (stiction/, non_stiction/)")
    ap.add_argument("--env", action="append", default=[], help="env records seat:SEEDS or mid:SEEDS (repeatable)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("OLD", "NEW"))
    ap.add_argument("--tol", type=float, default=0.05, help="a band may move this share of its sd")
    a = ap.parse_args(argv)
    if a.compare:
        old, new = (json.loads(p.read_text()) for p in a.compare)
        return compare(old, new, a.tol)
    if a.out is None:
        ap.error("give --out or --compare")
    try:
        check_output(a.out, force=a.force)  # the project's output policy, checked before the work
    except OutputError as exc:
        ap.error(str(exc))
    if a.jobs < 1:
        ap.error("--jobs must be at least 1")
    if a.real and a.data is None:
        ap.error("--real needs --data (the plant_loops folder)")
    jobs = jobs_for(a)
    out: dict[str, dict] = {}
    with ProcessPoolExecutor(a.jobs) as ex:
        for r in ex.map(_record, jobs):
            out[r["key"]] = r
            band = "" if r["band_pct"] is None else f" band {r['band_pct']:.3f} +/- {r['std_pct']:.3f}"
            print(f"{r['key']}: {r['cause']}{band}; CPU {r['cpu_s']:.2f} s ({r['n']} samples)", flush=True)
    cpu = [r["cpu_s"] / r["n"] * 720 for r in out.values() if math.isfinite(r["cpu_s"])]
    print(f"{len(out)} records; CPU per 720 samples mean {np.mean(cpu):.2f} s, max {np.max(cpu):.2f} s")
    atomic_write_text(a.out, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
