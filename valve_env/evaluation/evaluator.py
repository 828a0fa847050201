"""Score any controller (baselines and trained agents alike) on the KPIs of
docs/reference.md, section 5.

Each controller runs the same N seeded episodes: a gymnasium ``SyncVectorEnv``
of N envs wrapped in ``RecordEpisodeStatistics``, seeded ``seed, seed + 1,
..., seed + N - 1`` (SB3's ``VecEnv.seed`` convention), driven the way
stable-baselines3's ``evaluate_policy`` drives a ``VecEnv``: ``predict(obs,
state, episode_start, deterministic=True)`` on the whole batch at each step,
``episode_start`` true at the first step, ``info["kpis"]`` and the episode
return collected at each env's episode end. Every env runs exactly one
episode, so episode i has seed ``seed + i`` for every controller. The core
needs neither stable-baselines3 nor torch; ``tests/agents`` checks that SB3's
``evaluate_policy`` over ``DummyVecEnv`` of ``Monitor``-wrapped envs gives the
same returns.

The summary (:func:`evaluate`) is the docs/reference.md, section 7 JSON:
``{"env": ID, "episodes": N, "results": {name: {"return": {"mean", "std"},
"kpis": {kpi: {"mean", "std"}}}}}``; std is the population standard deviation
over the episodes (``np.std``, as ``evaluate_policy``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
from gymnasium.vector import SyncVectorEnv
from gymnasium.wrappers import RecordEpisodeStatistics

from valve_env.controllers import PredictPolicy, make_controller
from valve_env.env_registry import ALL_ENV_MODES
from valve_env.env_registry import env_config as registered_env_config
from valve_env.simulator import KPI_NAMES

DEFAULT_CONTROLLERS: tuple[str, ...] = ("self_acting", "pi", "pi_compensated")
#: the most episodes one call runs: they are stepped side by side, about 0.4 MB of env each
MAX_EPISODES = 1000

ControllerSpec = Mapping[str, PredictPolicy] | Sequence[str]


def check_env_id(env_id: str) -> None:
    if env_id not in ALL_ENV_MODES:
        raise ValueError(f"unknown env id {env_id!r}; known: {', '.join(ALL_ENV_MODES)}")


def env_config(env_id: str, env_kwargs: Mapping[str, Any] | None = None, config: Any = None) -> Any:
    """The EnvConfig that ``gym.make(env_id, config=config, **env_kwargs)`` builds (a task's
    own configuration for a task id); raises ConfigError naming a bad field."""
    return registered_env_config(env_id, config, **dict(env_kwargs or {}))


def make_env(env_id: str, env_kwargs: Mapping[str, Any] | None = None, config: Any = None) -> gym.Env:
    """``gym.make(env_id, config=config, **env_kwargs)`` with the time limit
    matched to the configured horizon (so ``info["kpis"]`` arrives at the end)."""
    check_env_id(env_id)
    kw = dict(env_kwargs or {})
    n_steps = env_config(env_id, kw, config).control.n_steps  # validates; raises ConfigError naming the field
    return gym.make(env_id, config=config, max_episode_steps=n_steps, **kw)


def parse_controller_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """``"name"`` or ``"name:key=value:key=value"`` (values parsed as YAML
    scalars), e.g. ``self_acting:setting_C=60``."""
    import yaml

    name, *parts = spec.strip().split(":")
    kwargs: dict[str, Any] = {}
    for part in parts:
        key, sep, value = part.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"bad controller spec {spec!r}: expected name:key=value")
        kwargs[key.strip()] = yaml.safe_load(value)
    if not name:
        raise ValueError(f"bad controller spec {spec!r}: empty name")
    return name, kwargs


def resolve_controllers(
    controllers: ControllerSpec, env_id: str, controller_kwargs: Mapping[str, Mapping[str, Any]] | None = None
) -> dict[str, PredictPolicy]:
    """Names (built by :func:`make_controller`) or a mapping name -> controller."""
    if isinstance(controllers, Mapping):
        out = dict(controllers)
    else:
        if isinstance(controllers, str):
            controllers = [c for c in controllers.split(",") if c]
        ckw = controller_kwargs or {}
        out = {}
        for spec in controllers:
            name, kw = parse_controller_spec(spec)
            out[spec] = make_controller(name, env_id, **{**dict(ckw.get(spec, {})), **kw})
    if not out:
        raise ValueError("no controllers to evaluate")
    for name, ctrl in out.items():
        if not callable(getattr(ctrl, "predict", None)):
            raise TypeError(f"controller {name!r} has no predict(observation, state, episode_start, deterministic)")
    return out


def bind_envs(controller: PredictPolicy, envs: Sequence[gym.Env]) -> None:
    """Give a controller that needs the true plant (``oracle``: it has ``bind_envs``) the envs it
    will control, in batch order; other controllers see only observations and are left alone."""
    bind = getattr(controller, "bind_envs", None)
    if callable(bind):
        bind(list(envs))


def run_episodes(
    controller: PredictPolicy,
    env_id: str = "ThermoValve-v0",
    episodes: int = 10,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    config: Any = None,
) -> pd.DataFrame:
    """Per-episode results of one controller: one row per episode with
    ``episode``, ``seed``, ``return`` and the KPIs (KPI_NAMES)."""
    if int(episodes) != episodes or episodes < 1:
        raise ValueError(f"episodes must be an integer >= 1, got {episodes!r}")
    if episodes > MAX_EPISODES:
        raise ValueError(f"episodes must be <= {MAX_EPISODES}, got {episodes!r}: the evaluator runs them side by side "
                         "(about 0.4 MB each); split a larger study into seed ranges")
    episodes = int(episodes)
    make_env(env_id, env_kwargs, config).close()  # fail early on a bad configuration
    vec = SyncVectorEnv([lambda: RecordEpisodeStatistics(make_env(env_id, env_kwargs, config))
                         for _ in range(episodes)])
    rows: dict[int, dict[str, float]] = {}
    try:
        bind_envs(controller, vec.envs)
        obs, _ = vec.reset(seed=[int(seed) + i for i in range(episodes)])
        state: Any = None
        episode_start = np.ones(episodes, dtype=bool)
        while len(rows) < episodes:
            actions, state = controller.predict(obs, state=state, episode_start=episode_start, deterministic=True)
            obs, _r, terminated, truncated, info = vec.step(actions)
            done = np.logical_or(terminated, truncated)
            for i in np.flatnonzero(done):
                if int(i) in rows:
                    continue
                ended = info.get("_kpis", np.zeros(episodes, bool))[i] and info.get("_episode", done)[i]
                if not ended:
                    raise RuntimeError(f"env {env_id!r} ended an episode without info['kpis'] "
                                       "(was it truncated early?)")
                rows[int(i)] = {"return": float(info["episode"]["r"][i]),
                                **{k: float(v[i]) for k, v in info["kpis"].items() if not k.startswith("_")}}
            episode_start = done
    finally:
        vec.close()
    df = pd.DataFrame([{"episode": i, "seed": int(seed) + i, **rows[i]} for i in sorted(rows)])
    return df


def _stat(x: np.ndarray) -> dict[str, float]:
    x = np.asarray(x, dtype=float)
    finite = x[np.isfinite(x)]
    if finite.size == 0:
        return {"mean": math.nan, "std": math.nan}
    return {"mean": float(np.mean(finite)), "std": float(np.std(finite))}


def kpi_columns(df: pd.DataFrame) -> list[str]:
    """The KPI columns of a per-episode table: the docs/reference.md, section 5 KPIs, then a task's own."""
    return [*KPI_NAMES, *(c for c in df.columns if c not in ("episode", "seed", "return", *KPI_NAMES))]


