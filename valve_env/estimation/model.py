"""Continuous-discrete stochastic state-space models (CTSM style).

A model is declared in plain Python:

    dx = f(t, x, u, p) dt + G(t, x, u, p) dw          (states x, inputs u)
    y_k = h(t_k, x_k, u_k, p) + e_k,  e_k ~ N(0, R(t_k, x_k, u_k, p))

``p`` is the vector of *all* parameters on their natural scale, ordered as
``model.param_names``. Parameters carry bounds and a transform (the optimiser
works on the transformed scale). Jacobians default to finite differences; a
model may override ``drift_jacobian`` and ``observation_jacobian``.

This file is the contract shared by the estimator (Kalman filters,
likelihood, maximum likelihood) and by the model library (the valve and its
effects, the diagnosis).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

Transform = Literal["none", "log", "logit"]


@dataclass(frozen=True)
class Parameter:
    """One model parameter.

    ``init`` is the starting value on the natural scale; ``lower``/``upper``
    bound it (also on the natural scale); ``transform`` is the scale the
    optimiser works on ("log" requires lower > 0 or None, "logit" maps
    (lower, upper) to the real line); ``fixed`` keeps it at ``init``.
    """

    name: str
    init: float
    lower: float | None = None
    upper: float | None = None
    transform: Transform = "none"
    fixed: bool = False
    unit: str = ""
    doc: str = ""


class SDEModel:
    """Base class of a continuous-discrete stochastic model. Subclasses set the
    name tuples and parameters and implement the four model functions."""

    name: str = "model"
    states: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    parameters: tuple[Parameter, ...] = ()

    # --- names -----------------------------------------------------------
    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(q.name for q in self.parameters)

    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def n_outputs(self) -> int:
        return len(self.outputs)

    def param_vector(self, values: dict[str, float] | None = None) -> np.ndarray:
        """The natural-scale parameter vector: ``init`` overridden by ``values``."""
        values = values or {}
        unknown = sorted(set(values) - set(self.param_names))
        if unknown:
            raise KeyError(f"{self.name}: unknown parameter(s) {unknown}")
        return np.array([float(values.get(q.name, q.init)) for q in self.parameters], dtype=float)

    # --- model functions (override) --------------------------------------
    def drift(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """f(t, x, u, p): shape (n_states,)."""
        raise NotImplementedError

    def diffusion(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """G(t, x, u, p): shape (n_states, n_noise)."""
        raise NotImplementedError

    def observation(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """h(t, x, u, p): shape (n_outputs,)."""
        raise NotImplementedError

    def obs_variance(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """R(t, x, u, p): shape (n_outputs, n_outputs)."""
        raise NotImplementedError

    def initial_state(self, p: np.ndarray, y0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Initial mean and covariance (x0, P0); may use the first observation."""
        raise NotImplementedError

    # --- Jacobians (finite differences unless overridden) ------------------
    def drift_jacobian(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return _fd_jacobian(lambda z: self.drift(t, z, u, p), x)

    def observation_jacobian(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return _fd_jacobian(lambda z: self.observation(t, z, u, p), x)


def _fd_jacobian(fun, x: np.ndarray, rel: float = 1e-7) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(fun(x), dtype=float)
    J = np.empty((f0.size, x.size))
    for j in range(x.size):
        h = rel * max(1.0, abs(x[j]))
        xp = x.copy()
        xp[j] += h
        xm = x.copy()
        xm[j] -= h
        J[:, j] = (np.asarray(fun(xp)) - np.asarray(fun(xm))) / (2.0 * h)
    return J


def check_names(model: SDEModel, columns: Sequence[str]) -> None:
    """Raise KeyError naming the first input or output missing from ``columns``."""
    for name in (*model.inputs, *model.outputs):
        if name not in columns:
            raise KeyError(f"{model.name}: column {name!r} is missing from the data")
