"""Training throughput: env-steps per second of SB3 ``learn`` (collection plus updates).

    python benchmarks/train_throughput.py [--json out/train_throughput.json] [--md out/train_throughput.md]
                                          [--seconds 20] [--threads 1] [--quick] [--force]
    python benchmarks/train_throughput.py --tasks current [--seconds 10] ...   # the current tasks only
    python benchmarks/train_throughput.py --tasks current --cem ...           # and their CEM training
    python benchmarks/train_throughput.py --tasks current --cem --no-ppo ...  # their CEM training only

Measures in one run, with the training stack of configs/<algo>.yml (residual PI action, physical
observation scaling, frame stack 4, energy shaping, VecNormalize; agents.wrappers.make_vec_env).
Every PPO comparison that is claimed runs the SAME PPO settings on both sides (samples per
update = n_steps x N, minibatch, epochs, network, learning rate...): only the VecEnv and N differ.

PPO on ThermoValve-v0 ("v0")
  * ``DummyVecEnv(8)``, ``SubprocVecEnv(2)`` and the native VecEnv (agents.vec_env) at N = 8 with the
    shipped hyperparameters of configs/ppo.yml (n_steps 1024, batch 1024, 5 epochs, 64x64 networks);
  * the large-N settings, for DummyVecEnv(8) and the native VecEnv at N = 256 and 1024 alike: the
    shipped ones except ``n_steps = clip(65536 / N, 32, 8192)`` (64k samples per update) and batch 4096;
  * native(1024) with torch's own tanh kernel (``activation_fn: torch_tanh``), to show what the
    faster kernel of agents/activations.py (``tanh``, the default) is worth;
  * native(1024) with 2 epochs instead of 5: reported, not claimed (fewer epochs learn less per sample).

PPO on ThermoValveStickyValve-v0 ("sticky")
  * the training configuration of configs/sweeps/sticky_ppo.yml (configs/ppo.yml's sticky block with
    the grid file's ``set:``: 32768 samples per update, batch 4096, 5 epochs, the linear action head
    and the 64x64 value net) for DummyVecEnv(8) (n_steps 4096) and the native VecEnv at N = 256,
    512 and 1024 (n_steps 32768 / N): the configuration PPO's own updates are trained with here.

SAC (off-policy, many envs)
  * ``DummyVecEnv(1)`` with configs/sac.yml (train_freq 4, 1 gradient step of 256: 64 replayed
    samples per env step);
  * the native VecEnv at N = 64 and 256 with batch 1024, ``train_freq = max(1, 128 / N)`` steps
    and ``gradient_steps = max(1, N / 128)``: 8 replayed samples per env step (UTD 1/128). A
    replay ratio of 64 at N = 256 would be 16 gradient steps of 1024 per env step of 256
    transitions: the updates, not the envs, would set the pace at any N. Not the same settings.

The current benchmark tasks (``--tasks current``: valve_env.CURRENT_TASK_IDS; or ``--tasks A,B``)
  * each task's training configuration of configs/ppo.yml (its residual base law, observation aids,
    frame stack, shaping and PPO settings: batch 4096, 10 epochs, the linear action head and the
    64x64 value net; PPO's own updates, ``optimizer: sgd``) at 4096 samples per update (the
    configs' own 32 x 2880 would make each measurement minutes long on a shared machine),
    DummyVecEnv(8) (n_steps 512) against the native VecEnv at N = 32 and 256 (n_steps 4096 / N),
    everything else the same; DummyVecEnv(8) measured first and again last for each task, the ratio
    over the mean of the two.

  * ``--cem``: the configuration every current task's shipped agent is trained with (``optimizer:
    cem``, agents/cem.py): one CEM generation's population evaluation, popsize x episodes whole days
    of the configuration each shipped CEM agent was trained with (agents/zoo/<task>/<name>.yml, its
    ``cem:`` block; candidates mu + sigma eps, mu = 0; configs/ppo.yml's block for a task without
    one), with its residual base law, observation aids and frame stack and the linear heads applied
    at once (agents.cem.BatchedLinearPolicies.returns, as ``cem_train`` calls it), on the native
    batched env (``gym.make_vec(..., vectorization_mode="vector_entry_point")``, all popsize x
    episodes envs in one) against the same evaluation on gymnasium's ``SyncVectorEnv`` over 8
    single envs (``vectorization_mode="sync"``: the same features, residual and heads on 8 rows at a
    time, whole days of 8 candidate-episodes in turn). No update is in the loop (CEM refits a mean
    and a spread: microseconds) and the search ranks the true return, so the configs'
    ``energy_shaping`` takes no part. SyncVectorEnv(8) is measured before and after the native
    generation (whole chunks of 8 days for about ``--seconds``, the first chunk a warm-up), the
    ratio over the mean of the two.

The two DummyVecEnv(8) references of the claimed comparisons run again at the end of the run;
the ratios use the mean of the two measurements (the machine is shared: both are reported, their
difference shows how much the load drifted). Each configuration is built, warmed up (one PPO
rollout and update; SAC's learning_starts plus a few updates; numba and torch compiled and
allocated), then ``learn`` runs on for about ``--seconds`` (whole rollouts) and the rate is the
env-steps it added over its wall time. For PPO the time inside rollout collection is reported
beside it (callbacks at rollout start and end), the rest is the update. torch runs on ``--threads``
threads (default 1, as ``thermovalve train``) for every configuration. Quote ratios from one run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ENV_ID = "ThermoValve-v0"
STICKY_ID = "ThermoValveStickyValve-v0"
STICKY_GRID = Path(__file__).resolve().parent.parent / "configs" / "sweeps" / "sticky_ppo.yml"
PPO_LARGE_N: tuple[int, ...] = (256, 1024)
STICKY_N: tuple[int, ...] = (256, 512, 1024)
SAC_FAST_N: tuple[int, ...] = (64, 256)
FAST_ROLLOUT = 65536
FAST_BATCH = 4096
STICKY_ROLLOUT = 32768
SAC_BATCH = 1024
SAC_REPLAY_RATIO = 8  # samples drawn from the buffer per env step


def large_n_overrides(n: int) -> list[str]:
    """The large-N PPO settings on ThermoValve-v0, the same for every VecEnv: the shipped ones
    (5 epochs, 64x64 networks) with 64k samples per update, n_steps = clip(65536 / N, 32, 8192),
    and minibatch 4096."""
    n_steps = int(np.clip(FAST_ROLLOUT // n, 32, 8192))
    return [f"hyperparams.n_steps={n_steps}", f"hyperparams.batch_size={FAST_BATCH}", "hyperparams.n_epochs=5"]


def sticky_overrides(n: int) -> list[str]:
    """configs/sweeps/sticky_ppo.yml's ``set:`` (the training configuration of PPO on the sticky
    task) at N envs with 32768 samples per update; desync only moves the first episode's end and
    is left out, so that both VecEnvs run the same configuration."""
    import yaml

    from agents.sweep import _yaml_value

    fixed = dict(yaml.safe_load(STICKY_GRID.read_text())[STICKY_ID]["set"])
    fixed.pop("desync", None)
    fixed.update({"n_envs": n, "hyperparams.n_steps": STICKY_ROLLOUT // n})
    return [f"{k}={_yaml_value(v)}" for k, v in fixed.items()]


def fast_sac_overrides(n: int) -> list[str]:
    train_freq = max(1, (SAC_BATCH // SAC_REPLAY_RATIO) // n)
    gradient_steps = max(1, n // (SAC_BATCH // SAC_REPLAY_RATIO))
    return [
        f"hyperparams.batch_size={SAC_BATCH}",
        f"hyperparams.train_freq={train_freq}",
        f"hyperparams.gradient_steps={gradient_steps}",
        "hyperparams.learning_starts=2048",
    ]


TASK_ROLLOUT = 4096  # samples per update on both sides (the configs' 92160 would take minutes per measurement here)
TASK_N: tuple[int, ...] = (32, 256)


def task_overrides(n: int) -> list[str]:
    """A current task's configs/ppo.yml block as PPO trains it (optimizer sgd) at TASK_ROLLOUT samples per
    update: n_steps = TASK_ROLLOUT / N; batch, epochs, network as the block has them."""
    return ["optimizer=sgd", f"hyperparams.n_steps={TASK_ROLLOUT // n}"]


def run_tasks(tasks: list[str], seconds: float, threads: int, quick: bool, progress: Any = None) -> dict[str, Any]:
    """Per task: DummyVecEnv(8), native(N) for N in TASK_N, DummyVecEnv(8) again; the ratios."""
    import stable_baselines3
    import torch

    torch.set_num_threads(int(threads))
    load_start = list(os.getloadavg())
    rows = []
    for task in tasks:
        plan = [("dummy", 8, "DummyVecEnv(8)")] + [("native", n, f"native({n})")
                                                    for n in (TASK_N[:1] if quick else TASK_N)]
        plan.append(("dummy", 8, "DummyVecEnv(8) (again)"))
        for vec, n, label in plan:
            if progress:
                progress(f"ppo {task} {label}")
            rows.append(measure("ppo", vec, n, task_overrides(n), seconds, label, task, task))
    ratios_ = {}
    for task in tasks:
        refs = [r["env_steps_per_s"] for r in rows if r["group"] == task and r["vec"] == "dummy"]
        nat = {r["n_envs"]: r["env_steps_per_s"] for r in rows if r["group"] == task and r["vec"] == "native"}
        best = max(nat, key=lambda k: nat[k])
        ref = float(np.mean(refs))
        ratios_[task] = {"dummy8_measurements": refs, "dummy8_mean": ref, "best_n": best,
                         "best_vs_dummy8": nat[best] / ref, **{f"native{n}_vs_dummy8": v / ref for n, v in nat.items()}}
    return {"seconds_per_config": seconds, "torch_threads": int(threads),
            "machine": {"python": platform.python_version(), "torch": torch.__version__,
                        "stable_baselines3": stable_baselines3.__version__, "cpu_count": os.cpu_count(),
                        "load_avg": list(os.getloadavg()), "load_avg_start": load_start, "nice": os.nice(0)},
            "rows": rows, "ratios": ratios_,
            "goal": {"native_vs_dummy8": 10.0, "met": {t: r["best_vs_dummy8"] >= 10.0 for t, r in ratios_.items()}}}


def cem_chunks(popsize: int, episodes: int, width: int = 8) -> list[tuple[slice, slice]]:
    """One CEM generation's (candidate rows, seed columns) cut into blocks of ``width`` envs, in the
    population's row order (candidate-major), for a reference VecEnv of ``width`` envs."""
    if episodes % width == 0:
        return [(slice(c, c + 1), slice(j, j + width)) for c in range(popsize) for j in range(0, episodes, width)]
    if width % episodes == 0 and popsize % (width // episodes) == 0:
        k = width // episodes
        return [(slice(c, c + k), slice(0, episodes)) for c in range(0, popsize, k)]
    raise ValueError(f"cem: {popsize} x {episodes} episodes cannot be cut into blocks of {width} envs")


def measure_cem(task: str, cfg: dict[str, Any], mode: str, seconds: float, label: str) -> dict[str, Any]:
    """Env-steps per second of a CEM generation's population evaluation (module docstring, ``--cem``)."""
    import gymnasium as gym

    from agents.cem import CEM_DEFAULTS, BatchedLinearPolicies

    opt = {**CEM_DEFAULTS, **dict(cfg.get("cem") or {})}
    P, E = int(opt["popsize"]), int(opt["episodes"])
    seeds = list(range(E))
    native = mode == "native"
    n = P * E if native else 8
    pols = BatchedLinearPolicies(task, cfg, n, vectorization_mode="vector_entry_point" if native else "sync")
    theta = float(opt["sigma"]) * np.random.default_rng(0).standard_normal((P, pols.n_params))
    theta[0] = 0.0
    single = gym.make(task, **dict(cfg.get("env_kwargs") or {}))
    ep_len = int(single.unwrapped.cfg.control.n_steps)  # type: ignore[attr-defined]
    single.close()
    chunks = [(slice(0, P), slice(0, E))] if native else cem_chunks(P, E)
    steps, wall, done = 0, 0.0, 0
    while done < 2 or wall < seconds:  # the first block (a whole generation on native) is the warm-up
        cs, js = chunks[done % len(chunks)]
        t0 = time.perf_counter()
        pols.returns(theta[cs], seeds[js])
        dt = time.perf_counter() - t0
        if done:
            steps += (cs.stop - cs.start) * (js.stop - js.start) * ep_len
            wall += dt
        done += 1
    pols.close()
    return {"label": label, "group": task, "env_id": task, "algo": "cem", "vec": mode, "n_envs": n,
            "env_steps": int(steps), "wall_s": round(wall, 3), "env_steps_per_s": steps / wall,
            "chunks": done, "popsize": P, "episodes": E, "frame_stack": int(cfg.get("frame_stack", 1) or 1),
            "obs_aids": sorted(cfg.get("obs_aids") or {}), "residual": dict(cfg["residual"]),
            "n_params": int(pols.n_params)}


def cem_configs(task: str) -> list[tuple[str, dict[str, Any]]]:
    """(name, resolved config) of each shipped agent of ``task`` trained by CEM (agents/zoo/<task>/<name>.yml,
    the configuration it was trained with); the task's configs/ppo.yml block if none is."""
    from agents.cem import yaml_load
    from agents.loader import ZOO_DIR, available_agents
    from agents.train import load_algo_config

    out = []
    for name in available_agents(task):
        cfg = yaml_load(Path(ZOO_DIR) / task / f"{name}.yml")
        if cfg.get("optimizer") == "cem":
            out.append((name, cfg))
    return out or [("configs/ppo.yml", load_algo_config("ppo", task))]


def run_cem(tasks: list[str], seconds: float, progress: Any = None) -> dict[str, Any]:
    """Per shipped CEM agent's configuration: SyncVectorEnv(8), native(popsize x episodes), SyncVectorEnv(8) again."""
    load_start = list(os.getloadavg())
    rows = []
    for task in tasks:
        for name, cfg in cem_configs(task):
            group = f"{task} {name}"
            for mode, label in (("sync", "SyncVectorEnv(8)"), ("native", "native"),
                                ("sync", "SyncVectorEnv(8) (again)")):
                if progress:
                    progress(f"cem {group} {label}")
                rows.append({**measure_cem(task, cfg, mode, seconds, label), "group": group, "agent": name})
    ratios_ = {}
    for group in dict.fromkeys(r["group"] for r in rows):
        refs = [r["env_steps_per_s"] for r in rows if r["group"] == group and r["vec"] == "sync"]
        nat = next(r for r in rows if r["group"] == group and r["vec"] == "native")
        ref = float(np.mean(refs))
        ratios_[group] = {"sync8_measurements": refs, "sync8_mean": ref, "native_n": nat["n_envs"],
                          "native_vs_sync8": nat["env_steps_per_s"] / ref}
    return {"seconds_per_config": seconds, "load_avg_start": load_start, "load_avg": list(os.getloadavg()),
            "rows": rows, "ratios": ratios_,
            "goal": {"native_vs_sync8": 10.0, "met": {t: r["native_vs_sync8"] >= 10.0 for t, r in ratios_.items()}}}


def _loads(xs: list[float]) -> str:
    """A load average (1, 5, 15 min) as the tables print it."""
    return ", ".join(f"{x:.1f}" for x in xs)


def markdown_cem(res: dict[str, Any]) -> str:
    lines = [f"CEM training (optimizer: cem, each shipped agent's resolved config: one generation's population "
             f"evaluation; about "
             f"{res['seconds_per_config']:g} s per reference measurement; load average at the start "
             f"{_loads(res['load_avg_start'])}, at the end "
             f"{_loads(res['load_avg'])})", "",
             "| task | agent | VecEnv | N | popsize x episodes | base law, aids, frames | env-steps/s "
             "| x SyncVectorEnv(8) |",
             "|---|---|---|---:|---|---|---:|---:|"]
    for r in res["rows"]:
        ref = res["ratios"][r["group"]]["sync8_mean"]
        law = ", ".join(f"{k} {v}" for k, v in r["residual"].items())
        lines.append(f"| {r['env_id']} | {r['agent']} | {r['vec']} | {r['n_envs']} | {r['popsize']} x "
                     f"{r['episodes']} | {law}; aids "
                     f"{r['obs_aids'] or 'none'}; {r['frame_stack']} frames | {r['env_steps_per_s']:,.0f} | "
                     f"{r['env_steps_per_s'] / ref:.1f} |")
    lines.append("")
    for t, x in res["ratios"].items():
        lines.append(f"* {t}: CEM native({x['native_n']}) {x['native_vs_sync8']:.1f}x SyncVectorEnv(8) (its two "
                     f"measurements {', '.join(f'{v:,.0f}' for v in x['sync8_measurements'])} env-steps/s; goal 10x: "
                     f"{'met' if x['native_vs_sync8'] >= 10 else 'not met'}).")
    return "\n".join(lines)


def markdown_tasks(res: dict[str, Any]) -> str:
    m = res["machine"]
    lines = [f"Training throughput on the current tasks' training configurations (PPO, configs/ppo.yml, "
             f"{TASK_ROLLOUT} samples per update; torch threads {res['torch_threads']}, about "
             f"{res['seconds_per_config']:g} s per configuration, nice {m['nice']}; load average at the start "
             f"{_loads(m['load_avg_start'])}, at the end "
             f"{_loads(m['load_avg'])})", "",
             "| task | VecEnv | N | settings | env-steps/s | x DummyVecEnv(8) | collection share |",
             "|---|---|---:|---|---:|---:|---:|"]
    for r in res["rows"]:
        ref = res["ratios"][r["group"]]["dummy8_mean"]
        lines.append(f"| {r['env_id']} | {r['vec']} | {r['n_envs']} | {_settings(r)} | {r['env_steps_per_s']:,.0f} | "
                     f"{r['env_steps_per_s'] / ref:.1f} | {r['collect_share']:.0%} |")
    lines.append("")
    for t, x in res["ratios"].items():
        lines.append(f"* {t}: native({x['best_n']}) {x['best_vs_dummy8']:.1f}x DummyVecEnv(8) (its two measurements "
                     f"{', '.join(f'{v:,.0f}' for v in x['dummy8_measurements'])} env-steps/s; goal 10x: "
                     f"{'met' if x['best_vs_dummy8'] >= 10 else 'not met'}).")
    return "\n".join(lines)


def measure(algo: str, vec: str, n: int, overrides: list[str], seconds: float, label: str,
            env_id: str = ENV_ID, group: str = "") -> dict[str, Any]:
    """Build, warm up and time one configuration; see the module docstring."""
    from stable_baselines3.common.callbacks import BaseCallback

    from agents.train import algo_class, apply_overrides, build_model_kwargs, load_algo_config
    from agents.wrappers import make_vec_env

    cfg = apply_overrides(load_algo_config(algo, env_id), overrides)
    hp = cfg["hyperparams"]
    venv = make_vec_env(env_id, cfg, seed=0, n_envs=n, vec=vec, training=True)
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
    pk = hp.get("policy_kwargs") or {}
    row: dict[str, Any] = {
        "label": label,
        "group": group,
        "env_id": env_id,
        "algo": algo,
        "vec": vec,
        "n_envs": n,
        "env_steps": int(steps),
        "wall_s": round(wall, 3),
        "env_steps_per_s": steps / wall,
        "hyperparams": {k: hp[k] for k in sorted(hp) if k != "policy_kwargs"},
        "network": {"net_arch": pk.get("net_arch"), "activation_fn": pk.get("activation_fn", "tanh")},
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
    load_start = list(os.getloadavg())
    plan: list[tuple[str, str, int, list[str], str, str, str]] = [
        ("ppo", "dummy", 8, [], "DummyVecEnv(8), shipped", ENV_ID, "v0 shipped"),
        ("ppo", "subproc", 2, [], "SubprocVecEnv(2), shipped", ENV_ID, "v0 shipped"),
        ("ppo", "native", 8, [], "native(8), shipped", ENV_ID, "v0 shipped"),
        ("ppo", "dummy", 8, large_n_overrides(8), "DummyVecEnv(8), large-N", ENV_ID, "v0 large-N"),
    ]
    for n in (PPO_LARGE_N[:1] if quick else PPO_LARGE_N):
        plan.append(("ppo", "native", n, large_n_overrides(n), f"native({n}), large-N", ENV_ID, "v0 large-N"))
    n_top = PPO_LARGE_N[-1]
    if not quick:
        torch_tanh = "hyperparams.policy_kwargs.activation_fn=torch_tanh"
        plan.append(("ppo", "native", n_top, [*large_n_overrides(n_top), torch_tanh],
                     f"native({n_top}), large-N, torch's tanh kernel", ENV_ID, "v0 variants"))
        plan.append(("ppo", "native", n_top, [*large_n_overrides(n_top)[:-1], "hyperparams.n_epochs=2"],
                     f"native({n_top}), large-N but 2 epochs", ENV_ID, "v0 variants"))
    plan.append(("ppo", "dummy", 8, sticky_overrides(8), "DummyVecEnv(8), sticky config", STICKY_ID,
                 "sticky config"))
    for n in (STICKY_N[1:2] if quick else STICKY_N):
        plan.append(("ppo", "native", n, sticky_overrides(n), f"native({n}), sticky config", STICKY_ID,
                     "sticky config"))
    plan.append(("sac", "dummy", 1, [], "DummyVecEnv(1), shipped", ENV_ID, "sac"))
    for n in (SAC_FAST_N[:1] if quick else SAC_FAST_N):
        plan.append(("sac", "native", n, fast_sac_overrides(n), f"native({n}), many envs", ENV_ID, "sac"))
    # the claimed comparisons' references again, at the end (load drift)
    plan.append(("ppo", "dummy", 8, large_n_overrides(8), "DummyVecEnv(8), large-N (again)", ENV_ID, "v0 large-N"))
    plan.append(("ppo", "dummy", 8, sticky_overrides(8), "DummyVecEnv(8), sticky config (again)", STICKY_ID,
                 "sticky config"))
    rows = []
    for algo, vec, n, ov, label, env_id, group in plan:
        if progress:
            progress(f"{algo} {label}")
        rows.append(measure(algo, vec, n, ov, seconds, label, env_id, group))
    res: dict[str, Any] = {
        "seconds_per_config": seconds,
        "torch_threads": int(threads),
        "machine": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "stable_baselines3": stable_baselines3.__version__,
            "cpu_count": os.cpu_count(),
            "load_avg": list(os.getloadavg()),
            "load_avg_start": load_start,
            "nice": os.nice(0),
        },
        "rows": rows,
    }
    res["ratios"] = ratios(rows)
    res["goal"] = {"ppo_same_settings_vs_dummy8": 10.0,
                   "met_v0_large_n": res["ratios"]["v0 large-N"]["best_vs_dummy8"] >= 10.0,
                   "met_sticky_config": res["ratios"]["sticky config"]["best_vs_dummy8"] >= 10.0}
    return res


def ratios(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per PPO comparison group: each native row over the group's DummyVecEnv(8) reference (the mean of
    its measurements), the best N; and the rows that are not same-settings comparisons."""
    out: dict[str, Any] = {}
    for group in ("v0 large-N", "sticky config"):
        refs = [r["env_steps_per_s"] for r in rows if r["group"] == group and r["vec"] == "dummy"]
        ref = float(np.mean(refs))
        nat = {r["n_envs"]: r["env_steps_per_s"] for r in rows if r["group"] == group and r["vec"] == "native"}
        best = max(nat, key=lambda k: nat[k])
        out[group] = {"dummy8_measurements": refs, "dummy8_mean": ref, "best_n": best,
                      "best_vs_dummy8": nat[best] / ref, **{f"native{n}_vs_dummy8": v / ref for n, v in nat.items()}}
    by = {r["label"]: r["env_steps_per_s"] for r in rows}
    ref = out["v0 large-N"]["dummy8_mean"]
    shipped = by["DummyVecEnv(8), shipped"]
    out["not same settings"] = {
        "native8_shipped_vs_dummy8_shipped": by["native(8), shipped"] / shipped,
        "subproc2_shipped_vs_dummy8_shipped": by["SubprocVecEnv(2), shipped"] / shipped,
        **{f"{k} vs DummyVecEnv(8) large-N": v / ref for k, v in by.items() if "torch's tanh" in k or "2 epochs" in k},
    }
    sac = {r["vec"]: r["env_steps_per_s"] for r in rows if r["algo"] == "sac" and r["vec"] == "dummy"}
    sac_fast = [r["env_steps_per_s"] for r in rows if r["algo"] == "sac" and r["vec"] == "native"]
    out["sac_best_many_envs_vs_dummy1"] = max(sac_fast) / sac["dummy"]
    return out


def _settings(r: dict[str, Any]) -> str:
    hp, net = r["hyperparams"], r["network"]
    if r["algo"] == "ppo":
        arch = net["net_arch"]
        arch_s = (f"pi {arch.get('pi')}, vf {arch.get('vf')}" if isinstance(arch, dict) else f"pi = vf = {arch}")
        return (f"n_steps {hp['n_steps']} (x N = {r['rollout']} per update), batch {hp['batch_size']}, epochs "
                f"{hp['n_epochs']}, lr {hp['learning_rate']}, {arch_s}, {net['activation_fn']}")
    return (f"batch {hp['batch_size']}, train_freq {hp['train_freq']}, gradient_steps {hp['gradient_steps']}"
            f" (replay ratio {r['replay_ratio']:g})")


def markdown(res: dict[str, Any]) -> str:
    m = res["machine"]
    lines = [
        f"Training throughput (torch threads {res['torch_threads']}, about {res['seconds_per_config']:g} s per "
        f"configuration, nice {m['nice']}; load average at the start "
        f"{_loads(m['load_avg_start'])}, "
        f"at the end {_loads(m['load_avg'])})",
        "",
        "| group | env | algo | VecEnv | N | settings | env-steps/s | x reference | collection share |",
        "|---|---|---|---|---:|---|---:|---:|---:|",
    ]
    ra = res["ratios"]
    shipped = next(r["env_steps_per_s"] for r in res["rows"] if r["label"] == "DummyVecEnv(8), shipped")
    sac_ref = next(r["env_steps_per_s"] for r in res["rows"] if r["algo"] == "sac" and r["vec"] == "dummy")
    for r in res["rows"]:
        g = r["group"]
        ref = (ra[g]["dummy8_mean"] if g in ("v0 large-N", "sticky config") else ra["v0 large-N"]["dummy8_mean"]
               if g == "v0 variants" else sac_ref if r["algo"] == "sac" else shipped)
        share = f"{r['collect_share']:.0%}" if r["algo"] == "ppo" else ""
        lines.append(f"| {g} | {r['env_id'].replace('ThermoValve', '').replace('-v0', '') or 'v0'} | {r['algo']} | "
                     f"{r['vec']} | {r['n_envs']} | {_settings(r)} | {r['env_steps_per_s']:,.0f} | "
                     f"{r['env_steps_per_s'] / ref:.1f} | {share} |")
    lines += ["", "x reference: over the DummyVecEnv row of the same group (v0 large-N, sticky config: the mean of "
              "its two measurements; v0 variants: over v0 large-N's)."]
    for g, what in (("v0 large-N", "ThermoValve-v0, the large-N settings"),
                    ("sticky config", "ThermoValveStickyValve-v0, the sticky training configuration")):
        x = ra[g]
        lines.append(
            f"* PPO, same settings on both sides, {what}: native({x['best_n']}) {x['best_vs_dummy8']:.1f}x "
            f"DummyVecEnv(8) (its two measurements {', '.join(f'{v:,.0f}' for v in x['dummy8_measurements'])} "
            f"env-steps/s; goal 10x: {'met' if x['best_vs_dummy8'] >= 10 else 'not met'}).")
    ns = ra["not same settings"]
    lines += [
        f"* Not the same settings, not claimed: native(8) shipped {ns['native8_shipped_vs_dummy8_shipped']:.1f}x "
        f"DummyVecEnv(8) shipped; SubprocVecEnv(2) {ns['subproc2_shipped_vs_dummy8_shipped']:.1f}x; "
        + "; ".join(f"{k} {v:.1f}x" for k, v in ns.items() if " vs " in k)
        + f"; SAC with many envs against DummyVecEnv(1): {ra['sac_best_many_envs_vs_dummy1']:.1f}x.",
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
    p.add_argument("--tasks", default=None, metavar="current|A,B",
                   help="only the benchmark tasks' training configurations (current: valve_env.CURRENT_TASK_IDS)")
    p.add_argument("--cem", action="store_true",
                   help="with --tasks: also their CEM training (optimizer: cem), native against SyncVectorEnv(8)")
    p.add_argument("--no-ppo", action="store_true", help="with --tasks --cem: the CEM measurement only")
    args = p.parse_args(argv)
    if (args.cem or args.no_ppo) and not args.tasks or args.no_ppo and not args.cem:
        print("thermovalve: error: --cem needs --tasks, and --no-ppo needs --cem", file=sys.stderr)
        return 2
    if args.seconds <= 0 or args.threads < 1:
        print("thermovalve: error: --seconds must be > 0 and --threads >= 1", file=sys.stderr)
        return 2
    tasks: list[str] = []
    if args.tasks:
        import valve_env

        tasks = list(valve_env.CURRENT_TASK_IDS) if args.tasks == "current" else [t for t in args.tasks.split(",") if t]
        bad = [t for t in tasks if t not in valve_env.TASK_IDS]
        if bad:
            print(f"thermovalve: error: --tasks: unknown task {bad[0]!r}", file=sys.stderr)
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

    progress = lambda m: print(f"train_throughput: {m} ...", file=sys.stderr, flush=True)  # noqa: E731
    seconds = 3.0 if args.quick else args.seconds
    if tasks:
        import torch

        torch.set_num_threads(int(args.threads))
        res, parts = {}, []
        if not args.no_ppo:
            res = run_tasks(tasks, seconds, args.threads, args.quick, progress=progress)
            parts.append(markdown_tasks(res))
        if args.cem:
            res["cem"] = run_cem(tasks, seconds, progress=progress)
            parts.append(markdown_cem(res["cem"]))
        text = "\n\n".join(parts)
    else:
        res = run(seconds, args.threads, args.quick, progress=progress)
        text = markdown(res)
    print(text)
    outs.write_text(json_path, json.dumps(res, indent=2) + "\n")
    outs.write_text(md_path, text + "\n")
    outs.commit()
    print(f"train_throughput: {outs.summary()}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
