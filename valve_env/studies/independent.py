"""A second, independent simulator of the valve experiment, for the uncertainty studies.

Written apart from the project's generator (:mod:`valve_env.experiment`) so that a
study on its runs tests the estimators against data they were not built around
(docs/uncertainty.md). What differs on purpose:

* **Integration.** The continuous ODEs are integrated by ``scipy.integrate.solve_ivp``
  (adaptive Runge-Kutta, tight tolerances): the Dahl friction
  ``dF/dt = v sigma (1 - F / F_hmax sgn v)`` (paper eq. 14/15, alpha = 1) and, with
  ``sensor_lag``, the bulb ``tau dT_g/dt = T_env - T_g``. The project's generator
  uses the exact per-increment Dahl update on a fixed grid instead.
* **Inputs.** The tank and medium temperatures are smooth sums of tanh transitions
  between random plateaus (analytic rates), not first-order responses to steps.
* **Force balance.** Re-derived here from the paper (eq. 11/16) and the methanol
  vapour pressure (Antoine), with the valve constants (only the numbers) from
  :class:`~valve_env.params.ValveParams`; a test checks it against
  :mod:`valve_env.physics.valve` (the two must agree: that is a physics check,
  not shared code).
* **Stiction, three re-stick rules** (``stiction_variant``), applied to the
  clipped demanded opening on a 1 s grid (end stops always win, the stem then
  rests there):

  - ``"reset"``: Karnopp-style *re-sticks after every slip*: the resting stem
    stays until the demand is ``band_mm`` away, jumps to the demand and sticks
    again at once (a staircase on a ramp).
  - ``"sj"``: the two-parameter (S, J) model of Choudhury, Thornhill & Shah
    (2005, Control Eng. Practice 13, 641-658), with Kano et al.'s (2004) rule
    that the valve sticks when its input stops or reverses. S = ``band_mm``
    (dead band plus stick band), J = ``sj_jump`` x S (the slip jump). Once it
    slips the stem *moves with the demand* (lagging by (S - J)/2) until the
    demand reverses or stops: it re-sticks only then, not after every slip.
  - ``"force"``: a quasi-static stem with separate static and Coulomb
    friction (Karnopp 1985's stick/slip switch on the force): the spring force
    imbalance ``C (x_d - x)`` must exceed the static friction
    ``F_s = C band_mm / 2 (1 + r)`` to break away, and while slipping the
    stem sits where the imbalance equals the Coulomb friction ``F_c = r F_s``
    (``r`` = ``force_ratio``). It re-sticks when the demand reverses. From
    a reversal the demand travels ``(F_s + F_c) / C = band_mm`` before the stem
    breaks away, so ``band_mm`` has the same meaning as in the other two. (With
    a massless stem this is equivalent to an (S, J) valve with
    J = (1 - r) / (1 + r) S; it is written from the force law, on its own.)

Conventions of measured data (docs/reference.md, section 2): ``medium`` ``"steps"`` holds the medium
temperature on plateaus changed by a thermostat in sharp steps, ``"constant"`` holds it at 60 degC;
``conventions`` names measurement conventions of :mod:`valve_env.studies.conventions` (quantised,
stepped, noiseless, held, dropped rows, a gap, a longer interval, spikes, extra columns), applied in
order to the simulated record (truth columns kept). ``jitter`` jitters the sample times.

Noise: temperature channels ``T_noise_C`` (0.001-0.02 degC in the studies),
flow and pressures relative ``rel_noise`` (paper Table 1: 1.5 %), the opening
``x_noise_mm`` (the paper's residual sd, 2.4e-3 mm). Everything is seeded.

Output: a DataFrame with the docs/reference.md, section 2 columns (``time_s, T_tank_C, T_med_C,
q_kgh, dp_mbar, ps_bar, x_mm``) and ``true_T_tank_C, true_T_med_C, true_T_g_C,
true_F_h_N, true_x_demand_mm, true_x_mm``; ``attrs`` hold the truth (valve
parameters, effects, variant, seed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from valve_env.params import ConfigError, ValveParams

#: effect names (docs/reference.md, section 3) and their parameters
EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    "sensor_lag": ("tau_s",),
    "medium_temperature": ("beta",),
    "stiction": ("band_mm",),
    "setpoint_drift": ("rate_MPa_per_h",),
}
STICTION_VARIANTS: tuple[str, ...] = ("reset", "sj", "force")
#: the medium temperature's programme: smooth tanh transitions (the default), a thermostat's sharp
#: steps between held plateaus, or one constant level
MEDIUM_PROGRAMMES: tuple[str, ...] = ("smooth", "steps", "constant")
COLUMNS: tuple[str, ...] = ("time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm")


@dataclass(frozen=True)
class IndependentRun:
    """One run of the independent simulator (all units in the names).

    ``effects`` maps docs/reference.md, section 3 names to their parameters. ``stiction_variant`` one of
    :data:`STICTION_VARIANTS`; ``sj_jump`` J / S of the (S, J) variant; ``force_ratio`` F_c / F_s
    of the force variant."""

    seed: int
    duration_h: float = 24.0
    dt_s: float = 10.0
    T_noise_C: float = 0.01
    x_noise_mm: float = 2.4e-3
    rel_noise: float = 0.015
    dp_mbar: float = 100.0
    ps_bar: float = 2.0
    jitter: float = 0.0
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    stiction_variant: str = "reset"
    sj_jump: float = 1.0
    force_ratio: float = 0.5
    valve: ValveParams = field(default_factory=ValveParams)
    medium: str = "smooth"
    conventions: tuple[str, ...] = ()

    def check(self) -> None:
        for name in ("duration_h", "dt_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be > 0, got {v!r}")
        for name in ("T_noise_C", "x_noise_mm", "rel_noise"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be >= 0, got {v!r}")
        if not 0.0 <= self.jitter < 0.5:
            raise ConfigError(f"jitter must be in [0, 0.5), got {self.jitter!r}")
        if self.stiction_variant not in STICTION_VARIANTS:
            raise ConfigError(f"stiction_variant must be one of {STICTION_VARIANTS}, got {self.stiction_variant!r}")
        if not 0.0 <= self.sj_jump <= 1.0:
            raise ConfigError(f"sj_jump must be in [0, 1], got {self.sj_jump!r}")
        if self.medium not in MEDIUM_PROGRAMMES:
            raise ConfigError(f"medium must be one of {MEDIUM_PROGRAMMES}, got {self.medium!r}")
        from valve_env.studies.conventions import CONVENTIONS, frame_problem

        unknown = [c for c in self.conventions if c not in CONVENTIONS]
        if unknown:
            raise ConfigError(f"unknown convention {unknown[0]!r}; known: {sorted(CONVENTIONS)}")
        if frame_problem(self.conventions):
            raise ConfigError(frame_problem(self.conventions))
        if not 0.0 <= self.force_ratio < 1.0:
            raise ConfigError(f"force_ratio must be in [0, 1), got {self.force_ratio!r}")
        for name, pars in self.effects.items():
            if name not in EFFECT_PARAMS:
                raise ConfigError(f"unknown effect {name!r}; known: {sorted(EFFECT_PARAMS)}")
            if set(pars) != set(EFFECT_PARAMS[name]):
                raise ConfigError(f"effect {name!r} needs exactly {EFFECT_PARAMS[name]}, got {sorted(pars)}")


# --------------------------------------------------------------------------- physics (paper eq. 11/16)
def vapour_pressure_MPa(T_C: np.ndarray | float, vp: ValveParams) -> np.ndarray:
    """Methanol charge: log10(p / bar) = A - B / (T/K + C) (NIST Antoine), in MPa."""
    return 0.1 * 10.0 ** (vp.antoine_A - vp.antoine_B / (np.asarray(T_C, dtype=float) + 273.15 + vp.antoine_C))


def demanded_opening_mm(T_g: np.ndarray, F_h: np.ndarray, dp_mbar: np.ndarray | float, ps_bar: np.ndarray | float,
                        p_bset: np.ndarray | float, vp: ValveParams) -> np.ndarray:
    """The unclipped force-balance opening (paper eq. 16), mm; pressures converted to MPa."""
    dpk = np.asarray(dp_mbar, dtype=float) * 1e-4
    dps = np.asarray(ps_bar, dtype=float) * 0.1
    num = (vp.A_k * (dpk - vp.dp_k_sp) + vp.A_s * (dps - vp.dp_s_sp)
           - vp.A_b * (vapour_pressure_MPa(T_g, vp) - p_bset) + F_h)
    return num / (vp.C_v + vp.C_i + vp.C_b + vp.K_f * dpk)


def flow_from_opening(x_mm: np.ndarray, dp_mbar: np.ndarray, vp: ValveParams) -> np.ndarray:
    """q = 31.62 Kv sqrt(dp), Kv = Kvs (l + (1 - l) x / stroke), kg/h (docs/reference.md, section 1 default valve)."""
    kv = vp.Kvs * (vp.leakage + (1.0 - vp.leakage) * np.clip(x_mm, 0.0, vp.stroke) / vp.stroke)
    return 31.62 * kv * np.sqrt(np.maximum(dp_mbar, 0.0))


def setpoint_C(vp: ValveParams) -> float:
    """The gas temperature at which the bellows pressure equals p_bset (Antoine inverted)."""
    return vp.antoine_B / (vp.antoine_A - math.log10(vp.p_bset * 10.0)) - vp.antoine_C - 273.15


# --------------------------------------------------------------------------- smooth inputs
@dataclass(frozen=True)
class TanhProgramme:
    """T(t) = level_0 + sum_i a_i (1 + tanh((t - t_i) / w_i)) / 2, with its analytic rate."""

    level0: float
    t_i: np.ndarray
    a_i: np.ndarray
    w_i: np.ndarray

    def __call__(self, t: np.ndarray | float) -> np.ndarray:
        z = (np.atleast_1d(np.asarray(t, dtype=float))[:, None] - self.t_i) / self.w_i
        return self.level0 + (self.a_i * 0.5 * (1.0 + np.tanh(z))).sum(axis=1)

    def rate(self, t: np.ndarray | float) -> np.ndarray:
        z = (np.atleast_1d(np.asarray(t, dtype=float))[:, None] - self.t_i) / self.w_i
        return (self.a_i * 0.5 / self.w_i / np.cosh(np.clip(z, -300.0, 300.0)) ** 2).sum(axis=1)


def _programme(rng: np.random.Generator, t_end: float, lo: float, hi: float, dwell_min: tuple[float, float],
               width_min: tuple[float, float], alternate: bool) -> TanhProgramme:
    level = float(rng.uniform(lo + 0.3 * (hi - lo), hi - 0.2 * (hi - lo)))
    level0 = level
    ts, amps, ws = [], [], []
    t = float(rng.uniform(0.3, 1.0)) * dwell_min[0] * 60.0
    up = bool(rng.integers(2))
    while t < t_end + 3600.0:
        if alternate:
            room = (hi - level) if up else (level - lo)
            amp = rng.uniform(0.25, 1.5) if rng.random() < 0.35 else rng.uniform(0.35, 1.0) * room
            amp = float(min(max(amp, 0.2), max(room, 0.2)))
            new = level + amp if up else level - amp
            up = not up
        else:
            new = float(rng.uniform(lo, hi))
        new = float(np.clip(new, lo, hi))
        ts.append(t)
        amps.append(new - level)
        ws.append(60.0 * math.exp(rng.uniform(math.log(width_min[0]), math.log(width_min[1]))))
        level = new
        t += 60.0 * float(rng.uniform(*dwell_min))
    return TanhProgramme(level0, np.array(ts), np.array(amps), np.array(ws))


# --------------------------------------------------------------------------- stick-slip rules
def stick_reset(xd: np.ndarray, band: float, stroke: float) -> np.ndarray:
    """Re-sticks after every slip: rest until |x_d - x| >= band, jump to x_d, rest again."""
    x = np.empty_like(xd)
    x[0] = xd[0]
    for i in range(1, len(xd)):
        if xd[i] <= 0.0 or xd[i] >= stroke or abs(xd[i] - x[i - 1]) >= band:
            x[i] = xd[i]
        else:
            x[i] = x[i - 1]
    return x


def stick_sj(xd: np.ndarray, S: float, J: float, stroke: float) -> np.ndarray:
    """Choudhury et al. (2005) (S, J) model with Kano et al.'s (2004) stop/reversal rule, on the
    demanded opening ``xd`` (already clipped to the stops). Written from the papers' flow chart."""
    n = len(xd)
    y = np.empty(n)
    y[0] = xd[0]
    stuck = True
    x_ss = xd[0]  # the demand where the stem last stuck
    d_old = 0.0
    stuck_dir = 0.0  # the direction of motion when it stuck
    for k in range(1, n):
        dx = xd[k] - xd[k - 1]
        d_new = float(np.sign(dx))
        if xd[k] <= 0.0 or xd[k] >= stroke:  # end stop wins; the stem rests there
            y[k] = xd[k]
            stuck, x_ss, d_old, stuck_dir = True, xd[k], 0.0, 0.0
            continue
        if d_new == 0.0 or (d_old != 0.0 and d_new != d_old):  # the input stops or reverses: stick
            if not stuck:
                stuck, x_ss, stuck_dir = True, xd[k - 1], d_old
        if stuck:
            # after a reversal the demand crosses dead band and stick band (S); after a stop that
            # resumes in the same direction only the stick band (J) (Choudhury et al. 2005)
            thresh = J if (d_new != 0.0 and d_new == stuck_dir) else S
            if d_new != 0.0 and abs(xd[k] - x_ss) > thresh:
                stuck = False
                y[k] = xd[k] - d_new * (S - J) / 2.0
            else:
                y[k] = y[k - 1]
        else:
            y[k] = xd[k] - d_new * (S - J) / 2.0
        if d_new != 0.0:
            d_old = d_new
        y[k] = min(max(y[k], 0.0), stroke)
    return y


