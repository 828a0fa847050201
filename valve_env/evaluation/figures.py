"""Evaluation figures (matplotlib, Agg backend): one episode's trajectories per
controller and the tracking-versus-energy trade-off across controllers."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from valve_env.plotting import headless, save_figure

headless()
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from valve_env.config import EnvConfig, make_config  # noqa: E402


def plot_trajectories(
    trajectories: Mapping[str, pd.DataFrame], path: str | Path, env_id: str = "", cfg: EnvConfig | None = None
) -> Path:
    """Outlet temperature, manipulated variable(s), valve opening and draws of
    one episode (the same seed) for each controller."""
    cfg = cfg if cfg is not None else make_config()
    fig, axes = plt.subplots(4, 1, figsize=(11, 10), sharex=True, height_ratios=[3, 2, 1.5, 1])
    ax_t, ax_u, ax_x, ax_d = axes
    for name, df in trajectories.items():
        (line,) = ax_t.plot(df["t_h"], df["T_out_C"], lw=1.0, label=name)
        c = line.get_color()
        if env_id == "ThermoValvePressure-v0":
            ax_u.plot(df["t_h"], df["dp_mbar"], lw=0.9, color=c, label=name)
        else:
            ax_u.plot(df["t_h"], df["setting_C"], lw=0.9, color=c, label=name)
            if env_id == "ThermoValveDual-v0":
                ax_u.plot(df["t_h"], df["dp_mbar"] / 10.0, lw=0.7, ls=":", color=c)
        ax_x.plot(df["t_h"], df["x_mm"], lw=0.8, color=c)
    first = next(iter(trajectories.values()))
    ax_d.fill_between(first["t_h"], first["draw_l_min"], step="pre", color="tab:blue", alpha=0.5)
    ax_t.axhline(cfg.control.T_target_C, color="k", lw=0.8, ls="--", label="target")
    ax_t.axhline(cfg.control.T_floor_C, color="tab:red", lw=0.8, ls=":", label="floor")
    ax_t.set_ylabel("outlet T (degC)")
    ax_t.legend(loc="lower right", ncol=3, fontsize=8)
    if env_id == "ThermoValvePressure-v0":
        ax_u.set_ylabel("dp (mbar)")
    elif env_id == "ThermoValveDual-v0":
        ax_u.set_ylabel("setting (degC)\n(dotted: dp/10 mbar)")
    else:
        ax_u.set_ylabel("valve setting (degC)")
    ax_x.set_ylabel("opening x (mm)")
    ax_d.set_ylabel("draw (l/min)")
    ax_d.set_xlabel("time of day (h)")
    ax_t.set_title(f"{env_id}: one episode (seed {first.attrs.get('seed', '')}) per controller".replace("(seed )", ""))
    fig.tight_layout()
    return save_figure(fig, path)


def plot_tradeoff(summary: Mapping[str, Any], path: str | Path) -> Path:
    """Tracking (rmse_K) versus primary heat (heat_kWh) per controller, mean and
    standard deviation over the episodes."""
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for name, res in summary["results"].items():
        k = res["kpis"]
        ax.errorbar(
            k["rmse_K"]["mean"], k["heat_kWh"]["mean"], xerr=k["rmse_K"]["std"], yerr=k["heat_kWh"]["std"],
            fmt="o", capsize=3, label=name,
        )
    ax.set_xlabel("outlet RMSE vs target (K)")
    ax.set_ylabel("heat from the primary side (kWh/day)")
    ax.set_title(f"{summary['env']}: tracking vs energy ({summary['episodes']} episodes)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