def summarise(per_episode: Mapping[str, pd.DataFrame], env_id: str) -> dict[str, Any]:
    """The docs/reference.md, section 7 summary from per-episode tables (a task's KPIs after the section 5 ones)."""
    n = {len(df) for df in per_episode.values()}
    results = {
        name: {"return": _stat(df["return"].to_numpy()),
               "kpis": {k: _stat(df[k].to_numpy()) for k in kpi_columns(df)}}
        for name, df in per_episode.items()
    }
    return {"env": env_id, "episodes": n.pop() if len(n) == 1 else sorted(n), "results": results}


def evaluate_detailed(
    controllers: ControllerSpec = DEFAULT_CONTROLLERS,
    env_id: str = "ThermoValve-v0",
    episodes: int = 10,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    config: Any = None,
    controller_kwargs: Mapping[str, Mapping[str, Any]] | None = None,
) -> tuple[dict[str, Any], dict[str, pd.DataFrame]]:
    """:func:`evaluate` plus the per-episode tables (name -> DataFrame)."""
    check_env_id(env_id)
    make_env(env_id, env_kwargs, config).close()
    ctrls = resolve_controllers(controllers, env_id, controller_kwargs)
    per_ep = {name: run_episodes(c, env_id, episodes, seed, env_kwargs, config) for name, c in ctrls.items()}
    return summarise(per_ep, env_id), per_ep


def evaluate(
    controllers: ControllerSpec = DEFAULT_CONTROLLERS,
    env_id: str = "ThermoValve-v0",
    episodes: int = 10,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    config: Any = None,
    controller_kwargs: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, Any]:
    """Evaluate controllers on ``episodes`` seeded episodes (seeds ``seed ..
    seed + episodes - 1``, the same for every controller).

    ``controllers``: names (``self_acting``, ``pi``, ``pi_compensated`` or a
    trained agent's name, see :func:`valve_env.controllers.make_controller`;
    ``name:key=value`` passes constructor arguments, e.g. ``self_acting:setting_C=60``)
    or a mapping name -> object with SB3's ``predict``. ``env_kwargs`` and
    ``config`` (a YAML path) select the scenario as in ``gym.make``.
    Returns the docs/reference.md, section 7 dict.
    """
    return evaluate_detailed(controllers, env_id, episodes, seed, env_kwargs, config, controller_kwargs)[0]