def stick_force(xd: np.ndarray, band: float, ratio: float, C: float, stroke: float) -> np.ndarray:
    """Quasi-static stem with static friction F_s and Coulomb friction F_c = ratio F_s (N): the
    imbalance f = C (x_d - x) breaks the stem away when |f| > F_s; while it slips the stem follows
    x = x_d - sgn(v) F_c / C; it sticks when the demand reverses (the imbalance falls below F_c)."""
    F_s = C * band / (1.0 + ratio)
    F_c = ratio * F_s
    x = np.empty_like(xd)
    x[0] = xd[0]
    moving = 0.0  # +1/-1 while slipping, 0 while stuck
    for i in range(1, len(xd)):
        if xd[i] <= 0.0 or xd[i] >= stroke:
            x[i] = xd[i]
            moving = 0.0
            continue
        f = C * (xd[i] - x[i - 1])
        if moving != 0.0 and f * moving > F_c:  # still pushed along its motion: keeps slipping
            x[i] = xd[i] - moving * F_c / C
        elif abs(f) > F_s:  # break away
            moving = float(np.sign(f))
            x[i] = xd[i] - moving * F_c / C
        else:  # static friction holds
            moving = 0.0
            x[i] = x[i - 1]
    return x


# --------------------------------------------------------------------------- the simulator
def simulate_independent(run: IndependentRun) -> pd.DataFrame:
    """Simulate one run (see the module docstring)."""
    run.check()
    vp = run.valve
    rng = np.random.default_rng(run.seed)
    t_end = run.duration_h * 3600.0
    T_sp = setpoint_C(vp)
    tank = _programme(rng, t_end, T_sp - 12.0, T_sp + 3.5, (25.0, 100.0), (2.0, 15.0), True)
    med = _programme(rng, t_end, 45.0, 75.0, (15.0, 70.0), (1.0, 8.0), False)
    if run.medium == "steps":  # a thermostat: the same plateaus, each change within about 20 s
        med = TanhProgramme(med.level0, med.t_i, med.a_i, np.full_like(med.w_i, 10.0))
    elif run.medium == "constant":
        med = TanhProgramme(60.0, np.zeros(0), np.zeros(0), np.ones(0))
    eff = {k: dict(v) for k, v in run.effects.items()}
    beta = eff.get("medium_temperature", {}).get("beta", 0.0)
    tau = eff.get("sensor_lag", {}).get("tau_s", 0.0)
    band = eff.get("stiction", {}).get("band_mm", 0.0)
    rate = eff.get("setpoint_drift", {}).get("rate_MPa_per_h", 0.0) / 3600.0
    sig, Fm = vp.sigma, vp.F_hmax

    def T_env(t: np.ndarray | float) -> np.ndarray:
        a = tank(t)
        return a + beta * (med(t) - a)

    def v_env(t: float) -> float:
        a = tank.rate(t)[0]
        return float(a + beta * (med.rate(t)[0] - a))

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        if tau > 0.0:
            v = (float(T_env(t)[0]) - y[0]) / tau
            F = y[1]
            return np.array([v, v * sig * (1.0 - F / Fm * np.sign(v))])
        v = v_env(t)
        return np.array([v * sig * (1.0 - y[0] / Fm * np.sign(v))])

    y0 = np.array([float(T_env(0.0)[0]), 0.0]) if tau > 0.0 else np.array([0.0])
    sol = solve_ivp(rhs, (0.0, t_end), y0, method="RK45", rtol=1e-9, atol=1e-10, max_step=10.0,
                    dense_output=True)
    if not sol.success:  # pragma: no cover - smooth inputs
        raise RuntimeError(f"independent simulator: integration failed: {sol.message}")

    n = int(math.floor(t_end / run.dt_s + 1e-9)) + 1
    t_s = np.arange(n) * run.dt_s
    if run.jitter > 0:
        t_s = t_s + rng.uniform(-run.jitter, run.jitter, n) * run.dt_s
        t_s[0] = 0.0
        t_s = np.clip(t_s, 0.0, t_end)

    def state(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Y = sol.sol(t)
        if tau > 0.0:
            return Y[0], Y[1]
        return T_env(t), Y[0]

    def demand(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        Tg, F = state(t)
        xd = demanded_opening_mm(Tg, F, run.dp_mbar, run.ps_bar, vp.p_bset + rate * t, vp)
        return Tg, F, xd

    Tg_s, F_s, xd_s = demand(t_s)
    if band > 0.0:  # the stem's stick-slip on a 1 s grid, then sampled (held: no interpolation across a slip)
        t_f = np.arange(0.0, t_end + 1.0, 1.0)
        _, _, xd_f = demand(t_f)
        xc = np.clip(xd_f, 0.0, vp.stroke)
        if run.stiction_variant == "reset":
            xs_f = stick_reset(xc, band, vp.stroke)
        elif run.stiction_variant == "sj":
            xs_f = stick_sj(xc, band, run.sj_jump * band, vp.stroke)
        else:
            C = vp.C_v + vp.C_i + vp.C_b + vp.K_f * run.dp_mbar * 1e-4
            xs_f = stick_force(xc, band, run.force_ratio, C, vp.stroke)
        idx = np.minimum(np.searchsorted(t_f, t_s + 1e-9, side="right") - 1, len(t_f) - 1)
        x_true = xs_f[idx]
    else:
        x_true = np.clip(xd_s, 0.0, vp.stroke)

    T_tank_true = tank(t_s)
    T_med_true = med(t_s)
    dp_true = np.full(n, run.dp_mbar)
    ps_true = np.full(n, run.ps_bar)
    q_true = flow_from_opening(x_true, dp_true, vp)
    z = rng.standard_normal((6, n))
    df = pd.DataFrame({
        "time_s": t_s,
        "T_tank_C": T_tank_true + run.T_noise_C * z[0],
        "T_med_C": T_med_true + run.T_noise_C * z[1],
        "q_kgh": q_true * (1.0 + run.rel_noise * z[2]),
        "dp_mbar": dp_true * (1.0 + run.rel_noise * z[3]),
        "ps_bar": ps_true * (1.0 + run.rel_noise * z[4]),
        "x_mm": x_true + run.x_noise_mm * z[5],
        "true_T_tank_C": T_tank_true,
        "true_T_med_C": T_med_true,
        "true_T_g_C": Tg_s,
        "true_F_h_N": F_s,
        "true_x_demand_mm": xd_s,
        "true_x_mm": x_true,
    })
    attrs = {"simulator": "valve_env.studies.independent", "seed": run.seed, "effects": eff,
             "stiction_variant": run.stiction_variant if band > 0 else None,
             "truth": {"sigma": vp.sigma, "F_hmax": vp.F_hmax, "p_bset": vp.p_bset},
             "medium": run.medium, "conventions": list(run.conventions)}
    if run.conventions:  # recorded the way measured data are (valve_env.studies.conventions), truth kept
        from valve_env.studies.conventions import apply_convention

        crng = np.random.default_rng([run.seed, 37])
        for name in run.conventions:
            df = apply_convention(df, name, crng, keep_truth=True)
    df.attrs.update(attrs)
    return df


def draw_run(rng: np.random.Generator, effect: str = "none", *, T_noise_C: float | None = None,
             stiction_variant: str = "reset", valve: ValveParams | None = None, medium: str = "smooth",
             conventions: tuple[str, ...] = ()) -> IndependentRun:
    """A randomised study run: 14-24 h at 5-15 s, temperature noise U(0.001, 0.02) degC unless given,
    the effect's size drawn from its own range (docs/uncertainty.md), a fresh run seed."""
    eff: dict[str, dict[str, float]] = {}
    if effect == "sensor_lag":
        eff = {effect: {"tau_s": float(math.exp(rng.uniform(math.log(30.0), math.log(150.0))))}}
    elif effect == "medium_temperature":
        eff = {effect: {"beta": float(rng.uniform(0.05, 0.2))}}
    elif effect == "stiction":
        eff = {effect: {"band_mm": float(rng.uniform(0.02, 0.05))}}
    elif effect == "setpoint_drift":
        eff = {effect: {"rate_MPa_per_h": float(rng.choice([-1.0, 1.0]) * rng.uniform(2e-5, 6e-5))}}
    elif effect != "none":
        raise ConfigError(f"unknown effect {effect!r}")
    return IndependentRun(
        seed=int(rng.integers(0, 2**31 - 1)),
        duration_h=float(rng.uniform(14.0, 24.0)),
        dt_s=float(rng.integers(5, 16)),
        T_noise_C=float(rng.uniform(0.001, 0.02)) if T_noise_C is None else float(T_noise_C),
        effects=eff, stiction_variant=stiction_variant,
        valve=valve if valve is not None else ValveParams(), medium=medium, conventions=tuple(conventions),
    )


def truth_of(df: pd.DataFrame) -> dict[str, Any]:
    """The true parameters stored by :func:`simulate_independent` (base and effects)."""
    return {"base": dict(df.attrs["truth"]), "effects": dict(df.attrs["effects"])}


__all__ = ["IndependentRun", "simulate_independent", "draw_run", "truth_of", "demanded_opening_mm",
           "vapour_pressure_MPa", "flow_from_opening", "setpoint_C", "stick_reset", "stick_sj", "stick_force",
           "TanhProgramme", "STICTION_VARIANTS", "EFFECT_PARAMS", "COLUMNS", "MEDIUM_PROGRAMMES"]
