"""Stiction compensation through PI tuning, by describing-function analysis (docs/controllers.md,
"pi_stiction_tuned").

Method
------
Mohammad, M.A., Huang, B. (2012). Compensation of control valve stiction through controller tuning.
*J. Process Control* 22(9), 1800-1819: the loop "PI + sticky valve + process" is analysed with the
describing function of the valve's stick-slip; the PI's gains are chosen so that the predicted limit
cycle is absent, or as harmless as possible (small amplitude, long period). Detuning the integral
action is the field's first remedy (Gerry, J., Ruel, M. (2001). How to measure and combat valve
stiction online. *ISA 2001*, Houston). The paper's own text was not at hand (the project's search did
not return it), so its tuning chart is not reproduced; what is implemented is its analysis, with a
criterion stated here:

* **The nonlinearity** is the two-parameter (S, J) stick-slip of Choudhury, Thornhill and Shah
  (2005), *Modelling valve stiction*, Control Eng. Practice 13(5), 641-658, whose describing function
  (their section 6) is, for an input ``X sin(wt)`` with ``X > S/2`` (``N = 0`` below)::

      N(X) = -(A - jB) / (pi X),  phi = asin((X - S) / X)
      A = X/2 sin(2 phi) - 2 X cos(phi) - X pi/2 - X phi + 2 (S - J) cos(phi)
      B = -3X/2 + X/2 cos(2 phi) + 2 X sin(phi) - 2 (S - J) sin(phi)

  (:func:`sj_describing_function`; a test checks it against the fundamental of
  :func:`valve_env.physics.stickslip.simulate`).
* **Where it sits in this plant** (docs/controllers.md, "How the literature's sticky loop maps onto
  this plant"). The stem's input is the force balance's demand, which is, linearised and in kelvin of
  setting, ``u - T_b``: the controller's setting minus the bulb temperature (the valve's own
  proportional action, gain 1 in these units; ``g = physics.valve.gain_mm_per_K`` converts mm). The
  stem sticks by the stiction band ``S = J = band_mm / g``; the Dahl friction (F_hmax of
  :class:`~valve_env.params.ValveParams`) adds a hysteresis ``2 physics.valve.friction_band_K`` that the
  demand must also cross after a reversal, so the stem sees ``S_eff = band_mm / g + 2 friction_band_K``
  and ``J = jump_mm / g`` (1.30 K and 0.56 K at 60 degC and 100 mbar for the 0.1 mm band).
* **The linear part.** The stored FOPDT model from setting to outlet (``K, tau, theta`` in
  valve_env/data/controllers.yaml, the model the SIMC ``pi`` is tuned on) is the valve's own loop closed
  around the stem-to-tank response ``G_x``: ``K e^{-theta s} / (tau s + 1) = G_x / (1 + G_x)`` with
  the delay kept outside, so ``G_x(s) = K e^{-theta s} / (tau s + 1 - K)`` (nearly an integrator: the
  tank). With the PI ``C(s) = Kp (1 + 1 / (Ti s))`` on the outlet error and the bulb's unit feedback,
  the stem's input is ``-(C + 1) G_x`` times the stem position, so the loop is
  ``L(s) = (C(s) + 1) G_x(s)`` (theta takes half a control step for the hold, as SIMC does), and the
  harmonic balance ``1 + N(X) L(jw) = 0`` gives the predicted limit cycle: the stem's input amplitude
  ``X`` and the frequency ``w`` (:func:`predict_limit_cycle`); the outlet swings by
  ``Y = |G_x(jw) N(X)| X`` and the stem reverses twice per period.
* **The criterion.** A PI with an integrator on this near-integrating process always has a predicted
  cycle; along SIMC's one-parameter family (Skogestad 2003; ``tau_c`` from theta_eff, "tight", to
  tau, "smooth"), faster tuning gives a smaller outlet amplitude and more reversals, slower tuning
  the reverse. The gains chosen are those of the ``tau_c`` that minimises the predicted product
  *outlet amplitude x reversal rate* (``Y w / pi``, the cycle's share of iae times its reversals: the
  benchmark's trade-off product, docs/controllers.md), found by a bounded scalar search on
  ``log tau_c`` (:func:`df_tune`). Nothing here looks at an episode: the inputs are the band, the
  valve's parameters and the stored model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from scipy.optimize import fsolve, minimize_scalar

from valve_env.config import ControlParams
from valve_env.controllers.baselines import PIController
from valve_env.controllers.compensators import DEFAULT_BAND_MM, SETTING_ENV_IDS, _stored
from valve_env.params import ValveParams
from valve_env.physics.valve import friction_band_K, gain_mm_per_K
from valve_env.scenario import ScenarioParams

_CTRL = ControlParams()
_SCEN = ScenarioParams()


def sj_describing_function(X: float | np.ndarray, S: float, J: float) -> np.ndarray:
    """Describing function of the (S, J) stick-slip (Choudhury et al. 2005, section 6) for an input
    amplitude ``X`` (same units as ``S`` and ``J``); 0 where ``X <= S / 2`` (the stem never moves)."""
    X = np.asarray(X, dtype=float)
    if not (np.isfinite(S) and S > 0 and np.isfinite(J) and J >= 0):
        raise ValueError(f"the describing function needs S > 0 and J >= 0, got S={S!r}, J={J!r}")
    moving = X > 0.5 * S
    Xm = np.where(moving, X, S)
    phi = np.arcsin(np.clip((Xm - S) / Xm, -1.0, 1.0))
    A = 0.5 * Xm * np.sin(2 * phi) - 2 * Xm * np.cos(phi) - 0.5 * Xm * np.pi - Xm * phi + 2 * (S - J) * np.cos(phi)
    B = -1.5 * Xm + 0.5 * Xm * np.cos(2 * phi) + 2 * Xm * np.sin(phi) - 2 * (S - J) * np.sin(phi)
    return np.where(moving, -(A - 1j * B) / (np.pi * Xm), 0.0 + 0.0j)


@dataclass(frozen=True)
class StemLoopModel:
    """The linear part seen by the stem (module docstring), all in kelvin of setting."""

    K: float
    """Static gain of the stored FOPDT model, setting -> outlet, K/K (< 1: losses)."""
    tau_s: float
    """Its time constant, s."""
    theta_s: float
    """Its dead time plus half a control step (the hold), s."""
    S_K: float
    """The stem's effective stick band (stiction plus the Dahl hysteresis), K of setting."""
    J_K: float
    """The slip jump, K of setting."""

    def __post_init__(self) -> None:
        if not (0 < self.K < 1 and self.tau_s > 0 and self.theta_s >= 0 and self.S_K > 0 and self.J_K >= 0):
            raise ValueError(f"stem-loop model needs 0 < K < 1, tau > 0, theta >= 0, S > 0, J >= 0: {self}")

    def G_x(self, w: np.ndarray) -> np.ndarray:
        """The stem (K of setting) -> outlet response at the angular frequencies ``w`` (rad/s)."""
        s = 1j * np.asarray(w, dtype=float)
        return self.K * np.exp(-self.theta_s * s) / (self.tau_s * s + 1.0 - self.K)

    def loop(self, w: np.ndarray, Kp: float, Ti_s: float) -> np.ndarray:
        """L(jw) = (C(jw) + 1) G_x(jw): the PI and the valve's own proportional action on the stem."""
        s = 1j * np.asarray(w, dtype=float)
        return (Kp * (1.0 + 1.0 / (Ti_s * s)) + 1.0) * self.G_x(w)


