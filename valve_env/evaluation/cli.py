"""``thermovalve evaluate``, ``thermovalve demo`` and ``thermovalve tune``.

    thermovalve evaluate --env ID --controllers a,b,... --episodes N --seed S --json OUT.json
                         [--out DIR] [--scenario NAME | --config YAML] [--env-kwargs k=v ...] [--force]
    thermovalve demo [--out DIR] [--episodes N] [--seed S] [--force]
    thermovalve tune [--write] [--gains PATH] [--force]

Bad input raises; the shared handler (valve_env.cli) prints one line and exits 2. Every
file goes through one OutputSet: checked before the evaluation, replaced only with
--force, written atomically and together.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from valve_env.cliutil import UsageError, add_force
from valve_env.outputs import json_text

#: gym.make keywords that the command sets itself
RESERVED_ENV_KWARGS: dict[str, str] = {
    "config": "give the file with --config",
    "task_id": "give the id with --env",
    "max_episode_steps": "the episode length follows control.horizon_h (e.g. horizon_h=48)",
    "render_mode": "the evaluator does not render",
}


def parse_env_kwargs(items: Sequence[str] | None) -> dict[str, Any]:
    """``["tapping_profile=L", "valve={F_hmax: 2.0}"]`` -> dict (values parsed as YAML)."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"bad --env-kwargs item {item!r}: expected key=value")
        if key.strip() in RESERVED_ENV_KWARGS:
            raise UsageError(f"--env-kwargs {key.strip()}=...: {RESERVED_ENV_KWARGS[key.strip()]}")
        if key.strip() in out:
            raise UsageError(f"--env-kwargs {key.strip()} is given twice")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise UsageError(f"bad --env-kwargs value in {item!r}: {str(exc).splitlines()[0]}") from exc
    return out


def check_episodes(episodes: int) -> None:
    """``--episodes`` within 1 .. MAX_EPISODES (checked before any output is declared)."""
    from valve_env.evaluation.evaluator import MAX_EPISODES

    if episodes < 1:
        raise UsageError(f"--episodes must be >= 1, got {episodes}")
    if episodes > MAX_EPISODES:
        raise UsageError(f"--episodes must be <= {MAX_EPISODES}, got {episodes} (the episodes run side by side, "
                         "about 0.4 MB each)")


def _default_controllers(env_id: str) -> list[str]:
    from valve_env.controllers import BASELINES, original_id

    return [n for n, cls in BASELINES.items() if original_id(env_id) in cls.supported_env_ids]


def _run_evaluation(
    env_id: str,
    controllers: list[str],
    episodes: int,
    seed: int,
    env_kwargs: dict[str, Any],
    config: str | None,
    out_dir: Path | None,
) -> tuple[dict[str, Any], dict[str, Path]]:
    """Evaluate; with ``out_dir`` (a staging directory) also write the tables and figures there."""
    from valve_env.cliutil import progress_bar
    from valve_env.evaluation.evaluator import (
        check_env_id,
        env_config,
        make_env,
        resolve_controllers,
        rollout,
        run_episodes,
        summarise,
        write_outputs,
    )

    check_env_id(env_id)
    make_env(env_id, env_kwargs, config).close()  # a bad config fails here, before any episode
    ctrls = resolve_controllers(controllers, env_id)
    bar = progress_bar(len(ctrls) * (2 if out_dir is not None else 1), desc="evaluate", unit="controller")
    try:
        per_ep = {}
        for name, c in ctrls.items():
            bar.set_postfix_str(name)
            per_ep[name] = run_episodes(c, env_id, episodes, seed, env_kwargs, config)
            bar.update(1)
        summary = summarise(per_ep, env_id)
        paths: dict[str, Path] = {}
        trajs = {}
        if out_dir is not None:
            for name, c in ctrls.items():
                bar.set_postfix_str(f"{name} trajectory")
                df = rollout(c, env_id, seed, env_kwargs, config)
                df.attrs["seed"] = seed
                trajs[name] = df
                bar.update(1)
    finally:
        bar.close()
    if out_dir is not None:
        paths = write_outputs(summary, per_ep, out_dir, trajs, env_config(env_id, env_kwargs, config))
    return summary, paths


