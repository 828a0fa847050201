"""A causal estimate on ThermoValveSmallCylinder-v0: the oracle's MPC without foresight of the draws
(docs/history/smallcylinder_causal_bound.md).

    python studies/smallcylinder_causal.py run --seed 48000 --episodes 20 --futures 8 --out out/habit_k8.csv
    python studies/smallcylinder_causal.py run ... --base-law ppo       # the plan on the agents' PI + feedforward
    python studies/smallcylinder_causal.py run ... --controller ppo_pi --trace out/trace_ppo_pi.csv
    python studies/smallcylinder_causal.py table --episodes out/tl48000/task_episodes.csv \
        --episodes out/benchmark_oracle48000/episodes.csv habit_k8=out/habit_k8.csv

The oracle (:mod:`valve_env.controllers.oracle`) plans on exact copies of the plant loaded with the
day's *whole* scenario, so it knows when today's bath starts. :class:`HabitMPC` is the same
controller (the same true plant state, the same CEM planner and settings) scored on ``futures``
sampled days instead of the true one:

* draws whose start lies before the time of the plan are kept as they are (their start, flow,
  temperature and energy: what a perfect state estimate of the draws so far would give);
* every draw not yet started is drawn afresh from the scenario's own distribution
  (:func:`valve_env.scenario.make_scenario`: the tabled cycle's start plus a Gaussian jitter of
  ``draw_jitter_min``, the tabled energy times a lognormal factor of ``draw_energy_cv``), the start
  conditioned on "not yet" (a normal truncated below at the plan's time, above at the day's end),
  from a generator independent of the day's (seeded by ``future_seed``, the day's seed and the step);
* one action sequence maximises the mean return over the futures (every candidate is scored on the
  same futures, which are kept over the plan's CEM iterations);
* it replans every ``replan_steps`` as the oracle does, and also at the first step after a draw has
  started (``replan_on_draw``): its plan was scored on futures in which that draw had not started,
  and waiting up to ``replan_steps`` to see it costs a feedback controller the draw's first minutes
  (the oracle, which foresaw it, needs no such replan).

What it knows that a real controller does not: the plant's true state (tank layers, bulb, stem and
friction) and, for a draw under way, its remaining energy. What it does not know: when, and how
large, the draws still to come are. It is not the causal optimum: a plan re-optimised every few
steps over sampled futures approximates the stochastic optimum (an open-loop plan per sample path
set, not a policy), and the CEM planner is approximate.

With ``true_future=True`` (and any ``futures``) every future is the true day, and the controller is
the oracle step for step (the check that the machinery is the oracle's).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pandas as pd
from gymnasium.utils import seeding
from scipy import stats

from valve_env.controllers.oracle import Oracle
from valve_env.scenario import Draws, ScenarioParams, draw_columns, sample_draws, tapping_cycle

TASK = "ThermoValveSmallCylinder-v0"
ENV_ID = "ThermoValveSmallCylinder-v0"


# ----------------------------------------------------------------------------------- the day's draws
def scenario_columns(draws: Draws, n_steps: int, dt_s: float) -> np.ndarray:
    """The scenario's first three columns (draw_W, draw_T_C, draw_mmax) from ``draws``, as make_scenario computes
    them (:func:`valve_env.scenario.draw_columns`)."""
    return np.stack(draw_columns(draws, n_steps, dt_s), axis=1)


def day_draws(cfg: Any, seed: int) -> Draws:
    """The draws of the day the env of configuration ``cfg`` samples at ``reset(seed=seed)``."""
    rng, _ = seeding.np_random(int(seed))
    return sample_draws(cfg.scenario, rng, cfg.control.n_steps, cfg.control.dt_s, cfg.tank.T_cold, cfg.tank.cp)


def resample_future(draws: Draws, params: ScenarioParams, t_now_s: float, horizon_s: float,
                    rng: np.random.Generator) -> Draws:
    """``draws`` with every draw not started by ``t_now_s`` drawn afresh: its start from the tabled start
    plus the jitter, conditioned on [t_now_s, horizon_s) (a truncated normal), its energy from the tabled
    energy times a fresh lognormal factor. Draws that started before ``t_now_s`` are kept."""
    todo = draws.start_s >= t_now_s
    if not todo.any():
        return draws
    start = draws.start_s.copy()
    energy = draws.energy_J.copy()
    mu = draws.tabled_s[todo]
    n = int(todo.sum())
    sd = params.draw_jitter_min * 60.0 if params.stochastic_draws else 0.0
    if sd > 0:
        a = (t_now_s - mu) / sd
        b = (horizon_s - mu) / sd
        start[todo] = stats.truncnorm.rvs(a, b, loc=mu, scale=sd, size=n, random_state=rng)
    else:
        start[todo] = mu
    cyc = tapping_cycle(params.tapping_profile)
    q_tab = np.tile(cyc["Qtap_kWh"].to_numpy(dtype=float) * 3.6e6, draws.start_s.size // len(cyc))[todo]
    if params.stochastic_draws and params.draw_energy_cv > 0:
        s2 = np.log1p(params.draw_energy_cv**2)
        energy[todo] = q_tab * rng.lognormal(-0.5 * s2, np.sqrt(s2), size=n)
    else:
        energy[todo] = q_tab
    return replace(draws, start_s=start, energy_J=energy)


# ----------------------------------------------------------------------------------- the controller
class HabitMPC(Oracle):
    """The oracle's MPC scored on ``futures`` sampled days (module docstring). ``future_seed`` seeds the
    sampler of the futures; ``true_future=True`` makes every future the true day (the oracle)."""

    name: ClassVar[str] = "habit_mpc"

    def __init__(self, env_id: str = ENV_ID, futures: int = 8, future_seed: int = 1, true_future: bool = False,
                 replan_on_draw: bool = True, base_law: str | None = None, event_iterations: int | None = None,
                 **settings: Any) -> None:
        super().__init__(env_id, **settings)
        #: CEM iterations of a plan made because a draw has started (None: ``iterations``): the plan must
        #: then move far from the warm start (open the valve for a draw the last plan did not expect)
        self.event_iterations = event_iterations
        self._event = False
        #: the law the plan perturbs: the oracle's PI (None), or a shipped agent's residual base law
        #: (``"ppo"``: the PI with the draw feedforward, ``ppo_base_law``), whose feedforward reacts in
        #: every sampled future to that future's draws
        self.base_law = base_law
        self._residual: Any = None
        if base_law is not None:
            from valve_env.controllers import make_controller

            self._residual = make_controller(base_law, env_id).residual
            if self._residual is None or self.act_dim != 1:
                raise ValueError(f"{base_law!r} has no residual base law on a one-action task")
        if int(futures) != futures or futures < 1:
            raise ValueError(f"futures must be an integer >= 1, got {futures!r}")
        self.futures = int(futures)
        self.future_seed = int(future_seed)
        self.true_future = bool(true_future)
        self.replan_on_draw = bool(replan_on_draw)
        self._started_at_plan: dict[int, int] = {}
        self.event_plans = 0
        self._days: dict[tuple[int, int], Draws] = {}
        self._plan_futures: tuple[tuple[int, int, int], list[Any]] | None = None

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        mem = super().initial_state(obs)
        if self._residual is not None:
            mem[:, : self._n_pi] = 0.0  # the residual law's integrator starts at 0 (as the agent's)
        return mem

    def _base_action(self, obs: np.ndarray, pi_mem: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The oracle's (the PI's output plus the plan), or with ``base_law`` the agent's residual law
        with the plan as its residual (in units of the setting; its span bounds it)."""
        if self._residual is None:
            return super()._base_action(obs, pi_mem, delta)
        u, pi_mem[:, :1] = self._residual.step(obs, delta / self._residual.span, pi_mem[:, :1])
        return u

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "base_law": self.base_law, "futures": self.futures,
                "future_seed": self.future_seed, "event_iterations": self.event_iterations,
                "true_future": self.true_future, "replan_on_draw": self.replan_on_draw}

    def _simulator(self, core: Any) -> Any:
        key = self._keys.get(id(core))
        if key is None:
            key = self._keys[id(core)] = _key(core)
        vec: Any = self._sims.get(key)
        if vec is None:
            vec = self._sims[key] = gym.make_vec(
                self.env_id, num_envs=int(self.settings.samples) * self.futures,
                vectorization_mode="vector_entry_point", config=core.cfg)
            vec.reset(seed=int(self.settings.seed))
            space = vec.single_action_space
            self._lo = np.asarray(space.low, np.float64)
            self._hi = np.asarray(space.high, np.float64)
        return vec

    def bind_envs(self, envs: Any) -> HabitMPC:
        super().bind_envs(envs)
        self._keys = {id(c): _key(c) for c in self._envs}
        return self

    def _true_draws(self, core: Any, st: Any) -> Draws:
        seed = core.np_random_seed
        key = (id(core), int(seed))
        d = self._days.get(key)
        if d is None:
            cfg = core.cfg
            d = day_draws(cfg, seed)
            cols = scenario_columns(d, cfg.control.n_steps, cfg.control.dt_s)
            if not np.array_equal(cols, st.scenario[:, :3]):
                raise RuntimeError(f"the draws rebuilt from seed {seed} are not the env's: "
                                   "valve_env.scenario.make_scenario and sample_draws differ")
            self._days[key] = d
        return d

    def futures_of(self, core: Any, st: Any) -> list[Any]:
        """The snapshots (``st`` with a sampled scenario) the plan from ``st`` is scored on."""
        seed = int(core.np_random_seed)
        tag = (id(core), seed, int(st.k))
        if self._plan_futures is not None and self._plan_futures[0] == tag:
            return self._plan_futures[1]
        if self.true_future:
            out = [st] * self.futures
        else:
            cfg = core.cfg
            n, dt = cfg.control.n_steps, cfg.control.dt_s
            truth = self._true_draws(core, st)
            rng = np.random.default_rng([self.future_seed, seed, int(st.k)])
            out = []
            for _ in range(self.futures):
                d = resample_future(truth, cfg.scenario, int(st.k) * dt, n * dt, rng)
                scen = st.scenario.copy()
                scen[:, :3] = scenario_columns(d, n, dt)
                out.append(replace(st, scenario=scen))
        self._plan_futures = (tag, out)
        return out

    def _replan_due(self, core: Any, st: Any, age: float) -> bool:
        """The oracle's reasons to replan, and one more: a draw has started since the last plan (the plan was scored
        on futures in which it had not; the oracle, which knows it, needs none)."""
        started = self._started(core, st)
        new_draw = started != self._started_at_plan.get(id(core), started)
        due = super()._replan_due(core, st, age)
        if new_draw and not due:
            self.event_plans += 1
        if due or new_draw:
            self._event = bool(new_draw)
            self._started_at_plan[id(core)] = started
        return due or new_draw

    def plan(self, core: Any, st: Any, obs: np.ndarray, pi_mem: np.ndarray, prev: np.ndarray) -> np.ndarray:
        self._core = core  # whose futures _rollout scores the candidates on
        event, self._event = self._event, False
        if not (event and self.event_iterations):
            return super().plan(core, st, obs, pi_mem, prev)
        kept = self.settings
        self.settings = replace(kept, iterations=int(self.event_iterations))
        try:
            return super().plan(core, st, obs, pi_mem, prev)
        finally:
            self.settings = kept

    def _started(self, core: Any, st: Any) -> int:
        """How many of the day's draws have started by the snapshot's time."""
        if self.true_future or not self.replan_on_draw:
            return 0
        return int((self._true_draws(core, st).start_s < int(st.k) * core.cfg.control.dt_s).sum())

    def _rollout(self, vec: Any, st: Any, obs: np.ndarray, pi_mem: np.ndarray, seqs: np.ndarray,
                 h_eff: int) -> np.ndarray:
        n, K = seqs.shape[0], self.futures
        for m, fut in enumerate(self.futures_of(self._core, st)):
            vec.set_state(fut, envs=slice(m * n, (m + 1) * n), rng=False)
        mem = np.repeat(pi_mem[None, :], n * K, axis=0)
        o = np.repeat(np.asarray(obs, np.float64)[None, :], n * K, axis=0)
        s_all = np.tile(seqs, (K, 1, 1))
        ret = np.zeros(n * K)
        for t in range(h_eff):
            a = self._base_action(o, mem, s_all[:, t])
            o, r = vec.plan_step(a)
            o = o.astype(np.float64)
            ret += r
        self.sim_steps += h_eff * K
        return ret.reshape(K, n).mean(axis=0)


