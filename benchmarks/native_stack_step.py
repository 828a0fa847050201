"""The native training stack's step on its own: milliseconds per step of N envs, per task.

    python benchmarks/native_stack_step.py [--tasks current|A,B] [--n-envs 256] [--steps 300]

Builds each task's training stack of configs/ppo.yml over the native VecEnv exactly as training does
(``agents.wrappers.make_vec_env(task, cfg, seed=0, n_envs=N, vec="native")``: ThermoValveVecEnv, VecKPIInfo,
VecMonitor, energy shaping, the residual base law, scaling and observation aids, frame history,
VecNormalize), steps it with fixed random actions in [-1, 1] and prints the best of three timings of
``--steps`` steps (after 50 warm-up steps). No PPO: the collection's env half, which the native VecEnv
owns (benchmarks/train_throughput.py times the whole of ``learn``). Run it on two checkouts in turn to
compare them (docs/agents.md, "Training throughput").
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def step_ms(task: str, n: int, steps: int) -> float:
    from agents.train import apply_overrides, load_algo_config
    from agents.wrappers import make_vec_env

    cfg = apply_overrides(load_algo_config("ppo", task), ["optimizer=sgd"])
    venv = make_vec_env(task, cfg, seed=0, n_envs=n, vec="native", training=True)
    venv.reset()
    acts = np.random.default_rng(0).uniform(-1.0, 1.0, (64, n, *venv.action_space.shape)).astype(np.float32)
    for t in range(50):
        venv.step(acts[t % 64])
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for t in range(steps):
            venv.step(acts[t % 64])
        best = min(best, (time.perf_counter() - t0) / steps)
    venv.close()
    return best * 1e3


def main(argv: list[str] | None = None) -> int:
    import valve_env

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", default="current", metavar="current|A,B")
    p.add_argument("--n-envs", type=int, default=256)
    p.add_argument("--steps", type=int, default=300)
    args = p.parse_args(argv)
    tasks = list(valve_env.CURRENT_TASK_IDS) if args.tasks == "current" else [t for t in args.tasks.split(",") if t]
    bad = [t for t in tasks if t not in valve_env.ALL_ENV_IDS]
    if bad or args.n_envs < 1 or args.steps < 1:
        what = f"unknown task {bad[0]!r}" if bad else "--n-envs and --steps must be >= 1"
        print(f"thermovalve: error: {what}", file=sys.stderr)
        return 2
    for task in tasks:
        ms = step_ms(task, args.n_envs, args.steps)
        print(f"{task}: {ms:.3f} ms per step of {args.n_envs} envs ({ms * 1e3 / args.n_envs:.2f} us per env-step)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
