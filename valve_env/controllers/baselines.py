"""Baseline controllers: the self-acting valve, a PI and a PI with a Dahl
hysteresis compensator.

All three implement stable-baselines3's ``predict`` through
:class:`~valve_env.controllers.base.Controller` and work on a batch of
observations with vectorised NumPy.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from valve_env.config import ControlParams
from valve_env.controllers.base import I_DP, I_SETTING, I_T_OUT, I_T_POCKET, I_T_TARGET, Controller
from valve_env.params import BulbParams, ValveParams, field_spec
from valve_env.physics.valve import dahl_update, saturation_temperature, vapour_pressure, vapour_pressure_slope
from valve_env.scenario import ScenarioParams

_CTRL = ControlParams()
_SCEN = ScenarioParams()


class SelfActing(Controller):
    """Today's practice: the valve alone at a fixed setting.

    ThermoValve-v0 sends the fixed ``setting_C`` (default: the outlet target,
    60 degC, as an installer dials it in); ThermoValvePressure-v0 sends a constant
    pump differential pressure ``dp_mbar`` (default: the network's calibration
    value, 100 mbar) while the env holds the setting; ThermoValveDual-v0 sends
    both.
    """

    name: ClassVar[str] = "self_acting"

    def __init__(
        self, env_id: str = "ThermoValve-v0", setting_C: float = _CTRL.T_target_C, dp_mbar: float = _SCEN.dp_mbar
    ) -> None:
        super().__init__(env_id)
        # the widest ranges any configuration's action space allows (docs/configuration.md); within them
        # the env clips to its own box
        self.setting_C = float(field_spec(ControlParams, "setting_C").check("self_acting setting_C", setting_C))
        self.dp_mbar = float(field_spec(ScenarioParams, "dp_mbar").check("self_acting dp_mbar", dp_mbar))
        values = {"setting": [self.setting_C], "pressure": [self.dp_mbar], "dual": [self.setting_C, self.dp_mbar]}
        self._action = np.array(values[self.mode], dtype=np.float64)

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((obs.shape[0], 0))

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.broadcast_to(self._action, (obs.shape[0], self._action.size)).copy(), state


class PIController(Controller):
    """Discrete PI on the outlet temperature, with anti-windup and bumpless start.

    Error ``e = T_target - T_out`` (observations 11 and 0), sample time ``dt_s``:

        v = r + Kp e + I            (setting loop; the pressure loop uses u_bias instead of r)
        u = clip(v, u_lo, u_hi)
        I <- I + Kp dt / Ti e + dt / Tt (u - v)       (back-calculation anti-windup, Tt = Ti / 2)

    * **Bumpless**: at an episode start the integrator is set so that the first
      output equals the manipulated variable in force (``setting_C`` or
      ``dp_mbar`` in the observation): switching the loop in does not move the
      valve.
    * **Anti-windup on the valve's dead zone** (setting loop): a self-acting
      valve is shut whenever its setting is below the bulb temperature, so
      lowering the setting further does nothing but wind the integrator down;
      the lower limit is therefore ``max(setting_min, T_pocket - closed_margin_K)``
      (the pocket temperature is observed; the margin covers the friction band
      and the bulb lag). Set ``closed_margin_K=None`` for the plain box limits.

    * **Measurement filter** (optional, ``filter_s`` > 0): a first-order
      filter on T_out for noisy sensors (``sensors.noise_K``); off by default
      (the default env's sensors are exact).

    Loops: ThermoValve-v0 trims the setting; ThermoValvePressure-v0 sets the
    pump's differential pressure around ``u_bias`` (the setting is the env's);
    ThermoValveDual-v0 trims the setting and holds ``dp_hold_mbar``.
    Gains default to ``valve_env/data/controllers.yaml`` (see
    :mod:`valve_env.controllers.tuning`).
    """

    name: ClassVar[str] = "pi"

    def __init__(
        self,
        env_id: str = "ThermoValve-v0",
        Kp: float | None = None,
        Ti_s: float | None = None,
        dt_s: float = _CTRL.dt_s,
        Tt_s: float | None = None,
        u_bias: float | None = None,
        closed_margin_K: float | None = 2.0,
        dp_hold_mbar: float = _SCEN.dp_mbar,
        filter_s: float = 0.0,
        gains: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__(env_id)
        if Kp is None or Ti_s is None:
            from valve_env.controllers.tuning import load_gains

            stored = dict(gains) if gains is not None else load_gains(env_id)["pi"]
            Kp = float(stored["Kp"]) if Kp is None else Kp
            Ti_s = float(stored["Ti_s"]) if Ti_s is None else Ti_s
        if not (np.isfinite(Kp) and np.isfinite(Ti_s) and Ti_s > 0):
            raise ValueError(f"PI gains must be finite with Ti_s > 0, got Kp={Kp!r}, Ti_s={Ti_s!r}")
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"PI dt_s must be a finite sample time > 0 s, got {dt_s!r}")
        self.Kp = float(Kp)
        self.Ti_s = float(Ti_s)
        self.dt_s = float(dt_s)
        self.Tt_s = float(Tt_s) if Tt_s is not None else 0.5 * self.Ti_s
        self.loop = "pressure" if self.mode == "pressure" else "setting"
        if self.loop == "setting":
            self.u_min, self.u_max = _CTRL.setting_min_C, _CTRL.setting_max_C
            self.u_index = I_SETTING
        else:
            self.u_min, self.u_max = _CTRL.dp_min_mbar, _CTRL.dp_max_mbar
            self.u_index = I_DP
        self.u_bias = None if u_bias is None else float(u_bias)
        self.closed_margin_K = None if closed_margin_K is None or self.loop != "setting" else float(closed_margin_K)
        self.dp_hold_mbar = float(dp_hold_mbar)
        if not (np.isfinite(filter_s) and filter_s >= 0):
            raise ValueError(f"filter_s must be finite and >= 0, got {filter_s!r}")
        self.filter_s = float(filter_s)
        self._fa = float(np.exp(-self.dt_s / self.filter_s)) if self.filter_s > 0 else 0.0
        self.state_size = 2  # the integral term I (units of u) and the filtered outlet temperature

    # -- the PI law -----------------------------------------------------------
    def _bias(self, obs: np.ndarray) -> np.ndarray:
        if self.u_bias is not None:
            return np.full(obs.shape[0], self.u_bias)
        if self.loop == "setting":
            return obs[:, I_T_TARGET]
        return np.full(obs.shape[0], _SCEN.dp_mbar)

    def _limits(self, obs: np.ndarray) -> tuple[np.ndarray | float, float]:
        """The output's limits for a batch (scalars where they do not depend on the observation)."""
        if self.closed_margin_K is not None:
            return np.clip(obs[:, I_T_POCKET] - self.closed_margin_K, self.u_min, self.u_max), self.u_max
        return self.u_min, self.u_max

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        y = obs[:, I_T_OUT]
        e = obs[:, I_T_TARGET] - y
        lo, hi = self._limits(obs)
        u_now = np.clip(obs[:, self.u_index], lo, hi)
        return np.stack([u_now - self._bias(obs) - self.Kp * e, y], axis=1)

    def pi_output(self, obs: np.ndarray, state: np.ndarray, feedforward: np.ndarray | None = None) -> np.ndarray:
        """One PI update on a batch: returns u (clipped) and updates ``state[:, :2]`` in place.

        ``feedforward`` (units of u, per env) is added before the limits, so the
        anti-windup sees it (the oracle's plan perturbs the PI this way)."""
        y = state[:, 1] * self._fa + obs[:, I_T_OUT] * (1.0 - self._fa)
        state[:, 1] = y
        e = obs[:, I_T_TARGET] - y
        integ = state[:, 0]
        v = self._bias(obs) + self.Kp * e + integ
        if feedforward is not None:
            v = v + feedforward
        lo, hi = self._limits(obs)
        u = np.minimum(np.maximum(v, lo), hi)
        state[:, 0] = integ + self.Kp * self.dt_s / self.Ti_s * e + self.dt_s / self.Tt_s * (u - v)
        return u

    def _assemble(self, u: np.ndarray) -> np.ndarray:
        if self.mode == "dual":
            return np.stack([u, np.full_like(u, self.dp_hold_mbar)], axis=1)
        return u[:, None]

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._assemble(self.pi_output(obs, state)), state


