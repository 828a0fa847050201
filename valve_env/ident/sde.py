"""Continuous-discrete stochastic state-space models (CTSM style).

A model is declared in plain Python:

    dx = f(t, x, u, p) dt + G(t, x, u, p) dw          (states x, inputs u)
    y_k = h(t_k, x_k, u_k, p) + e_k,  e_k ~ N(0, R(t_k, x_k, u_k, p))

``p`` is the vector of *all* parameters on their natural scale, ordered as
``model.param_names``. Parameters carry bounds and a transform (the optimiser
works on the transformed scale). Jacobians default to finite differences; a
model may override ``drift_jacobian`` and ``observation_jacobian``.

Beyond the four model functions a model may declare itself ``linear`` (the
drift is affine in the states and the inputs; the estimator then offers the
linear Kalman filter with exact discretisation) and may return compiled
(numba) versions of its functions from :meth:`SDEModel.compiled`, which the
fast filter kernel uses; without them the generic Python filter runs.

This file is the contract shared by the estimator (Kalman filters,
likelihood, maximum likelihood) and by the model library (the valve and its
effects, the diagnosis).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numba.core.errors import NumbaExperimentalFeatureWarning

Transform = Literal["none", "log", "logit"]


@dataclass(frozen=True)
class Parameter:
    """One model parameter.

    ``init`` is the starting value on the natural scale; ``lower``/``upper``
    bound it (also on the natural scale); ``transform`` is the scale the
    optimiser works on ("log" requires lower > 0 or None, "logit" maps
    (lower, upper) to the real line, "none" divides by ``scale``, the typical
    size); ``fixed`` keeps it at ``init``. These transforms are the one set
    both likelihoods use (the EKF of :mod:`valve_env.ident.mle` and the
    output error of :mod:`valve_env.valveid.fitting`).
    """

    name: str
    init: float
    lower: float | None = None
    upper: float | None = None
    transform: Transform = "none"
    fixed: bool = False
    unit: str = ""
    doc: str = ""
    scale: float = 1.0


def to_work(value: float, q: Parameter) -> float:
    """Natural scale -> the optimiser's (transformed) scale."""
    if q.transform == "log":
        return _log(value)
    if q.transform == "logit":
        lo, hi = _finite_bounds(q)
        z = (value - lo) / (hi - lo)
        z = min(max(z, 1e-15), 1.0 - 1e-15)
        return _log(z / (1.0 - z))
    return float(value) / q.scale


def from_work(theta: float, q: Parameter) -> float:
    """The optimiser's scale -> natural scale."""
    if q.transform == "log":
        return _exp(theta)
    if q.transform == "logit":
        lo, hi = _finite_bounds(q)
        return float(lo + (hi - lo) / (1.0 + _exp(-theta)))
    return float(theta) * q.scale


def dnat_dwork(theta: float, q: Parameter) -> float:
    """Derivative of the natural value with respect to the transformed one (delta method)."""
    if q.transform == "log":
        return _exp(theta)
    if q.transform == "logit":
        lo, hi = _finite_bounds(q)
        s = 1.0 / (1.0 + _exp(-theta))
        return float((hi - lo) * s * (1.0 - s))
    return float(q.scale)


def work_bounds(q: Parameter) -> tuple[float | None, float | None]:
    """Bounds on the optimiser's scale (None = unbounded)."""
    if q.transform == "logit":
        return (None, None)
    if q.transform == "log":
        lo = None if q.lower is None or q.lower <= 0 else _log(q.lower)
        hi = None if q.upper is None else _log(q.upper)
        return (lo, hi)
    return (None if q.lower is None else q.lower / q.scale, None if q.upper is None else q.upper / q.scale)


def _log(v: float) -> float:
    """log of a scalar (math's, the diagnosis's historical values), -inf at 0 and NaN below as numpy."""
    return math.log(v) if v > 0 else (-math.inf if v == 0 else math.nan)


def _exp(v: float) -> float:
    """exp of a scalar (math's), inf on overflow as numpy."""
    return math.exp(v) if not v > 709.0 else math.inf


def _finite_bounds(q: Parameter) -> tuple[float, float]:
    if q.lower is None or q.upper is None:
        raise ValueError(f"parameter {q.name!r}: the logit transform needs finite lower and upper bounds")
    return float(q.lower), float(q.upper)


