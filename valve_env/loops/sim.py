"""Simulated control loops: several process types under PI control with a sticky valve and noise
(docs/loops.md, "Simulated loops"). The valve is the project's one stick-slip model
(:func:`valve_env.physics.stickslip.stick_slip_step`) in % of OP.

The process runs at a 1 s step, the PI controller at the same step (velocity form, clipped to
0-100 %), and the historian records every ``dt`` seconds the mean over the interval (as a
historian's averaging compression does). Tuning is SIMC (Skogestad 2003) with closed-loop time
constant ``tau_c``; a smaller ``tau_c`` is more aggressive. Disturbances: a load random walk
(filtered), an optional external sinusoid, white measurement noise, and set-point steps; optionally the plant's
other habits (:func:`simulate_loop`'s options; :func:`random_case` with ``plant=True``) and the historian's own
conventions (:class:`Historian`). :func:`stiction_visibility` says how much a sticky valve shows in its record.
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


def _ou(increments: np.ndarray, tau_s: float, h: float) -> np.ndarray:
    """An Ornstein-Uhlenbeck (AR(1)) path driven by ``increments``, time constant ``tau_s``, from 0."""
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -math.exp(-h / tau_s)], increments)


#: the shapes of an external oscillation: a sinusoid, a square wave, a triangle, and narrow-band noise about the period
#: (a second-order resonance of damping 0.05 driven by white noise: its phase and amplitude wander)
SHAPES: tuple[str, ...] = ("sine", "square", "triangle", "narrowband")


def _external(shape: str, n: int, period_s: float, h: float, rng: np.random.Generator) -> np.ndarray:
    """An external oscillation of ``shape`` (:data:`SHAPES`) of unit amplitude (narrow-band: the sd of a unit
    sinusoid)."""
    phase = 2 * np.pi * np.arange(n) * h / period_s + rng.uniform(0, 2 * np.pi)
    if shape == "sine":
        return np.sin(phase)
    if shape == "square":
        return np.sign(np.sin(phase))
    if shape == "triangle":
        return 2.0 / np.pi * np.arcsin(np.sin(phase))
    if shape == "narrowband":
        from scipy.signal import lfilter

        w, zeta = 2 * np.pi * h / period_s, 0.05
        r = math.exp(-zeta * w)
        x = lfilter([1.0], [1.0, -2.0 * r * math.cos(w), r * r], rng.normal(size=n))
        return x / (math.sqrt(2.0) * max(float(x.std()), 1e-12))
    raise ValueError(f"external_shape must be one of {', '.join(SHAPES)}; got {shape!r}")


@dataclass(frozen=True)
class Historian:
    """How a plant historian stores a signal: rounded to a resolution (``pv_step``, ``op_step``: the set point shares
    the PV's; 0 for none) and compressed by store-on-change (a value is kept when it moves more than ``pv_dev`` /
    ``op_dev`` from the last one kept; the export interpolates linearly between kept values; 0 for none)."""

    pv_step: float = 0.0
    op_step: float = 0.0
    pv_dev: float = 0.0
    op_dev: float = 0.0

    @staticmethod
    def record(x: np.ndarray, step: float, dev: float) -> np.ndarray:
        if dev > 0:
            keep = [0]
            for i in range(1, x.size):
                if abs(x[i] - x[keep[-1]]) > dev:
                    keep.append(i)
            if keep[-1] != x.size - 1:
                keep.append(x.size - 1)
            x = np.interp(np.arange(x.size), keep, x[keep])
        return np.round(x / step) * step if step > 0 else x


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
                  load_tau_s: float | None = None, kc_factor: float = 1.0, external_shape: str = "sine",
                  noise_ar: float = 0.0, slow_load_sd: float = 0.0, slow_load_tau_s: float = 3600.0,
                  drift_per_h: float = 0.0, sp_walk_sd: float = 0.0, sp_walk_tau_s: float = 600.0,
                  historian: Historian | None = None) -> tuple[LoopData, SimTruth]:
    """One loop record (``hours`` at ``dt``) and its truth. ``S, J`` in % of OP (J defaults to S). ``ti_factor``
    multiplies the SIMC integral time (a detuned PI: > 1) and ``kc_factor`` its gain (< 1: a timid gain);
    ``load_tau_s`` makes the load a mean-reverting (Ornstein-Uhlenbeck) process with that time constant instead of a
    random walk (None), with the same increments over times short beside it.

    The plant's other habits, all off by default: ``external_shape`` of the external oscillation (:data:`SHAPES`:
    a sinusoid, a square wave, a triangle, or narrow-band noise about the period, each of amplitude
    ``external_amp``); measurement noise coloured by an AR(1) filter of coefficient ``noise_ar`` (same sd); a slow
    load wander (OU, stationary sd ``slow_load_sd`` % of valve, time constant ``slow_load_tau_s``, often longer
    than the record) and a load ramp of ``drift_per_h`` % of valve per hour; a set point that follows a master
    loop (a cascade's secondary: OU in PV units, stationary sd ``sp_walk_sd``, time constant ``sp_walk_tau_s``);
    and the historian's own conventions (:class:`Historian`: quantised values, store-on-change compression)."""
    p = PROCESSES[process] if isinstance(process, str) else process
    J = S if J is None else J
    rng = np.random.default_rng(seed)
    tau_c = tau_c_s if tau_c_s is not None else max(p.delay_s, 0.5 * p.tau_s, 60.0 if p.integrating else 10.0)
    # SIMC (valve_env.controllers.process), no sampling correction at the 1 s step; a lag under 1 s counts as 1 s
    g = simc_pi(ModelFit("ipdt" if p.integrating else "fopdt", p.gain, max(p.tau_s, 1.0), p.delay_s, 0.0), tau_c, 0.0)
    kc, ti = g.Kp * kc_factor, g.Ti_s * ti_factor
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
        load = _ou(steps, load_tau_s, h)
    ext = external_amp * _external(external_shape, n_fast, external_period_s, h, rng)
    # the plant's other habits (each draws its random numbers only when on, so the default loop is unchanged)
    if slow_load_sd > 0:
        load = load + _ou(rng.normal(0.0, slow_load_sd * math.sqrt(2.0 * h / slow_load_tau_s), n_fast),
                          slow_load_tau_s, h)
    if drift_per_h != 0:
        load = load + drift_per_h * np.arange(n_fast) * h / 3600.0
    if sp_walk_sd > 0:
        sp_val = sp_val + _ou(rng.normal(0.0, sp_walk_sd * math.sqrt(2.0 * h / sp_walk_tau_s), n_fast),
                              sp_walk_tau_s, h)
    noise = rng.normal(0.0, p.noise_sd * math.sqrt(1.0 - noise_ar ** 2), n_fast) if noise_ar > 0 else None
    if noise is not None:
        from scipy.signal import lfilter

        noise = lfilter([1.0], [1.0, -noise_ar], noise)
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
        meas = y + (rng.normal(0.0, p.noise_sd) if noise is None else noise[k])
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

    pv_r, op_r, sp_r = rec(pv_f) + 50.0, rec(op_f), rec(sp_val) + 50.0
    if historian is not None:
        pv_r, op_r, sp_r = (historian.record(pv_r, historian.pv_step, historian.pv_dev),
                            historian.record(op_r, historian.op_step, historian.op_dev),
                            historian.record(sp_r, historian.pv_step, 0.0))
    loop = LoopData(time_s=np.arange(nr) * dt, sp=sp_r, pv=pv_r, op=op_r,
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


def random_case(seed: int, kind: str | None = None, plant: bool = False) -> dict:
    """The parameters of one simulated loop of wide variety (docs/loops.md, "Simulated loops"), from ``seed``
    alone; ``plant`` adds the plant's habits (below; a different population: the same seed gives another loop).

    * **Process**: self-regulating (lag 1-600 s; ``plant``: 1-1200 s; dead time 0-60 s) or, one time in three,
      integrating (dead time 0-60 s).
    * **Tuning**: SIMC with a closed-loop time constant of 0.25-3 times the SIMC default (aggressive to sluggish);
      for half the loops an integral time 1-10 times SIMC's (``plant``: for 70 % of the loops 1-30 times, and for half
      of those a gain 0.1-1 times SIMC's: detuned, as many plant loops are; slow limit cycles, a timid controller
      output).
    * **Noise and load**, scaled by a band ``S_ref`` of 0.3-5 % of OP drawn for every loop, so that they are
      distributed alike with and without stiction: white measurement noise 1-20 % of the PV's move for ``S_ref``
      (``plant``: 1-50 %, for half the loops AR(1)-coloured with coefficient 0-0.9); a load with increments 0.1-1 % of
      ``S_ref`` per sqrt(s), mean-reverting with a time constant of 5-60 min. ``plant``: for half the loops a slow
      wander (sd 0.3-3 ``S_ref``, time constant 1-8 h: often longer than the record), for a quarter a ramp of 0.1-3
      ``S_ref`` per hour.
    * **Set point**: 0-3 steps. ``plant``: for 15 % of the loops it follows a master loop (a cascade's secondary: sd
      0.3-3 times the PV's move for ``S_ref``, time constant 2-30 min).
    * **Record**: 1.5-4 h sampled at 5 or 10 s, or 2-4 h at 30 s (at least 240 samples). ``plant``: for half the
      loops the historian rounds PV, SP and OP (resolution 0.5-20 % of the noise sd and 0.001-0.1 % of OP), for a
      fifth it compresses them by store-on-change (dead bands 0.5-3 noise sd and 0.01-0.3 % of OP).
    * **Valve and disturbance** of ``kind`` (drawn from :data:`CASE_KINDS` when None): stick-slip with S =
      ``S_ref`` and J/S 0.2-0.95; a deadband of 0.2-2 % without stick; an external sinusoid of 0.2-2 ``S_ref`` (% of
      valve travel) at a period of 3-60 min (``plant``: 3-180 min, its shape drawn from :data:`SHAPES`).

    The label is ``stiction`` for the sticky kinds, else ``none``."""
    rng = np.random.default_rng([seed, 38])
    if kind is None:
        names, w = zip(*CASE_KINDS, strict=True)
        kind = str(rng.choice(names, p=np.asarray(w) / sum(w)))
    integrating = bool(rng.uniform() < 1.0 / 3.0)
    delay = float(rng.uniform(0.0, 60.0))
    tau = 0.0 if integrating else _logu(rng, 1.0, 1200.0 if plant else 600.0)
    gain = _logu(rng, 2e-4, 5e-3) if integrating else _logu(rng, 0.3, 3.0)
    default = max(delay, 0.5 * tau, 60.0 if integrating else 10.0)
    tau_c = default * _logu(rng, 0.25, 3.0)
    # the band a sticky valve of this loop has; drawn for every kind, so that noise and load, scaled by it, are
    # distributed alike with and without stiction
    S_ref = _logu(rng, 0.3, 5.0)
    pv_per_pct = gain * (tau_c + delay) if integrating else gain  # the PV's move for 1 % of valve, settled
    noise_sd = pv_per_pct * S_ref * _logu(rng, 0.01, 0.5 if plant else 0.2)
    proc = Process("integrating" if integrating else "self-regulating", gain=gain, tau_s=tau, delay_s=delay,
                   integrating=integrating, noise_sd=noise_sd, load_sd=S_ref * _logu(rng, 0.001, 0.01))
    dt = float(rng.choice([5.0, 10.0, 10.0, 30.0]))
    detuned = bool(rng.uniform() < 0.7) if plant else False
    case = {"kind": kind, "process": proc, "tau_c_s": tau_c,
            "dt": dt, "hours": float(rng.uniform(2.0 if dt >= 30.0 else 1.5, 4.0)),
            "sp_steps": int(rng.integers(0, 4)), "S": 0.0, "J": 0.0, "external_amp": 0.0,
            "external_period_s": 600.0, "seed": int(seed), "op0": float(rng.uniform(20.0, 80.0))}
    if plant:
        case["ti_factor"] = _logu(rng, 1.0, 30.0) if detuned else 1.0
        case["kc_factor"] = _logu(rng, 0.1, 1.0) if detuned and rng.uniform() < 0.5 else 1.0
    else:
        case["ti_factor"] = _logu(rng, 1.0, 10.0) if rng.uniform() < 0.5 else 1.0
    case["load_tau_s"] = _logu(rng, 300.0, 3600.0)
    jump = float(rng.uniform(0.2, 0.95))
    hyst = _logu(rng, 0.2, 2.0)
    ext_amp = S_ref * _logu(rng, 0.2, 2.0)
    ext_period = _logu(rng, 180.0, 10800.0 if plant else 3600.0)
    if plant:
        case["external_shape"] = str(rng.choice(SHAPES))
        # the plant's other habits, drawn for every kind
        case["noise_ar"] = float(rng.uniform(0.0, 0.9)) if rng.uniform() < 0.5 else 0.0
        case["slow_load_sd"] = S_ref * _logu(rng, 0.3, 3.0) if rng.uniform() < 0.5 else 0.0
        case["slow_load_tau_s"] = _logu(rng, 3600.0, 28800.0)
        case["drift_per_h"] = (S_ref * _logu(rng, 0.1, 3.0) * float(rng.choice([-1.0, 1.0]))
                               if rng.uniform() < 0.25 else 0.0)
        case["sp_walk_sd"] = pv_per_pct * S_ref * _logu(rng, 0.3, 3.0) if rng.uniform() < 0.15 else 0.0
        case["sp_walk_tau_s"] = _logu(rng, 120.0, 1800.0)
        rounded, compressed = rng.uniform() < 0.5, rng.uniform() < 0.2
        case["historian"] = Historian(pv_step=noise_sd * _logu(rng, 0.005, 0.2) if rounded else 0.0,
                                      op_step=_logu(rng, 0.001, 0.1) if rounded else 0.0,
                                      pv_dev=noise_sd * _logu(rng, 0.5, 3.0) if compressed else 0.0,
                                      op_dev=_logu(rng, 0.01, 0.3) if compressed else 0.0)
    if kind in ("stiction", "stiction_external"):
        case["S"] = S_ref
        case["J"] = S_ref * jump
    elif kind == "hysteresis":
        case["S"] = hyst
    if kind in ("external", "stiction_external"):
        case["external_amp"] = ext_amp
        case["external_period_s"] = ext_period
    else:
        case.pop("external_shape", None)
    case["label"] = "stiction" if kind.startswith("stiction") else "none"
    return case


#: :func:`simulate_loop`'s options that :func:`random_case` sets only with ``plant`` (absent: the option's default)
_PLANT_OPTIONS = ("kc_factor", "external_shape", "noise_ar", "slow_load_sd", "slow_load_tau_s", "drift_per_h",
                  "sp_walk_sd", "sp_walk_tau_s", "historian")


def simulate_case(case: dict) -> tuple[LoopData, SimTruth]:
    """The record of a :func:`random_case`."""
    loop, truth = simulate_loop(case["process"], S=case["S"], J=case["J"], seed=case["seed"], hours=case["hours"],
                                dt=case["dt"], tau_c_s=case["tau_c_s"], external_amp=case["external_amp"],
                                external_period_s=case["external_period_s"], sp_steps=case["sp_steps"],
                                op0=case["op0"], ti_factor=case["ti_factor"], load_tau_s=case["load_tau_s"],
                                **{k: case[k] for k in _PLANT_OPTIONS if k in case})
    truth.label = case["label"]
    truth.extra["kind"] = case["kind"]
    loop.tag = f"sim-{case['kind']}-{case['process'].name}-seed{case['seed']}"
    return loop, truth


def stiction_visibility(case: dict, loop: LoopData | None = None) -> float:
    """How much a sticky valve shows in its record: the variance of the control error (SP - PV) of the loop of
    ``case`` (``loop``, simulated when None) over that of its smooth twin (the same case and random numbers, S = J =
    0). About 1 when the stiction hides under noise and load (the stem is kept moving, no limit cycle), large when the
    valve drives the loop into a limit cycle. NaN for a valve without a band."""
    if case["S"] <= 0:
        return math.nan
    if loop is None:
        loop, _ = simulate_case(case)
    twin, _ = simulate_case({**case, "S": 0.0, "J": 0.0})
    return float(np.var(loop.sp - loop.pv) / max(float(np.var(twin.sp - twin.pv)), 1e-300))


__all__ = ["CASE_KINDS", "Historian", "SHAPES", "Process", "PROCESSES", "SimTruth", "random_case", "simulate_case",
           "simulate_loop", "stiction_visibility"]
