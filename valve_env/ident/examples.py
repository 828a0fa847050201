"""Small example models: ctsmTMB's Ornstein-Uhlenbeck models (used to check the
filters against ctsmTMB's stored numbers) and a template for user models."""

from __future__ import annotations

import numba as nb
import numpy as np

from valve_env.ident.sde import CompiledFunctions, CompiledSDEModel, Parameter, SDEModel


class Ornstein2D(CompiledSDEModel):
    """ctsmTMB's ``create.Ornstein2D.model()``:

        dx1 = theta (mu + u - x1) dt + sigma_x1 dw1
        dx2 = alpha (x1 - x2) dt + sigma_x2 dw2
        y_i = x_i + e_i,  e_i ~ N(0, sigma_yi^2)

    theta, alpha and the sigmas are estimated on the log scale (ctsmTMB's
    logtheta, ...); the initial state is (3, 3) with covariance 0.1 I."""

    name = "ornstein2d"
    states = ("x1", "x2")
    inputs = ("u",)
    outputs = ("y1", "y2")
    linear = True
    parameters = (
        Parameter("theta", 1.0, 1e-3, 1e3, "log"),
        Parameter("mu", 1.0, -10.0, 10.0),
        Parameter("alpha", 1.0, 1e-3, 1e3, "log"),
        Parameter("sigma_x1", 0.5, 1e-8, 10.0, "log"),
        Parameter("sigma_x2", 0.5, 1e-8, 10.0, "log"),
        Parameter("sigma_y1", 0.1, 1e-8, 10.0, "log"),
        Parameter("sigma_y2", 0.1, 1e-8, 10.0, "log"),
    )

    def __init__(self, x0: tuple[float, float] = (3.0, 3.0), P0: float = 0.1) -> None:
        self.x0 = np.array(x0, dtype=float)
        self.P0 = float(P0)

    def initial_state(self, p: np.ndarray, y0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.x0.copy(), self.P0 * np.eye(2)

    def compiled(self) -> CompiledFunctions:
        return CompiledFunctions(_o2_drift, _o2_drift_jac, _o2_diffusion, _o2_obs, _o2_obs_jac, _o2_obs_var)


@nb.njit(cache=True)
def _o2_drift(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, ctx: tuple = ()) -> np.ndarray:
    out = np.empty(2)
    out[0] = p[0] * (p[1] + u[0] - x[0])
    out[1] = p[2] * (x[0] - x[1])
    return out


@nb.njit(cache=True)
def _o2_drift_jac(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, ctx: tuple = ()) -> np.ndarray:
    J = np.zeros((2, 2))
    J[0, 0] = -p[0]
    J[1, 0] = p[2]
    J[1, 1] = -p[2]
    return J


@nb.njit(cache=True)
def _o2_diffusion(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, ctx: tuple = ()) -> np.ndarray:
    G = np.zeros((2, 2))
    G[0, 0] = p[3]
    G[1, 1] = p[4]
    return G


@nb.njit(cache=True)
def _o2_obs(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, ctx: tuple = ()) -> np.ndarray:
    return x.copy()


@nb.njit(cache=True)
def _o2_obs_jac(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, ctx: tuple = ()) -> np.ndarray:
    return np.eye(2)


@nb.njit(cache=True)
def _o2_obs_var(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, ctx: tuple = ()) -> np.ndarray:
    R = np.zeros((2, 2))
    R[0, 0] = p[5] ** 2
    R[1, 1] = p[6] ** 2
    return R


class Ornstein1D(SDEModel):
    """ctsmTMB's 1-D Ornstein-Uhlenbeck model (plain Python, no compiled functions):
    dx = theta (mu + u - x) dt + sigma_x dw, y = x + e, e ~ N(0, sigma_y^2)."""

    name = "ornstein1d"
    states = ("x",)
    inputs = ("u",)
    outputs = ("y",)
    linear = True
    parameters = (
        Parameter("theta", 1.0, 1e-3, 1e3, "log"),
        Parameter("mu", 1.0, -10.0, 10.0),
        Parameter("sigma_x", 0.5, 1e-8, 10.0, "log"),
        Parameter("sigma_y", 0.1, 1e-8, 10.0, "log"),
    )

    def drift(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.array([p[0] * (p[1] + u[0] - x[0])])

    def diffusion(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.array([[p[2]]])

    def observation(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.array([x[0]])

    def obs_variance(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.array([[p[3] ** 2]])

    def initial_state(self, p: np.ndarray, y0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x0 = y0[0] if np.isfinite(y0[0]) else 0.0
        return np.array([x0]), np.array([[1.0]])
