"""Figures of docs/controllers.md: the compensators and the wear-aware PI on a sticky and a smooth valve,
and the oracle's cost and time per 24 h episode, on held-out seeds (the settings were chosen on seeds
0-4; these default to seeds 100-109, never looked at while building).

    python benchmarks/controllers_bench.py compensators [--seed 100 --episodes 10 --band 0.1]
    python benchmarks/controllers_bench.py task-compensators [--task ThermoValveStickyValve-v0 --band MM]
    python benchmarks/controllers_bench.py oracle [--seed 100 --episodes 3 --tasks ID ...] [--oracle-settings JSON]
    python benchmarks/controllers_bench.py bound --seed 0 --episodes 5 --tasks ThermoValveDistrictHeating-v0
    ... oracle|bound --env-kwargs '{"tariff": {"price_max_rel": 2.0}}' --baselines pi,self_acting,pi_wear

Prints markdown tables (means over the episodes; paired differences against ``pi``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import gymnasium as gym
import pandas as pd

import valve_env
from valve_env.controllers import make_controller
from valve_env.evaluation.evaluator import run_episodes

COLS = ("return", "iae_Kh", "rmse_K", "tdis_Kh", "heat_kWh", "travel_mm", "reversals")


def _table(rows: dict[str, pd.DataFrame], ref: str = "pi") -> str:
    head = "| controller | " + " | ".join(COLS) + " | iae vs pi | reversals vs pi | seeds better iae / fewer rev |"
    lines = [head, "|---|" + "---:|" * (len(COLS) + 3)]
    base = rows[ref]
    for name, df in rows.items():
        m = df.mean(numeric_only=True)
        d_iae = 100 * (m["iae_Kh"] / base["iae_Kh"].mean() - 1)
        d_rev = 100 * (m["reversals"] / base["reversals"].mean() - 1)
        better = int((df["iae_Kh"].to_numpy() < base["iae_Kh"].to_numpy()).sum())
        fewer = int((df["reversals"].to_numpy() < base["reversals"].to_numpy()).sum())
        cells = [f"{m[c]:.3f}" if abs(m[c]) < 100 else f"{m[c]:.0f}" for c in COLS]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {d_iae:+.0f} % | {d_rev:+.0f} % | {better} / {fewer} |")
    return "\n".join(lines)


def compensators(seed: int, episodes: int, band: float) -> None:
    names = ("self_acting", "pi", "pi_compensated", "pi_wear", "knocker", "constant_reinforcement", "two_move")
    for label, kw in (("smooth valve (no stiction)", {}),
                      (f"sticky valve, band_mm = {band}", {"valve": {"effects": {"stiction": {"band_mm": band}}}})):
        t0 = time.perf_counter()
        rows = {n: run_episodes(make_controller(n, band_mm=band) if n in ("knocker", "constant_reinforcement",
                                                                          "two_move") else make_controller(n),
                                "ThermoValve-v0", episodes, seed, env_kwargs=kw) for n in names}
        print(f"\nThermoValve-v0, {label}, seeds {seed}..{seed + episodes - 1} ({time.perf_counter() - t0:.0f} s)\n")
        print(_table(rows))


def task_compensators(task: str, seed: int, episodes: int, band: float | None) -> None:
    """The compensators on a sticky task (its own band, or ``band`` mm on the valve and in the
    compensators), and the issue's goal: iae_Kh -30 % with fewer reversals and tdis_Kh no worse."""
    names = ("pi", "pi_compensated", "pi_wear", "knocker", "constant_reinforcement", "two_move")
    kw = {} if band is None else {"valve": {"effects": {"stiction": {"band_mm": band}}}}
    comp = {} if band is None else {"band_mm": band}
    t0 = time.perf_counter()
    rows = {n: run_episodes(make_controller(n, task, **(comp if n in ("knocker", "constant_reinforcement",
                                                                         "two_move") else {})),
                            task, episodes, seed, env_kwargs=kw) for n in names}
    label = "its own band" if band is None else f"band_mm = {band}"
    print(f"\n{task}, {label}, seeds {seed}..{seed + episodes - 1} ({time.perf_counter() - t0:.0f} s)\n")
    print(_table(rows))
    base = rows["pi"].mean(numeric_only=True)
    for name, df in rows.items():
        if name == "pi":
            continue
        m = df.mean(numeric_only=True)
        met = (m["iae_Kh"] <= 0.7 * base["iae_Kh"] and m["reversals"] < base["reversals"]
               and m["tdis_Kh"] <= base["tdis_Kh"] + 1e-9)
        print(f"* {name}: iae {100 * (m['iae_Kh'] / base['iae_Kh'] - 1):+.0f} %, reversals "
              f"{100 * (m['reversals'] / base['reversals'] - 1):+.0f} %, tdis {m['tdis_Kh']:.3f} "
              f"(pi {base['tdis_Kh']:.3f}): goal {'met' if met else 'not met'}")


