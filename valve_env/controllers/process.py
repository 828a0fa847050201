"""Process models of a control loop and their PI tuning, shared by the valve's tuning procedure
(:mod:`valve_env.controllers.tuning`, its step tests) and the simulated plant loops
(:mod:`valve_env.loops.sim`):

* first order plus dead time (FOPDT), ``K exp(-theta s) / (tau s + 1)``, and integrating plus dead
  time (IPDT), ``k exp(-theta s) / s``: their step responses and least-squares fits to a step response;
* the SIMC PI rules (Skogestad 2003), sampling-corrected (``theta_eff = theta + dt / 2``):
  FOPDT ``Kc = tau / (K (tau_c + theta_eff))``, ``Ti = min(tau, 4 (tau_c + theta_eff))``;
  IPDT ``Kc = 1 / (k (tau_c + theta_eff))``, ``Ti = 4 (tau_c + theta_eff)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares


@dataclass(frozen=True)
class StepResponse:
    t_s: np.ndarray
    """Time since the step, s (first sample one control step after the step)."""
    y: np.ndarray
    """Outlet temperature (setting loop) or its difference between the two runs (pressure loop), degC / K."""
    y0: float
    """Outlet temperature at the step, degC (0 for the differential test)."""
    dt_s: float


@dataclass(frozen=True)
class ModelFit:
    kind: str
    """"fopdt" or "ipdt"."""
    K: float
    """Static gain (K/K, FOPDT) or integrating gain (K/s per unit of u, IPDT)."""
    tau_s: float
    """Time constant, s (nan for IPDT)."""
    theta_s: float
    """Dead time, s."""
    rms: float
    """Residual RMS of the fit, K."""


@dataclass(frozen=True)
class PIGains:
    Kp: float
    """Proportional gain, units of u per K."""
    Ti_s: float
    """Integral time, s."""
    tau_c_s: float = math.nan
    """The SIMC closed-loop time constant used, s."""


def fopdt_response(t: np.ndarray, K: float, tau: float, theta: float, du: float, y0: float) -> np.ndarray:
    """Step response of K exp(-theta s) / (tau s + 1) to a step du at t = 0."""
    s = np.maximum(t - theta, 0.0)
    return y0 + K * du * (1.0 - np.exp(-s / tau))


def ipdt_response(t: np.ndarray, k: float, theta: float, du: float) -> np.ndarray:
    """Step response of k exp(-theta s) / s to a step du at t = 0."""
    return k * du * np.maximum(t - theta, 0.0)


def fit_fopdt(resp: StepResponse, du: float) -> ModelFit:
    """Least-squares FOPDT fit to a step response."""
    t, y = resp.t_s, resp.y
    K0 = (y[-1] - resp.y0) / du
    tau0 = max(float(t[np.argmax(np.abs(y - resp.y0) >= 0.632 * abs(y[-1] - resp.y0))]), resp.dt_s)

    def res(p: np.ndarray) -> np.ndarray:
        return fopdt_response(t, p[0], p[1], p[2], du, resp.y0) - y

    sol = least_squares(
        res, x0=[K0, tau0, 0.5 * resp.dt_s], bounds=([1e-6, 1.0, 0.0], [np.inf, 1e6, 3600.0]),
        x_scale=[1.0, 100.0, 10.0], xtol=1e-12, ftol=1e-12, gtol=1e-12,
    )
    K, tau, theta = (float(v) for v in sol.x)
    return ModelFit("fopdt", K, tau, _at_bound(theta, resp.dt_s), float(np.sqrt(np.mean(sol.fun**2))))


def fit_ipdt(resp: StepResponse, du: float) -> ModelFit:
    """Least-squares IPDT fit to a (differential) step response."""
    t, y = resp.t_s, resp.y
    k0 = float(y[-1] / (du * t[-1]))

    def res(p: np.ndarray) -> np.ndarray:
        return ipdt_response(t, p[0] * 1e-4, p[1], du) - y

    sol = least_squares(
        res, x0=[k0 * 1e4, 0.5 * resp.dt_s], bounds=([0.0, 0.0], [np.inf, 3600.0]),
        xtol=1e-12, ftol=1e-12, gtol=1e-12,
    )
    return ModelFit("ipdt", float(sol.x[0]) * 1e-4, math.nan, _at_bound(float(sol.x[1]), resp.dt_s),
                    float(np.sqrt(np.mean(sol.fun**2))))


def _at_bound(theta_s: float, dt_s: float) -> float:
    """A fitted dead time below a thousandth of the sampling interval is 0, its lower bound: the step test
    cannot resolve it, and least_squares' trust region keeps the estimate strictly inside its bounds, which
    left a zero delay printed and stored as 1.5e-17 s."""
    return 0.0 if theta_s < 1e-3 * dt_s else theta_s


def simc_pi(model: ModelFit, tau_c_s: float | None, dt_s: float) -> PIGains:
    """SIMC PI settings for a FOPDT or IPDT model, sampling-corrected."""
    theta = model.theta_s + 0.5 * dt_s
    tau_c_s = theta if tau_c_s is None else tau_c_s
    if model.kind == "fopdt":
        return PIGains(
            Kp=model.tau_s / (model.K * (tau_c_s + theta)),
            Ti_s=min(model.tau_s, 4.0 * (tau_c_s + theta)),
            tau_c_s=tau_c_s,
        )
    if model.kind == "ipdt":
        return PIGains(Kp=1.0 / (model.K * (tau_c_s + theta)), Ti_s=4.0 * (tau_c_s + theta), tau_c_s=tau_c_s)
    raise ValueError(f"unknown model kind {model.kind!r}")


__all__ = ["StepResponse", "ModelFit", "PIGains", "fopdt_response", "ipdt_response", "fit_fopdt", "fit_ipdt",
           "simc_pi"]