def _key(core: Any) -> tuple[str, type]:
    return repr(core.cfg), type(core)


# ----------------------------------------------------------------------------------- the table
def gap_closed(cost: np.ndarray, base: np.ndarray, oracle: np.ndarray) -> float:
    """(base - X) / (base - oracle) on the mean costs over the days."""
    b, o = float(np.mean(base)), float(np.mean(oracle))
    return (b - float(np.mean(cost))) / (b - o)


def gap_interval(cost: np.ndarray, base: np.ndarray, oracle: np.ndarray, seed: int = 0,
                 n_resamples: int = 9999) -> tuple[float, float]:
    """A paired bootstrap 95 % interval of :func:`gap_closed` over the days (scipy.stats.bootstrap, BCa:
    the three costs of a day resampled together)."""
    res = stats.bootstrap((np.asarray(cost), np.asarray(base), np.asarray(oracle)),
                          lambda c, b, o, axis=-1: (b.mean(axis) - c.mean(axis)) / (b.mean(axis) - o.mean(axis)),
                          paired=True, vectorized=True, n_resamples=n_resamples, confidence_level=0.95,
                          random_state=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def table(per_episode: dict[str, pd.DataFrame], baselines: list[str], agents: list[str]) -> tuple[str, str]:
    """Markdown: one row per controller (cost and tdis_Kh), then the gap closed by each agent."""
    seeds = None
    for name, df in per_episode.items():
        s = df["seed"].to_numpy()
        if seeds is None:
            seeds = s
        elif not np.array_equal(np.sort(s), np.sort(seeds)):
            raise ValueError(f"{name}: other seeds than the first controller's (paired days needed)")
    cost = {name: (-df.sort_values("seed")["return"]).to_numpy() for name, df in per_episode.items()}
    best = min(baselines, key=lambda b: cost[b].mean())
    rows = ["| controller | cost (mean) | sd | tdis_Kh | iae_Kh | heat_kWh |", "|---|---:|---:|---:|---:|---:|"]
    for name in sorted(per_episode, key=lambda n: cost[n].mean()):
        df = per_episode[name]
        rows.append(f"| {name} | {cost[name].mean():.1f} | {cost[name].std():.1f} | {df['tdis_Kh'].mean():.3f} "
                    f"| {df['iae_Kh'].mean():.2f} | {df['heat_kWh'].mean():.2f} |")
    gap = [f"Best non-agent baseline: {best} ({cost[best].mean():.1f}); oracle {cost['oracle'].mean():.1f}.", "",
           "| controller | cost | gap closed | 95 % CI (paired bootstrap over days) | days better than the baseline |",
           "|---|---:|---:|---|---:|"]
    for a in agents:
        g = gap_closed(cost[a], cost[best], cost["oracle"])
        lo, hi = gap_interval(cost[a], cost[best], cost["oracle"])
        wins = int((cost[a] < cost[best]).sum())
        gap.append(f"| {a} | {cost[a].mean():.1f} | {100 * g:.1f} % | {100 * lo:.1f} % .. {100 * hi:.1f} % "
                   f"| {wins}/{len(cost[a])} |")
    return "\n".join(rows), "\n".join(gap)


def bath_starts(seed: int) -> tuple[float, float]:
    """The clock hours at which the day ``seed``'s two baths (the cycle's 10 l/min draws) begin."""
    from valve_env.evaluation.evaluator import env_config

    d = day_draws(env_config(ENV_ID), seed)
    big = d.f_kgs >= d.f_kgs.max() - 1e-12
    morning, evening = np.sort(d.start_s[big])[:2] / 3600.0
    return float(morning), float(evening)


def per_day(per_episode: dict[str, pd.DataFrame], base: str, scored: list[str]) -> str:
    """Markdown: per day, the baths' start (the habit: 08:05 and 21:00), the costs and each scored
    controller's share of that day's gap."""
    cost = {n: (-df.sort_values("seed")["return"]).to_numpy() for n, df in per_episode.items()}
    seeds = np.sort(per_episode["oracle"]["seed"].to_numpy())
    head = ["seed", "bath 1", "bath 2", "oracle", base, *scored, *(f"{a} share" for a in scored)]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * 3 + "---:|" * (len(head) - 3)]
    for i, sd in enumerate(seeds):
        m, e = bath_starts(int(sd))
        gap = cost[base][i] - cost["oracle"][i]
        shares = [f"{100 * (cost[base][i] - cost[a][i]) / gap:.0f} %" for a in scored]
        rows.append("| " + " | ".join([str(sd), _hhmm(m), _hhmm(e), f"{cost['oracle'][i]:.1f}", f"{cost[base][i]:.1f}",
                                       *(f"{cost[a][i]:.1f}" for a in scored), *shares]) + " |")
    return "\n".join(rows)