def oracle(seed: int, episodes: int, tasks: list[str], settings: dict[str, Any] | None = None,
           env_kwargs: dict[str, Any] | None = None, baselines: tuple[str, ...] = ("pi",)) -> None:
    """The oracle's cost against pi's and its wall time per 24 h episode, on each task (``settings``
    over the task's own, for tuning on seeds 0-4; ``env_kwargs`` as gym.make's, e.g. a ``tariff``, for
    screening a task variant); the headroom against the best of ``baselines`` (pi first)."""
    summary = []
    for task in tasks:
        rows = {}
        base = {b: run_episodes(make_controller(b, task), task, episodes, seed, env_kwargs) for b in baselines}
        pi = base[baselines[0]]
        times = []
        recs = []
        for i in range(episodes):
            o = make_controller("oracle", task, **(settings or {}))
            t0 = time.perf_counter()
            recs.append(run_episodes(o, task, 1, seed + i, env_kwargs))
            times.append(time.perf_counter() - t0)
            print(f"{task} seed {seed + i}: oracle 24 h episode in {times[-1]:.1f} s ({o.plans_made} plans, "
                  f"{o.sim_steps} batched steps of {o.settings.samples} envs)", flush=True)
        rows.update(base)
        rows["oracle"] = pd.concat(recs, ignore_index=True)
        print(f"\n{task}, seeds {seed}..{seed + episodes - 1}; oracle time per 24 h episode: "
              f"mean {sum(times) / len(times):.1f} s, max {max(times):.1f} s\n")
        print(_table(rows, ref=baselines[0]))
        cost_pi, cost_or = -pi["return"].mean(), -rows["oracle"]["return"].mean()
        print(f"\ncost (-return): {baselines[0]} {cost_pi:.2f}, oracle {cost_or:.2f} "
              f"({100 * (cost_or / cost_pi - 1):+.1f} %)")
        best = min(baselines, key=lambda b: -base[b]["return"].mean())
        cost_best = -base[best]["return"].mean()
        print(f"headroom: oracle {cost_or:.2f} against the best of {', '.join(baselines)}, {best} {cost_best:.2f}: "
              f"{100 * (1 - cost_or / cost_best):.1f} %\n", flush=True)
        summary.append((task, sum(times) / len(times), max(times)))
    print("| task | oracle s per 24 h episode (mean) | max |\n|---|---:|---:|")
    for task, mean, mx in summary:
        print(f"| {task} | {mean:.1f} | {mx:.1f} |")


