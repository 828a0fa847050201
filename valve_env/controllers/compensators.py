"""Stiction compensators and a wear-aware PI for the setting loop (docs/controllers.md).

How the literature's loop maps onto this plant
----------------------------------------------
In the papers a controller output ``u_c`` (% OP) drives a sticky valve whose stem follows the (S, J)
stick-slip model (Choudhury et al. 2005). Here the controller trims the valve's temperature
*setting* (ThermoValve-v0, the setting channel of ThermoValveDual-v0). The sticky element is the
stem, and its input is the force balance's *demanded opening* ``x_d`` (mm; docs/reference.md,
section 3, stiction). The setting spring moves the set pressure, so a setting change ``dT`` moves the demand by
``g dT``, with ``g = A_b p_b'(T) / (C_v + C_i + C_b + K_f dp)`` (``physics.valve.gain_mm_per_K``,
about 0.18 mm/K at 60 degC and 100 mbar). Unlike the papers' loops, the demand also moves with the
bulb temperature (the valve's own proportional action) and the Dahl friction force. The compensators
state their amplitudes in stem millimetres, set from the stiction band ``band_mm`` (as a stiction
quantification such as ``thermovalve diagnose`` reports it), and convert them to kelvin of setting
with ``g`` at the current operating point.

Compensators (each the tuned ``pi`` of :class:`~valve_env.controllers.baselines.PIController` plus a
term added to its output):

* :class:`Knocker`: Hägglund, T. (2002). A friction compensator for pneumatic control valves.
  *J. Process Control* 12(8), 897-904. Pulses of amplitude ``a``, width ``tau`` and period ``h_k``
  in the direction of the controller output's change since the last pulse.
* :class:`ConstantReinforcement`: Ivan, L.Z.X., Lakshminarayanan, S. (2009). A new unified approach
  to valve stiction quantification and compensation. *Ind. Eng. Chem. Res.* 48(7), 3474-3483. A
  constant ``a`` added in the direction of the controller output's last change.
* :class:`TwoMove`: Srinivasan, R., Rengaswamy, R. (2005). Stiction compensation in process control
  loops: a framework for integrating stiction measure and compensation. *Ind. Eng. Chem. Res.* 44(24),
  9164-9174; and (2008) Approaches for efficient stiction compensation in process control valves.
  *Comput. Chem. Eng.* 32(1-2), 218-229. The stem is placed where the controller wants it with at
  most two moves computed from the (S, J) model: away by more than a band, then back onto the target.
  Between repositionings the setting holds the demand still, so the stem stays stuck and does not
  hunt. Adapted: the stem's position is read from the measured primary flow (a heat meter's reading,
  observation ``q_primary_kgh``, inverted through the valve characteristic), and the demand is
  computed from the valve model driven by the observed pocket temperature (the bulb lag and Dahl
  friction estimates of :class:`~valve_env.controllers.baselines.DahlCompensator`).

* :class:`TwoMovePosition`: the same two moves in the papers' own loop, where the controller's
  output is the valve position (S&R 2005, 2008): a PI on the outlet whose output is the stem
  position in mm, SIMC-tuned (Skogestad 2003) on the integrating model of the tank's response to the
  stem, ``k' = (dq/dx) (T_supply - T_target) / m_tank`` (K/s per mm); the stem is re-placed when that
  position and the stem (read from the flow) are more than ``replace_band x band_mm`` apart,
  approaching every target from above (a stem near its seat cannot be placed from below).

* :class:`PIIntegralBand`: a PI whose integral action is frozen while the error is inside a band, so
  a stem resting within the band's reach of the target is left there instead of being wound loose
  again (the "modified PI" for stiction of Farenzena, M., Trierweiler, J.O. (2010), *IFAC DYCOPS 2010*,
  Leuven; the idea, as the issue states it: the paper's text was not at hand, so the band is derived
  here, not taken from it): the band is the error at which the proportional action alone moves the
  stem's demand by one stiction band, ``band_factor x band_mm / (g Kp)``.

Wear-aware PI:

* :class:`PIWear`: an event-based PI (Årzén, K.-E. (1999). A simple event-based PID controller.
  *Proc. 14th IFAC World Congress*, Beijing, 423-428). The control is recomputed only when the
  error has moved by more than ``e_lim_K`` since the last update or ``h_max`` steps have passed, the
  integral over the elapsed time; between events the setting holds, so the stem is not nudged every
  30 s. The gains are SIMC's (Skogestad 2003) on the stored FOPDT model with the longest hold's half
  added to the dead time (theta_eff = theta + h_max dt / 2), the ``pi``'s own rule for its longer
  sampling.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from valve_env.config import ControlParams
from valve_env.controllers.base import I_DP, I_SETTING, I_T_OUT, I_T_TARGET, OBS_NAMES, Controller, original_id
from valve_env.controllers.baselines import DahlCompensator, PIController
from valve_env.params import I_A_B, I_A_K, I_A_S, I_DP_K_SP, I_DP_S_SP, I_STROKE, TankParams, ValveParams
from valve_env.physics.valve import (
    BAR_TO_MPA,
    MBAR_TO_MPA,
    demanded_opening,
    flow_kgh,
    gain_mm_per_K,
    opening_from_flow,
    saturation_temperature,
    setpoint_pressure,
    stiffness,
    vapour_pressure,
)
from valve_env.scenario import ScenarioParams

_CTRL = ControlParams()
_SCEN = ScenarioParams()
I_Q = OBS_NAMES.index("q_primary_kgh")
SETTING_ENV_IDS = ("ThermoValve-v0", "ThermoValveDual-v0")
DEFAULT_BAND_MM = 0.1
"""Default stiction band of the compensators, mm (5 % of the 2 mm stroke); pass the valve's own."""


