"""Train a stable-baselines3 agent on a ThermoValve environment.

    python -m agents.train --algo ppo --env ThermoValve-v0 --seed 0 [--timesteps N] [--out runs/...]
    thermovalve train --algo ppo --env ThermoValve-v0 --seed 0 --ship     # retrain + ship into agents/zoo

Hyperparameters come from ``agents/configs/<algo>.yml`` (rl-baselines3-zoo style,
keyed by env id). Every run directory holds: ``config.yml`` (the resolved
config), ``command.txt``, ``run.json`` (seed, versions, wall time),
``monitor/`` (SB3 Monitor CSVs with the episode KPIs), ``tb/`` (TensorBoard),
``model.zip`` + ``vecnormalize.pkl`` + ``obs_norm.json`` (final) and
``best/`` (the best periodic evaluation's model and statistics).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import shlex
import shutil
import sys
import time
from collections.abc import Mapping, Sequence
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

#: the algorithms with a tuned config in agents/configs/<algo>.yml (a2c has none, so it is not offered)
ALGOS: tuple[str, ...] = ("ppo", "sac", "td3")
#: the VecEnv kinds of agents.wrappers.make_vec_env (``vec_env`` in agents/configs/<algo>.yml, ``--vec``)
VEC_KINDS: tuple[str, ...] = ("native", "dummy", "subproc")
#: the packaged hyperparameter files (agents/configs/<algo>.yml), read through importlib.resources
CONFIG_DIR: Traversable = resources.files("agents") / "configs"
#: the shipped agents: a directory of the installed package (``train --ship`` writes there)
ZOO_DIR = Path(str(resources.files("agents") / "zoo"))
#: training runs go under out/ of the working directory (docs/cli.md, "Outputs")
DEFAULT_RUNS = Path("out") / "runs"


# --------------------------------------------------------------------------- config
def load_algo_config(algo: str, env_id: str, config_dir: str | Path | None = None) -> dict[str, Any]:
    """The hyperparameter block for ``env_id`` in ``agents/configs/<algo>.yml``."""
    algo = algo.lower()
    path = (Path(config_dir) if config_dir else CONFIG_DIR) / f"{algo}.yml"
    if not path.is_file():
        raise FileNotFoundError(f"no hyperparameter file {path} for algo {algo!r}")
    data = yaml.safe_load(path.read_text()) or {}
    if env_id not in data:
        raise KeyError(f"{path} has no entry for env id {env_id!r}; it has {sorted(data)}")
    cfg = copy.deepcopy(data[env_id])
    cfg.setdefault("hyperparams", {})
    return cfg


def _set_nested(cfg: dict[str, Any], dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    d = cfg
    for k in keys[:-1]:
        d = d.setdefault(k, {})
    d[keys[-1]] = value


def apply_overrides(cfg: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """``key.sub=value`` overrides (values parsed as YAML), e.g. ``hyperparams.learning_rate=1e-4``."""
    out = copy.deepcopy(cfg)
    for item in overrides:
        if "=" not in item:
            raise ValueError(f"override {item!r} must look like key=value")
        k, v = item.split("=", 1)
        _set_nested(out, k.strip(), yaml.safe_load(v))
    return out


def _number(value: Any) -> Any:
    """YAML 1.1 reads ``1e-4`` (no dot) as a string: make such strings numbers."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _schedule(value: Any) -> Any:
    """rl-zoo style ``lin_3e-4`` linear schedules; numbers pass through."""
    if isinstance(value, str) and value.startswith("lin_"):
        start = float(value[4:])

        def lin(progress_remaining: float) -> float:
            return progress_remaining * start

        return lin
    return value


