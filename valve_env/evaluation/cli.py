"""``thermovalve evaluate``, ``thermovalve demo`` and ``thermovalve tune``.

    thermovalve evaluate --env ID --controllers a,b,... --episodes N --seed S --json OUT.json
                         [--out DIR] [--config YAML] [--env-kwargs k=v ...]
    thermovalve demo [--out DIR] [--episodes N] [--seed S]
    thermovalve tune [--write] [--gains PATH]

Bad input exits with status 2 and one line on stderr. ``--json`` refuses to
replace an existing file that is not an earlier evaluation result unless
``--force`` is given.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

EXIT_BAD_INPUT = 2


class CLIError(Exception):
    """Bad input: reported as one line, exit status 2."""


def parse_env_kwargs(items: Sequence[str] | None) -> dict[str, Any]:
    """``["tapping_profile=L", "valve={F_hmax: 2.0}"]`` -> dict (values parsed as YAML)."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CLIError(f"bad --env-kwargs item {item!r}: expected key=value")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise CLIError(f"bad --env-kwargs value in {item!r}: {str(exc).splitlines()[0]}") from exc
    return out


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def write_json(summary: dict[str, Any], path: str | Path, force: bool = False) -> Path:
    """Write the SPEC JSON atomically; never replace a file that is not an
    earlier evaluation result unless ``force``."""
    p = Path(path)
    if p.is_dir():
        raise CLIError(f"--json {str(p)!r} is a directory")
    if p.exists() and not force:
        try:
            old = json.loads(p.read_text())
            ours = isinstance(old, dict) and {"env", "episodes", "results"} <= set(old)
        except (OSError, ValueError):
            ours = False
        if not ours:
            raise CLIError(f"--json {str(p)!r} exists and is not an evaluation result; use --force to replace it")
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(_json_safe(summary), fh, indent=2)
            fh.write("\n")
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


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
    out_dir: str | None,
) -> tuple[dict[str, Any], dict[str, Path]]:
    from valve_env.evaluation.evaluator import (
        env_config,
        evaluate_detailed,
        resolve_controllers,
        rollout,
        write_outputs,
    )

    ctrls = resolve_controllers(controllers, env_id)
    summary, per_ep = evaluate_detailed(ctrls, env_id, episodes, seed, env_kwargs, config)
    paths: dict[str, Path] = {}
    if out_dir is not None:
        trajs = {}
        for name, c in ctrls.items():
            df = rollout(c, env_id, seed, env_kwargs, config)
            df.attrs["seed"] = seed
            trajs[name] = df
        paths = write_outputs(summary, per_ep, out_dir, trajs, env_config(env_id, env_kwargs, config))
    return summary, paths


def _guard(fn: Any) -> Any:
    """Turn bad input into one line on stderr and exit status 2."""

    def wrapped(args: argparse.Namespace) -> int:
        from valve_env.controllers import UnknownControllerError
        from valve_env.params import ConfigError

        try:
            return int(fn(args))
        except (CLIError, ConfigError, UnknownControllerError, ValueError, TypeError, KeyError, OSError,
                ImportError) as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            print(f"thermovalve {args.command}: error: {msg}", file=sys.stderr)
            return EXIT_BAD_INPUT

    return wrapped


