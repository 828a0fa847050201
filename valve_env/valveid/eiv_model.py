"""Errors in variables inside the likelihood: a noisy input as a state observed with its own noise.

A model ``base`` (an :class:`~valve_env.ident.sde.SDEModel`) takes an input
``u_j`` that is itself a measurement: the sensed temperature of the valve, whose
white noise (docs/reference.md, section 2) the base valve model removes by
total-variation denoising and then treats as exact. :class:`InputErrorModel`
instead writes the true input as the prepared (denoised) input plus an error
state ``d``,

    u_j,true = u_j + d,        dd = -d / tau_d dt + s_d sqrt(2 / tau_d) dw_d      (OU, stationary sd s_d)

and observes the raw measurement of the input as an extra output with its own noise,

    y_meas = u_j + d + e_T,    e_T ~ N(0, s_e^2).

The base model sees ``u_j + d`` wherever it reads ``u_j``, so the likelihood (and
the inverse Hessian, and the sandwich of :mod:`valve_env.valveid.robust`) carry
the input's uncertainty: the filter's innovations of the base outputs include
``dh/du_j P_dd dh/du_j'`` and the estimates are no longer conditioned on an
exact input. Extra parameters: ``s_d`` (stationary sd of the input error, the
input's units), ``tau_d`` (its correlation time, s), ``s_e`` (the measurement
noise sd of the input). With ``s_d = 0`` the error state stays at 0 with zero
variance and the model is the base model plus an independent Gaussian channel
for the input measurement: the base outputs' likelihood is the base model's
exactly (``tests/estimation/test_eiv_model.py`` checks this on ctsmTMB's
Ornstein2D references).

For the valve (:class:`ValveEIVModel`) the noisy input is ``T_tank_s`` (the
denoised tank temperature, the gas temperature of the base model's force
balance), measured as ``T_tank_C``. The error state moves the force balance's
temperature, so the bellows' vapour pressure (hence ``p_bset``) and the
friction force read off the opening (hence ``sigma`` and ``F_hmax``) are
estimated against an uncertain temperature. The Dahl friction's driver stays
the rate of the denoised temperature: the derivative of an OU state is white
noise, and a rate filtered from the noisy signal jitters through every spurious
reversal (docs/estimation.md, why the temperature is a denoised input), so the
reversal timing is not part of the error state. The valve version runs the base
model's hand-written numba EKF with its errors-in-variables option
(:func:`~valve_env.valveid.valve_model.fast_valve_filter`: the exact Dahl step and
the exact OU step per interval, a joint update of the two outputs), about as
fast as the base model's.

    est = MLEstimator(ValveEIVModel(), n_starts=3).fit(df)     # or: thermovalve fit RUN --json F --eiv
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from valve_env.ident.sde import Parameter, SDEModel, with_overrides
from valve_env.valveid.valve_model import (
    C_SIGN_EPS,
    P_F_HMAX,
    P_SIGMA,
    U_V,
    ValveModel,
    denoise_temperature,
    fast_valve_filter,
    noise_sd,
    smooth_sign,
)


class InputErrorModel(SDEModel):
    """Errors in variables for one input of ``base`` (see the module doc).

    ``input`` the base model's input that is uncertain (a column the base's
    ``prepare`` produces), ``measured`` the data column that measures it (an
    extra output). ``init``/``fixed`` map parameter names (the base's and
    ``s_d``, ``tau_d``, ``s_e``) to start or fixed values; ``s_d = 0`` fixed
    turns the error state off. Runs the generic Python EKF (finite-difference
    Jacobians); subclasses may provide a fast kernel (:class:`ValveEIVModel`)."""

    def __init__(self, base: SDEModel, input: str, measured: str | None = None, *,
                 init: Mapping[str, float] | None = None, fixed: Mapping[str, float] | None = None,
                 s_d: float = 0.003, tau_d: float = 300.0, s_e: float = 0.01) -> None:
        if input not in base.inputs:
            raise KeyError(f"{base.name}: {input!r} is not one of its inputs {list(base.inputs)}")
        self.base = base
        self.input = input
        self.measured = measured
        self.j_input = base.inputs.index(input)
        self.name = f"{base.name}+eiv({input})"
        self.states = (*base.states, f"d_{input}")
        self.inputs = tuple(base.inputs)
        self.outputs = (*base.outputs, measured) if measured else tuple(base.outputs)
        self.simulation_outputs = (*getattr(base, "simulation_outputs", ()), *([measured] if measured else []))
        self.jacobian_each_stage = getattr(base, "jacobian_each_stage", True)
        # u + d is affine in the state when the base drift is affine in u: a linear base stays linear
        self.linear = bool(base.linear)
        extra = (
            Parameter("s_d", s_d, 1e-7, 10.0, "log", doc="stationary sd of the input error (input's units)"),
            Parameter("tau_d", tau_d, 1.0, 1e6, "log", unit="s", doc="correlation time of the input error"),
            *([Parameter("s_e", s_e, 1e-7, 10.0, "log", doc="measurement noise sd of the input")] if measured else []),
        )
        self.parameters = with_overrides(self.name, [*base.parameters, *extra], init, fixed)
        self.n_base_params = len(base.parameters)
        self.n_base_states = base.n_states

    # --- data ---------------------------------------------------------------
    def prepare(self, data: Any) -> Any:
        return self.base.prepare(data)

    # --- helpers --------------------------------------------------------------
    def _split(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nb_ = self.n_base_states
        ub = np.array(u, dtype=float, copy=True)
        ub[self.j_input] += x[nb_]
        return np.asarray(x[:nb_], dtype=float), ub, np.asarray(p[:self.n_base_params], dtype=float)

    def _extra(self, p: np.ndarray) -> tuple[float, float, float]:
        k = self.n_base_params
        return float(p[k]), float(p[k + 1]), (float(p[k + 2]) if self.measured else 0.0)

    # --- model functions ------------------------------------------------------
    def drift(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        xb, ub, pb = self._split(x, u, p)
        _, tau, _ = self._extra(p)
        return np.append(np.asarray(self.base.drift(t, xb, ub, pb), dtype=float), -x[self.n_base_states] / tau)

    def diffusion(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        xb, ub, pb = self._split(x, u, p)
        s_d, tau, _ = self._extra(p)
        Gb = np.asarray(self.base.diffusion(t, xb, ub, pb), dtype=float).reshape(len(xb), -1)
        G = np.zeros((len(xb) + 1, Gb.shape[1] + 1))
        G[:-1, :-1] = Gb
        G[-1, -1] = s_d * np.sqrt(2.0 / tau)
        return G

    def observation(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        xb, ub, pb = self._split(x, u, p)
        h = np.asarray(self.base.observation(t, xb, ub, pb), dtype=float)
        return np.append(h, ub[self.j_input]) if self.measured else h

    def obs_variance(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        xb, ub, pb = self._split(x, u, p)
        Rb = np.asarray(self.base.obs_variance(t, xb, ub, pb), dtype=float)
        if not self.measured:
            return Rb
        m = Rb.shape[0]
        R = np.zeros((m + 1, m + 1))
        R[:m, :m] = Rb
        R[m, m] = self._extra(p)[2] ** 2
        return R

    def initial_state(self, p: np.ndarray, y0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pb = np.asarray(p[:self.n_base_params], dtype=float)
        xb, Pb = self.base.initial_state(pb, np.asarray(y0)[:self.base.n_outputs], u0)
        n = self.n_base_states
        x0 = np.zeros(n + 1)
        P0 = np.zeros((n + 1, n + 1))
        x0[:n] = xb
        P0[:n, :n] = Pb
        P0[n, n] = self._extra(p)[0] ** 2
        return x0, P0


class ValveEIVModel(InputErrorModel):
    """The base valve model (docs/reference.md, section 1) with the tank temperature as an
    uncertain input: the force balance reads ``T_tank_s + d``, the raw ``T_tank_C`` is observed with
    sd ``s_e`` (see the module doc). Parameters: the base valve's (``sigma, F_hmax, p_bset, s_F,
    s_x``), then ``s_d`` (degC), ``tau_d`` (s), ``s_e`` (degC). ``valve`` and the keyword
    options of :class:`~valve_env.valveid.valve_model.ValveModel` pass through (``init`` and
    ``fixed`` may name any parameter)."""

    def __init__(self, valve: Any = None, *, init: Mapping[str, float] | None = None,
                 fixed: Mapping[str, float] | None = None, s_d: float = 0.003, tau_d: float = 300.0,
                 s_e: float = 0.01, measured: str | None = None, **options: Any) -> None:
        base = ValveModel(valve, **options)
        super().__init__(base, "T_tank_s", measured, init=init, fixed=fixed, s_d=s_d, tau_d=tau_d, s_e=s_e)
        self.name = "valve+eiv(T_tank)"
        self.valve = base.valve
        self.tv_factor = base.tv_factor
        self.denoiser = base.denoiser

    @property
    def constants(self) -> np.ndarray:
        assert isinstance(self.base, ValveModel)
        return self.base.constants

    def _coupling(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> float:
        """dF_h/dT of the Dahl law along the interval's direction: the error's travel moves the friction."""
        sv = float(smooth_sign(float(u[U_V]), float(self.constants[C_SIGN_EPS])))
        return float(p[P_SIGMA] * sv * (sv - x[0] / p[P_F_HMAX]))

    def drift(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        f = super().drift(t, x, u, p)
        _, tau, _ = self._extra(p)
        f[0] += self._coupling(x, u, p) * (-x[self.n_base_states] / tau)
        return f

    def diffusion(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        G = super().diffusion(t, x, u, p)
        G[0, -1] = self._coupling(x, u, p) * G[-1, -1]
        return G

    def valve_params(self, values: dict[str, float]) -> Any:
        assert isinstance(self.base, ValveModel)
        return self.base.valve_params(values)

    def fast_filter(self, p: np.ndarray, arr: Any) -> Any | None:
        """The hand-written EKF (exact Dahl and OU steps), or None if the base valve's hooks changed."""
        assert isinstance(self.base, ValveModel)
        if not self.base.is_base:
            return None
        k = self.n_base_params
        return fast_valve_filter(p, self.constants, arr, eiv=True, s_d=float(p[k]), tau=float(p[k + 1]),
                                 s_e=float(p[k + 2]) if self.measured else 1.0)


