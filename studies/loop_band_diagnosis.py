"""Where the band goes wrong on simulated loops of wide variety (docs/loops.md, "The band"; docs/history/loops.md).

    python studies/loop_band_diagnosis.py --seeds 900000-900199

For every sticky loop of ``valve_env.loops.sim.random_case`` among ``--seeds`` (development seeds only: never the
seeds a figure is reported on), prints the truth (S, J/S, process, lag, delay, sampling, record length, noise for the
band, cycles of the control error), the band's fit (band, sd, J/S, which valve, the log-likelihood at the fit and at
the true S and J), the controller's within-sample jitter (the simulated 1 s output's sd about its interval mean, and
``model.op_jitter``'s estimate from the record), and three oracle bands: the band whose valve path best reproduces the
true stem position (``mv``) from the recorded OP with the smooth sub-sample valve, with the jitter-driven valve, and
from the controller's own 1 s output. The summary gives the share of loops within 20 % for the fit and each oracle:
what a valve model driven by the record can reach at best.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace

import numpy as np

from valve_env.cliutil import int_list
from valve_env.loops.detectors import oscillation
from valve_env.loops.diagnose import diagnose_loop
from valve_env.loops.model import BAND_J_FRACTIONS, fit_process, op_jitter, valve_path
from valve_env.loops.sim import random_case, simulate_case


def oracle_band(op: np.ndarray, mv: np.ndarray, S: float, substeps: int, jitter: float = 0.0,
                block: int = 1) -> float:
    """The band (J / S and direction free) whose valve path from ``op`` best reproduces the true stem ``mv`` (least
    sd of the difference: an offset is the process's constant); ``block`` > 1 averages the path over blocks of that
    many steps (``op`` at the controller's rate, ``mv`` at the record's)."""
    best = (math.inf, 0.0)
    for Sx in S * np.geomspace(0.1, 4.0, 40):
        for f in BAND_J_FRACTIONS:
            for d0 in (1.0, -1.0):
                x = valve_path(op, Sx, f * Sx, d0, substeps, jitter)
                if block > 1:
                    x = x[: mv.size * block].reshape(mv.size, block).mean(axis=1)
                best = min(best, (float(np.std(x - mv)), float(Sx)))
    return best[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="900000-900199")
    a = ap.parse_args(argv)
    keys = ("fit", "smooth", "jitter", "1s")
    within: dict[str, list[bool]] = {k: [] for k in keys}
    print(f"{'seed':>7s} {'S':>5s} {'J/S':>4s} {'proc':5s} {'tau':>5s} {'dly':>3s} {'dt':>3s} {'h':>4s} {'noise':>5s} "
          f"{'cyc':>5s} | {'band':>6s} {'sd':>5s} {'J/S':>4s} {'valve':6s} {'llfit-lltrue':>12s} | {'jit1s/S':>7s} "
          f"{'est/S':>6s} | oracle/S: {'smooth':>6s} {'jitter':>6s} {'1s':>5s}")
    for seed in int_list(a.seeds):
        case = random_case(seed)
        if case["label"] != "stiction":
            continue
        loop, _ = simulate_case(case)
        d = diagnose_loop(loop, quantify=True)
        if "stiction" not in d.result:
            continue
        st, fit = d.result["stiction"], d.fits["stiction"]
        S, J, p = case["S"], case["J"], case["process"]
        s = replace(d.settings, substeps=fit.substeps, jitter=fit.jitter)
        ll_true = max(fit_process(loop.pv, valve_path(loop.op, S, J, d0, s.substeps, s.jitter), s).loglik
                      for d0 in (1.0, -1.0))
        m = int(round(case["dt"]))
        fine, _ = simulate_case({**case, "dt": 1.0})  # the same loop at the controller's 1 s step
        op1 = fine.op[: loop.n * m].reshape(loop.n, m)
        jit_true = float((op1 - op1.mean(axis=1, keepdims=True)).std())
        jit_est = op_jitter(loop.op, loop.dt, 1.0)
        orc = {"smooth": oracle_band(loop.op, loop.mv, S, 4),
               "jitter": oracle_band(loop.op, loop.mv, S, max(4, m), jit_est),
               "1s": oracle_band(fine.op, loop.mv, S, 1, block=m)}
        within["fit"].append(abs(st["band_pct"] - S) <= 0.2 * S)
        for k, v in orc.items():
            within[k].append(abs(v - S) <= 0.2 * S)
        osc = oscillation(loop.pv - loop.sp, loop.dt)
        cycles = loop.n * loop.dt / osc["period_s"] if osc["oscillating"] else 0.0
        pv_per = p.gain * (case["tau_c_s"] + p.delay_s) if p.integrating else p.gain
        print(f"{seed:7d} {S:5.2f} {J / S:4.2f} {'integ' if p.integrating else 'fopdt':5s} {p.tau_s:5.0f} "
              f"{p.delay_s:3.0f} {case['dt']:3.0f} {case['hours']:4.1f} {p.noise_sd / (pv_per * S):5.2f} "
              f"{cycles:5.1f} | "
              f"{st['band_pct']:6.2f} {st['std_pct']:5.2f} {fit.J / max(fit.S, 1e-12):4.2f} "
              f"{'jitter' if fit.jitter > 0 else 'smooth':6s} {fit.loglik - ll_true:12.1f} | {jit_true / S:7.3f} "
              f"{jit_est / S:6.3f} | {orc['smooth'] / S:16.2f} {orc['jitter'] / S:6.2f} {orc['1s'] / S:5.2f}")
    n = len(within["fit"])
    print(f"\n{n} sticky loops; within 20 % of the truth: " + ", ".join(
        f"{k} {100 * np.mean(v):.1f} %" for k, v in within.items()) + " (fit: the band's fit; the others: the oracle "
          "bands from the true stem position)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