@dataclass(frozen=True)
class LimitCycle:
    """A limit cycle predicted by the harmonic balance ``1 + N(X) L(jw) = 0``."""

    omega: float
    """Angular frequency, rad/s."""
    X_K: float
    """Amplitude of the stem's input (the demand), K of setting."""
    Y_K: float
    """Amplitude of the outlet temperature, K."""
    u_K: float
    """Amplitude of the controller's output (the setting), K."""

    @property
    def period_s(self) -> float:
        return 2.0 * math.pi / self.omega

    @property
    def reversals_per_day(self) -> float:
        """Two stem reversals per period."""
        return 2.0 * 86400.0 / self.period_s


def _segment_crossings(a: np.ndarray, b: np.ndarray) -> list[tuple[int, int, float, float]]:
    """Where the polylines ``a`` and ``b`` (complex points) cross: (i, j, s, t) with the crossing at
    ``a[i] + s (a[i+1] - a[i]) = b[j] + t (b[j+1] - b[j])``, 0 <= s, t <= 1."""
    p, r = a[:-1, None], (a[1:] - a[:-1])[:, None]
    q, d = b[None, :-1], (b[1:] - b[:-1])[None, :]
    den = (r.real * d.imag - r.imag * d.real)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((q - p).real * d.imag - (q - p).imag * d.real) / den
        t = ((q - p).real * r.imag - (q - p).imag * r.real) / den
    hit = np.isfinite(s) & np.isfinite(t) & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    return [(int(i), int(j), float(s[i, j]), float(t[i, j])) for i, j in zip(*np.nonzero(hit), strict=True)]


