"""Simulated loops against real ones, feature by feature (docs/loops.md, "Simulated loops"; docs/history/loops.md,
2026-11-28 "The simulator against the plant").

    python studies/loop_sim_vs_real.py --data /work/shared/data/plant_loops --sim-seeds 0-299 [--plant]
    python studies/loop_sim_vs_real.py --data /work/shared/data/plant_loops --sim-seeds 100000-100399 --plant \
        --labels

Without ``--labels`` it reads the real records **without their labels** (every ``*.txt`` under ``--data``, pooled)
and prints, for every feature of ``valve_env.loops.detect.features`` and a few of the record itself (repeated values,
the OP's and PV's steps against their spread, set-point moves), the real and simulated 10/50/90 % quantiles and the
share of real records outside the simulated 5-95 % range, then a domain classifier's cross-validated AUC (logistic,
5 folds, the detector features): 0.5 when the simulated loops' features are distributed like the real ones. This
uses no real outcome and may guide the simulator.

``--labels`` (a diagnosis after a frozen rule was scored, never for a design choice) reads ``index.csv`` and prints
each feature's AUC for sticky against clean loops on the real records and on the simulated ones.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
from scipy.stats import mannwhitneyu

from valve_env.cliutil import int_list
from valve_env.loops.detect import features
from valve_env.loops.io import LoopData, LoopDataError, read_loop
from valve_env.loops.sim import random_case, simulate_case

try:
    from studies.loop_train_detector import fit_logistic, prob
except ModuleNotFoundError:  # run as ``python studies/loop_sim_vs_real.py``: its own folder is on the path
    from loop_train_detector import fit_logistic, prob  # type: ignore[no-redef]


def record_stats(loop: LoopData) -> dict[str, float]:
    """The record's own habits: shares of repeated OP and PV values, the sd of each one's steps over its sd, and the
    number of set-point moves."""
    dop, dpv = np.diff(loop.op), np.diff(loop.pv)
    return {"op_repeats": float(np.mean(dop == 0)), "pv_repeats": float(np.mean(dpv == 0)),
            "op_step_share": float(np.std(dop) / max(np.std(loop.op), 1e-300)),
            "pv_step_share": float(np.std(dpv) / max(np.std(loop.pv), 1e-300)),
            "sp_moves": float(np.sum(np.diff(loop.sp) != 0))}


def auc(x: np.ndarray, t: np.ndarray) -> float:
    return float(mannwhitneyu(x[t], x[~t]).statistic / (t.sum() * (~t).sum()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--sim-seeds", default="0-299")
    ap.add_argument("--plant", action="store_true", help="the simulated loops with the plant's habits")
    ap.add_argument("--labels", action="store_true", help="also each feature's AUC, sticky against clean (diagnosis)")
    a = ap.parse_args(argv)
    files = sorted(a.data.rglob("*.txt"), key=lambda p: p.name)
    if not files:
        print(f"loop_sim_vs_real: error: no *.txt records under {a.data}", file=sys.stderr)
        return 2
    label_of = {}
    if a.labels:
        label_of = {r["file"]: r["label"] == "stiction" for r in csv.DictReader(open(a.data / "index.csv"))}
    real, real_y = [], []
    for p in files:
        try:
            loop = read_loop(p)
        except LoopDataError:
            continue
        real.append({**features(loop)[0], **record_stats(loop)})
        real_y.append(label_of.get(p.name, False))
    sim, sim_y = [], []
    for s in int_list(a.sim_seeds):
        case = random_case(s, plant=a.plant)
        loop, truth = simulate_case(case)
        sim.append({**features(loop)[0], **record_stats(loop)})
        sim_y.append(truth.label == "stiction")
    names = list(real[0])
    R = np.array([[r[k] for k in names] for r in real])
    S = np.array([[r[k] for k in names] for r in sim])
    print(f"{len(R)} readable real records, {len(S)} simulated loops (seeds {a.sim_seeds})")
    print(f"{'feature':18s} {'real q10 / q50 / q90':>28s}   {'simulated q10 / q50 / q90':>28s}   "
          "real outside sim 5-95 %")
    for i, k in enumerate(names):
        qr, qs = np.quantile(R[:, i], [0.1, 0.5, 0.9]), np.quantile(S[:, i], [0.1, 0.5, 0.9])
        lo, hi = np.quantile(S[:, i], [0.05, 0.95])
        print(f"{k:18s} {qr[0]:9.3g} {qr[1]:9.3g} {qr[2]:9.3g}   {qs[0]:9.3g} {qs[1]:9.3g} {qs[2]:9.3g}   "
              f"{100 * float(np.mean((R[:, i] < lo) | (R[:, i] > hi))):5.0f} %")
    det = [i for i, k in enumerate(names) if k in real[0] and k not in ("op_repeats", "pv_repeats", "op_step_share",
                                                                         "pv_step_share", "sp_moves")]
    X = np.vstack([R[:, det], S[:, det]])
    d = np.r_[np.ones(len(R)), np.zeros(len(S))]
    fold = np.random.default_rng(0).integers(0, 5, d.size)
    p = np.zeros(d.size)
    for f in range(5):
        tr = fold != f
        mu, sd = X[tr].mean(axis=0), X[tr].std(axis=0) + 1e-12
        p[~tr] = prob(fit_logistic((X[tr] - mu) / sd, d[tr], 1.0), (X[~tr] - mu) / sd)
    one = sorted(((max(auc(X[:, j], d == 1), 1 - auc(X[:, j], d == 1)), names[i]) for j, i in enumerate(det)),
                 reverse=True)[:5]
    print(f"domain classifier, real against simulated (5-fold AUC; 0.5: alike): {auc(p, d == 1):.2f}; the features "
          "that differ most: " + ", ".join(f"{k} {v:.2f}" for v, k in one))
    if a.labels:
        ry, sy = np.array(real_y), np.array(sim_y)
        print(f"AUC for sticky against clean ({int(ry.sum())}/{int((~ry).sum())} real, "
              f"{int(sy.sum())}/{int((~sy).sum())} simulated), and the medians of each class:")
        for i in det:
            print(f"  {names[i]:18s} real {auc(R[:, i], ry):5.2f}  simulated {auc(S[:, i], sy):5.2f}   real "
                  f"{np.median(R[ry, i]):7.3f} / {np.median(R[~ry, i]):7.3f}   simulated {np.median(S[sy, i]):7.3f} / "
                  f"{np.median(S[~sy, i]):7.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