def denoising_error(T_C: np.ndarray, t: np.ndarray, *, tv_factor: float = 4.5, B: int = 4, seed: int = 0,
                    noise_C: float | None = None, denoiser: str = "relaxed") -> tuple[float, float, float]:
    """The error of the denoised temperature as a Gauss-Markov (OU) process: (s_d, tau_d, noise sd).

    The denoised signal stands for the true one: ``B`` times white noise of the channel's sd
    (``noise_C``, default estimated from second differences) is added to it and the copy is
    denoised again (:func:`~valve_env.valveid.valve_model.denoise_temperature`); the pooled sd of
    (re-denoised - denoised) is ``s_d`` and its lag-1 autocorrelation rho gives
    ``tau_d = -dt / ln rho`` (dt the median sample interval). The raw measurement cannot tell this
    error itself (the denoised signal was fitted to it), so the error state's size is fixed from
    this calibration rather than estimated (docs/uncertainty.md)."""

    T_C = np.asarray(T_C, dtype=float)
    t = np.asarray(t, dtype=float)
    s_n = noise_sd(T_C) if noise_C is None else float(noise_C)
    Ts, _ = denoise_temperature(T_C, t, tv_factor, denoiser)
    dt = float(np.median(np.diff(t)))
    if s_n <= 0.0:
        return 0.0, 10.0 * dt, 0.0
    rng = np.random.default_rng(seed)
    errs = []
    for _ in range(max(int(B), 1)):
        Tb, _ = denoise_temperature(Ts + s_n * rng.standard_normal(len(Ts)), t, tv_factor, denoiser)
        errs.append(Tb - Ts)
    E = np.vstack(errs)
    E = E - E.mean(axis=1, keepdims=True)
    s_d = float(np.sqrt(np.mean(E**2)))
    rho = float(np.sum(E[:, 1:] * E[:, :-1]) / max(np.sum(E[:, :-1] ** 2), 1e-300))
    rho = min(max(rho, 1e-6), 1.0 - 1e-9)
    return s_d, float(-dt / np.log(rho)), s_n


def valve_eiv_model(data: Any, valve: Any = None, *, B: int = 4, seed: int = 0, **options: Any) -> ValveEIVModel:
    """The valve EIV model for ``data`` (docs/reference.md, section 2 columns) with the error state's size
    (``s_d``, ``tau_d``) fixed by :func:`denoising_error` on the data's tank temperature."""
    tv_factor = float(options.get("tv_factor", 4.5))
    s_d, tau_d, _ = denoising_error(data["T_tank_C"].to_numpy(dtype=float), data["time_s"].to_numpy(dtype=float),
                                    tv_factor=tv_factor, B=B, seed=seed,
                                    denoiser=str(options.get("denoiser", "relaxed")))
    return ValveEIVModel(valve, fixed={"s_d": s_d, "tau_d": tau_d}, **options)


__all__ = ["InputErrorModel", "ValveEIVModel", "denoising_error", "valve_eiv_model"]
