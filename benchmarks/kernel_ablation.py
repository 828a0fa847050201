"""Where the simulator kernel's time goes: ``plant_step`` with one part removed at a time.

    python benchmarks/kernel_ablation.py [--envs 2048] [--steps 60] [--rounds 5] [--block 64]

Builds variants of the block kernel :func:`valve_env.simulator.plant_step` from its
own source (buoyancy mixing skipped; the valve's Dahl/opening update skipped; the
coil's exchange skipped; draws, advection and losses skipped), compiles each with
numba, and times them over the same envs in interleaved rounds (medians).
The variants are wrong physics on purpose: they only say what each part costs.
A variant whose state drifts far from physical (no mixing, a frozen valve, no
draws) can run *slower* than the full kernel (subnormal numbers and long mixing
passes in the drifting tanks): read a negative saving as "not measurable this way".
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
    "no buoyancy mixing": [("        buoyancy_mix(T, mix_S, mix_R, mix_M, flag, lo, hi)\n", "")],
    "no valve update (Dahl + opening)": [
        ("            F = dahl_update(F_h[i], Tg1 - T_g[i], vp)\n", "            F = F_h[i]\n"),
        ("            x = opening(Tg1, F, dp[i], ps, p_bset[i], vp)\n", "            x = X[i] + 0.0\n"),
    ],
    "no coil exchange": [
        ("        coil_heat(T, nc, m, T_sup, pp[P_UA_COIL], cp, Q, T_ret, eps, lo, hi)\n",
         "        for j in range(nl):\n            for i in range(c0, c1):\n                Q[j, i] = 0.0\n"),
    ],
    "no draws, advection, losses": [
        ("        draw_flow(draw_W, draw_T, tap_m, T_top, T_cold, cp, m_draw, q_deliv, lo, hi, pp[P_DRAW_MAX])\n",
         ""),
        ("        advection_heat(T, m_draw, T_cold, cp, Q, lo, hi)\n", ""),
        ("        loss_heat(T, pp[P_UA_LOSS], pp[P_T_AMB], Q, q_loss, lo, hi)\n", ""),
    ],
}


def _variant(name: str, edits: list[tuple[str, str]]) -> Callable[..., Any]:
    src = textwrap.dedent(inspect.getsource(sim.plant_step.py_func))
    src = src.replace('@njit(cache=True, error_model="numpy")\n', "")
    for old, new in edits:
        if old not in src:
            raise RuntimeError(f"variant {name!r}: the kernel's source has changed ({old.strip()!r} not found)")
        src = src.replace(old, new)
    ns: dict[str, Any] = dict(vars(sim))
    exec(compile(src, f"<plant_step: {name}>", "exec"), ns)
    step = njit(error_model="numpy")(ns["plant_step"])

    @njit
    def loop(Z, vp, pp, block):  # type: ignore[no-untyped-def]
        n = Z.shape[1]
        for lo in range(0, n, block):
            step(Z, lo, min(n, lo + block), vp, pp)

    return loop


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--envs", type=int, default=2048)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--block", type=int, default=64, help="envs per plant_step call")
    args = ap.parse_args()
    cfg = make_config()
    n, nl = args.envs, cfg.tank.n_layers
    c = cfg.control
    scen = make_scenario(cfg.scenario, np.random.default_rng(0), c.n_steps, c.dt_s, cfg.tank.T_cold, cfg.tank.cp)
    sc = scen.as_matrix()
    vp, pp = cfg.valve.to_array(), sim.pack_plant(cfg)
    ns = nl + sim.N_STATE_EXTRA
    Z0 = np.zeros((sim.block_rows(nl), n))
    Z0[:ns] = sim.initial_state(cfg, 55.0)[:, None]
    Z0[:nl] += np.linspace(-2.0, 2.0, n)[None, :]
    runs = {}
    for name, edits in VARIANTS.items():
        fn = _variant(name, edits)
        Z = Z0.copy()
        fn(Z, vp, pp, args.block)
        runs[name] = (fn, Z, [])
    for _ in range(args.rounds):
        for _name, (fn, Z, times) in runs.items():
            spent = 0.0
            for k in range(1, args.steps + 1):
                row = sc[k]
                for i in range(n):  # this step's inputs (not timed)
                    sim.load_inputs(Z, i, ns, row, 50.0 + i % 20, 100.0)
                t0 = time.perf_counter()
                fn(Z, vp, pp, args.block)
                spent += time.perf_counter() - t0
            times.append(spent / n / args.steps * 1e9)
    full = statistics.median(runs["full kernel"][2])
    print(f"plant_step over {n} envs in blocks of {args.block}, serial, median of {args.rounds} interleaved rounds")
    print("| variant | ns per env-step | share of the full kernel saved |")
    print("|---|---|---|")
    for name, (_fn, _a, times) in runs.items():
        med = statistics.median(times)
        print(f"| {name} | {med:.0f} | {0.0 if name == 'full kernel' else (full - med) / full:.0%} |")


if __name__ == "__main__":
    main()