def _stored(env_id: str, name: str) -> dict[str, Any]:
    """The stored settings of controller ``name`` for ``env_id`` in valve_env/data/controllers.yaml ({} if none)."""
    from valve_env.controllers.tuning import load_gains

    try:
        entry = load_gains(env_id)
    except (KeyError, FileNotFoundError):
        return {}
    return dict(entry.get(name) or {})


class _PICompensatorBase(PIController):
    """The tuned ``pi`` plus a compensating term on its setting output (setting loops only)."""

    supported_env_ids: ClassVar[tuple[str, ...]] = SETTING_ENV_IDS
    _extra: ClassVar[int] = 0

    def __init__(self, env_id: str = "ThermoValve-v0", band_mm: float | None = None,
                 valve: ValveParams | None = None, **pi_kwargs: Any) -> None:
        stored = _stored(env_id, self.name)
        band = stored.get("band_mm", DEFAULT_BAND_MM) if band_mm is None else band_mm
        super().__init__(env_id, **pi_kwargs)
        if not (np.isfinite(band) and band > 0):
            raise ValueError(f"{self.name}: band_mm must be finite and > 0, got {band!r}")
        self.band_mm = float(band)
        self.valve = valve or ValveParams()
        self.vp = self.valve.to_array()
        self._n_pi = self.state_size
        self.state_size = self._n_pi + self._extra
        self._stored = stored

    def _mm_to_K(self, mm: np.ndarray | float, u: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """Stem millimetres of demand as kelvin of setting at the setting ``u``."""
        return np.asarray(mm) / gain_mm_per_K(u, obs[:, I_DP], self.vp)

    def _out(self, u: np.ndarray) -> np.ndarray:
        return self._assemble(np.clip(u, self.u_min, self.u_max))


class _AmplitudeBase(_PICompensatorBase):
    """A compensator adding an amplitude ``amplitude_band x band_mm`` (stem mm, as K of setting) to the
    ``pi``'s setting; memory: the PI's, the last u_c and one more value (zero at the start)."""

    _extra: ClassVar[int] = 2

    def __init__(self, env_id: str = "ThermoValve-v0", band_mm: float | None = None,
                 amplitude_band: float | None = None, **kw: Any) -> None:
        super().__init__(env_id, band_mm, **kw)
        a = self._stored.get("amplitude_band", 0.5) if amplitude_band is None else amplitude_band
        if not (np.isfinite(a) and a > 0):
            raise ValueError(f"{self.name}: amplitude_band must be finite and > 0, got {amplitude_band!r}")
        self.amplitude_band = float(a)

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        return np.concatenate([super().initial_state(obs), obs[:, I_SETTING : I_SETTING + 1], np.zeros((n, 1))], 1)

    def amplitude_K(self, uc: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The amplitude as kelvin of setting at the setting ``uc``."""
        return self._mm_to_K(self.amplitude_band * self.band_mm, uc, obs)


class Knocker(_AmplitudeBase):
    """Hägglund's (2002) knocker on the ``pi``'s setting (module docstring).

    ``u = u_c + a sign(u_c(t) - u_c(t_p))`` for ``t_p <= t < t_p + tau``, else ``u_c``; a pulse starts
    every ``h_k``; ``t_p`` is the last pulse's start. ``a`` = ``amplitude_band`` x ``band_mm`` (stem
    mm, converted to K of setting), ``tau`` = ``width_steps``, ``h_k`` = ``period_steps`` control steps.
    Memory: the PI's, u_c at the last pulse start, steps since the episode start.
    """

    name: ClassVar[str] = "knocker"

    def __init__(self, env_id: str = "ThermoValve-v0", band_mm: float | None = None,
                 amplitude_band: float | None = None, period_steps: int | None = None,
                 width_steps: int | None = None, **kw: Any) -> None:
        super().__init__(env_id, band_mm, amplitude_band, **kw)
        s = self._stored
        self.period_steps = int(s.get("period_steps", 10) if period_steps is None else period_steps)
        self.width_steps = int(s.get("width_steps", 1) if width_steps is None else width_steps)
        if not (self.period_steps >= 1 and 1 <= self.width_steps <= self.period_steps):
            raise ValueError("knocker: 1 <= width_steps <= period_steps required")

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uc = self.pi_output(obs, state)
        j = self._n_pi
        k = state[:, j + 1]
        phase = np.mod(k, self.period_steps)
        ref = state[:, j]
        pulse = np.where(phase < self.width_steps, np.sign(uc - ref), 0.0)
        state[:, j] = np.where(phase == 0, uc, ref)  # u_c at the start of this pulse
        state[:, j + 1] = k + 1
        return self._out(uc + self.amplitude_K(uc, obs) * pulse), state


class ConstantReinforcement(_AmplitudeBase):
    """Constant reinforcement (Ivan & Lakshminarayanan 2009) on the ``pi``'s setting.

    ``u = u_c + a sgn(du_c)``, the sign of the last nonzero change of the controller output held;
    ``a`` = ``amplitude_band`` x ``band_mm`` (stem mm, as K of setting). Memory: the PI's, the last
    u_c, the held sign.
    """

    name: ClassVar[str] = "constant_reinforcement"

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uc = self.pi_output(obs, state)
        j = self._n_pi
        du = uc - state[:, j]
        sgn = np.where(du > 0, 1.0, np.where(du < 0, -1.0, state[:, j + 1]))
        state[:, j], state[:, j + 1] = uc, sgn
        return self._out(uc + self.amplitude_K(uc, obs) * sgn), state


class TwoMove(_PICompensatorBase):
    """Srinivasan & Rengaswamy's two-move compensation on the ``pi``'s setting (module docstring).

    Each step the PI's setting ``u_c`` is turned into the stem position it asks for, the demand
    ``x_pi = x_d(T_g_hat, F_h_hat, dp, u_c)`` of the valve model. The stem's position ``x_hat`` is read
    from the measured primary flow. While ``|x_pi - x_hat| <= trigger_band * band_mm`` or the outlet is
    within ``error_band_K`` of its target (S&R's compensation acts on a loop away from its set point), the setting holds
    the demand where the last move left it (it follows the bulb's drift, so the stuck stem is not
    pushed). Otherwise the stem is moved onto ``x_pi`` by the (S, J) model: in one move if the move is
    larger than ``J`` in the direction of the last motion or ``S`` against it; else in two, first a band
    and a margin beyond the stem away from the target, then onto the target (the landing offset
    ``(S - J) / 2`` of the model added). A target at or below the seat is the seat (closed), and an open
    stem whose target is the seat is always closed.

    Memory: the PI's (2), the bulb and friction estimates (3), the pending second move flag, the
    demand held (mm), the second move's demand (mm), the direction of the last move.
    """

    name: ClassVar[str] = "two_move"
    _extra: ClassVar[int] = DahlCompensator.state_size + 4

    def __init__(self, env_id: str = "ThermoValve-v0", band_mm: float | None = None,
                 jump_mm: float | None = None, trigger_band: float | None = None,
                 margin_band: float | None = None, error_band_K: float | None = None,
                 ps_bar: float = _SCEN.ps_bar, **kw: Any) -> None:
        super().__init__(env_id, band_mm, **kw)
        s = self._stored
        self.jump_mm = float(self.band_mm if jump_mm is None else jump_mm)
        self.trigger_band = float(s.get("trigger_band", 1.0) if trigger_band is None else trigger_band)
        self.margin_band = float(s.get("margin_band", 0.1) if margin_band is None else margin_band)
        self.error_band_K = float(s.get("error_band_K", 0.05) if error_band_K is None else error_band_K)
        if not (np.isfinite(self.jump_mm) and self.jump_mm >= 0 and self.trigger_band > 0 and self.margin_band > 0
                and self.error_band_K >= 0):
            raise ValueError("two_move: jump_mm >= 0, trigger_band > 0, margin_band > 0, error_band_K >= 0 required")
        self.ps_bar = float(ps_bar)
        self.seated_mm = 1e-3  # an opening read from the flow below this is the seat (leakage)
        self.bulb = DahlCompensator(self.valve, None, self.dt_s)

    # -- the valve model: demand of a setting and its inverse ----------------------------------
    def demand_mm(self, T_set: np.ndarray, T_g: np.ndarray, F_h: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """The force balance's (unclipped) demanded opening for the setting ``T_set``, mm."""
        return demanded_opening(T_g, F_h, dp, self.ps_bar, setpoint_pressure(T_set, self.vp), self.vp)

    def setting_for(self, x_mm: np.ndarray, T_g: np.ndarray, F_h: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """The setting whose demanded opening is ``x_mm`` (inverse of :meth:`demand_mm`), degC."""
        vp = self.vp
        other = (vp[I_A_K] * (dp * MBAR_TO_MPA - vp[I_DP_K_SP]) + vp[I_A_S] * (self.ps_bar * BAR_TO_MPA - vp[I_DP_S_SP])
                 + F_h - x_mm * stiffness(dp, vp))
        p_set = vapour_pressure(T_g, vp) - other / vp[I_A_B]
        return saturation_temperature(np.maximum(p_set, 1e-9), vp)

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        bulb = self.bulb.initial_state(obs)
        held = self.demand_mm(obs[:, I_SETTING], bulb[:, 1], bulb[:, 2], obs[:, I_DP])
        extra = np.stack([np.zeros(n), held, held, np.ones(n)], axis=1)
        return np.concatenate([super().initial_state(obs), bulb, extra], 1)

    def _advance_estimates(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance the bulb and friction estimates in ``state`` (in place): F_h_hat, T_g_hat, dp."""
        j, nb = self._n_pi, DahlCompensator.state_size
        mem = state[:, j : j + nb]
        fh = self.bulb.update(obs, mem)
        state[:, j : j + nb] = mem
        return fh, mem[:, 1], obs[:, I_DP]

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uc = self.pi_output(obs, state)
        err = obs[:, I_T_TARGET] - obs[:, I_T_OUT]
        j = self._n_pi
        nb = DahlCompensator.state_size
        fh, tg, dp = self._advance_estimates(obs, state)
        pending, held, second, d_last = (state[:, j + nb + q] for q in range(4))
        S, J = self.band_mm, self.jump_mm
        m = self.margin_band * S
        x_hat = opening_from_flow(obs[:, I_Q], dp, self.vp)
        target = self.demand_mm(uc, tg, fh, dp)
        target = np.where(target <= 0.0, -m, target)  # closed: seat it
        gap = target - x_hat
        a = np.where(gap >= 0.0, 1.0, -1.0)
        land = a * (S - J) * 0.5
        closing = (target <= 0.0) & (x_hat > self.seated_mm)  # a valve that should be shut is shut
        move = (pending == 0.0) & (((np.abs(gap) > self.trigger_band * S) & (np.abs(err) > self.error_band_K))
                                   | closing)
        one = move & (np.abs(gap) > np.where(a == d_last, J, S) + m)
        two = move & ~one
        cmd = np.where(pending != 0.0, second, held)
        cmd = np.where(one, target + land, cmd)
        cmd = np.where(two, x_hat - a * (S + m), cmd)
        new_second = np.where(two, target + land, second)
        state[:, j + nb] = np.where(two, 1.0, 0.0)
        state[:, j + nb + 1] = np.where(two, held, cmd)
        state[:, j + nb + 1] = np.where(pending != 0.0, second, state[:, j + nb + 1])
        state[:, j + nb + 1] = np.where(one, cmd, state[:, j + nb + 1])
        state[:, j + nb + 2] = new_second
        state[:, j + nb + 3] = np.where(move, a, d_last)
        return self._out(self.setting_for(cmd, tg, fh, dp)), state


class TwoMovePosition(TwoMove):
    """Srinivasan & Rengaswamy's two moves in the papers' loop: the controller's output is the stem position.

    In S&R (2005, 2008) the controller's output is the valve position demand and the compensator
    places the sticky valve there. Here a PI on the outlet error ``e`` gives that position in mm,
    ``x_c = Kc e + I`` (``I <- I + Kc dt / Ti e``, limited to the stroke), and the setting turns it into
    the force balance's demand (``TwoMove.setting_for``, the bulb and friction estimates of
    :class:`~valve_env.controllers.baselines.DahlCompensator`): the valve's own proportional action is
    cancelled and the stem sees the controller's position, as in the papers. The stem's position
    ``x_hat`` is read from the measured flow. When ``|x_c - x_hat| > replace_band x band_mm`` (and the
    outlet is more than ``error_band_K`` from its target; default 0: always) the stem is placed on
    ``x_c``: in one move if the move is longer than the band and a margin, else in two moves
    that approach from above (first to ``max(x_hat, x_c) + S + margin``, then down onto ``x_c``): from
    below, a stem within a band of its seat would have to leave the seat, which takes a breakaway of S
    and lands it at least a band open. A position at or below the seat shuts the valve. Between moves
    the demand is held where the last move put it.

    Gains: SIMC (Skogestad 2003) for an integrating process, ``Kc = 1 / (k' (tau_c + theta))``,
    ``Ti = 4 (tau_c + theta)``, with ``k' = (dq/dx) (T_supply - T_target) / m_tank`` (the valve's linear
    characteristic at ``dp``: one band open heats the tank at ``k' band`` K/s while the coil returns at
    tank temperature), ``theta`` the stored FOPDT model's dead time plus ``dt / 2`` (as the ``pi``) and
    ``tau_c = tau_c_factor x theta`` (1: SIMC's tight setting).

    Memory: the two-move's (the PI's 2 unused, bulb 3, pending, held, second, direction) and ``I`` (mm).
    """

    name: ClassVar[str] = "two_move_position"
    _extra: ClassVar[int] = TwoMove._extra + 1

    def __init__(self, env_id: str = "ThermoValve-v0", band_mm: float | None = None,
                 replace_band: float = 0.4, tau_c_factor: float = 1.0, Kc: float | None = None,
                 Ti_s: float | None = None, supply_C: float = _SCEN.supply_C, dp_mbar: float = _SCEN.dp_mbar,
                 tank: TankParams | None = None, **kw: Any) -> None:
        from valve_env.controllers.process import ModelFit, simc_pi
        from valve_env.controllers.tuning import load_gains

        kw.setdefault("error_band_K", 0.0)  # no error gate: the position PI decides (two_move's is 0.05 K)
        super().__init__(env_id, band_mm, **kw)
        if not (np.isfinite(replace_band) and replace_band > 0 and np.isfinite(tau_c_factor) and tau_c_factor > 0):
            raise ValueError("two_move_position: replace_band > 0 and tau_c_factor > 0 required")
        self.replace_band = float(replace_band)
        tk = tank or TankParams()
        vp = self.vp
        # the valve's linear characteristic at dp: its slope, kg/s per mm
        dq_dx = (flow_kgh(vp[I_STROKE], dp_mbar, vp) - flow_kgh(0.0, dp_mbar, vp)) / vp[I_STROKE] / 3600.0
        self.k_int = float(dq_dx * (supply_C - _CTRL.T_target_C) / (tk.volume_l * tk.rho))  # K/s per mm
        if not self.k_int > 0:
            raise ValueError(f"two_move_position: the supply ({supply_C} degC) must be above the target")
        if Kc is None or Ti_s is None:
            theta = float(load_gains(original_id(env_id))["model"]["theta_s"])
            g = simc_pi(ModelFit("ipdt", self.k_int, float("nan"), theta, 0.0),
                        tau_c_factor * (theta + 0.5 * self.dt_s), self.dt_s)
            Kc = g.Kp if Kc is None else Kc
            Ti_s = g.Ti_s if Ti_s is None else Ti_s
        if not (np.isfinite(Kc) and Kc > 0 and np.isfinite(Ti_s) and Ti_s > 0):
            raise ValueError(f"two_move_position: Kc and Ti_s must be finite and > 0, got {Kc!r}, {Ti_s!r}")
        self.Kc, self.Ti_x_s = float(Kc), float(Ti_s)

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        x0 = opening_from_flow(obs[:, I_Q], obs[:, I_DP], self.vp)  # bumpless: the integral starts at the stem
        return np.concatenate([super().initial_state(obs), x0[:, None]], 1)

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        err = obs[:, I_T_TARGET] - obs[:, I_T_OUT]
        j = self._n_pi
        nb = DahlCompensator.state_size
        fh, tg, dp = self._advance_estimates(obs, state)
        pending, held, second = state[:, j + nb], state[:, j + nb + 1], state[:, j + nb + 2]
        S, m = self.band_mm, self.margin_band * self.band_mm
        integ = state[:, -1]
        target = self.Kc * err + integ
        state[:, -1] = np.clip(integ + self.Kc * self.dt_s / self.Ti_x_s * err, -m, self.vp[I_STROKE])
        x_hat = opening_from_flow(obs[:, I_Q], dp, self.vp)
        gap = target - x_hat
        shut = target <= 0.0
        seated = x_hat <= self.seated_mm
        move = ((pending == 0.0) & (np.abs(gap) > self.replace_band * S) & (np.abs(err) >= self.error_band_K)
                & ~(shut & seated))
        one = move & ((np.abs(gap) > S + m) | shut)
        two = move & ~one
        land = np.where(gap >= 0.0, 1.0, -1.0) * (S - self.jump_mm) * 0.5
        goal = np.where(shut, -m, target)
        cmd = np.where(pending != 0.0, second, held)
        cmd = np.where(one, np.where(shut, -m, goal + land), cmd)
        cmd = np.where(two, np.maximum(x_hat, goal) + S + m, cmd)
        state[:, j + nb] = np.where(two, 1.0, 0.0)
        state[:, j + nb + 1] = cmd
        state[:, j + nb + 2] = np.where(two, goal - (S - self.jump_mm) * 0.5, second)
        state[:, j + nb + 3] = np.where(move, np.sign(gap), state[:, j + nb + 3])
        return self._out(self.setting_for(cmd, tg, fh, dp)), state


class PIIntegralBand(_PICompensatorBase):
    """The ``pi`` with its integral frozen inside an error band (Farenzena & Trierweiler 2010; module
    docstring).

    ``u = r + Kp e + I``; ``I`` is updated as the ``pi``'s only when ``|e| >= delta``, with
    ``delta = band_factor x band_mm / (g(u) Kp)`` K (``g`` the setting's gain on the stem's demand,
    mm/K): inside the band the proportional action alone cannot move the demand by more than
    ``band_factor`` stiction bands, so a stuck stem near its target stays stuck and the outlet keeps
    an offset of at most ``delta`` instead of a limit cycle. Memory: the PI's.
    """

    name: ClassVar[str] = "pi_integral_band"

    def __init__(self, env_id: str = "ThermoValve-v0", band_mm: float | None = None,
                 band_factor: float | None = None, **kw: Any) -> None:
        super().__init__(env_id, band_mm, **kw)
        f = self._stored.get("band_factor", 1.0) if band_factor is None else band_factor
        if not (np.isfinite(f) and f >= 0):
            raise ValueError(f"pi_integral_band: band_factor must be finite and >= 0, got {band_factor!r}")
        if self.Kp == 0.0:
            raise ValueError("pi_integral_band: Kp must not be 0 (the band is an error of the proportional action)")
        self.band_factor = float(f)

    def error_band_K(self, u: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The error band ``delta`` (K) at the setting ``u``."""
        return self._mm_to_K(self.band_factor * self.band_mm, u, obs) / abs(self.Kp)

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        integ = state[:, 0].copy()
        u = self.pi_output(obs, state)
        e = obs[:, I_T_TARGET] - state[:, 1]
        state[:, 0] = np.where(np.abs(e) < self.error_band_K(u, obs), integ, state[:, 0])
        return self._out(u), state


class PIWear(PIController):
    """Event-based PI (Årzén 1999), SIMC-retuned for its longest hold (module docstring).

    At each step the error ``e = T_target - T_out`` is compared with the error at the last update;
    the PI is updated when ``|e - e_last| > e_lim_K`` or ``h_max`` steps have passed since the last
    update: ``v = r + Kp e + I``, ``u = clip(v)``, ``I <- I + h (Kp dt / Ti e + dt / Tt (u - v))`` with
    ``h`` the steps since the last update. Between updates the setting holds. Gains: SIMC on the
    stored FOPDT model (valve_env/data/controllers.yaml) with theta_eff = theta + dt/2 + (h_max - 1) dt / 2
    (the hold's mean extra delay), tau_c = theta_eff, unless ``Kp``/``Ti_s`` are given.
    Memory: the PI's (2), the setting sent, the error at the last update, steps since it.
    """

    name: ClassVar[str] = "pi_wear"
    supported_env_ids: ClassVar[tuple[str, ...]] = SETTING_ENV_IDS

    def __init__(self, env_id: str = "ThermoValve-v0", e_lim_K: float | None = None, h_max: int | None = None,
                 Kp: float | None = None, Ti_s: float | None = None, **kw: Any) -> None:
        from valve_env.controllers.process import ModelFit, simc_pi
        from valve_env.controllers.tuning import load_gains

        Controller.__init__(self, env_id)  # the env id check first: only setting loops have the FOPDT model
        stored = _stored(env_id, self.name)
        e_lim = float(stored.get("e_lim_K", 0.02) if e_lim_K is None else e_lim_K)
        hmax = int(stored.get("h_max", 4) if h_max is None else h_max)
        if not (np.isfinite(e_lim) and e_lim >= 0 and hmax >= 1):
            raise ValueError(f"pi_wear: e_lim_K must be >= 0 and h_max >= 1, got {e_lim_K!r}, {h_max!r}")
        dt = float(kw.get("dt_s", _CTRL.dt_s))
        if Kp is None or Ti_s is None:
            m = load_gains(env_id)["model"]
            model = ModelFit("fopdt", float(m["K"]), float(m["tau_s"]), float(m["theta_s"]) + (hmax - 1) * dt / 2, 0.0)
            g = simc_pi(model, None, dt)
            Kp = g.Kp if Kp is None else Kp
            Ti_s = g.Ti_s if Ti_s is None else Ti_s
        super().__init__(env_id, Kp=Kp, Ti_s=Ti_s, **kw)
        self.e_lim_K = e_lim
        self.h_max = hmax
        self._n_pi = self.state_size
        self.state_size = self._n_pi + 3

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        e = obs[:, I_T_TARGET] - obs[:, I_T_OUT]
        u0 = np.clip(obs[:, I_SETTING], *self._limits(obs))
        return np.concatenate([super().initial_state(obs), np.stack([u0, e, np.zeros(n)], 1)], 1)

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j = self._n_pi
        y = state[:, 1] * self._fa + obs[:, I_T_OUT] * (1.0 - self._fa)
        state[:, 1] = y
        e = obs[:, I_T_TARGET] - y
        h = state[:, j + 2] + 1.0
        event = (np.abs(e - state[:, j + 1]) > self.e_lim_K) | (h >= self.h_max)
        v = self._bias(obs) + self.Kp * e + state[:, 0]
        lo, hi = self._limits(obs)
        u = np.minimum(np.maximum(v, lo), hi)
        integ = state[:, 0] + h * (self.Kp * self.dt_s / self.Ti_s * e + self.dt_s / self.Tt_s * (u - v))
        state[:, 0] = np.where(event, integ, state[:, 0])
        state[:, j] = np.where(event, u, state[:, j])
        state[:, j + 1] = np.where(event, e, state[:, j + 1])
        state[:, j + 2] = np.where(event, 0.0, h)
        return self._assemble(state[:, j]), state