def cmd_evaluate(args: argparse.Namespace) -> int:
    import valve_env

    if args.env not in valve_env.ALL_ENV_IDS:
        raise CLIError(f"unknown env id {args.env!r}; known: {', '.join(valve_env.ALL_ENV_IDS)}")
    if args.episodes < 1:
        raise CLIError(f"--episodes must be >= 1, got {args.episodes}")
    names = [c.strip() for c in args.controllers.split(",") if c.strip()] if args.controllers else None
    names = names or _default_controllers(args.env)
    env_kwargs = parse_env_kwargs(args.env_kwargs)
    if args.json is not None and Path(args.json).is_dir():
        raise CLIError(f"--json {args.json!r} is a directory")
    t0 = time.perf_counter()
    summary, paths = _run_evaluation(args.env, names, args.episodes, args.seed, env_kwargs, args.config, args.out)
    from valve_env.evaluation.evaluator import markdown_table

    print(f"{args.env}: {args.episodes} episodes per controller, seeds {args.seed}..{args.seed + args.episodes - 1}"
          f" ({time.perf_counter() - t0:.1f} s)")
    print(markdown_table(summary))
    if args.json is not None:
        print(f"wrote {write_json(summary, args.json, force=args.force)}")
    for p in paths.values():
        print(f"wrote {p}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    env_id = "ThermoValve-v0"
    names = ["self_acting", "pi", "pi_compensated"]
    t0 = time.perf_counter()
    print(f"Simulating one day ({env_id}, seed {args.seed}) and evaluating the baselines on {args.episodes} "
          f"seeded days each ...")
    summary, paths = _run_evaluation(env_id, names, args.episodes, args.seed, {}, None, args.out)
    paths["json"] = write_json(summary, Path(args.out) / "results.json", force=True)
    from valve_env.evaluation.evaluator import markdown_table

    print()
    print(f"{env_id}, default scenario (EU tapping cycle M, stochastic), {args.episodes} episodes, "
          f"seeds {args.seed}..{args.seed + args.episodes - 1}, mean ± std:")
    print()
    print(markdown_table(summary))
    for p in paths.values():
        print(f"wrote {p}")
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


def cmd_tune(args: argparse.Namespace) -> int:
    from valve_env.controllers.tuning import GAINS_PATH, tune, write_gains

    table = tune()
    for env_id, entry in table.items():
        m, g = entry["model"], entry["pi"]
        print(f"{env_id}: {m['kind']} K={m['K']:.4g} tau_s={m['tau_s']} theta_s={m['theta_s']:.3g} "
              f"-> Kp={g['Kp']:.4g} Ti_s={g['Ti_s']:.4g} (tau_c_s={g['tau_c_s']:.4g})")
    if args.write:
        print(f"wrote {write_gains(table, args.gains or GAINS_PATH)}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "evaluate", help="score controllers on the SPEC section 5 KPIs over seeded episodes",
        description="Run N seeded episodes per controller (the same seeds for all) and report each KPI's mean "
                    "and std and the return; writes the SPEC section 7 JSON, a markdown table, CSVs and figures.",
    )
    p.add_argument("--env", default="ThermoValve-v0", help="env id (default ThermoValve-v0)")
    p.add_argument("--controllers", default=None,
                   help="comma-separated names: self_acting, pi, pi_compensated, pi_wear, knocker, "
                        "constant_reinforcement, two_move, oracle (MPC bound: slow), trained agents (ppo, sac, ...); "
                        "name:key=value passes options, e.g. self_acting:setting_C=60 (default: the baselines "
                        "that support the env, without the oracle)")
    p.add_argument("--episodes", type=int, default=10, help="episodes per controller (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seed of episode 0; episode i uses seed + i (default 0)")
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the SPEC section 7 JSON here")
    p.add_argument("--out", default=None, metavar="DIR", help="also write table.md, CSVs and figures into DIR")
    p.add_argument("--config", default=None, metavar="YAML", help="env configuration file (configs/*.yaml)")
    p.add_argument("--env-kwargs", nargs="*", default=None, metavar="K=V",
                   help="env overrides, e.g. tapping_profile=L supply_C=60 'valve={F_hmax: 2.0}'")
    p.add_argument("--force", action="store_true", help="replace --json even if it is not an evaluation result")
    p.set_defaults(func=_guard(cmd_evaluate))

    d = subparsers.add_parser(
        "demo", help="simulate a day, evaluate the baselines, write the table and figures",
        description="Simulates one day per baseline, evaluates self_acting (set at the target), "
                    "pi and pi_compensated on seeded days of the default scenario, prints the table "
                    "and writes table.md, results.csv, episodes.csv, results.json, trajectories.png, tradeoff.png.",
    )
    d.add_argument("--out", default="out/demo", metavar="DIR", help="output directory (default out/demo)")
    d.add_argument("--episodes", type=int, default=10, help="episodes per controller (default 10)")
    d.add_argument("--seed", type=int, default=0, help="seed of episode 0 (default 0)")
    d.set_defaults(func=_guard(cmd_demo))

    t = subparsers.add_parser(
        "tune", help="re-run the PI tuning procedure (step test, FOPDT/IPDT fit, SIMC)",
        description="Runs valve_env.controllers.tuning.tune() and prints the gains; --write stores them.",
    )
    t.add_argument("--write", action="store_true", help="write the gains to configs/controllers.yaml (or --gains)")
    t.add_argument("--gains", default=None, metavar="PATH", help="gains file to write")
    t.set_defaults(func=_guard(cmd_tune))
