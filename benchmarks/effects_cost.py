"""Each named effect's extra cost per env-step, single and batched (interleaved rounds).

    python benchmarks/effects_cost.py [--rounds 3] [--steps 3000] [--n 1024] [--batch-steps 200]

For the base valve and each effect of the registry (at its default parameters) and all four together:
the single env's steps per second through gym.make (ThermoValve-v0, a fixed action) and the batched
env's env-steps per second at N envs; rounds interleave the variants so that a shared machine's load
falls on all of them alike. Prints the median over rounds and the extra ns per env-step against the
base valve.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import gymnasium as gym
import numpy as np

import valve_env  # noqa: F401 - registers the ids
from valve_env.effects import REGISTRY


def _variants() -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {"base": {}}
    for name in REGISTRY:
        out[name] = {"valve": {"effects": {name: {}}}}
    out["all"] = {"valve": {"effects": {name: {} for name in REGISTRY}}}
    return out


def single_rate(kw: dict[str, Any], steps: int) -> float:
    env = gym.make("ThermoValve-v0", **kw)
    env.reset(seed=0)
    a = np.array([60.0], np.float32)
    for _ in range(200):  # warm
        env.step(a)
    t0 = time.perf_counter()
    for _ in range(steps):
        *_, trunc, _ = env.step(a)
        if trunc:
            env.reset()
    return steps / (time.perf_counter() - t0)


def batch_rate(kw: dict[str, Any], n: int, steps: int) -> float:
    env = gym.make_vec("ThermoValve-v0", num_envs=n, vectorization_mode="vector_entry_point", **kw)
    env.reset(seed=0)
    a = np.full((n, 1), 60.0, np.float32)
    for _ in range(20):
        env.step(a)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(a)
    return n * steps / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--batch-steps", type=int, default=200)
    args = ap.parse_args(argv)
    var = _variants()
    single: dict[str, list[float]] = {k: [] for k in var}
    batch: dict[str, list[float]] = {k: [] for k in var}
    for r in range(args.rounds):
        for k, kw in var.items():
            single[k].append(single_rate(kw, args.steps))
            batch[k].append(batch_rate(kw, args.n, args.batch_steps))
        print(f"round {r + 1}: " + ", ".join(f"{k} {single[k][-1]:.0f}/s {batch[k][-1] / 1e6:.2f}M/s" for k in var))
    s0, b0 = np.median(single["base"]), np.median(batch["base"])
    print(f"\n{'variant':>20} {'single steps/s':>15} {'extra us/step':>14} {'batched M env-steps/s':>22} "
          f"{'extra ns/env-step':>18}")
    for k in var:
        s, b = float(np.median(single[k])), float(np.median(batch[k]))
        print(f"{k:>20} {s:15.0f} {1e6 / s - 1e6 / s0:14.2f} {b / 1e6:22.2f} {1e9 / b - 1e9 / b0:18.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