def build_model_kwargs(algo: str, cfg: Mapping[str, Any], n_actions: int) -> dict[str, Any]:
    """SB3 constructor keywords from the ``hyperparams`` block (no eval of strings)."""
    import torch.nn as nn
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    hp = {k: _number(v) for k, v in copy.deepcopy(dict(cfg.get("hyperparams") or {})).items()}
    pk = {k: _number(v) for k, v in dict(hp.pop("policy_kwargs", {}) or {}).items()}
    if "activation_fn" in pk:
        from agents.activations import Tanh  # torch's tanh, through a faster CPU kernel (agents/activations.py)

        acts = {"tanh": Tanh, "torch_tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU}
        pk["activation_fn"] = acts[str(pk["activation_fn"]).lower()]
    if algo.lower() == "ppo" and "optimizer_class" not in pk and "optimizer_kwargs" not in pk:
        # SB3's own choice for PPO (Adam, eps 1e-5) run by torch's multi-tensor implementation:
        # the same update bit for bit (tests/agents/test_activations.py), 0.27 against 0.70 ms per
        # step for the task networks on one thread
        pk["optimizer_kwargs"] = {"eps": 1e-5, "foreach": True}
    if pk:
        hp["policy_kwargs"] = pk
    for key in ("learning_rate", "clip_range"):
        if key in hp:
            hp[key] = _schedule(hp[key])
    noise = hp.pop("action_noise", None)
    if noise:
        sigma = float(noise.get("sigma", 0.1)) * np.ones(n_actions)
        kind = noise.get("type", "normal")
        if kind == "normal":
            hp["action_noise"] = NormalActionNoise(np.zeros(n_actions), sigma)
        elif kind == "ornstein-uhlenbeck":
            hp["action_noise"] = OrnsteinUhlenbeckActionNoise(np.zeros(n_actions), sigma)
        else:
            raise ValueError(f"unknown action_noise type {kind!r}")
    if "train_freq" in hp and isinstance(hp["train_freq"], list):
        hp["train_freq"] = tuple(hp["train_freq"])
    return hp


def algo_class(algo: str) -> Any:
    import stable_baselines3 as sb3

    classes = {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3, "a2c": sb3.A2C}
    if algo.lower() not in classes:
        raise ValueError(f"unknown algo {algo!r}; choose from {sorted(classes)}")
    return classes[algo.lower()]


# --------------------------------------------------------------------------- statistics
def save_obs_norm(venv: Any, path: str | Path) -> None:
    """VecNormalize's observation statistics as plain JSON (what agents.loader reads)."""
    from stable_baselines3.common.vec_env import VecNormalize

    data: dict[str, Any] = {"norm_obs": False}
    if isinstance(venv, VecNormalize) and venv.norm_obs:
        rms: Any = venv.obs_rms  # a RunningMeanStd for Box observations
        data = {
            "norm_obs": True,
            "mean": np.asarray(rms.mean, dtype=np.float64).tolist(),
            "var": np.asarray(rms.var, dtype=np.float64).tolist(),
            "count": float(rms.count),
            "clip_obs": float(venv.clip_obs),
            "epsilon": float(venv.epsilon),
        }
    Path(path).write_text(json.dumps(data, indent=1))


def _versions() -> dict[str, str]:
    import gymnasium
    import stable_baselines3
    import torch

    import valve_env

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "gymnasium": gymnasium.__version__,
        "valve_env": valve_env.__version__,
    }


