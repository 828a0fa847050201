"""Simulated control loops: several process types under PI control with a sticky valve and noise
(docs/loops.md, "Simulated loops"). The valve is the project's one stick-slip model
(:func:`valve_env.physics.stickslip.stick_slip_step`) in % of OP.

The process runs at a 1 s step, the PI controller at the same step (velocity form, clipped to
0-100 %), and the historian records every ``dt`` seconds the mean over the interval (as a
historian's averaging compression does). Tuning is SIMC (Skogestad 2003) with closed-loop time
constant ``tau_c``; a smaller ``tau_c`` is more aggressive. Disturbances: a load random walk
(filtered), an optional external sinusoid, white measurement noise, and set-point steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from valve_env.controllers.process import ModelFit, simc_pi
from valve_env.loops.io import LoopData
from valve_env.physics.stickslip import initial_state, stick_slip_step


@dataclass(frozen=True)
class Process:
    """A first-order-plus-dead-time (or integrating-plus-dead-time) process, gain per % of valve."""

    name: str
    gain: float          # PV units per % (integrating: per % per s)
    tau_s: float         # lag, s (0 for none)
    delay_s: float
    integrating: bool = False
    noise_sd: float = 0.05   # measurement noise, PV units
    load_sd: float = 0.02    # load random-walk increment per sqrt(s), in % of valve equivalent


#: the process types of the generator (flow, pressure, temperature, level)
PROCESSES: dict[str, Process] = {
    "flow": Process("flow", gain=2.0, tau_s=5.0, delay_s=2.0, noise_sd=0.15),
    "pressure": Process("pressure", gain=0.8, tau_s=40.0, delay_s=10.0, noise_sd=0.03),
    "temperature": Process("temperature", gain=1.2, tau_s=150.0, delay_s=30.0, noise_sd=0.03),
    "level": Process("level", gain=0.004, tau_s=0.0, delay_s=5.0, integrating=True, noise_sd=0.01),
}


@dataclass
class SimTruth:
    process: str
    S: float
    J: float
    tau_c_s: float
    external_amp: float
    label: str
    extra: dict[str, float] = field(default_factory=dict)


def simulate_loop(process: str | Process, S: float = 0.0, J: float | None = None, seed: int = 0,
                  hours: float = 2.0, dt: float = 10.0, tau_c_s: float | None = None,
                  external_amp: float = 0.0, external_period_s: float = 600.0,
                  sp_steps: int = 2, op0: float = 50.0) -> tuple[LoopData, SimTruth]:
    """One loop record (``hours`` at ``dt``) and its truth. ``S, J`` in % of OP (J defaults to S)."""
    p = PROCESSES[process] if isinstance(process, str) else process
    J = S if J is None else J
    rng = np.random.default_rng(seed)
    tau_c = tau_c_s if tau_c_s is not None else max(p.delay_s, 0.5 * p.tau_s, 60.0 if p.integrating else 10.0)
    # SIMC (valve_env.controllers.process), no sampling correction at the 1 s step; a lag under 1 s counts as 1 s
    g = simc_pi(ModelFit("ipdt" if p.integrating else "fopdt", p.gain, max(p.tau_s, 1.0), p.delay_s, 0.0), tau_c, 0.0)
    kc, ti = g.Kp, g.Ti_s
    n_fast = int(round(hours * 3600.0))
    h = 1.0
    nd = int(round(p.delay_s / h))
    # set point: steps at random times, size a few noise sd scaled to the process gain
    sp_val = np.zeros(n_fast)
    step_size = 4.0 * max(p.noise_sd, 0.02)
    for t_step in np.sort(rng.uniform(0.15, 0.85, sp_steps)) * n_fast:
        sp_val[int(t_step):] += step_size * rng.choice([-1.0, 1.0])
    load = np.cumsum(rng.normal(0.0, p.load_sd, n_fast))  # % of valve equivalent
    load -= load[0]
    ext = external_amp * np.sin(2 * np.pi * np.arange(n_fast) / external_period_s + rng.uniform(0, 2 * np.pi))
    y = 0.0  # deviation of PV
    op = op0
    xs = initial_state(op, S, J, 0.0, 100.0)
    yv, u_prev, du_prev, u_s, stuck, d = xs
    xbuf = np.full(nd + 1, yv)
    pv_f = np.empty(n_fast)
    op_f = np.empty(n_fast)
    x_f = np.empty(n_fast)
    e_prev = 0.0
    a = math.exp(-h / p.tau_s) if p.tau_s > 0 else 0.0
    for k in range(n_fast):
        meas = y + rng.normal(0.0, p.noise_sd)
        e = sp_val[k] - meas
        op = min(100.0, max(0.0, op + kc * (e - e_prev) + kc * h / ti * e))
        e_prev = e
        yv, u_prev, du_prev, u_s, stuck, d = stick_slip_step(op, yv, u_prev, du_prev, u_s, stuck, d, S, J,
                                                            0.0, 100.0)
        xbuf = np.roll(xbuf, 1)
        xbuf[0] = yv
        u_eff = xbuf[nd] - op0 + load[k] + ext[k]
        if p.integrating:
            y = y + h * p.gain * u_eff
        else:
            y = a * y + (1.0 - a) * p.gain * u_eff
        pv_f[k] = meas
        op_f[k] = op
        x_f[k] = yv
    m = int(round(dt / h))
    nr = n_fast // m

    def rec(v: np.ndarray) -> np.ndarray:
        return v[: nr * m].reshape(nr, m).mean(axis=1)

    loop = LoopData(time_s=np.arange(nr) * dt, sp=rec(sp_val) + 50.0, pv=rec(pv_f) + 50.0, op=rec(op_f),
                    mv=rec(x_f), tag=f"sim-{p.name}-S{S:g}-seed{seed}", source="valve_env.loops.sim")
    label = "stiction" if S > 0 else ("external_oscillation" if external_amp > 0 else "none")
    return loop, SimTruth(p.name, S, J, tau_c, external_amp, label, {"kc": kc, "ti_s": ti})


__all__ = ["Process", "PROCESSES", "SimTruth", "simulate_loop"]