def storage_bound(task: str, seed: int, env_kwargs: dict[str, Any] | None = None) -> dict[str, float]:
    """A lower bound on the cost (-return) of any controller on one district-heating day (docs/controllers.md,
    "oracle: the bound"): the tank as one energy store (heat in at most the fully open
    valve's flow times supply minus cold water, out the day's draws and the standing loss, linear in the mean
    temperature), bought at the step's price, settled at the end as the task settles it; tracking costs at
    least w_track (T_mean - T_target - free_band_K)^2 above the band (the top is the hottest layer; v1's
    store behind a mixing valve is free up to free_band_K above the target), the floor at least w_floor times the
    top's shortfall when all the heat sat in the top layer; the return tariff is counted as zero. The coil
    gives at most UA_coil (T_sup - its layers' mean), and no layer is hotter than the hottest supply or
    start, so a full store bounds the heat it can still take (and the store's own size). A linear
    programme (HiGHS; the quadratic by tangents from below). It bounds the plant only as far as the store
    model does (one explicit step per control step; the flow limit taken from one day at the top setting)."""
    import gymnasium as gym
    import numpy as np
    from scipy import sparse
    from scipy.optimize import linprog

    from valve_env import simulator as sim

    env = gym.make(task, **(env_kwargs or {}))
    env.reset(seed=seed)
    core = env.unwrapped
    cfg, layer = core.cfg, core.layer
    st0 = core.get_state()
    scen = np.asarray(st0.scenario, np.float64)
    tk, ctl = cfg.tank, cfg.control
    N, dt = int(ctl.n_steps), float(ctl.dt_s)
    # the fully open valve's flow at each step (the setting at its maximum all day)
    flow = np.empty(N)
    for k in range(N):
        env.step(np.array([ctl.setting_max_C], np.float32))
        flow[k] = core.get_state().out[sim.O_Q_KGH] / 3600.0
    env.close()
    C = tk.volume_l * tk.rho * tk.cp  # J/K
    m_l = tk.layer_mass_kg * tk.cp  # J/K of one layer
    q_max = flow * tk.cp * np.maximum(scen[:, 3] - tk.T_cold, 0.0)  # W
    draw = scen[:, 0]  # W, delivered while the top is above the floor
    E0 = float(st0.E0_J)
    t = layer.tariff
    price = layer.price_at(np.arange(N))
    w = t.w_eur
    # variables: q (N), E_1..E_N (N), track (N), short (N), [peak kW]
    power = hasattr(t, "power_eur_kW_day")
    nv = 4 * N + (1 if power else 0)
    iq, iE, it, isf = 0, N, 2 * N, 3 * N
    c = np.zeros(nv)
    c[iq:iq + N] = w * price * dt / 3.6e9
    c[iE + N - 1] = -w * t.price_eur_MWh / 3.6e9  # settlement: w p_mean (E0 - E_N)
    c[it:it + N] = 1.0
    c[isf:isf + N] = ctl.w_floor
    if power:
        c[-1] = w * t.power_eur_kW_day
    a = 1.0 - dt * tk.UA_loss / C
    rows, cols, vals = [], [], []
    b_eq = np.empty(N)
    for k in range(N):  # E_{k+1} - a E_k - dt q_k = dt (UA T_amb - draw_k)
        rows += [k, k]
        cols += [iE + k, iq + k]
        vals += [1.0, -dt]
        if k > 0:
            rows.append(k)
            cols.append(iE + k - 1)
            vals.append(-a)
        b_eq[k] = dt * (tk.UA_loss * tk.T_ambient - draw[k]) + (a * E0 if k == 0 else 0.0)
    A_eq = sparse.csr_matrix((vals, (rows, cols)), shape=(N, nv))
    ub_r, ub_c, ub_v, b_ub = [], [], [], []
    r = 0
    T_band = ctl.T_target_C + ctl.free_band_K  # the top of the band free of tracking (v1: a mixing valve)
    for d in (*np.arange(0.25, 3.0, 0.25), *np.arange(3.0, 12.1, 1.0)):  # track_k >= w (2 d x - d^2), x = E/C - T_b
        for k in range(N):
            ub_r += [r, r]
            ub_c += [iE + k, it + k]
            ub_v += [ctl.w_track * 2 * d / C, -1.0]
            b_ub.append(ctl.w_track * (2 * d * T_band + d * d))
            r += 1
    for k in range(N):  # short_k >= T_floor - T_top_max, T_top_max = (E - (M - m_l) T_cold) / m_l
        ub_r += [r, r]
        ub_c += [iE + k, isf + k]
        ub_v += [-1.0 / m_l, -1.0]
        b_ub.append(-ctl.T_floor_C - (C - m_l) * tk.T_cold / m_l)
        r += 1
    # the coil (the lowest coil_layers layers) gives at most UA_coil (T_sup - mean coil-layer temperature)
    # (each segment's inlet is at most T_sup); no layer is hotter than the hottest supply or start
    # (heat comes only through the coil), so the coil layers' mean is at least
    # (C T_mean - (C - C_coil) T_hot) / C_coil: a store fuller than the upper layers can hold forces
    # a warm coil and a smaller heat input
    T_hot = float(max(scen[:, 3].max(), np.max(np.asarray(st0.state)[: tk.n_layers])))
    f_coil = tk.coil_layers / tk.n_layers
    for k in range(N):  # q_k + UA E_{k-1} / (f C) <= UA (T_sup_k + (1 - f) T_hot / f)
        ub_r.append(r)
        ub_c.append(iq + k)
        ub_v.append(1.0)
        rhs = tk.UA_coil * (scen[k, 3] + (1.0 - f_coil) * T_hot / f_coil)
        if k > 0:
            ub_r.append(r)
            ub_c.append(iE + k - 1)
            ub_v.append(tk.UA_coil / (f_coil * C))
        else:
            rhs -= tk.UA_coil * E0 / (f_coil * C)
        b_ub.append(rhs)
        r += 1
    if power:  # peak >= each clock hour's heat, kW
        per_h = int(round(3600.0 / dt))
        for h in range(N // per_h):
            for k in range(h * per_h, (h + 1) * per_h):
                ub_r.append(r)
                ub_c.append(iq + k)
                ub_v.append(dt / 3.6e6)
            ub_r.append(r)
            ub_c.append(nv - 1)
            ub_v.append(-1.0)
            b_ub.append(0.0)
            r += 1
    A_ub = sparse.csr_matrix((ub_v, (ub_r, ub_c)), shape=(r, nv))
    q_top = np.minimum(q_max, tk.UA_coil * np.maximum(scen[:, 3] - tk.T_cold, 0.0))  # W
    bounds = ([(0.0, float(q)) for q in q_top]
              + [(C * tk.T_cold, C * T_hot)] * N + [(0.0, None)] * (2 * N)
              + ([(0.0, None)] if power else []))
    res = linprog(c, A_ub=A_ub, b_ub=np.array(b_ub), A_eq=A_eq, b_eq=b_eq, bounds=bounds, method="highs")
    if res.status != 0:
        raise RuntimeError(f"the bound's linear programme failed: {res.message}")
    x = res.x
    const = w * t.price_eur_MWh * E0 / 3.6e9
    q = x[iq:iq + N]
    return {"cost": float(res.fun + const), "heat_kWh": float(q.sum() * dt / 3.6e6),
            "track": float(x[it:it + N].sum()), "mean_price": float((price * q).sum() / max(q.sum(), 1e-9))}


def bound(seed: int, episodes: int, tasks: list[str], env_kwargs: dict[str, Any] | None = None) -> None:
    """:func:`storage_bound` per day, beside self_acting's and pi's cost on the same days (``env_kwargs``
    as gym.make's, for screening a task variant), and its mean."""
    print("| task | seed | self_acting | pi | bound (any controller) | bound below the better of the two | heat kWh | "
          "mean price EUR/MWh | tracking |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for task in tasks:
        sa = run_episodes(make_controller("self_acting", task), task, episodes, seed, env_kwargs)
        pi = run_episodes(make_controller("pi", task), task, episodes, seed, env_kwargs)
        costs = []
        for i in range(episodes):
            b = storage_bound(task, seed + i, env_kwargs)
            costs.append(b["cost"])
            best = min(-sa["return"].iloc[i], -pi["return"].iloc[i])
            print(f"| {task} | {seed + i} | {-sa['return'].iloc[i]:.2f} | {-pi['return'].iloc[i]:.2f} | "
                  f"{b['cost']:.2f} | {100 * (1 - b['cost'] / best):.1f} % | {b['heat_kWh']:.2f} | "
                  f"{b['mean_price']:.1f} | {b['track']:.2f} |", flush=True)
        sa_m, pi_m, b_m = -sa["return"].mean(), -pi["return"].mean(), sum(costs) / len(costs)
        print(f"| {task} | mean | {sa_m:.2f} | {pi_m:.2f} | {b_m:.2f} | {100 * (1 - b_m / min(sa_m, pi_m)):.1f} % "
              "| | | |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("compensators", "task-compensators", "oracle", "bound"))
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--episodes", type=int, default=None)
    ap.add_argument("--band", type=float, default=None,
                    help="stiction band, mm (compensators: default 0.1; task-compensators: the task's own)")
    ap.add_argument("--task", default="ThermoValveStickyValve-v0", help="env id for task-compensators")
    ap.add_argument("--tasks", nargs="+", default=["ThermoValve-v0", *valve_env.TASK_IDS],
                    help="env ids for `oracle` (default: ThermoValve-v0 and every benchmark task)")
    ap.add_argument("--oracle-settings", default="{}",
                    help='JSON object of oracle settings over the task\'s own, e.g. \'{"replan_steps": 240}\'')
    ap.add_argument("--env-kwargs", default="{}",
                    help="JSON object of gym.make keyword arguments for `oracle` and `bound`, to screen a task "
                         'variant, e.g. \'{"tariff": {"surcharge_per_K": 0.02}}\' '
                         '(docs/tasks.md, "The benchmark report")')
    ap.add_argument("--baselines", default="pi",
                    help="comma-separated controllers the oracle's headroom is taken against (first: the table's "
                         "reference), e.g. pi,self_acting,pi_wear")
    a = ap.parse_args()
    for flag, text in (("--oracle-settings", a.oracle_settings), ("--env-kwargs", a.env_kwargs)):
        try:
            value = json.loads(text)
            if not isinstance(value, dict):
                raise ValueError("not a JSON object")
            if flag == "--oracle-settings" and a.what == "oracle":
                make_controller("oracle", a.tasks[0], **value)  # an unknown or bad setting fails here
            if flag == "--env-kwargs":
                for task in a.tasks if a.what in ("oracle", "bound") else ():
                    gym.make(task, **value).close()  # an unknown or bad parameter fails here
        except Exception as exc:  # noqa: BLE001 - any bad value is the user's input: one line, exit 2
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            print(f"thermovalve: error: {flag} {text!r}: {msg}", file=sys.stderr)
            raise SystemExit(2) from None
        if flag == "--oracle-settings":
            settings = value
        else:
            env_kwargs = value
    baselines = tuple(b.strip() for b in a.baselines.split(",") if b.strip()) or ("pi",)
    if a.what == "compensators":
        compensators(a.seed, a.episodes or 10, 0.1 if a.band is None else a.band)
    elif a.what == "task-compensators":
        task_compensators(a.task, a.seed, a.episodes or 10, a.band)
    elif a.what == "bound":
        bound(a.seed, a.episodes or 3, a.tasks, env_kwargs)
    else:
        oracle(a.seed, a.episodes or 3, a.tasks, settings, env_kwargs, baselines)


if __name__ == "__main__":
    main()