def predict_limit_cycles(model: StemLoopModel, Kp: float, Ti_s: float, dt_s: float = _CTRL.dt_s) -> list[LimitCycle]:
    """Every solution of the harmonic balance ``N(X) = -1 / L(jw)`` below the Nyquist frequency pi/dt:
    the crossings of the two loci in the complex plane, refined by Newton's method (scipy's fsolve)."""
    if not (np.isfinite(Kp) and Kp >= 0 and np.isfinite(Ti_s) and Ti_s > 0):
        raise ValueError(f"PI gains must be finite with Kp >= 0 and Ti_s > 0, got {Kp!r}, {Ti_s!r}")
    S, J = model.S_K, model.J_K
    lX = np.linspace(math.log(0.5 * S * (1 + 1e-9)), math.log(1e3 * S), 400)
    lw = np.linspace(math.log(1e-7), math.log(math.pi / dt_s), 1500)
    n_curve = sj_describing_function(np.exp(lX), S, J)
    m_curve = -1.0 / model.loop(np.exp(lw), Kp, Ti_s)

    def resid(p: np.ndarray) -> list[float]:
        X, w = math.exp(p[0]), math.exp(p[1])
        z = 1.0 + complex(sj_describing_function(X, S, J)) * complex(model.loop(np.array([w]), Kp, Ti_s)[0])
        return [z.real, z.imag]

    out: list[LimitCycle] = []
    for i, j, s, t in _segment_crossings(n_curve, m_curve):
        p0 = np.array([lX[i] + s * (lX[i + 1] - lX[i]), lw[j] + t * (lw[j + 1] - lw[j])])
        p, _, ier, _ = fsolve(resid, p0, full_output=True, xtol=1e-12)
        if ier != 1 or max(abs(v) for v in resid(p)) > 1e-8:
            p = p0  # the grid's crossing, if Newton's method wanders off
        X, w = float(math.exp(p[0])), float(math.exp(p[1]))
        if X <= 0.5 * S or w > math.pi / dt_s:
            continue
        n = complex(sj_describing_function(X, S, J))
        Y = abs(complex(model.G_x(np.array([w]))[0]) * n) * X
        u = abs(Kp * (1.0 + 1.0 / (Ti_s * 1j * w))) * Y
        if not any(abs(c.omega - w) < 1e-6 * w and abs(c.X_K - X) < 1e-6 * X for c in out):
            out.append(LimitCycle(omega=w, X_K=X, Y_K=float(Y), u_K=float(u)))
    return sorted(out, key=lambda c: c.X_K)


def predict_limit_cycle(model: StemLoopModel, Kp: float, Ti_s: float, dt_s: float = _CTRL.dt_s) -> LimitCycle | None:
    """The limit cycle the describing function predicts for the PI (Kp K/K, Ti s), or None if the
    harmonic balance has no solution below the Nyquist frequency; with several, the one of largest
    amplitude (the outer intersection, the stable one of a stick-slip loop)."""
    cycles = predict_limit_cycles(model, Kp, Ti_s, dt_s)
    return cycles[-1] if cycles else None


@dataclass(frozen=True)
class DFTuning:
    """The result of :func:`df_tune`."""

    Kp: float
    Ti_s: float
    tau_c_s: float
    cycle: LimitCycle | None


def simc_family(model: StemLoopModel, tau_c_s: float) -> tuple[float, float]:
    """SIMC's PI (Skogestad 2003) on the stored FOPDT model for the closed-loop time constant tau_c."""
    from valve_env.controllers.process import ModelFit, simc_pi

    g = simc_pi(ModelFit("fopdt", model.K, model.tau_s, model.theta_s, 0.0), tau_c_s, 0.0)
    return g.Kp, g.Ti_s


