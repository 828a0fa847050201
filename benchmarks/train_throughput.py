"""Training throughput: env-steps per second of SB3 ``learn`` (collection plus updates).

    python benchmarks/train_throughput.py [--json out/train_throughput.json] [--md out/train_throughput.md]
                                          [--seconds 20] [--threads 1] [--quick] [--force]

Measures in one run, on ThermoValve-v0 (24 h episodes) with the training stack of
configs/<algo>.yml (residual PI action, physical observation scaling, frame stack 4,
energy shaping, VecNormalize; agents.wrappers.make_vec_env):

PPO
  * ``DummyVecEnv(8)`` and ``SubprocVecEnv(2)`` of single wrapped envs with the shipped
    hyperparameters of configs/ppo.yml (n_steps 1024, batch 1024, 5 epochs, target_kl 0.02);
  * the native VecEnv (agents.vec_env) at N = 8 with the same hyperparameters (the env's
    share of the gain alone);
  * the native VecEnv at N = 8, 64, 256, 1024 with the *fast* hyperparameters: everything as
    shipped (network, learning rate, gamma, GAE, clipping, 5 epochs, target_kl) except the
    rollout and the minibatch: ``n_steps = clip(65536 / N, 32, 1024)`` and batch 4096, so a
    rollout is 64k transitions at N >= 64 (16 minibatches per epoch);
  * the same with 2 epochs instead of 5 at N = 256 and 1024: what the update's cost per
    transition (epochs x one forward and backward pass of both networks) does to the rate.
    Fewer epochs learn less per transition; the goal is judged on the 5-epoch settings.
  * the fair comparison at the large-N settings: DummyVecEnv(8) and the native VecEnv at
    N = 64, 256, 1024 with the *same* hyperparameters (``large_n_overrides``: batch 4096, 5
    epochs, n_steps = clip(65536 / N, 32, 1024), the benchmark tasks' 64x64 networks): the
    update costs the same per transition for both, only the collection differs.

SAC (off-policy, many envs)
  * ``DummyVecEnv(1)`` with configs/sac.yml (train_freq 4, 1 gradient step of 256: 64 replayed
    samples per env step);
  * the native VecEnv at N = 64 and 256 with batch 1024, ``train_freq = max(1, 128 / N)`` steps
    and ``gradient_steps = max(1, N / 128)``: 8 replayed samples per env step (UTD 1/128). A
    replay ratio of 64 at N = 256 would be 16 gradient steps of 1024 per env step of 256
    transitions: the updates, not the envs, would set the pace at any N.

Each configuration is built, warmed up (one PPO rollout and update; SAC's learning_starts plus
a few updates; numba and torch compiled and allocated), then ``learn`` runs on for about
``--seconds`` (whole rollouts) and the rate is the env-steps it added over its wall time. For
PPO the time inside rollout collection is reported beside it (callbacks at rollout start and
end), the rest is the update. torch runs on ``--threads`` threads (default 1, as ``thermovalve
train``) for every configuration. The machine is shared: quote ratios from one run.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ENV_ID = "ThermoValve-v0"
PPO_FAST_N: tuple[int, ...] = (8, 64, 256, 1024)
SAC_FAST_N: tuple[int, ...] = (64, 256)
FAST_ROLLOUT = 65536
FAST_BATCH = 4096
SAC_BATCH = 1024
SAC_REPLAY_RATIO = 8  # samples drawn from the buffer per env step


def fast_ppo_overrides(n: int) -> list[str]:
    n_steps = int(np.clip(FAST_ROLLOUT // n, 32, 1024))
    return [f"hyperparams.n_steps={n_steps}", f"hyperparams.batch_size={FAST_BATCH}"]


def large_n_overrides(n: int) -> list[str]:
    """The PPO settings configs/ppo.yml gives the benchmark tasks for large N (batch 4096, the
    tasks' network), with 5 epochs, for every VecEnv alike: n_steps = clip(65536 / N, 32, 1024)."""
    return [*fast_ppo_overrides(n), "hyperparams.n_epochs=5",
            "hyperparams.policy_kwargs.net_arch={pi: [64, 64], vf: [64, 64]}"]


def fast_sac_overrides(n: int) -> list[str]:
    train_freq = max(1, (SAC_BATCH // SAC_REPLAY_RATIO) // n)
    gradient_steps = max(1, n // (SAC_BATCH // SAC_REPLAY_RATIO))
    return [
        f"hyperparams.batch_size={SAC_BATCH}",
        f"hyperparams.train_freq={train_freq}",
        f"hyperparams.gradient_steps={gradient_steps}",
        "hyperparams.learning_starts=2048",
    ]


def measure(algo: str, vec: str, n: int, overrides: list[str], seconds: float, label: str) -> dict[str, Any]:
    """Build, warm up and time one configuration; see the module docstring."""
    from stable_baselines3.common.callbacks import BaseCallback

    from agents.train import algo_class, apply_overrides, build_model_kwargs, load_algo_config
    from agents.wrappers import make_vec_env

    cfg = apply_overrides(load_algo_config(algo, ENV_ID), overrides)
    hp = cfg["hyperparams"]
    venv = make_vec_env(ENV_ID, cfg, seed=0, n_envs=n, vec=vec, training=True)
    n_actions = int(venv.action_space.shape[0])  # type: ignore[index]
    model = algo_class(algo)("MlpPolicy", venv, seed=0, device="cpu", **build_model_kwargs(algo, cfg, n_actions))

    class Split(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.collect_s = 0.0
            self._t0 = 0.0

        def _on_rollout_start(self) -> None:
            self._t0 = time.perf_counter()

        def _on_rollout_end(self) -> None:
            self.collect_s += time.perf_counter() - self._t0

        def _on_step(self) -> bool:
            return True

    if algo == "ppo":
        chunk = int(hp["n_steps"]) * n
        model.learn(chunk)  # warm-up: one rollout and one update
    else:
        chunk = max(n, 256) * 8
        model.learn(int(float(hp["learning_starts"])) + chunk)
    # time a first chunk to size the run, then learn on for about `seconds` in whole chunks
    split = Split()
    t0 = time.perf_counter()
    start = model.num_timesteps
    model.learn(chunk, reset_num_timesteps=False, callback=split)
    first = time.perf_counter() - t0
    more = max(0, int(round((seconds - first) / max(first, 1e-9))))
    if more:
        model.learn(chunk * more, reset_num_timesteps=False, callback=split)
    wall = time.perf_counter() - t0
    steps = model.num_timesteps - start
    venv.close()
    row: dict[str, Any] = {
        "label": label,
        "algo": algo,
        "vec": vec,
        "n_envs": n,
        "env_steps": int(steps),
        "wall_s": round(wall, 3),
        "env_steps_per_s": steps / wall,
        "hyperparams": {k: hp[k] for k in sorted(hp) if k != "policy_kwargs"},
    }
    if algo == "ppo":
        row["collect_share"] = split.collect_s / wall
        row["rollout"] = int(hp["n_steps"]) * n
    else:
        tf = int(hp["train_freq"])
        row["replay_ratio"] = int(hp["gradient_steps"]) * int(hp["batch_size"]) / (tf * n)
    return row


def run(seconds: float, threads: int, quick: bool, progress: Any = None) -> dict[str, Any]:
    import stable_baselines3
    import torch

    torch.set_num_threads(int(threads))
    plan: list[tuple[str, str, int, list[str], str]] = [
        ("ppo", "dummy", 8, [], "DummyVecEnv(8), shipped"),
        ("ppo", "subproc", 2, [], "SubprocVecEnv(2), shipped"),
        ("ppo", "native", 8, [], "native(8), shipped"),
    ]
    for n in (PPO_FAST_N[1:3] if quick else PPO_FAST_N):
        plan.append(("ppo", "native", n, fast_ppo_overrides(n), f"native({n}), fast"))
    for n in (PPO_FAST_N[2:3] if quick else PPO_FAST_N[2:]):
        plan.append(("ppo", "native", n, [*fast_ppo_overrides(n), "hyperparams.n_epochs=2"],
                     f"native({n}), fast, 2 epochs"))
    # the fair comparison at the large-N settings (the same PPO hyperparameters for both VecEnvs:
    # batch 4096, 5 epochs, the tasks' network; only N and so the rollout differ)
    for vec, n in (("dummy", 8), *(("native", n) for n in (PPO_FAST_N[1:3] if quick else PPO_FAST_N[1:]))):
        plan.append(("ppo", vec, n, large_n_overrides(n), f"{'DummyVecEnv' if vec == 'dummy' else 'native'}({n}), "
                     "large-N settings"))
    plan.append(("sac", "dummy", 1, [], "DummyVecEnv(1), shipped"))
    for n in (SAC_FAST_N[:1] if quick else SAC_FAST_N):
        plan.append(("sac", "native", n, fast_sac_overrides(n), f"native({n}), many envs"))
    rows = []
    for algo, vec, n, ov, label in plan:
        if progress:
            progress(f"{algo} {label}")
        rows.append(measure(algo, vec, n, ov, seconds, label))
    res: dict[str, Any] = {
        "env_id": ENV_ID,
        "seconds_per_config": seconds,
        "torch_threads": int(threads),
        "machine": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "stable_baselines3": stable_baselines3.__version__,
            "cpu_count": __import__("os").cpu_count(),
            "load_avg": list(__import__("os").getloadavg()),
        },
        "rows": rows,
    }
    ppo = {r["label"]: r["env_steps_per_s"] for r in rows if r["algo"] == "ppo"}
    base = ppo["DummyVecEnv(8), shipped"]
    fast = {r["n_envs"]: r["env_steps_per_s"] for r in rows if r["algo"] == "ppo" and r["label"].endswith("fast")}
    fast2 = {r["n_envs"]: r["env_steps_per_s"] for r in rows if r["label"].endswith("2 epochs")}
    best_n = max(fast, key=lambda k: fast[k])
    sac = {r["label"]: r["env_steps_per_s"] for r in rows if r["algo"] == "sac"}
    sac_fast = {r["n_envs"]: r["env_steps_per_s"] for r in rows if r["algo"] == "sac" and r["vec"] == "native"}
    res["ratios"] = {
        "ppo_native8_shipped_vs_dummy8": ppo["native(8), shipped"] / base,
        "ppo_subproc2_vs_dummy8": ppo["SubprocVecEnv(2), shipped"] / base,
        "ppo_best_fast_n": best_n,
        "ppo_best_fast_vs_dummy8": fast[best_n] / base,
        **{f"ppo_native{n}_fast_vs_dummy8": v / base for n, v in fast.items()},
        **{f"ppo_native{n}_fast_2epochs_vs_dummy8": v / base for n, v in fast2.items()},
        "sac_best_many_envs_vs_dummy1": max(sac_fast.values()) / sac["DummyVecEnv(1), shipped"],
    }
    large = {r["label"]: r["env_steps_per_s"] for r in rows if r["label"].endswith("large-N settings")}
    large_base = large.pop("DummyVecEnv(8), large-N settings")
    large_n = {int(k.split("(")[1].split(")")[0]): v for k, v in large.items()}
    best_large = max(large_n, key=lambda k: large_n[k])
    res["ratios"]["ppo_large_n_settings_best_n"] = best_large
    res["ratios"]["ppo_large_n_settings_best_vs_dummy8_same_settings"] = large_n[best_large] / large_base
    res["goal"] = {"ppo_best_fast_vs_dummy8": 10.0, "met": res["ratios"]["ppo_best_fast_vs_dummy8"] >= 10.0,
                   "met_same_settings": res["ratios"]["ppo_large_n_settings_best_vs_dummy8_same_settings"] >= 10.0}
    return res


def markdown(res: dict[str, Any]) -> str:
    lines = [
        f"Training throughput on {res['env_id']} (torch threads {res['torch_threads']}, "
        f"about {res['seconds_per_config']:g} s per configuration, load average at the end "
        f"{', '.join(f'{x:.1f}' for x in res['machine']['load_avg'])})",
        "",
        "| algo | VecEnv | envs | settings | env-steps/s | x DummyVecEnv | collection share |",
        "|---|---|---:|---|---:|---:|---:|",
    ]
    base = {r["algo"]: r["env_steps_per_s"] for r in res["rows"] if r["vec"] == "dummy" and "large-N" not in r["label"]}
    large_base = next((r["env_steps_per_s"] for r in res["rows"] if r["label"] == "DummyVecEnv(8), large-N settings"),
                      None)
    for r in res["rows"]:
        hp = r["hyperparams"]
        if r["algo"] == "ppo":
            s = f"n_steps {hp['n_steps']}, batch {hp['batch_size']}, epochs {hp['n_epochs']}"
            share = f"{r['collect_share']:.0%}"
        else:
            s = (f"batch {hp['batch_size']}, train_freq {hp['train_freq']}, gradient_steps {hp['gradient_steps']}"
                 f" (replay ratio {r['replay_ratio']:g})")
            share = ""
        ref = large_base if "large-N" in r["label"] and large_base else base[r["algo"]]
        if "large-N" in r["label"]:
            s += " (large-N settings; x the DummyVecEnv(8) row with the same settings)"
        lines.append(
            f"| {r['algo']} | {r['vec']} | {r['n_envs']} | {s} | {r['env_steps_per_s']:,.0f} | "
            f"{r['env_steps_per_s'] / ref:.1f} | {share} |"
        )
    ra = res["ratios"]
    lines += [
        "",
        f"PPO, best N ({ra['ppo_best_fast_n']}) of the fast settings against DummyVecEnv(8) shipped: "
        f"{ra['ppo_best_fast_vs_dummy8']:.1f}x (goal 10x: {'met' if res['goal']['met'] else 'not met'}); "
        f"native(8) with the shipped settings: {ra['ppo_native8_shipped_vs_dummy8']:.1f}x; "
        f"SAC with many envs against DummyVecEnv(1): {ra['sac_best_many_envs_vs_dummy1']:.1f}x.",
        "",
        "PPO with the same large-N settings for both (batch 4096, 5 epochs): "
        f"native({ra['ppo_large_n_settings_best_n']}) against DummyVecEnv(8) "
        f"{ra['ppo_large_n_settings_best_vs_dummy8_same_settings']:.1f}x "
        f"(goal 10x: {'met' if res['goal']['met_same_settings'] else 'not met'}).",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from valve_env.outputs import DEFAULT_OUT_DIR, OutputError, OutputSet

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", default=str(DEFAULT_OUT_DIR / "train_throughput.json"), metavar="OUT.json")
    p.add_argument("--md", default=str(DEFAULT_OUT_DIR / "train_throughput.md"), metavar="OUT.md")
    p.add_argument("--seconds", type=float, default=20.0, help="timed learning per configuration (default 20)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--quick", action="store_true", help="fewer N and 3 s per configuration (a smoke run)")
    p.add_argument("--force", action="store_true", help="replace existing outputs")
    args = p.parse_args(argv)
    if args.seconds <= 0 or args.threads < 1:
        print("thermovalve: error: --seconds must be > 0 and --threads >= 1", file=sys.stderr)
        return 2
    outs = OutputSet(force=args.force)
    try:
        for path in (args.json, args.md):
            if Path(path).parent == DEFAULT_OUT_DIR:
                DEFAULT_OUT_DIR.mkdir(exist_ok=True)
        json_path = outs.add(args.json)
        md_path = outs.add(args.md)
    except OutputError as exc:
        print(f"thermovalve: error: {exc}", file=sys.stderr)
        return 2
    import valve_env  # noqa: F401

    res = run(3.0 if args.quick else args.seconds, args.threads, args.quick,
              progress=lambda m: print(f"train_throughput: {m} ...", file=sys.stderr, flush=True))
    text = markdown(res)
    print(text)
    outs.write_text(json_path, json.dumps(res, indent=2) + "\n")
    outs.write_text(md_path, text + "\n")
    outs.commit()
    print(f"train_throughput: {outs.summary()}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
