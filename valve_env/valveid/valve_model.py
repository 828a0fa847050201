"""The valve of docs/reference.md, section 1 as a continuous-discrete stochastic model.

The paper's model (eq. 15-17): one state, the Dahl friction force ``F_h`` (N),
driven by the rate v_g of the gas temperature T_g = T_tank,

    dF_h = v_g sigma (1 - F_h / F_hmax sgn(v_g)) dt + s_F dw
    x_mm = clip(x_d(T_g, F_h, dp, ps; p_bset), 0, stroke) + e,   e ~ N(0, s_x^2)

with x_d the force balance (paper eq. 16, :func:`valve_env.physics.valve.demanded_opening`).

The temperatures as inputs. The temperature channels carry white noise
(0.01 degC) and the Dahl force responds to every reversal of T_g with slope
2 sigma (about 13 N/K against a range of 2 F_hmax = 2.6 N): a reversal of a few
millikelvin moves it visibly, so neither a finite difference of the raw signal
nor a Gaussian smoother (which leaves small wiggles, each one a reversal) is a
usable driver; filtering a latent temperature jointly with the valve has the
same flaw (the filtered rate jitters; tried, sigma came out at half its value).
The inputs are therefore the total-variation-denoised temperatures
(:func:`tv_denoise`, Condat's exact algorithm): the least-squares fit with a
penalty ``lam`` on the total variation, which removes spurious reversals (each
costs 2 x its height in total variation) while keeping ramps and steps, with
the extreme blocks re-estimated without the penalty (:func:`relaxed_tv`). ``lam`` =
``tv_factor`` x the noise sd estimated from second differences (default 4.5; on
paper-like runs the noise-free Dahl driven by the denoised temperature
reproduces the true opening to 1-2e-3 mm, below the 2.4e-3 mm of the
measurement). :func:`prepare_inputs`
adds the columns ``T_tank_s``, ``v_tank`` (rate over the following interval,
K/s), ``T_med_s`` and ``v_med``; the model's :meth:`ValveModel.prepare` calls it.

Extension (the effect models, docs/reference.md, section 3): subclass :class:`ValveModel`,
append states and parameters, and replace the *hooks*, which are numba
``@njit`` functions ``hook(t, x, u, p, c)`` (``x`` full state vector, ``u``
inputs, ``p`` the natural-scale vector of all parameters, ``c`` constants:
the packed :class:`~valve_env.params.ValveParams` followed by model options).
The same hook functions serve the Python filter and the compiled one. See
docs/estimation.md, "Extending the valve model".
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, ClassVar

import numba as nb
import numpy as np
import pandas as pd
from numba.core.errors import NumbaExperimentalFeatureWarning

from valve_env.data_io import censored_opening
from valve_env.ident.kalman import _alloc
from valve_env.ident.sde import CompiledFunctions, CompiledSDEModel, Parameter, with_overrides
from valve_env.params import I_F_HMAX, I_P_BSET, I_SIGMA, I_STROKE, N_VALVE, ValveParams
from valve_env.physics import valve as phys
from valve_env.valveid.temperature import DENOISERS, denoise_temperature, noise_sd, relaxed_tv, tv_denoise

# Indices into the parameter vector p (base parameters come first, extensions append).
P_SIGMA, P_F_HMAX, P_P_BSET, P_S_F, P_S_X = 0, 1, 2, 3, 4
N_BASE_PARAMS = 5
# Index into the state vector x (extensions append states).
X_F = 0
N_BASE_STATES = 1
# Indices into the input vector u (the model's inputs, see ValveModel.inputs).
U_T, U_V, U_T_MED, U_V_MED, U_DP, U_PS, U_TIME = 0, 1, 2, 3, 4, 5, 6
# Indices into the constants vector c: the packed ValveParams (0..N_VALVE-1), then options.
C_CLIP_W = N_VALVE  # width (mm) of the smooth clipping weight in the observation Jacobian
C_SIGN_EPS = N_VALVE + 1  # rate scale (K/s) of the smooth sign tanh(v / eps) in the Dahl drift (0 = sgn)
N_BASE_CONSTANTS = N_VALVE + 2


# --------------------------------------------------------------------------- input preparation
def prepare_inputs(data: pd.DataFrame, tv_factor: float = 4.5, time: str = "time_s",
                   denoiser: str = "relaxed") -> pd.DataFrame:
    """A copy of ``data`` with ``T_tank_s``, ``v_tank`` (from ``T_tank_C``) and ``T_med_s``,
    ``v_med`` (from ``T_med_C``): the denoised temperatures and their rates (see the module doc),
    and ``t_in``, the sample time (so that a hook can interpolate inside an interval, see
    :func:`tank_temperature`). An opening derived from a flow read as 0 under a meter's low-flow cut-off
    (:func:`valve_env.data_io.censored_opening`) is only known to lie below the cut-off's: it is missing (NaN) here,
    as the filter takes a missing output."""
    out = data.copy()
    censored = censored_opening(data)
    if censored is not None and "x_mm" in out.columns:
        out["x_mm"] = np.where(censored, np.nan, out["x_mm"].to_numpy(dtype=float))
    t = out[time].to_numpy(dtype=float)
    out["t_in"] = t
    out["T_tank_s"], out["v_tank"] = denoise_temperature(out["T_tank_C"].to_numpy(dtype=float), t, tv_factor,
                                                         denoiser)
    if "T_med_C" in out.columns:
        out["T_med_s"], out["v_med"] = denoise_temperature(out["T_med_C"].to_numpy(dtype=float), t, tv_factor,
                                                           denoiser)
    else:
        out["T_med_s"], out["v_med"] = out["T_tank_s"], out["v_tank"]
    return out


# --------------------------------------------------------------------------- base hooks
@nb.njit(cache=True)
def tank_temperature(t: float, u: np.ndarray) -> float:
    """The denoised tank temperature at time t: exact at the samples, linear in between.
    (The filter holds u at the interval's start, u[U_TIME] = t_k-1, so this interpolates.)"""
    return u[U_T] + u[U_V] * (t - u[U_TIME])


@nb.njit(cache=True)
def medium_temperature(t: float, u: np.ndarray) -> float:
    """The denoised medium temperature at time t (as :func:`tank_temperature`)."""
    return u[U_T_MED] + u[U_V_MED] * (t - u[U_TIME])


@nb.njit(cache=True)
def hook_gas_temperature(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    """T_g, degC. Base: the denoised tank temperature (paper eq. 17)."""
    return tank_temperature(t, u)


@nb.njit(cache=True)
def hook_gas_rate(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    """v_g = dT_g/dt, K/s, the Dahl driver. Base: the rate of the denoised tank temperature."""
    return u[U_V]


@nb.njit(cache=True)
def hook_set_pressure(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> float:
    """p_b,set, MPa. Base: the parameter p_bset."""
    return p[P_P_BSET]


@nb.njit(cache=True)
def _valve_vector(p: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The packed ValveParams (from c) with the fitted sigma, F_hmax and p_bset."""
    vp = c[:N_VALVE].copy()
    vp[I_SIGMA] = p[P_SIGMA]
    vp[I_F_HMAX] = p[P_F_HMAX]
    vp[I_P_BSET] = p[P_P_BSET]
    return vp


@nb.njit(cache=True)
def hook_opening(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray,
                 T_g: float, p_set: float) -> float:
    """The unclipped opening, mm (the observation clips it to [0, stroke]).
    Base: the force balance, paper eq. 16, with F_h = x[X_F]."""
    return phys.demanded_opening(T_g, x[X_F], u[U_DP], u[U_PS], p_set, _valve_vector(p, c))


@nb.njit(cache=True)
def smooth_sign(v: float, eps: float) -> float:
    """tanh(v / eps), or sgn(v) for eps <= 0."""
    if eps <= 0.0:
        return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return np.tanh(v / eps)


@nb.njit(cache=True)
def hook_dahl(F: float, v: float, sigma: float, F_hmax: float, eps: float) -> float:
    """Dahl drift, alpha = 1 (paper eq. 14; physics.valve.dahl_rate), written as
    sigma |v| (sgn(v) - F / F_hmax); with eps > 0 sgn becomes s = tanh(v / eps) and |v| = v s,
    which keeps |F| <= F_hmax."""
    s = smooth_sign(v, eps)
    return sigma * v * s * (s - F / F_hmax)


@nb.njit(cache=True)
def hook_extra_drift(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Drift of the appended states (none in the base model)."""
    return np.zeros(x.shape[0] - N_BASE_STATES)


@nb.njit(cache=True)
def hook_extra_diffusion(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Diffusion (one independent Wiener process each, standard deviations) of the appended states."""
    return np.zeros(x.shape[0] - N_BASE_STATES)


# --------------------------------------------------------------------------- compiled model
# The model functions take ctx = (gas_temperature, gas_rate, set_pressure, opening, extra_drift,
# extra_diffusion, n_constants): the hooks are first-class function arguments. Functions that take
# dispatchers as arguments are not cached on disk (numba 0.6x cannot reload such cache entries:
# "ReferenceError: underlying object has vanished"), so they compile once per process.
@nb.njit(cache=True)
def _split(pc: np.ndarray, nc: int) -> tuple[np.ndarray, np.ndarray]:
    n = pc.shape[0] - nc
    return pc[:n], pc[n:]


@nb.njit
def valve_drift(t: float, x: np.ndarray, u: np.ndarray, pc: np.ndarray, ctx: Any) -> np.ndarray:
    p, c = _split(pc, ctx[6])
    n = x.shape[0]
    out = np.empty(n)
    vg = ctx[1](t, x, u, p, c)
    out[X_F] = hook_dahl(x[X_F], vg, p[P_SIGMA], p[P_F_HMAX], c[C_SIGN_EPS])
    if n > N_BASE_STATES:
        ex = ctx[4](t, x, u, p, c)
        for i in range(n - N_BASE_STATES):
            out[N_BASE_STATES + i] = ex[i]
    return out


@nb.njit
def valve_drift_jacobian(t: float, x: np.ndarray, u: np.ndarray, pc: np.ndarray, ctx: Any) -> np.ndarray:
    """Central differences of :func:`valve_drift`."""
    n = x.shape[0]
    J = np.empty((n, n))
    xp = x.copy()
    for j in range(n):
        h = 1e-6 * max(1.0, abs(x[j]))
        xp[j] = x[j] + h
        fp = valve_drift(t, xp, u, pc, ctx)
        xp[j] = x[j] - h
        fm = valve_drift(t, xp, u, pc, ctx)
        xp[j] = x[j]
        for i in range(n):
            J[i, j] = (fp[i] - fm[i]) / (2.0 * h)
    return J


@nb.njit
def valve_diffusion(t: float, x: np.ndarray, u: np.ndarray, pc: np.ndarray, ctx: Any) -> np.ndarray:
    p, c = _split(pc, ctx[6])
    n = x.shape[0]
    G = np.zeros((n, n))
    G[X_F, X_F] = p[P_S_F]
    if n > N_BASE_STATES:
        g = ctx[5](t, x, u, p, c)
        for k in range(n - N_BASE_STATES):
            G[N_BASE_STATES + k, N_BASE_STATES + k] = g[k]
    return G


@nb.njit
def _demand(t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray, c: np.ndarray, ctx: Any) -> float:
    return ctx[3](t, x, u, p, c, ctx[0](t, x, u, p, c), ctx[2](t, x, u, p, c))


@nb.njit
def valve_observation(t: float, x: np.ndarray, u: np.ndarray, pc: np.ndarray, ctx: Any) -> np.ndarray:
    p, c = _split(pc, ctx[6])
    out = np.empty(1)
    xd = _demand(t, x, u, p, c, ctx)
    out[0] = min(max(xd, 0.0), c[I_STROKE])
    return out


@nb.njit(cache=True)
def clip_weight(xd: float, stroke: float, w: float) -> float:
    """Smooth stand-in for the derivative of clip(xd, 0, stroke): logistic of width w at both stops."""
    return 1.0 / (1.0 + np.exp(-xd / w)) / (1.0 + np.exp(-(stroke - xd) / w))


@nb.njit
def valve_observation_jacobian(t: float, x: np.ndarray, u: np.ndarray, pc: np.ndarray, ctx: Any) -> np.ndarray:
    """dh/dx: the derivative of the unclipped force balance times :func:`clip_weight` (instead of
    the step derivative of the clipping, which would blind a seated valve's filter near x = 0)."""
    p, c = _split(pc, ctx[6])
    n = x.shape[0]
    H = np.zeros((1, n))
    xd = _demand(t, x, u, p, c, ctx)
    weight = clip_weight(xd, c[I_STROKE], c[C_CLIP_W])
    xp = x.copy()
    for j in range(n):
        h = 1e-6 * max(1.0, abs(x[j]))
        xp[j] = x[j] + h
        dpl = _demand(t, xp, u, p, c, ctx)
        xp[j] = x[j] - h
        dmi = _demand(t, xp, u, p, c, ctx)
        xp[j] = x[j]
        H[0, j] = weight * (dpl - dmi) / (2.0 * h)
    return H


@nb.njit
def valve_obs_variance(t: float, x: np.ndarray, u: np.ndarray, pc: np.ndarray, ctx: Any) -> np.ndarray:
    R = np.zeros((1, 1))
    R[0, 0] = pc[P_S_X] ** 2
    return R


# --------------------------------------------------------------------------- fast kernel (base and EIV)
@nb.njit(cache=True)
def _scalar_update(F: float, d: float, P00: float, P01: float, P11: float, ek: float, h0: float, h1: float,
                   Rk: float) -> tuple[float, float, float, float, float, float]:  # pragma: no cover - compiled
    """One scalar measurement update of the 2-state filter (Joseph form) and its nll term."""
    PH0 = P00 * h0 + P01 * h1
    PH1 = P01 * h0 + P11 * h1
    Sk = h0 * PH0 + h1 * PH1 + Rk
    if not Sk > 0.0:
        return F, d, P00, P01, P11, np.inf
    K0 = PH0 / Sk
    K1 = PH1 / Sk
    B00 = 1.0 - K0 * h0
    B01 = -K0 * h1
    B10 = -K1 * h0
    B11 = 1.0 - K1 * h1
    M00 = B00 * P00 + B01 * P01
    M01 = B00 * P01 + B01 * P11
    M10 = B10 * P00 + B11 * P01
    M11 = B10 * P01 + B11 * P11
    n00 = M00 * B00 + M01 * B01 + K0 * K0 * Rk
    n01 = M00 * B10 + M01 * B11 + K0 * K1 * Rk
    n11 = M10 * B10 + M11 * B11 + K1 * K1 * Rk
    term = 0.5 * np.log(Sk) + 0.5 * ek * ek / Sk + 0.5 * np.log(2.0 * np.pi)
    return F + K0 * ek, d + K1 * ek, n00, n01, n11, term


@nb.njit(cache=True)
def _fast_valve_kernel(t: np.ndarray, U: np.ndarray, Y: np.ndarray, p: np.ndarray, c: np.ndarray, s_d: float,
                       tau: float, s_e: float, x_pred: np.ndarray, P_pred: np.ndarray, x_filt: np.ndarray,
                       P_filt: np.ndarray, y_pred: np.ndarray, S_out: np.ndarray, innov: np.ndarray,
                       Phi_out: np.ndarray) -> float:  # pragma: no cover - compiled
    """EKF of the base valve model, allocation-free, with the exact time update: over an interval the rate
    input is constant (zero-order hold of v), so the mean takes the exact Dahl step F <- s F_hmax + (F - s
    F_hmax) exp(-sigma |dT| / F_hmax) (docs/reference.md, section 1) and the variance P <- e^2 P + s_F^2 dt
    with e = dF+/dF.

    With two states (the arrays' shape), :class:`~valve_env.valveid.eiv_model.ValveEIVModel`'s errors in
    variables (states F_h, d; outputs x_mm and, with a second column of ``Y``, T_tank_C): d the OU error of the
    temperature (stationary sd ``s_d``, time constant ``tau``), T_tank_C its measurement (sd ``s_e``). Per
    interval the exact OU step of d and the exact Dahl step for the interval's temperature travel dT_s + dd
    (the denoised travel plus the error's), linearised in dd (the bulb is driven by the true temperature); at
    each sample the update with whichever outputs are present."""
    N = t.shape[0]
    eiv = x_pred.shape[1] == 2
    ny = Y.shape[1]
    sig = p[P_SIGMA]
    Fm = p[P_F_HMAX]
    qF = p[P_S_F] ** 2
    R0 = p[P_S_X] ** 2
    R1 = s_e ** 2
    stroke = c[I_STROKE]
    w = c[C_CLIP_W]
    eps = c[C_SIGN_EPS]
    vp = _valve_vector(p, c)
    F = 0.0
    d = 0.0
    P00 = Fm * Fm
    P01 = 0.0
    P11 = s_d * s_d
    nll = 0.0
    log2pi = np.log(2.0 * np.pi)
    hT = 1e-4
    for k in range(N):
        e = 1.0
        A01 = 0.0
        A11 = 1.0
        if k > 0:
            dt = t[k] - t[k - 1]
            v = U[k - 1, U_V]
            sv = smooth_sign(v, eps)
            if eiv:
                a = np.exp(-dt / tau)
                qd = s_d * s_d * (1.0 - a * a)
                # F+ = s Fm + (F - s Fm) exp(-sigma s (dT_s + dd) / Fm), dd = (a - 1) d + w_d
                e = np.exp(-sig * sv * (v * dt + (a - 1.0) * d) / Fm)
                if e > 1.0 and sv != 0.0:  # the error's travel cannot reverse the interval's direction
                    e = 1.0
                g = sig * sv * (sv * Fm - F) / Fm * e  # dF+/d(dd)
                A01 = g * (a - 1.0)
                A11 = a
                # P+ = A P A' + Q, Q = [[qF dt + g^2 qd, g qd], [g qd, qd]]
                n00 = e * e * P00 + 2.0 * e * A01 * P01 + A01 * A01 * P11 + qF * dt + g * g * qd
                n01 = e * A11 * P01 + A01 * A11 * P11 + g * qd
                n11 = A11 * A11 * P11 + qd
                P00, P01, P11 = n00, n01, n11
                d = a * d
            else:
                e = np.exp(-sig * v * sv * dt / Fm)
                P00 = e * e * P00 + qF * dt
            F = phys.dahl_relax(F, sv, e, vp)  # the exact Dahl step of physics.valve
        x_pred[k, 0] = F
        P_pred[k, 0, 0] = P00
        Phi_out[k, 0, 0] = e
        T_g = U[k, U_T] + d
        dpk = U[k, U_DP]
        psk = U[k, U_PS]
        xd = phys.demanded_opening(T_g, F, dpk, psk, vp[I_P_BSET], vp)
        wgt = clip_weight(xd, stroke, w)
        hF = wgt / phys.stiffness(dpk, vp)
        y0 = min(max(xd, 0.0), stroke)
        y_pred[k, 0] = y0
        if not eiv:
            S = hF * hF * P00 + R0
            S_out[k, 0, 0] = S
            if np.isfinite(Y[k, 0]):
                if S <= 0.0:
                    return np.inf
                ek = Y[k, 0] - y0
                nll += 0.5 * np.log(S) + 0.5 * ek * ek / S + 0.5 * log2pi
                K = P00 * hF / S
                F += K * ek
                ikh = 1.0 - K * hF
                P00 = ikh * ikh * P00 + K * K * R0
                innov[k, 0] = ek
            x_filt[k, 0] = F
            P_filt[k, 0, 0] = P00
            continue
        x_pred[k, 1] = d
        P_pred[k, 0, 1] = P_pred[k, 1, 0] = P01
        P_pred[k, 1, 1] = P11
        Phi_out[k, 0, 1] = A01
        Phi_out[k, 1, 0] = 0.0
        Phi_out[k, 1, 1] = A11
        hd = wgt * (phys.demanded_opening(T_g + hT, F, dpk, psk, vp[I_P_BSET], vp)
                    - phys.demanded_opening(T_g - hT, F, dpk, psk, vp[I_P_BSET], vp)) / (2.0 * hT)
        # S = H P H' + R with H = [[hF, hd], [0, 1]]
        PH00 = P00 * hF + P01 * hd  # (P H')[:, 0]
        PH10 = P01 * hF + P11 * hd
        S_out[k, 0, 0] = hF * PH00 + hd * PH10 + R0
        if ny == 2:
            y_pred[k, 1] = T_g
            S_out[k, 0, 1] = S_out[k, 1, 0] = PH10
            S_out[k, 1, 1] = P11 + R1
        # the joint update of the present outputs as sequential scalar updates with the same
        # linearisation (exact for independent measurement noises: same state, covariance and nll)
        F0 = F
        d0 = d
        for j in range(ny):
            if not np.isfinite(Y[k, j]):
                continue
            if j == 0:
                h0, h1, Rk, ek = hF, hd, R0, Y[k, 0] - y0
            else:
                h0, h1, Rk, ek = 0.0, 1.0, R1, Y[k, 1] - T_g
            innov[k, j] = ek
            ek -= h0 * (F - F0) + h1 * (d - d0)  # against the state updated by the first output
            F, d, P00, P01, P11, term = _scalar_update(F, d, P00, P01, P11, ek, h0, h1, Rk)
            if not np.isfinite(term):
                return np.inf
            nll += term
        x_filt[k, 0] = F
        x_filt[k, 1] = d
        P_filt[k, 0, 0] = P00
        P_filt[k, 0, 1] = P_filt[k, 1, 0] = P01
        P_filt[k, 1, 1] = P11
    return nll


def fast_valve_filter(p: np.ndarray, c: np.ndarray, arr: Any, *, eiv: bool = False, s_d: float = 0.0,
                      tau: float = 1.0, s_e: float = 1.0) -> Any:
    """:func:`_fast_valve_kernel` on ``arr``: the :class:`~valve_env.ident.kalman.FilterResult` of the base
    valve model or, with ``eiv``, of :class:`~valve_env.valveid.eiv_model.ValveEIVModel` (its outputs those of
    ``arr.Y``)."""
    res = _alloc(len(arr.t), 2 if eiv else 1, arr.Y.shape[1])
    res.nll = float(_fast_valve_kernel(arr.t, arr.U, arr.Y, _f(p), c, s_d, tau, s_e, res.x_pred, res.P_pred,
                                       res.x_filt, res.P_filt, res.y_pred, res.S, res.innov, res.Phi))
    return res


# --------------------------------------------------------------------------- the model class
class ValveModel(CompiledSDEModel):
    """The base valve model (docs/reference.md, section 1, paper eq. 15-17), a
    :class:`~valve_env.ident.sde.CompiledSDEModel` (its Python functions are the compiled ones).

    Free parameters (natural units): ``sigma`` N/K, ``F_hmax`` N, ``p_bset`` MPa
    (paper Table 4), ``s_F`` (N/sqrt(s), friction diffusion, paper eq. 15 dw) and
    ``s_x`` (mm, opening observation sd). The other valve constants come from
    ``valve``. Inputs are prepared from the docs/reference.md, section 2 columns by
    :meth:`prepare` (denoised temperatures, see the module docstring).

    ``fixed`` maps parameter names to values kept fixed; ``init`` overrides
    starting values; ``clip_width_mm`` is the width of the smooth weight that
    replaces the step derivative of the clipping in the observation Jacobian;
    ``sign_eps`` (K/s) the scale of a smooth sign in the Dahl drift (0: sgn, the
    default: the rate input does not depend on the parameters, so the
    likelihood stays smooth); ``tv_factor`` the total-variation penalty in units
    of the temperature noise sd; ``denoiser`` "relaxed" (default) or "tv" (:func:`denoise_temperature`).

    Subclasses extend ``extra_states``, ``extra_parameters`` and the hook
    class attributes (see docs/estimation.md).
    """

    name = "valve"
    base_states: ClassVar[tuple[str, ...]] = ("F_h",)
    extra_states: ClassVar[tuple[str, ...]] = ()
    extra_parameters: ClassVar[tuple[Parameter, ...]] = ()
    inputs = ("T_tank_s", "v_tank", "T_med_s", "v_med", "dp_mbar", "ps_bar", "t_in")
    outputs = ("x_mm",)
    #: generic compiled EKF: Jacobian once per RK4 step (2-3x faster; the mean is still RK4)
    jacobian_each_stage = False

    # hooks: numba @njit functions hook(t, x, u, p, c) (opening also takes T_g, p_set)
    gas_temperature_hook: ClassVar[Callable[..., float]] = hook_gas_temperature
    gas_rate_hook: ClassVar[Callable[..., float]] = hook_gas_rate
    set_pressure_hook: ClassVar[Callable[..., float]] = hook_set_pressure
    opening_hook: ClassVar[Callable[..., float]] = hook_opening
    extra_drift_hook: ClassVar[Callable[..., np.ndarray]] = hook_extra_drift
    extra_diffusion_hook: ClassVar[Callable[..., np.ndarray]] = hook_extra_diffusion

    def __init__(self, valve: ValveParams | None = None, *, fixed: dict[str, float] | None = None,
                 init: dict[str, float] | None = None, clip_width_mm: float = 0.01, sign_eps: float = 0.0,
                 tv_factor: float = 4.5, denoiser: str = "relaxed") -> None:
        if denoiser not in DENOISERS:
            raise ValueError(f"unknown denoiser {denoiser!r}; use one of {DENOISERS}")
        self.denoiser = denoiser
        self.valve = valve if valve is not None else ValveParams()
        self.clip_width_mm = float(clip_width_mm)
        self.sign_eps = float(sign_eps)
        self.tv_factor = float(tv_factor)
        self.states = (*self.base_states, *self.extra_states)
        v = self.valve
        base = (
            Parameter("sigma", v.sigma, 0.05, 500.0, "log", unit="N/K", doc="Dahl stiffness (paper Table 4)"),
            Parameter("F_hmax", v.F_hmax, 0.005, 50.0, "log", unit="N", doc="maximum friction force (paper Table 4)"),
            Parameter("p_bset", v.p_bset, 0.005, 1.0, "log", unit="MPa",
                      doc="bellows pressure at the set point (paper Table 4)"),
            Parameter("s_F", 1e-3, 1e-6, 10.0, "log", unit="N/sqrt(s)", doc="diffusion of the friction force"),
            Parameter("s_x", 5e-3, 1e-5, 1.0, "log", unit="mm", doc="opening observation noise sd"),
        )
        self.parameters = with_overrides(self.name, [*base, *self.extra_parameters], init, fixed)

    # --- data ---------------------------------------------------------------
    def prepare(self, data: pd.DataFrame) -> pd.DataFrame:
        """Add the model's input columns (denoised temperatures and rates) unless present."""
        if all(c in data.columns for c in ("T_tank_s", "v_tank", "T_med_s", "v_med", "t_in")):
            return data
        return prepare_inputs(data, self.tv_factor, denoiser=self.denoiser)

    # --- constants and hooks from Python ------------------------------------
    @property
    def constants(self) -> np.ndarray:
        """The constants vector c: packed ValveParams, then the options, then extra_constants()."""
        return np.concatenate([self.valve.to_array(), [self.clip_width_mm, self.sign_eps], self.extra_constants()])

    def extra_constants(self) -> np.ndarray:
        """Constants appended after the base ones (override to add options for the hooks)."""
        return np.zeros(0)

    def compiled_constants(self) -> np.ndarray:
        return self.constants

    def demanded_opening(self, t: float, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> float:
        cf = self.compiled()
        pp, c = _f(p), self.constants
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            return float(_demand(float(t), _f(x), _f(u), pp, c, cf.ctx))

    def initial_state(self, p: np.ndarray, y0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """F_h = 0 +- F_hmax (the first opening measured settles it); extra states from
        :meth:`extra_initial_state`."""
        n = self.n_states
        x0 = np.zeros(n)
        P0 = np.zeros((n, n))
        P0[X_F, X_F] = p[P_F_HMAX] ** 2
        if n > N_BASE_STATES:
            m, var = self.extra_initial_state(p, y0, u0)
            x0[N_BASE_STATES:] = m
            P0[N_BASE_STATES:, N_BASE_STATES:] = np.diag(var)
        return x0, P0

    def extra_initial_state(self, p: np.ndarray, y0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variances of the appended states at the first sample (override when adding states)."""
        k = self.n_states - N_BASE_STATES
        return np.zeros(k), np.ones(k)

    def compiled(self) -> CompiledFunctions:
        """The model functions with this class's hooks (compiled once per machine, numba cache).
        They take ``pc = concatenate([p, constants])`` and ``ctx`` (the hooks)."""
        cls = type(self)
        ctx = (cls.gas_temperature_hook, cls.gas_rate_hook, cls.set_pressure_hook, cls.opening_hook,
               cls.extra_drift_hook, cls.extra_diffusion_hook, len(self.constants))
        return CompiledFunctions(valve_drift, valve_drift_jacobian, valve_diffusion, valve_observation,
                                 valve_observation_jacobian, valve_obs_variance, ctx)

    @property
    def is_base(self) -> bool:
        """True when the class keeps the base hooks and states (the fast kernel applies)."""
        cls = type(self)
        return (self.n_states == N_BASE_STATES and cls.gas_temperature_hook is hook_gas_temperature
                and cls.gas_rate_hook is hook_gas_rate and cls.set_pressure_hook is hook_set_pressure
                and cls.opening_hook is hook_opening)

    def fast_filter(self, p: np.ndarray, arr: Any) -> Any | None:
        """The allocation-free EKF of the base model (exact Dahl step per interval), or None
        for a subclass that changes the hooks or adds states (then the generic kernel runs)."""
        if not self.is_base:
            return None

        return fast_valve_filter(p, self.constants, arr)

    # --- conveniences -------------------------------------------------------
    def valve_params(self, values: dict[str, float]) -> ValveParams:
        """ValveParams with the fitted sigma, F_hmax and p_bset."""
        keep = {k: float(values[k]) for k in ("sigma", "F_hmax", "p_bset") if k in values}
        return self.valve.replace(**keep)


def _f(a: Any) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def base_valve_model(valve: ValveParams | None = None, **options: Any) -> ValveModel:
    """The base valve model of docs/reference.md, section 1 (see :class:`ValveModel` for the options)."""
    return ValveModel(valve, **options)


__all__ = [
    "ValveModel",
    "base_valve_model",
    "prepare_inputs",
    "denoise_temperature",
    "DENOISERS",
    "tv_denoise",
    "relaxed_tv",
    "noise_sd",
    "hook_gas_temperature",
    "hook_gas_rate",
    "hook_set_pressure",
    "hook_opening",
    "hook_dahl",
    "hook_extra_drift",
    "hook_extra_diffusion",
    "smooth_sign",
    "clip_weight",
    "N_BASE_PARAMS",
    "N_BASE_STATES",
    "N_BASE_CONSTANTS",
    "P_SIGMA",
    "P_F_HMAX",
    "P_P_BSET",
    "P_S_F",
    "P_S_X",
    "X_F",
    "U_T",
    "U_V",
    "U_T_MED",
    "U_V_MED",
    "U_DP",
    "U_PS",
    "U_TIME",
    "tank_temperature",
    "medium_temperature",
    "C_CLIP_W",
    "C_SIGN_EPS",
]