def df_tune(model: StemLoopModel, dt_s: float = _CTRL.dt_s) -> DFTuning:
    """The SIMC tau_c in [theta_eff, tau] whose PI minimises the predicted cycle's outlet amplitude x
    reversal rate (module docstring); a PI without a predicted cycle there is taken at once."""

    def cost(log_tc: float) -> float:
        Kp, Ti = simc_family(model, math.exp(log_tc))
        c = predict_limit_cycle(model, Kp, Ti, dt_s)
        return 0.0 if c is None else c.Y_K * c.omega / math.pi

    lo, hi = math.log(max(model.theta_s, dt_s)), math.log(model.tau_s)
    grid = np.linspace(lo, hi, 13)
    costs = [cost(float(v)) for v in grid]
    k = int(np.argmin(costs))
    a, b = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, len(grid) - 1)])
    res = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 1e-3})
    log_tc = float(res.x) if res.fun <= costs[k] else float(grid[k])
    tc = math.exp(log_tc)
    Kp, Ti = simc_family(model, tc)
    return DFTuning(Kp=Kp, Ti_s=Ti, tau_c_s=tc, cycle=predict_limit_cycle(model, Kp, Ti, dt_s))


def stem_loop_model(env_id: str, band_mm: float, jump_mm: float | None = None, valve: ValveParams | None = None,
                    T_C: float = _CTRL.T_target_C, dp_mbar: float = _SCEN.dp_mbar,
                    dt_s: float = _CTRL.dt_s) -> StemLoopModel:
    """The :class:`StemLoopModel` of ``env_id``'s stored FOPDT model and a stem with stiction band
    ``band_mm`` (and jump ``jump_mm``, default the band), linearised at the setting ``T_C`` and ``dp_mbar``."""
    from valve_env.controllers.base import original_id
    from valve_env.controllers.tuning import load_gains

    if not (np.isfinite(band_mm) and band_mm > 0):
        raise ValueError(f"pi_stiction_tuned: band_mm must be finite and > 0, got {band_mm!r}")
    jump = band_mm if jump_mm is None else jump_mm
    if not (np.isfinite(jump) and jump >= 0):
        raise ValueError(f"pi_stiction_tuned: jump_mm must be finite and >= 0, got {jump_mm!r}")
    vp = (valve or ValveParams()).to_array()
    g = float(gain_mm_per_K(T_C, dp_mbar, vp))
    m = load_gains(original_id(env_id))["model"]
    return StemLoopModel(K=float(m["K"]), tau_s=float(m["tau_s"]), theta_s=float(m["theta_s"]) + 0.5 * dt_s,
                         S_K=band_mm / g + 2.0 * float(friction_band_K(T_C, vp)), J_K=jump / g)


class PIStictionTuned(PIController):
    """A PI whose gains compensate the valve's stiction by tuning (Mohammad & Huang 2012; module docstring).

    The gains are computed at construction from the stiction band ``band_mm`` (mm of stem; the task's
    0.1 mm by default, or a diagnosed valve's), the jump ``jump_mm`` (default the band), the valve's
    parameters (the gain g and the Dahl band) and the stored FOPDT model of ``env_id``: the SIMC PI
    whose describing-function-predicted limit cycle has the smallest outlet amplitude x reversal rate
    (:func:`df_tune`). The law is :class:`~valve_env.controllers.baselines.PIController`'s;
    ``tuning`` holds the chosen tau_c and the predicted cycle. Memory: the PI's.
    """

    name: ClassVar[str] = "pi_stiction_tuned"
    supported_env_ids: ClassVar[tuple[str, ...]] = SETTING_ENV_IDS

    def __init__(self, env_id: str = "ThermoValve-v0", band_mm: float | None = None, jump_mm: float | None = None,
                 valve: ValveParams | None = None, **pi_kwargs: Any) -> None:
        from valve_env.controllers.base import Controller

        Controller.__init__(self, env_id)  # the env id check first: only setting loops have the FOPDT model
        if "Kp" in pi_kwargs or "Ti_s" in pi_kwargs:
            raise ValueError("pi_stiction_tuned: Kp and Ti_s are computed from the band, not given")
        stored = _stored(env_id, self.name)
        band = float(stored.get("band_mm", DEFAULT_BAND_MM) if band_mm is None else band_mm)
        dt = float(pi_kwargs.get("dt_s", _CTRL.dt_s))
        self.model = stem_loop_model(env_id, band, jump_mm, valve, dt_s=dt)
        self.tuning = df_tune(self.model, dt)
        self.band_mm = band
        super().__init__(env_id, Kp=self.tuning.Kp, Ti_s=self.tuning.Ti_s, **pi_kwargs)