class DahlCompensator:
    """Inverse-model hysteresis compensation (a teaching example).

    The valve's friction force F_h shifts its force balance exactly like a
    change of the set pressure, ``p_bset -> p_bset + F_h / A_b``: while the
    bulb warms (F_h -> +F_hmax) the valve behaves as if set about
    ``F_h / (A_b dp_b/dT)`` (~0.4 K) higher, while it cools as if set lower.
    The compensator runs the paper's Dahl model (``dahl_update`` with sigma,
    F_hmax of :class:`ValveParams`) on an *estimate* of the bulb temperature,
    a first-order lag (``tau_s`` of :class:`BulbParams`, 40 s) of the observed
    pocket temperature, interpolated linearly over each control step, and
    returns the setting that cancels the estimated force:

        T_cmd = p_b^-1( p_b(T_des) - F_h_hat / A_b )  ~  T_des - F_h_hat / (A_b dp_b/dT)

    The estimate starts at the pocket temperature with F_h_hat = 0 (the env's
    documented starting state). Memory per env: [T_pocket_prev, T_g_hat, F_h_hat].
    """

    state_size: ClassVar[int] = 3

    def __init__(
        self, valve: ValveParams | None = None, bulb: BulbParams | None = None, dt_s: float = _CTRL.dt_s
    ) -> None:
        self.vp = (valve or ValveParams()).to_array()
        self.valve = valve or ValveParams()
        self.tau_s = (bulb or BulbParams()).tau_s
        self.dt_s = float(dt_s)
        self._a = float(np.exp(-self.dt_s / self.tau_s))
        self._ramp = self.tau_s / self.dt_s * (1.0 - self._a)

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        tp = obs[:, I_T_POCKET]
        return np.stack([tp, tp, np.zeros_like(tp)], axis=1)

    def update(self, obs: np.ndarray, mem: np.ndarray) -> np.ndarray:
        """Advance the bulb and friction estimates to this observation (in place); returns F_h_hat."""
        tp_prev, tg, fh = mem[:, 0], mem[:, 1], mem[:, 2]
        tp = obs[:, I_T_POCKET]
        # exact response of the first-order bulb to a pocket temperature ramping tp_prev -> tp over the step
        tg_new = tp + (tg - tp_prev) * self._a - (tp - tp_prev) * self._ramp
        fh_new = dahl_update(fh, tg_new - tg, self.vp)
        mem[:, 0], mem[:, 1], mem[:, 2] = tp, tg_new, fh_new
        return fh_new

    def command(self, T_des: np.ndarray, fh: np.ndarray) -> np.ndarray:
        """The setting that cancels the friction force ``fh`` for a desired setting ``T_des``."""
        p = vapour_pressure(T_des, self.vp) - fh / self.valve.A_b
        return saturation_temperature(np.maximum(p, 1e-9), self.vp)

    def shift_K(self, T: np.ndarray, fh: np.ndarray) -> np.ndarray:
        """The linearised setting shift F_h / (A_b dp_b/dT), K."""
        return fh / (self.valve.A_b * vapour_pressure_slope(T, self.vp))


