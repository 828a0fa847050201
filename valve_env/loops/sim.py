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
                  sp_steps: int = 2, op0: float = 50.0, ti_factor: float = 1.0,
                  load_tau_s: float | None = None) -> tuple[LoopData, SimTruth]:
    """One loop record (``hours`` at ``dt``) and its truth. ``S, J`` in % of OP (J defaults to S). ``ti_factor``
    multiplies the SIMC integral time (a detuned PI: > 1); ``load_tau_s`` makes the load a mean-reverting
    (Ornstein-Uhlenbeck) process with that time constant instead of a random walk (None), with the same increments
    over times short beside it."""
    p = PROCESSES[process] if isinstance(process, str) else process
    J = S if J is None else J
    rng = np.random.default_rng(seed)
    tau_c = tau_c_s if tau_c_s is not None else max(p.delay_s, 0.5 * p.tau_s, 60.0 if p.integrating else 10.0)
    # SIMC (valve_env.controllers.process), no sampling correction at the 1 s step; a lag under 1 s counts as 1 s
    g = simc_pi(ModelFit("ipdt" if p.integrating else "fopdt", p.gain, max(p.tau_s, 1.0), p.delay_s, 0.0), tau_c, 0.0)
    kc, ti = g.Kp, g.Ti_s * ti_factor
    n_fast = int(round(hours * 3600.0))
    h = 1.0
    nd = int(round(p.delay_s / h))
    # set point: steps at random times, size a few noise sd scaled to the process gain
    sp_val = np.zeros(n_fast)
    step_size = 4.0 * max(p.noise_sd, 0.02)
    for t_step in np.sort(rng.uniform(0.15, 0.85, sp_steps)) * n_fast:
        sp_val[int(t_step):] += step_size * rng.choice([-1.0, 1.0])
    steps = rng.normal(0.0, p.load_sd, n_fast)  # % of valve equivalent
    if load_tau_s is None:
        load = np.cumsum(steps)
        load -= load[0]
    else:
        from scipy.signal import lfilter

        load = lfilter([1.0], [1.0, -math.exp(-h / load_tau_s)], steps)
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


#: the kinds of valve and disturbance of :func:`random_case` and how often each is drawn: a sticky valve (stick-slip,
#: band S and slip jump J < S), a smooth one, one with a deadband but no stick (J = 0: hysteresis, no stick-slip),
#: a smooth valve under an external sinusoidal load, and a sticky one under the same load
CASE_KINDS: tuple[tuple[str, float], ...] = (("stiction", 0.35), ("smooth", 0.2), ("hysteresis", 0.15),
                                            ("external", 0.2), ("stiction_external", 0.1))


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def random_case(seed: int, kind: str | None = None) -> dict:
    """The parameters of one simulated loop of wide variety (docs/loops.md, "Simulated loops"), from ``seed``
    alone: a self-regulating process (lag 1-600 s, dead time 0-60 s) or, one time in three, an integrating one
    (dead time 0-60 s); SIMC tuning with a closed-loop time constant of 0.25-3 times the SIMC default (aggressive
    to sluggish), and for half the loops an integral time 1-10 times SIMC's (detuned, as many plant loops are:
    slow limit cycles); a band ``S_ref`` of 0.3-5 % of OP drawn for every loop, which scales the measurement noise
    (1-20 % of the PV's move for ``S_ref``) and the load (increments 0.1-1 % of ``S_ref`` per sqrt(s), mean-reverting
    with a time constant of 5-60 min: a load wanders, it does not drift without bound), so that both are
    distributed alike with and without stiction; 0-3 set-point steps; records of 1.5-4 h sampled at 5 or 10 s,
    or 2-4 h at 30 s (at least 240 samples); and the valve and disturbance of ``kind`` (drawn from
    :data:`CASE_KINDS` when None): stick-slip with S = ``S_ref`` and J/S 0.2-0.95; a deadband of 0.2-2 % without
    stick; an external sinusoid of 0.2-2 ``S_ref`` (% of valve travel) at a period of 3-60 min. The label is
    ``stiction`` for the sticky kinds, else ``none``."""
    rng = np.random.default_rng([seed, 38])
    if kind is None:
        names, w = zip(*CASE_KINDS, strict=True)
        kind = str(rng.choice(names, p=np.asarray(w) / sum(w)))
    integrating = bool(rng.uniform() < 1.0 / 3.0)
    delay = float(rng.uniform(0.0, 60.0))
    tau = 0.0 if integrating else _logu(rng, 1.0, 600.0)
    gain = _logu(rng, 2e-4, 5e-3) if integrating else _logu(rng, 0.3, 3.0)
    default = max(delay, 0.5 * tau, 60.0 if integrating else 10.0)
    tau_c = default * _logu(rng, 0.25, 3.0)
    # the band a sticky valve of this loop has; drawn for every kind, so that noise and load, scaled by it, are
    # distributed alike with and without stiction
    S_ref = _logu(rng, 0.3, 5.0)
    pv_per_pct = gain * (tau_c + delay) if integrating else gain  # the PV's move for 1 % of valve, settled
    proc = Process("integrating" if integrating else "self-regulating", gain=gain, tau_s=tau, delay_s=delay,
                   integrating=integrating, noise_sd=pv_per_pct * S_ref * _logu(rng, 0.01, 0.2),
                   load_sd=S_ref * _logu(rng, 0.001, 0.01))
    dt = float(rng.choice([5.0, 10.0, 10.0, 30.0]))
    case = {"kind": kind, "process": proc, "tau_c_s": tau_c,
            "dt": dt, "hours": float(rng.uniform(2.0 if dt >= 30.0 else 1.5, 4.0)),
            "sp_steps": int(rng.integers(0, 4)), "S": 0.0, "J": 0.0, "external_amp": 0.0,
            "external_period_s": 600.0, "seed": int(seed), "op0": float(rng.uniform(20.0, 80.0)),
            "ti_factor": _logu(rng, 1.0, 10.0) if rng.uniform() < 0.5 else 1.0,
            "load_tau_s": _logu(rng, 300.0, 3600.0)}
    jump = float(rng.uniform(0.2, 0.95))
    hyst = _logu(rng, 0.2, 2.0)
    ext_amp = S_ref * _logu(rng, 0.2, 2.0)
    ext_period = _logu(rng, 180.0, 3600.0)
    if kind in ("stiction", "stiction_external"):
        case["S"] = S_ref
        case["J"] = S_ref * jump
    elif kind == "hysteresis":
        case["S"] = hyst
    if kind in ("external", "stiction_external"):
        case["external_amp"] = ext_amp
        case["external_period_s"] = ext_period
    case["label"] = "stiction" if kind.startswith("stiction") else "none"
    return case


def simulate_case(case: dict) -> tuple[LoopData, SimTruth]:
    """The record of a :func:`random_case`."""
    loop, truth = simulate_loop(case["process"], S=case["S"], J=case["J"], seed=case["seed"], hours=case["hours"],
                                dt=case["dt"], tau_c_s=case["tau_c_s"], external_amp=case["external_amp"],
                                external_period_s=case["external_period_s"], sp_steps=case["sp_steps"],
                                op0=case["op0"], ti_factor=case["ti_factor"], load_tau_s=case["load_tau_s"])
    truth.label = case["label"]
    truth.extra["kind"] = case["kind"]
    loop.tag = f"sim-{case['kind']}-{case['process'].name}-seed{case['seed']}"
    return loop, truth


__all__ = ["CASE_KINDS", "Process", "PROCESSES", "SimTruth", "random_case", "simulate_case", "simulate_loop"]
