"""Fit the stiction detector's combining rule on simulated loops only (docs/loops.md, "Detection").

The frozen rule (valve_env/loops/detector_coefs.py; the command is also in its docstring):

    python studies/loop_train_detector.py --train-seeds 0-1199 --val-seeds 100000-100399 --l2 10 \
        --clarity osc_acf_peak --drop osc_band_share --write

The two rules trained on the loops with the plant's habits (docs/history/loops.md, 2026-11-28 "The simulator against
the plant"; neither is frozen: they did no better on the real loops and worse on the environment's):

    python studies/loop_train_detector.py --plant --l2 100 --clarity osc_acf_peak
    python studies/loop_train_detector.py --plant --l2 10 --clarity osc_acf_peak --min-visibility 2

Simulates the loops of ``valve_env.loops.sim.random_case`` for the training seeds, computes every detector's
statistic (``valve_env.loops.detect.features``), fits an L2-penalised logistic regression (scipy) on the
standardised terms (``valve_env.loops.detect.terms``: the features, the shape features weighted by the
oscillation's clarity, and their squares), and chooses the decision threshold on the validation seeds: the one
with the best balanced accuracy among those naming at most ``--max-false-alarm`` of the validation loops without
stiction. Prints the coefficients and the validation figures per kind of loop; ``--write`` writes
``valve_env/loops/detector_coefs.py`` (the frozen rule: it is replaced only with ``--write``). No real loop is
read. The seeds of the final evaluation (benchmarks/loop_benchmark.py --sim-seed) must be neither of these.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from valve_env.cliutil import int_list
from valve_env.loops.detect import SHAPE_FEATURES, design_row, features, terms
from valve_env.loops.sim import random_case, simulate_case, stiction_visibility
from valve_env.outputs import atomic_write_text

OUT = Path(__file__).resolve().parents[1] / "valve_env" / "loops" / "detector_coefs.py"


def feature_table(seeds: list[int], plant: bool = False, visibility: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, list[str], tuple[str, ...], np.ndarray]:
    """Every feature of :func:`valve_env.loops.detect.features` for the loops of ``seeds``, the labels, the kinds,
    the feature names (the columns) and, with ``visibility``, each sticky loop's
    :func:`valve_env.loops.sim.stiction_visibility` (NaN for the others and without it); ``plant``: the loops of
    ``random_case(..., plant=True)``."""
    X, y, kinds, vis = [], [], [], []
    names: tuple[str, ...] = ()
    for s in seeds:
        case = random_case(s, plant=plant)
        loop, truth = simulate_case(case)
        f, _ = features(loop)
        names = tuple(f)
        X.append(design_row(f, names))
        y.append(truth.label == "stiction")
        kinds.append(case["kind"])
        vis.append(stiction_visibility(case, loop) if visibility else np.nan)
    return np.array(X), np.array(y, dtype=float), kinds, names, np.array(vis)


def fit_logistic(Z: np.ndarray, y: np.ndarray, l2: float) -> np.ndarray:
    """Coefficients (intercept first) of the logistic regression of ``y`` on ``Z`` with penalty ``l2 |b|^2 / 2``
    (not on the intercept)."""
    A = np.column_stack([np.ones(len(Z)), Z])

    def nll(b: np.ndarray) -> tuple[float, np.ndarray]:
        eta = A @ b
        p = 1.0 / (1.0 + np.exp(-eta))
        val = float(np.sum(np.logaddexp(0.0, eta) - y * eta) + 0.5 * l2 * np.sum(b[1:] ** 2))
        g = A.T @ (p - y)
        g[1:] += l2 * b[1:]
        return val, g

    return minimize(nll, np.zeros(A.shape[1]), jac=True, method="L-BFGS-B").x


def prob(b: np.ndarray, Z: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-(b[0] + Z @ b[1:])))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--train-seeds", default="0-1199")
    ap.add_argument("--val-seeds", default="100000-100399")
    ap.add_argument("--l2", type=float, default=10.0)
    ap.add_argument("--max-false-alarm", type=float, default=0.04)
    ap.add_argument("--plant", action="store_true", help="train on random_case(..., plant=True): the plant's habits")
    ap.add_argument("--drop", default="",
                    help="features of valve_env.loops.detect.features left out of the rule (a comma list)")
    ap.add_argument("--min-visibility", type=float, default=0.0,
                    help="leave out the sticky loops whose stiction_visibility is below this (0: keep all)")
    ap.add_argument("--clarity", default="osc_acf_peak",
                    help="the feature that weighs the shape features (how clearly the loop oscillates), or 'none'")
    ap.add_argument("--cache", type=Path, default=None, help="an .npz to keep the feature tables in (read if present)")
    ap.add_argument("--write", action="store_true", help="write valve_env/loops/detector_coefs.py")
    a = ap.parse_args(argv)
    tr, va = int_list(a.train_seeds), int_list(a.val_seeds)
    t0 = time.perf_counter()
    clarity = None if a.clarity == "none" else a.clarity
    if a.cache is not None and a.cache.exists():
        c = np.load(a.cache, allow_pickle=False)
        Xt, yt, kt, Xv, yv, kv = c["Xt"], c["yt"], list(c["kt"]), c["Xv"], c["yv"], list(c["kv"])
        names = tuple(str(k) for k in c["names"])
        vt, vv = c["vt"], c["vv"]
    else:
        Xt, yt, kt, names, vt = feature_table(tr, a.plant, a.min_visibility > 0)
        Xv, yv, kv, _, vv = feature_table(va, a.plant, a.min_visibility > 0)
        if a.cache is not None:
            np.savez(a.cache, Xt=Xt, yt=yt, kt=np.array(kt), Xv=Xv, yv=yv, kv=np.array(kv), names=np.array(names),
                     vt=vt, vv=vv)
    print(f"features of {len(tr)} training and {len(va)} validation loops in {time.perf_counter() - t0:.0f} s")
    if a.min_visibility > 0:
        # a sticky valve the record does not show (no limit cycle: noise and load keep the stem moving) is left out:
        # it is not what a plant's engineer labels stiction, and no shape test can see it
        kept_t, kept_v = ~((yt == 1) & ~(vt >= a.min_visibility)), ~((yv == 1) & ~(vv >= a.min_visibility))
        print(f"sticky loops kept (visibility >= {a.min_visibility:g}): training {int(np.sum(kept_t & (yt == 1)))}/"
              f"{int(np.sum(yt == 1))}, validation {int(np.sum(kept_v & (yv == 1)))}/{int(np.sum(yv == 1))}")
        Xt, yt, kt = Xt[kept_t], yt[kept_t], [k for k, m in zip(kt, kept_t, strict=True) if m]
        Xv, yv, kv = Xv[kept_v], yv[kept_v], [k for k, m in zip(kv, kept_v, strict=True) if m]
    if a.drop:
        drop = a.drop.split(",")
        if not set(drop) <= set(names):
            print(f"loop_train_detector: error: unknown feature(s) {sorted(set(drop) - set(names))}", file=sys.stderr)
            return 2
        idx = [i for i, k in enumerate(names) if k not in drop]
        Xt, Xv, names = Xt[:, idx], Xv[:, idx], tuple(names[i] for i in idx)
    if clarity is not None and clarity not in names:
        print(f"loop_train_detector: error: --clarity must be a feature ({', '.join(names)}) or 'none'",
              file=sys.stderr)
        return 2
    Xt, Xv = terms(Xt, names, clarity), terms(Xv, names, clarity)
    lin = [*names, *(f"{k}*{clarity}" for k in SHAPE_FEATURES if clarity is not None)]
    term_names = [*lin, *(f"({k})^2" for k in lin)]
    mu, sd = Xt.mean(axis=0), Xt.std(axis=0)
    sd[sd == 0] = 1.0
    b = fit_logistic((Xt - mu) / sd, yt, a.l2)
    pt, pv = prob(b, (Xt - mu) / sd), prob(b, (Xv - mu) / sd)
    best = (-1.0, 0.5)
    for th in np.round(np.arange(0.05, 0.99, 0.01), 2):
        fa = float(np.mean(pv[yv == 0] > th))
        ba = 0.5 * (float(np.mean(pv[yv == 1] > th)) + 1.0 - fa)
        if fa <= a.max_false_alarm and ba > best[0]:
            best = (ba, float(th))
    th = best[1]
    print(f"coefficients (standardised features; intercept {b[0]:+.3f}):")
    for name, v in zip(term_names, b[1:], strict=True):
        print(f"  {name:16s} {v:+.3f}")
    for label, P, Y, K in (("training", pt, yt, kt), ("validation", pv, yv, kv)):
        sens, fa = float(np.mean(P[Y == 1] > th)), float(np.mean(P[Y == 0] > th))
        print(f"{label}: threshold {th:.2f}: stiction named on {100 * sens:.1f} % of sticky loops, "
              f"{100 * fa:.1f} % of the others; balanced accuracy {50 * (sens + 1 - fa):.1f} %")
        for k in sorted(set(K)):
            m = np.array([kk == k for kk in K])
            print(f"    {k:18s} n={int(m.sum()):4d} named stiction {100 * float(np.mean(P[m] > th)):5.1f} %")
    if a.write:
        training = {"train_seeds": a.train_seeds, "validation_seeds": a.val_seeds, "l2": a.l2, "clarity": a.clarity,
                    "min_visibility": a.min_visibility, "plant": a.plant,
                    "max_false_alarm": a.max_false_alarm, "n_train": len(tr)}
        from pprint import pformat

        def const(name: str, value: object) -> str:
            return f"{name} = {pformat(value, width=118 - len(name), compact=True)}\n"

        import textwrap

        cmd = (f"python studies/loop_train_detector.py --train-seeds {a.train_seeds} --val-seeds {a.val_seeds} "
               f"--l2 {a.l2:g} --max-false-alarm {a.max_false_alarm:g} --clarity {a.clarity} "
               f"--min-visibility {a.min_visibility:g}{' --plant' if a.plant else ''}"
               f"{' --drop ' + a.drop if a.drop else ''} --write")
        text = ('"""The stiction detector\'s combining rule (valve_env.loops.detect), fitted on simulated loops '
                "only by\n\n" + textwrap.indent(textwrap.fill(cmd, 110, break_on_hyphens=False), "    ")
                + "\n\nGenerated: do not edit.\"\"\"\n\n"
                + const("FEATURES", tuple(names))
                + const("MEANS", tuple(round(float(v), 6) for v in mu))
                + const("SCALES", tuple(round(float(v), 6) for v in sd))
                + const("COEFS", tuple(round(float(v), 6) for v in b))
                + const("THRESHOLD", th)
                + const("CLARITY", clarity)
                + "TRAINING: dict = " + pformat(training, width=100, compact=True) + "\n")
        atomic_write_text(OUT, text)
        print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