def _scenario_kwargs(args: argparse.Namespace, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``--scenario NAME`` from the one registry (valve_env.evaluation.scenarios), under --env-kwargs."""
    if getattr(args, "scenario", None) is None:
        return env_kwargs
    from valve_env.evaluation.scenarios import episode_env_kwargs, is_randomised

    if is_randomised(args.scenario):
        raise UsageError(f"--scenario {args.scenario} changes per episode; use thermovalve leaderboard")
    if args.config is not None:
        raise UsageError("give --scenario or --config, not both")
    return {**episode_env_kwargs(args.scenario, 0), **env_kwargs}


def cmd_evaluate(args: argparse.Namespace) -> int:
    from valve_env.env_registry import ALL_ENV_MODES
    from valve_env.evaluation.evaluator import OUTPUT_FILES, markdown_table
    from valve_env.outputs import OutputSet

    if args.env not in ALL_ENV_MODES:
        raise UsageError(f"unknown env id {args.env!r}; known: {', '.join(ALL_ENV_MODES)}")
    check_episodes(args.episodes)
    if args.seed < 0:
        raise UsageError(f"--seed must be a non-negative integer, got {args.seed}")
    names = [c.strip() for c in args.controllers.split(",") if c.strip()] if args.controllers else None
    names = names or _default_controllers(args.env)
    env_kwargs = _scenario_kwargs(args, parse_env_kwargs(args.env_kwargs))
    outs = OutputSet(inputs=[args.config], force=args.force)
    json_out = outs.add(args.json, "--json") if args.json is not None else None
    out_dir = Path(args.out) if args.out is not None else None
    if out_dir is not None:
        outs.add_in_dir(out_dir, OUTPUT_FILES, "--out")
    t0 = time.perf_counter()
    with outs:
        summary, _ = _run_evaluation(args.env, names, args.episodes, args.seed, env_kwargs, args.config,
                                     outs.stage_dir(out_dir) if out_dir is not None else None)
        if json_out is not None:
            outs.write_text(json_out, json_text(summary))
    print(f"{args.env}: {args.episodes} episodes per controller, seeds {args.seed}..{args.seed + args.episodes - 1}"
          f" ({time.perf_counter() - t0:.1f} s)")
    print(markdown_table(summary))
    print(outs.summary())
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from valve_env.evaluation.evaluator import OUTPUT_FILES, markdown_table
    from valve_env.outputs import OutputSet

    env_id = "ThermoValve-v0"
    names = ["self_acting", "pi", "pi_compensated"]
    check_episodes(args.episodes)
    if args.seed < 0:
        raise UsageError(f"--seed must be a non-negative integer, got {args.seed}")
    out_dir = Path(args.out)
    outs = OutputSet(force=args.force)
    outs.add_in_dir(out_dir, [*OUTPUT_FILES, "results.json"], "--out")
    t0 = time.perf_counter()
    print(f"Simulating one day ({env_id}, seed {args.seed}) and evaluating the baselines on {args.episodes} "
          f"seeded days each ...")
    with outs:
        staged = outs.stage_dir(out_dir)
        summary, _ = _run_evaluation(env_id, names, args.episodes, args.seed, {}, None, staged)
        (staged / "results.json").write_text(json_text(summary))
    print()
    print(f"{env_id}, default scenario (EU tapping cycle M, stochastic), {args.episodes} episodes, "
          f"seeds {args.seed}..{args.seed + args.episodes - 1}, mean ± std:")
    print()
    print(markdown_table(summary))
    print(outs.summary())
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


def cmd_tune(args: argparse.Namespace) -> int:
    from valve_env.controllers.tuning import GAINS_PATH, gains_yaml, stored_gains, tune
    from valve_env.outputs import OutputSet

    outs = OutputSet(force=args.force)
    gains = outs.add(args.gains or str(GAINS_PATH), "--gains") if args.write else None
    table = tune()
    for env_id, entry in table.items():
        m, g = entry["model"], entry["pi"]
        print(f"{env_id}: {m['kind']} K={m['K']:.4g} tau_s={m['tau_s']} theta_s={m['theta_s']:.3g} "
              f"-> Kp={g['Kp']:.4g} Ti_s={g['Ti_s']:.4g} (tau_c_s={g['tau_c_s']:.4g})")
    if gains is not None:
        with outs:
            outs.write_text(gains, gains_yaml(table, stored_gains(gains)))
    print(outs.summary())
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "evaluate", help="score controllers on the docs/reference.md, section 5 KPIs over seeded episodes",
        description="Run N seeded episodes per controller (the same seeds for all) and report each KPI's mean "
                    "and std and the return; writes the JSON (docs/reference.md s. 7), tables and figures.",
    )
    p.add_argument("--env", default="ThermoValve-v0", help="env id (default ThermoValve-v0)")
    p.add_argument("--controllers", default=None,
                   help="comma-separated names: self_acting, pi, pi_compensated, pi_wear, knocker, "
                        "constant_reinforcement, two_move, two_move_position, pi_integral_band, pi_stiction_tuned, "
                        "oracle (MPC bound: slow), trained agents (ppo, sac, ...), a training run directory "
                        "given as a path (out/runs/tiny_ppo, ./run: what thermovalve train --out writes); "
                        "name:key=value passes options, e.g. self_acting:setting_C=60 (default: the baselines "
                        "that support the env, without the oracle)")
    p.add_argument("--episodes", type=int, default=10, help="episodes per controller (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seed of episode 0; episode i uses seed + i (default 0)")
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the docs/reference.md, section 7 JSON here")
    p.add_argument("--out", default=None, metavar="DIR", help="also write table.md, CSVs and figures into DIR")
    p.add_argument("--config", default=None, metavar="YAML",
                   help="env configuration file, or a packaged scenario's name (valve_env/data/scenarios/NAME.yaml)")
    p.add_argument("--scenario", default=None, metavar="NAME",
                   help="a named scenario of the one registry (valve_env.evaluation.scenarios, "
                        "valve_env/data/scenarios/NAME.yaml)")
    p.add_argument("--env-kwargs", nargs="*", default=None, metavar="K=V",
                   help="env overrides, e.g. tapping_profile=L supply_C=60 'valve={F_hmax: 2.0}'")
    add_force(p)
    p.set_defaults(func=cmd_evaluate)

    d = subparsers.add_parser(
        "demo", help="simulate a day, evaluate the baselines, write the table and figures",
        description="Simulates one day per baseline, evaluates self_acting (set at the target), "
                    "pi and pi_compensated on seeded days of the default scenario, prints the table "
                    "and writes table.md, results.csv, episodes.csv, results.json, trajectories.png, tradeoff.png.",
    )
    d.add_argument("--out", default="out/demo", metavar="DIR", help="output directory (default out/demo)")
    d.add_argument("--episodes", type=int, default=10, help="episodes per controller (default 10)")
    d.add_argument("--seed", type=int, default=0, help="seed of episode 0 (default 0)")
    add_force(d)
    d.set_defaults(func=cmd_demo)

    t = subparsers.add_parser(
        "tune", help="re-run the PI tuning procedure (step test, FOPDT/IPDT fit, SIMC)",
        description="Runs valve_env.controllers.tuning.tune() and prints the gains; --write stores them.",
    )
    t.add_argument("--write", action="store_true",
                   help="write the gains to valve_env/data/controllers.yaml (or --gains)")
    t.add_argument("--gains", default=None, metavar="PATH", help="gains file to write (default with --write: "
                   "valve_env/data/controllers.yaml, the tracked file, replaced only with --force)")
    add_force(t)
    t.set_defaults(func=cmd_tune)
