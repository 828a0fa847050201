"""Where the simulator kernel's time goes: ``plant_step`` with one part removed at a time.

    python benchmarks/kernel_ablation.py [--envs 2048] [--steps 60] [--rounds 5]

Builds variants of :func:`valve_env.simulator.plant_step` from its own source
(buoyancy mixing skipped; the valve's Dahl/opening update skipped; the coil's
exchange skipped; the per-sub-step accumulator writes skipped), compiles each
with numba, and times them over the same envs in interleaved rounds (medians).
The variants are wrong physics on purpose: they only say what each part costs.
Timing only, nothing here is used by the package.
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import textwrap
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit

from valve_env import simulator as sim
from valve_env.config import make_config
from valve_env.scenario import make_scenario

VARIANTS: dict[str, list[tuple[str, str]]] = {
    "full kernel": [],
    "no buoyancy mixing": [("        buoyancy_mix(T, wsum, wcnt)\n", "        pass\n")],
    "no valve update (Dahl + opening)": [
        ("        F_h = dahl_update(F_h, T_g_new - T_g, vp)\n", ""),
        ("        x_new = opening(T_g, F_h, dp, ps, p_bset, vp)\n", "        x_new = x + 0.0\n"),
    ],
    "no coil exchange": [
        (
            "        T_ret = coil_heat(T, nc, m, T_sup, pp[P_UA_COIL], cp, Q)\n",
            "        T_ret = T_sup\n        for j in range(nl):\n            Q[j] = 0.0\n",
        )
    ],
}


def _variant(name: str, edits: list[tuple[str, str]]) -> Callable[..., Any]:
    src = textwrap.dedent(inspect.getsource(sim.plant_step.py_func))
    src = src.replace("@njit(cache=True)\n", "")
    for old, new in edits:
        if old not in src:
            raise RuntimeError(f"variant {name!r}: the kernel's source has changed ({old.strip()!r} not found)")
        src = src.replace(old, new)
    ns: dict[str, Any] = dict(vars(sim))
    exec(compile(src, f"<plant_step: {name}>", "exec"), ns)
    step = njit(ns["plant_step"])

    @njit
    def loop(S, ACC, OUT, vp, pp, scen, k, W, R):  # type: ignore[no-untyped-def]
        for i in range(S.shape[0]):
            R[i] = step(S[i], ACC[i], OUT[i], vp, pp, scen[k], 50.0 + i % 20, 100.0, W[i])

    return loop


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--envs", type=int, default=2048)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    cfg = make_config()
    n, nl = args.envs, cfg.tank.n_layers
    c = cfg.control
    scen = make_scenario(cfg.scenario, np.random.default_rng(0), c.n_steps, c.dt_s, cfg.tank.T_cold, cfg.tank.cp)
    sc = scen.as_matrix()
    vp, pp = cfg.valve.to_array(), sim.pack_plant(cfg)
    runs = {}
    for name, edits in VARIANTS.items():
        S = np.tile(sim.initial_state(cfg, 55.0), (n, 1))
        S[:, :nl] += np.linspace(-2.0, 2.0, n)[:, None]
        arrays = (S, np.zeros((n, sim.N_ACC)), np.zeros((n, sim.N_OUT)), np.zeros((n, 3, nl)), np.zeros(n))
        fn = _variant(name, edits)
        fn(arrays[0], arrays[1], arrays[2], vp, pp, sc, 0, arrays[3], arrays[4])
        runs[name] = (fn, arrays, [])
    for _ in range(args.rounds):
        for _name, (fn, (S, ACC, OUT, W, R), times) in runs.items():
            t0 = time.perf_counter()
            for k in range(1, args.steps + 1):
                fn(S, ACC, OUT, vp, pp, sc, k, W, R)
            times.append((time.perf_counter() - t0) / n / args.steps * 1e9)
    full = statistics.median(runs["full kernel"][2])
    print(f"plant_step over {n} envs, serial, median of {args.rounds} interleaved rounds")
    print("| variant | ns per env-step | share of the full kernel saved |")
    print("|---|---|---|")
    for name, (_fn, _a, times) in runs.items():
        med = statistics.median(times)
        print(f"| {name} | {med:.0f} | {0.0 if name == 'full kernel' else (full - med) / full:.0%} |")


if __name__ == "__main__":
    main()