def with_overrides(model_name: str, params: Sequence[Parameter], init: Mapping[str, float] | None = None,
                   fixed: Mapping[str, float] | None = None) -> tuple[Parameter, ...]:
    """``params`` with starting values from ``init`` and values held fixed from ``fixed`` (natural
    scale); a KeyError names an unknown parameter."""
    init = dict(init or {})
    fixed = dict(fixed or {})
    known = {q.name for q in params}
    for name in (*init, *fixed):
        if name not in known:
            raise KeyError(f"{model_name}: unknown parameter {name!r}; known: {sorted(known)}")
    return tuple(
        dataclasses.replace(q, init=float(fixed.get(q.name, init.get(q.name, q.init))),
                            fixed=q.fixed or q.name in fixed)
        for q in params
    )


@dataclass(frozen=True)
class CompiledFunctions:
    """numba-compiled (``@njit``) model functions, each
    ``(t, x, u, pc, ctx) -> ndarray`` with the shapes of the corresponding
    :class:`SDEModel` methods (float64, C-contiguous). ``pc`` is the
    natural-scale vector of all parameters followed by
    :meth:`SDEModel.compiled_constants`; ``ctx`` is passed through unchanged
    (any numba-typable value, e.g. a tuple of further ``@njit`` functions that
    the model functions call). Functions that receive dispatchers in ``ctx``
    must not use ``cache=True`` (numba cannot reload such cache entries); the
    filter kernel that calls them compiles once per process. Used by the
    compiled filter kernel in :mod:`valve_env.ident.kalman`."""

    drift: Callable[..., Any]
    drift_jacobian: Callable[..., Any]
    diffusion: Callable[..., Any]
    observation: Callable[..., Any]
    observation_jacobian: Callable[..., Any]
    obs_variance: Callable[..., Any]
    ctx: Any = ()


class SDEModel:
    """Base class of a continuous-discrete stochastic model. Subclasses set the
    name tuples and parameters and implement the four model functions.

    Optional: ``linear = True`` when the drift is affine in states and inputs
    (``f = A x + B u + c`` with A, B, c free of x and u) and G, h (linear), R do
    not depend on the states: the linear Kalman filter with exact
    discretisation then applies. :meth:`compiled` may return numba versions of
    the model functions for the fast filter kernel."""

    name: str = "model"
    states: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    parameters: tuple[Parameter, ...] = ()
    linear: bool = False
    #: compiled EKF: drift Jacobian and diffusion at every RK4 stage (ctsmTMB) or once per step
    jacobian_each_stage: bool = True

    def compiled(self) -> CompiledFunctions | None:
        """numba versions of the model functions, or None (the generic Python path).

        A subclass that changes a model function must either override this too
        or return None; :class:`valve_env.valveid.valve_model.ValveModel`
        documents how its hooks are compiled."""
        return None

    def prepare(self, data: Any) -> Any:
        """Derived input columns the model needs (a DataFrame in, a DataFrame out); identity here."""
        return data

    def fast_filter(self, p: np.ndarray, arr: Any) -> Any | None:
        """A specialised filter pass for this model (a ``filters.FilterResult``) or None.

        Models with a hand-written kernel (the base valve model) return it here;
        ``filters.run_filter`` prefers it for the "ekf" method unless ``fast=False``."""
        return None

    def compiled_constants(self) -> np.ndarray:
        """Constants appended to ``p`` when the compiled functions are called
        (``pc = concatenate([p, compiled_constants()])``); empty by default."""
        return np.zeros(0)

    def parameter(self, name: str) -> Parameter:
        for q in self.parameters:
            if q.name == name:
                return q
        raise KeyError(f"{self.name}: unknown parameter {name!r}; known: {list(self.param_names)}")

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


class CompiledSDEModel(SDEModel):
    """An :class:`SDEModel` whose model functions are its compiled ones (:meth:`SDEModel.compiled`, which a
    subclass must return): each Python method calls the compiled function with
    ``pc = concatenate([p, compiled_constants()])`` and the functions' ``ctx``, so the Python filters, the
    linear Kalman filter and the compiled kernel evaluate the same code."""

    def _call(self, name: str, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        cf = self.compiled()
        assert cf is not None, f"{self.name}: a CompiledSDEModel needs compiled()"
        pc = np.concatenate([_f64(p), self.compiled_constants()])
        with warnings.catch_warnings():  # dispatchers in ctx: first-class functions are experimental in numba
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            return getattr(cf, name)(float(t), _f64(x), _f64(u), pc, cf.ctx)

    def drift(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self._call("drift", t, x, u, p)

    def drift_jacobian(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self._call("drift_jacobian", t, x, u, p)

    def diffusion(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self._call("diffusion", t, x, u, p)

    def observation(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self._call("observation", t, x, u, p)

    def observation_jacobian(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self._call("observation_jacobian", t, x, u, p)

    def obs_variance(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return self._call("obs_variance", t, x, u, p)


def _f64(a: Any) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


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
