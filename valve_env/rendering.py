"""rgb_array rendering of an episode's history (matplotlib, Agg backend)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from valve_env.config import EnvConfig


def render_history(hist: np.ndarray, cfg: EnvConfig, mode: str) -> np.ndarray:
    """Draw temperatures, valve opening and actions; returns an RGB uint8 array.

    ``hist`` columns: t_s, T_out, T_pocket, T_bottom, x_mm, setting_C, dp_mbar.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.8), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax1, ax2, ax3 = fig.subplots(3, 1, sharex=True)
    t_h = hist[:, 0] / 3600.0
    ax1.plot(t_h, hist[:, 1], label="outlet")
    ax1.plot(t_h, hist[:, 2], label="bulb pocket")
    ax1.plot(t_h, hist[:, 3], label="bottom")
    ax1.axhline(cfg.control.T_target_C, color="k", lw=0.8, ls="--", label="target")
    ax1.axhline(cfg.control.T_floor_C, color="r", lw=0.8, ls=":", label="floor")
    ax1.set_ylabel("T [degC]")
    ax1.legend(loc="lower left", fontsize=6, ncol=5)
    ax2.plot(t_h, hist[:, 4], color="C3")
    ax2.set_ylabel("opening [mm]")
    ax2.set_ylim(-0.05, cfg.valve.stroke * 1.05)
    if mode in ("setting", "dual"):
        ax3.plot(t_h, hist[:, 5], color="C4", label="setting [degC]")
    if mode in ("pressure", "dual"):
        ax3b = ax3.twinx() if mode == "dual" else ax3
        ax3b.plot(t_h, hist[:, 6], color="C5", label="dp [mbar]")
        ax3b.set_ylabel("dp [mbar]")
    if mode != "pressure":
        ax3.set_ylabel("setting [degC]")
    ax3.set_xlabel("time [h]")
    ax3.set_xlim(0, cfg.control.horizon_h)
    fig.tight_layout()
    canvas.draw()
    buf = np.asarray(canvas.buffer_rgba())
    return np.ascontiguousarray(buf[:, :, :3])