def bath_table(traces: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Per day, bath and controller (from ``run --trace`` CSVs): the bath's start, the cylinder's bottom
    and pocket temperatures and the setting when it begins, the highest setting and the mean bottom
    temperature over the hour before it, and the cost from an hour before to an hour after its start."""
    rows = []
    for name, tr in traces.items():
        for seed, day in tr.groupby("seed"):
            t = day["t_h"].to_numpy()
            for which, start in zip(("morning", "evening"), bath_starts(int(seed)), strict=True):
                k = int(np.searchsorted(t, start))  # the first observation after the bath began
                before = (t > start - 1.0) & (t <= start)
                around = (t > start - 1.0) & (t <= start + 1.0)
                rows.append({"controller": name, "seed": int(seed), "bath": which, "start_h": start,
                             "T_bottom_at_start": float(day["T_bottom_C"].iloc[max(k - 1, 0)]),
                             "T_pocket_at_start": float(day["T_pocket_C"].iloc[max(k - 1, 0)]),
                             "setting_at_start": float(day["setting_C"].iloc[max(k - 1, 0)]),
                             "setting_max_1h_before": float(day["setting_C"][before].max()),
                             "T_bottom_mean_1h_before": float(day["T_bottom_C"][before].mean()),
                             "cost_pm_1h": float(-day["reward"][around].sum())})
    return pd.DataFrame(rows)


def _hhmm(h: float) -> str:
    hh, mm = divmod(int(round(h * 60.0)), 60)
    return f"{hh:02d}:{mm:02d}"


# ----------------------------------------------------------------------------------- command line
def main(argv: list[str] | None = None) -> int:
    from valve_env.controllers import make_controller
    from valve_env.evaluation.evaluator import rollout
    from valve_env.outputs import OutputError, OutputSet

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the habit MPC on seeded days and write its per-day CSV")
    r.add_argument("--seed", type=int, default=48000)
    r.add_argument("--episodes", type=int, default=20)
    r.add_argument("--futures", type=int, default=8)
    r.add_argument("--future-seed", type=int, default=1)
    r.add_argument("--true-future", action="store_true", help="every future the true day (the oracle)")
    r.add_argument("--event-iterations", type=int, help="CEM iterations of a plan made at a draw's start")
    r.add_argument("--base-law", help="the law the plan perturbs: an agent with a residual base law (ppo); "
                                      "default the oracle's PI")
    r.add_argument("--set", nargs="*", default=[], metavar="K=V", help="planner settings (OracleSettings fields)")
    r.add_argument("--controller", default="habit_mpc",
                   help="habit_mpc (default), or any controller name of make_controller, or AGENT_base_law")
    r.add_argument("--out", required=True, help="the per-day CSV to write")
    r.add_argument("--trace", help="also write every step of every day here (CSV: seed, t_h, observations, reward)")
    r.add_argument("--force", action="store_true")
    t = sub.add_parser("table", help="the cost table and the gap closed from per-day CSVs")
    t.add_argument("csv", nargs="*", help="NAME=per-day CSV of one controller (run's output)")
    t.add_argument("--episodes", action="append", default=[],
                   help="a long per-episode CSV, the option repeated for more (columns controller, seed, "
                        "return, KPIs): task-leaderboard's "
                        "task_episodes.csv, thermovalve benchmark's episodes.csv")
    t.add_argument("--baselines", default="", help="comma-separated NAMEs of the run CSVs that are baselines")
    t.add_argument("--scored", default="ppo,ppo_pi",
                   help="comma-separated controllers scored by the gap closed (not baselines; the run CSVs "
                        "are scored too); every other controller but the oracle is a baseline")
    args = ap.parse_args(argv)
    if args.cmd == "run":
        import time

        import yaml

        settings = {}
        for kv in args.set:
            k, sep, v = kv.partition("=")
            if not sep:
                print(f"bad --set {kv!r}: expected K=V", file=sys.stderr)
                return 2
            settings[k] = yaml.safe_load(v)
        ctrl: Any
        if args.controller == "habit_mpc":
            ctrl = HabitMPC(ENV_ID, futures=args.futures, future_seed=args.future_seed,
                            true_future=args.true_future, base_law=args.base_law,
                            event_iterations=args.event_iterations, **settings)
        elif args.controller.endswith("_base_law"):
            ctrl = make_controller(args.controller.removesuffix("_base_law"), ENV_ID).base_law()
        else:
            ctrl = make_controller(args.controller, ENV_ID, **settings)
        outs = OutputSet(force=args.force)
        try:
            outs.add(args.out, "per-day CSV")
            if args.trace:
                outs.add(args.trace, "trace CSV")
        except OutputError as e:
            print(e, file=sys.stderr)
            return 2
        rows, traces = [], []
        for i in range(args.episodes):  # one day at a time, so that a long run reports as it goes
            seed = args.seed + i
            t0 = time.perf_counter()
            steps = rollout(ctrl, ENV_ID, seed)
            # the return summed in step order, as the evaluator's RecordEpisodeStatistics sums it
            rows.append({"episode": i, "seed": seed, "return": float(np.cumsum(steps["reward"].to_numpy())[-1]),
                         **steps.attrs["kpis"], "wall_s": time.perf_counter() - t0})
            traces.append(steps.assign(seed=seed))
            print(f"seed {seed}: cost {-rows[-1]['return']:.2f} tdis_Kh {rows[-1]['tdis_Kh']:.3f} "
                  f"({rows[-1]['wall_s']:.0f} s)", flush=True)
        with outs:
            outs.write_text(args.out, pd.DataFrame(rows).to_csv(index=False))
            if args.trace:
                outs.write_text(args.trace, pd.concat(traces, ignore_index=True).to_csv(index=False))
        if isinstance(ctrl, HabitMPC):
            print(ctrl.describe(), f"plans {ctrl.plans_made}, of them at a draw's start {ctrl.event_plans}")
        return 0
    per: dict[str, pd.DataFrame] = {}
    try:
        for path in args.episodes:
            long = pd.read_csv(path)
            if "task" in long.columns:
                long = long[long["task"] == TASK]
            for name, df in long.groupby("controller", sort=False):
                per[str(name)] = df.drop_duplicates("seed").reset_index(drop=True)  # a cached row once
        for spec in args.csv:
            name, sep, path = spec.partition("=")
            if not sep:
                print(f"bad csv argument {spec!r}: expected NAME=PATH", file=sys.stderr)
                return 2
            per[name] = pd.read_csv(path)
    except (OSError, ValueError, KeyError) as e:
        print(f"table: {e}", file=sys.stderr)
        return 2
    named = [spec.partition("=")[0] for spec in args.csv]
    base_names = [b for b in args.baselines.split(",") if b]
    scored = [c for c in args.scored.split(",") if c in per] + [
        n for n in named if n != "oracle" and n not in base_names and n not in args.scored.split(",")]
    baselines = [c for c in per if c not in scored and c != "oracle"]
    try:
        a, b = table(per, baselines, scored)
    except (KeyError, ValueError) as e:
        print(f"table: {e}", file=sys.stderr)
        return 2
    print(a)
    print()
    print(b)
    if "oracle" in per:
        cost = {n: -per[n]["return"].mean() for n in baselines}
        print()
        print(per_day(per, min(cost, key=cost.__getitem__), scored))
    return 0


if __name__ == "__main__":
    sys.exit(main())