def rollout(
    controller: PredictPolicy,
    env_id: str = "ThermoValve-v0",
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    config: Any = None,
) -> pd.DataFrame:
    """One seeded episode, step by step (for figures). The controller sees only
    the observation; the valve's hidden state (x_mm, F_h_N) comes from ``info``
    for plotting. The episode is the evaluator's episode 0 for this seed."""
    from valve_env.envs.thermovalve import OBS_NAMES

    env = make_env(env_id, env_kwargs, config)
    names = getattr(env.unwrapped, "obs_names", OBS_NAMES)
    bind_envs(controller, [env])
    obs, _ = env.reset(seed=int(seed))
    state: Any = None
    start = np.ones(1, dtype=bool)
    dt = float(env.unwrapped.cfg.control.dt_s)  # type: ignore[attr-defined]
    rows = []
    k = 0
    done = False
    info: dict[str, Any] = {}
    while not done:
        act, state = controller.predict(obs[None, :], state=state, episode_start=start, deterministic=True)
        start = np.zeros(1, dtype=bool)
        obs, r, term, trunc, info = env.step(np.asarray(act)[0])
        k += 1
        done = bool(term or trunc)
        rows.append(
            {"t_h": k * dt / 3600.0, **{n: float(v) for n, v in zip(names, obs, strict=True)}, "reward": float(r),
             "x_mm": float(info["x_mm"]), "F_h_N": float(info["F_h_N"])}
        )
    env.close()
    df = pd.DataFrame(rows)
    df.attrs["kpis"] = dict(info.get("kpis", {}))
    return df


# -- reporting ---------------------------------------------------------------
TABLE_COLUMNS: tuple[str, ...] = ("return", *KPI_NAMES)


def summary_frame(summary: Mapping[str, Any]) -> pd.DataFrame:
    """Wide table: one row per controller, ``<metric>_mean`` and ``<metric>_std`` columns."""
    rows = []
    for name, res in summary["results"].items():
        row: dict[str, Any] = {"controller": name}
        for m in ("return", *res["kpis"]):
            st = res["return"] if m == "return" else res["kpis"][m]
            row[f"{m}_mean"] = st["mean"]
            row[f"{m}_std"] = st["std"]
        rows.append(row)
    return pd.DataFrame(rows)


def _fmt(mean: float, std: float) -> str:
    if not math.isfinite(mean):
        return "n/a"
    a = abs(mean)
    if a >= 100:
        digits = 0
    elif a >= 1:
        digits = 2
    else:  # three significant digits for small values (at least three decimals)
        digits = 3 if a == 0 else min(6, max(3, 2 - math.floor(math.log10(a))))
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def markdown_table(summary: Mapping[str, Any]) -> str:
    """A markdown table: controllers as rows, return and KPIs as ``mean ± std``."""
    first = next(iter(summary["results"].values()))
    kpis = list(first["kpis"])
    head = "| controller | " + " | ".join(("return", *kpis)) + " |"
    sep = "|---|" + "---:|" * (1 + len(kpis))
    lines = [head, sep]
    for name, res in summary["results"].items():
        cells = [_fmt(res["return"]["mean"], res["return"]["std"])]
        cells += [_fmt(res["kpis"][k]["mean"], res["kpis"][k]["std"]) for k in kpis]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


#: the files :func:`write_outputs` writes (the PNG of trajectories only with trajectories)
OUTPUT_FILES: tuple[str, ...] = ("table.md", "results.csv", "episodes.csv", "tradeoff.png", "trajectories.png")


def write_outputs(
    summary: Mapping[str, Any],
    per_episode: Mapping[str, pd.DataFrame],
    out_dir: str | Path,
    trajectories: Mapping[str, pd.DataFrame] | None = None,
    env_cfg: Any = None,
) -> dict[str, Path]:
    """Write ``table.md``, ``results.csv`` (summary), ``episodes.csv`` (per
    episode) and, with ``trajectories``, ``trajectories.png`` and
    ``tradeoff.png`` into ``out_dir`` (:data:`OUTPUT_FILES`); returns name -> path. Commands stage
    ``out_dir`` in an :class:`valve_env.outputs.OutputSet` (``stage_dir``) so the files appear together."""
    from valve_env.evaluation.figures import plot_tradeoff, plot_trajectories

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output directory {str(out)!r} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    paths = {"table": out / "table.md", "summary_csv": out / "results.csv", "episodes_csv": out / "episodes.csv"}
    paths["table"].write_text(
        f"{summary['env']}, {summary['episodes']} seeded episodes per controller (mean ± std)\n\n"
        + markdown_table(summary)
    )
    summary_frame(summary).to_csv(paths["summary_csv"], index=False)
    pd.concat([df.assign(controller=name) for name, df in per_episode.items()], ignore_index=True).to_csv(
        paths["episodes_csv"], index=False
    )
    paths["tradeoff_png"] = plot_tradeoff(summary, out / "tradeoff.png")
    if trajectories:
        paths["trajectories_png"] = plot_trajectories(trajectories, out / "trajectories.png", summary["env"], env_cfg)
    return paths