class PICompensated(PIController):
    """The PI of :class:`PIController` plus the :class:`DahlCompensator`'s
    inverse-model feed-forward on the setting (same tuned gains).

    The PI's anti-windup sees its own (uncompensated) output; the
    compensated command is clipped to the setting range. ThermoValve-v0 and
    ThermoValveDual-v0 only (the compensator acts on the setting).
    """

    name: ClassVar[str] = "pi_compensated"
    supported_env_ids: ClassVar[tuple[str, ...]] = ("ThermoValve-v0", "ThermoValveDual-v0")

    def __init__(
        self,
        env_id: str = "ThermoValve-v0",
        valve: ValveParams | None = None,
        bulb: BulbParams | None = None,
        **pi_kwargs: Any,
    ) -> None:
        super().__init__(env_id, **pi_kwargs)
        self.compensator = DahlCompensator(valve, bulb, self.dt_s)
        self._n_pi = self.state_size
        self.state_size = self._n_pi + DahlCompensator.state_size

    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        return np.concatenate([super().initial_state(obs), self.compensator.initial_state(obs)], axis=1)

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = self.pi_output(obs, state)
        mem = state[:, self._n_pi :]
        fh = self.compensator.update(obs, mem)
        state[:, self._n_pi :] = mem
        cmd = np.clip(self.compensator.command(u, fh), self.u_min, self.u_max)
        return self._assemble(cmd), state