# --------------------------------------------------------------------------- training
def _fixed_seed_eval_callback() -> type:
    from stable_baselines3.common.callbacks import EvalCallback

    class FixedSeedEvalCallback(EvalCallback):
        """EvalCallback that re-seeds the evaluation env before every
        evaluation, so each checkpoint is scored on the same episodes and the
        kept "best" model is not just the one that met the easiest days."""

        def __init__(self, eval_seed: int, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.eval_seed = int(eval_seed)

        def _on_training_start(self) -> None:
            # score the initial policy too: with a residual action it is ~the base law,
            # so "best" can only be a checkpoint that beats it on these episodes
            n_calls = self.n_calls
            self.n_calls = 0
            self._on_step()
            self.n_calls = n_calls

        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                self.eval_env.seed(self.eval_seed)
            return super()._on_step()

    return FixedSeedEvalCallback


def train(
    algo: str,
    env_id: str,
    seed: int = 0,
    timesteps: int | None = None,
    out: str | Path | None = None,
    overrides: Sequence[str] = (),
    env_kwargs: Mapping[str, Any] | None = None,
    progress_bar: bool = True,
    eval_freq: int | None = None,
    n_threads: int = 1,
    config_dir: str | Path | None = None,
    command: str | None = None,
    verbose: int = 0,
    vec: str | None = None,
) -> Path:
    """Train one agent; returns its run directory. ``vec`` (native, dummy or
    subproc) overrides the config's ``vec_env``; the resolved config records it."""
    from valve_env.outputs import atomic_dir

    algo = algo.lower()
    cfg = apply_overrides(load_algo_config(algo, env_id, config_dir), overrides)
    if env_kwargs is not None:
        cfg["env_kwargs"] = {**(cfg.get("env_kwargs") or {}), **dict(env_kwargs)}
    cfg.setdefault("env_kwargs", {})
    if timesteps is not None:
        cfg["n_timesteps"] = int(timesteps)
    if vec is not None:
        cfg["vec_env"] = vec
    cfg["vec_env"] = str(cfg.get("vec_env", "dummy"))
    if cfg["vec_env"] not in VEC_KINDS:
        raise ValueError(f"vec_env must be one of {', '.join(VEC_KINDS)}, got {cfg['vec_env']!r}")
    n_timesteps = int(float(cfg["n_timesteps"]))
    cfg["n_timesteps"] = n_timesteps
    ev = dict(cfg.get("eval") or {})
    if eval_freq is not None:
        ev["freq"] = int(eval_freq)
    cfg["eval"] = ev

    stamp = time.strftime("%Y%m%d-%H%M%S")
    target = Path(out) if out else DEFAULT_RUNS / env_id / f"{algo}_s{seed}_{stamp}"
    # the run fills a hidden directory beside the target, which takes the target's place whole when it ends: a run
    # that fails or is interrupted leaves an earlier run there as it was, and a finished one leaves none of its files
    with atomic_dir(target) as run_dir:
        _train_into(run_dir, algo, env_id, seed, cfg, n_timesteps, ev, progress_bar, n_threads, command, verbose)
    return target


def _train_into(run_dir: Path, algo: str, env_id: str, seed: int, cfg: dict[str, Any], n_timesteps: int,
                ev: dict[str, Any], progress_bar: bool, n_threads: int, command: str | None, verbose: int) -> None:
    """:func:`train`'s run, written into ``run_dir``."""
    import torch
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.utils import set_random_seed

    from agents.wrappers import make_vec_env

    resolved = {"algo": algo, "env_id": env_id, "seed": int(seed), **cfg}
    (run_dir / "config.yml").write_text(yaml.safe_dump(resolved, sort_keys=False))
    cmd = command if command is not None else " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv])
    (run_dir / "command.txt").write_text(cmd + "\n")
    meta: dict[str, Any] = {
        "algo": algo,
        "env_id": env_id,
        "seed": int(seed),
        "n_timesteps": n_timesteps,
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "versions": _versions(),
    }
    (run_dir / "run.json").write_text(json.dumps(meta, indent=1))

    torch.set_num_threads(int(n_threads))
    set_random_seed(seed)
    if cfg.get("optimizer", "sgd") == "cem":  # policy search on the native batched env (agents.cem)
        from agents.cem import cem_train

        if algo != "ppo":
            raise ValueError("optimizer: cem is for the ppo configs (a PPO policy with a linear action head)")
        venv = make_vec_env(env_id, cfg, seed=seed, n_envs=1, training=False, vec="native")
        n_act = int(venv.action_space.shape[0])  # type: ignore[index]
        kwargs = build_model_kwargs(algo, cfg, n_act)
        kwargs["batch_size"] = kwargs.get("n_steps", 2048)  # no PPO update runs: one env, one batch
        model = algo_class(algo)(cfg.get("policy", "MlpPolicy"), venv, seed=seed, device="cpu", verbose=verbose,
                                 **kwargs)
        meta.update(cem_train(env_id, cfg, seed, run_dir, model, meta))
        meta["finished_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        (run_dir / "run.json").write_text(json.dumps(meta, indent=1))
        venv.close()
        return
    elif cfg.get("optimizer", "sgd") != "sgd":
        raise ValueError(f"optimizer must be sgd (the algo's own updates) or cem, got {cfg.get('optimizer')!r}")
    (run_dir / "monitor").mkdir(exist_ok=True)
    venv = make_vec_env(env_id, cfg, seed=seed, monitor_dir=run_dir / "monitor", training=True)
    n_actions = int(venv.action_space.shape[0])  # type: ignore[index]
    cls = algo_class(algo)
    kwargs = build_model_kwargs(algo, cfg, n_actions)
    model = cls(cfg.get("policy", "MlpPolicy"), venv, seed=seed, device="cpu", verbose=verbose, **kwargs)
    model.set_logger(configure(str(run_dir / "tb"), ["tensorboard", "csv"]))

    FixedSeedEvalCallback = _fixed_seed_eval_callback()
    callbacks: list[BaseCallback] = []
    eval_env = None
    freq = int(ev.get("freq", 0) or 0)
    if freq > 0:
        (run_dir / "best").mkdir(exist_ok=True)
        (run_dir / "eval_monitor").mkdir(exist_ok=True)
        eval_env = make_vec_env(
            env_id, cfg, seed=seed + 10_000, n_envs=1, monitor_dir=run_dir / "eval_monitor", training=False
        )

        class SaveStats(BaseCallback):
            def _on_step(self) -> bool:
                save_obs_norm(venv, run_dir / "best" / "obs_norm.json")
                if hasattr(venv, "save"):
                    venv.save(str(run_dir / "best" / "vecnormalize.pkl"))
                return True

        callbacks.append(
            FixedSeedEvalCallback(
                seed + 10_000,
                eval_env,
                callback_on_new_best=SaveStats(),
                n_eval_episodes=int(ev.get("episodes", 2)),
                eval_freq=max(1, freq // venv.num_envs),
                log_path=str(run_dir / "best"),
                best_model_save_path=str(run_dir / "best"),
                deterministic=True,
                verbose=0,
            )
        )
    t0 = time.time()
    model.learn(
        total_timesteps=n_timesteps,
        callback=CallbackList(callbacks) if callbacks else None,
        progress_bar=progress_bar,
        tb_log_name="run",
    )
    wall = time.time() - t0
    model.save(str(run_dir / "model.zip"))
    if hasattr(venv, "save"):
        venv.save(str(run_dir / "vecnormalize.pkl"))
    save_obs_norm(venv, run_dir / "obs_norm.json")
    meta.update(
        {
            "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "wall_time_s": round(wall, 1),
            "steps_per_s": round(model.num_timesteps / max(wall, 1e-9), 1),
            "num_timesteps": int(model.num_timesteps),
        }
    )
    if (run_dir / "best" / "evaluations.npz").is_file():
        d = np.load(run_dir / "best" / "evaluations.npz")
        means = d["results"].mean(axis=1)
        i = int(np.argmax(means))
        meta["best_eval"] = {"timesteps": int(d["timesteps"][i]), "mean_return": float(means[i])}
    (run_dir / "run.json").write_text(json.dumps(meta, indent=1))
    venv.close()
    if eval_env is not None:
        eval_env.close()


# --------------------------------------------------------------------------- shipping
def ship_files(algo: str) -> list[str]:
    """The files :func:`ship` writes into ``agents/zoo/<env_id>/``."""
    return [f"{algo}.zip", f"{algo}_obs_norm.json", f"{algo}.yml"]


def ship(run_dir: str | Path, zoo_dir: str | Path | None = None, use_best: bool = True,
         outs: Any = None, name: str | None = None, commit: bool = True) -> Path:
    """Copy a run's model into ``agents/zoo/<env_id>/<name>.zip`` (``name`` defaults to the
    algo) with its config (``<name>.yml``) and observation statistics
    (``<name>_obs_norm.json``), the three together and atomically (an
    :class:`valve_env.outputs.OutputSet`, replacing existing files only when it was made
    with ``force``; by default it is)."""
    from valve_env.outputs import OutputSet

    run_dir = Path(run_dir)
    cfg = yaml.safe_load((run_dir / "config.yml").read_text())
    env_id = cfg["env_id"]
    algo = name or cfg["algo"]
    src = run_dir / "best" if use_best and (run_dir / "best" / "best_model.zip").is_file() else run_dir
    model = src / ("best_model.zip" if src.name == "best" else "model.zip")
    dest = Path(zoo_dir or ZOO_DIR) / env_id
    dest.mkdir(parents=True, exist_ok=True)
    outs = outs if outs is not None else OutputSet(force=True)
    outs.stage(dest / f"{algo}.zip", lambda tmp: shutil.copyfile(model, tmp))
    outs.stage(dest / f"{algo}_obs_norm.json", lambda tmp: shutil.copyfile(src / "obs_norm.json", tmp))
    meta = json.loads((run_dir / "run.json").read_text())
    shipped = {
        **cfg,
        "shipped_from": {
            "checkpoint": "best evaluation" if src.name == "best" else "final",
            "run": meta,
            "command": (run_dir / "command.txt").read_text().strip(),
        },
    }
    from agents.cem import warm_start_chain

    if chain := warm_start_chain(cfg):  # a CEM run started from earlier models: how to rebuild them
        shipped["warm_start"] = chain
    outs.write_text(dest / f"{algo}.yml", yaml.safe_dump(shipped, sort_keys=False))
    if commit:
        outs.commit()
    return dest / f"{algo}.zip"


# --------------------------------------------------------------------------- CLI
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--algo", required=True, choices=ALGOS, help="stable-baselines3 algorithm")
    p.add_argument("--env", default="ThermoValve-v0", help="environment id (default ThermoValve-v0)")
    p.add_argument("--seed", type=int, default=0, help="training seed (>= 0)")
    p.add_argument("--timesteps", type=int, default=None, help="override n_timesteps of the config")
    p.add_argument("--out", default=None, help="run directory (default out/runs/<env>/<algo>_s<seed>_<time>)")
    p.add_argument("--config-dir", default=None,
                   help="directory of <algo>.yml files (default: the packaged agents/configs/)")
    p.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="override a config entry, e.g. --set hyperparams.learning_rate=1e-4 (repeatable)",
    )
    p.add_argument("--eval-freq", type=int, default=None, help="env steps between evaluations (0: none)")
    p.add_argument(
        "--vec", choices=VEC_KINDS, default=None,
        help="VecEnv: native (the batched kernel, agents.vec_env), dummy or subproc (SB3's, of single envs); "
        "default: the config's vec_env",
    )
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (tests, CI)")
    p.add_argument("--ship", action="store_true", help="copy the best model into agents/zoo/<env>/<algo>.* "
                   "(replacing a shipped agent needs --force)")
    p.add_argument("--name", default=None, help="shipped agent's name (default: the algo), e.g. ppo_pi")
    p.add_argument("--ship-run", default=None, metavar="RUN_DIR",
                   help="ship this finished run directory (its best checkpoint) instead of training")
    p.add_argument("--force", action="store_true", help="train into a non-empty --out; replace a shipped agent")
    p.add_argument("--verbose", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    import valve_env
    from valve_env.outputs import OutputError, OutputSet

    if args.env not in valve_env.ALL_ENV_IDS:
        raise ValueError(f"unknown env id {args.env!r}; known: {', '.join(valve_env.ALL_ENV_IDS)}")
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    if args.timesteps is not None and args.timesteps < 1:
        raise ValueError(f"--timesteps must be >= 1, got {args.timesteps}")
    if args.out is not None:
        out = Path(args.out)
        if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
            raise OutputError(f"--out {out} exists and is not empty; use --force to train into it")
    name = args.name or args.algo
    if not name.replace("_", "").isalnum():
        raise ValueError(f"--name must be letters, digits and underscores, got {name!r}")
    ship_outs = None
    if args.ship or args.ship_run:  # checked before training: a shipped agent is replaced only with --force
        ship_outs = OutputSet(force=args.force)
        ship_outs.add_in_dir(ZOO_DIR / args.env, ship_files(name), "--ship")
    if args.ship_run:
        run_cfg = Path(args.ship_run) / "config.yml"
        if not run_cfg.is_file():
            raise ValueError(f"--ship-run {args.ship_run} is not a training run directory (no config.yml)")
        got = yaml.safe_load(run_cfg.read_text())
        if (got.get("env_id"), got.get("algo")) != (args.env, args.algo):
            raise ValueError(f"--ship-run {args.ship_run} trained {got.get('algo')} on {got.get('env_id')}, "
                             f"not {args.algo} on {args.env}")
        ship(args.ship_run, outs=ship_outs, name=name)
        print(f"shipped: {ship_outs.summary()}")  # type: ignore[union-attr]
        return 0
    import stable_baselines3  # noqa: F401  (ImportError here names the extra: pip install -e '.[rl]')

    progress = not args.no_progress and os.environ.get("THERMOVALVE_NO_PROGRESS", "") == ""
    run_dir = train(
        args.algo,
        args.env,
        seed=args.seed,
        timesteps=args.timesteps,
        out=args.out,
        overrides=args.overrides,
        progress_bar=progress,
        eval_freq=args.eval_freq,
        n_threads=args.threads,
        config_dir=args.config_dir,
        verbose=args.verbose,
        vec=args.vec,
    )
    meta = json.loads((run_dir / "run.json").read_text())
    asked = int(meta.get("n_timesteps", 0))
    more = (f" (the {asked} asked for, rounded up to whole rollouts of n_envs x n_steps)"
            if meta["num_timesteps"] > asked > 0 and meta.get("optimizer") != "cem" else "")
    print(f"trained {meta['num_timesteps']} steps{more} in {meta['wall_time_s']} s ({meta['steps_per_s']} steps/s)")
    if "best_eval" in meta:
        print(f"best evaluation: return {meta['best_eval']['mean_return']:.2f} at {meta['best_eval']['timesteps']}")
    if ship_outs is not None:
        ship(run_dir, outs=ship_outs, name=name)
        print(f"shipped: {ship_outs.summary()}")
    files = sorted(str(f.relative_to(run_dir)) for f in run_dir.iterdir())
    print(f"wrote {run_dir}/ ({', '.join(files)})")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.train", description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
