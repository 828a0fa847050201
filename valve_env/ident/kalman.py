"""Continuous-discrete Kalman filters and the likelihood (prediction-error decomposition).

* :func:`ekf_python`: the continuous-discrete extended Kalman filter for any
  :class:`~valve_env.ident.sde.SDEModel` (plain Python, slow but generic).
* :func:`ekf_compiled`: the same algorithm in a numba kernel that calls the
  model's compiled functions (:meth:`SDEModel.compiled`).
* :func:`lkf`: the linear Kalman filter with exact discretisation (matrix
  exponential, Van Loan) for models with ``linear = True``.
* :func:`rts_smooth`: Rauch-Tung-Striebel smoothing of a filter pass.
* :func:`ou_loglik`: the scalar filter of an Ornstein-Uhlenbeck error plus white noise on a residual
  (the output-error likelihood's noise model), compiled; its time step :func:`ou_predict` and its
  measurement step with a second state observed with the OU error, :func:`ou_innovation` and
  :func:`ou_update` (the valve's stick-slip filter is these steps plus its stem's logic).

Conventions (those of ctsmTMB, checked against its stored numbers, see
tests/data/ctsmtmb_ornstein/SOURCE.md): the data update at t_0 comes before
any time update; the covariance update is in Joseph form; per observation time
``nll += 0.5 log det S + 0.5 e' S^-1 e + (m/2) log 2 pi`` over the ``m``
outputs present (NaN = missing); the EKF time update is ``n_sub`` classical
RK4 steps per sample interval on the mean ODE ``dx/dt = f`` jointly with
``dP/dt = A P + P A' + G G'`` (A the drift Jacobian at each stage). Zero-order
hold keeps the input at u_i over (t_i, t_i+1]; first-order hold interpolates
linearly to u_i+1. Sampling may be uneven.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numba as nb
import numpy as np
import pandas as pd
import scipy.linalg
from numba.core.errors import NumbaExperimentalFeatureWarning

from valve_env.ident.sde import SDEModel, check_names

LOG2PI = float(np.log(2.0 * np.pi))

# the model functions reach the kernel as first-class function arguments (numba calls that experimental)
warnings.filterwarnings("ignore", category=NumbaExperimentalFeatureWarning)


@dataclass
class FilterResult:
    """A filter pass. Arrays indexed by sample k (N samples):

    ``x_pred``/``P_pred`` one-step predictions of the state (at k = 0 the
    initial state), ``x_filt``/``P_filt`` after the data update, ``y_pred``
    the predicted outputs, ``S`` their covariance, ``innov`` the prediction
    errors (NaN where missing), ``Phi`` the state-transition matrix of the
    linearisation from k-1 to k (identity at k = 0) for smoothing, ``nll``
    the negative log-likelihood."""

    nll: float
    x_pred: np.ndarray
    P_pred: np.ndarray
    x_filt: np.ndarray
    P_filt: np.ndarray
    y_pred: np.ndarray
    S: np.ndarray
    innov: np.ndarray
    Phi: np.ndarray


@dataclass
class Arrays:
    """Data as arrays: times (N,), inputs (N, n_u), outputs (N, n_y) with NaN = missing."""

    t: np.ndarray
    U: np.ndarray
    Y: np.ndarray


def to_arrays(model: SDEModel, data: pd.DataFrame, time: str = "time_s") -> Arrays:
    """Pick the model's inputs and outputs from a DataFrame (time column ``time`` or ``t``)."""
    data = model.prepare(data)
    if time not in data.columns:
        if "t" in data.columns:
            time = "t"
        else:
            raise KeyError(f"{model.name}: the data have no time column {time!r}")
    check_names(model, list(data.columns))
    # own, writable C copies: pandas may hand out read-only views, and numba compiles its kernels once per
    # read-only flag, so a mix would compile each twice
    t = np.array(data[time].to_numpy(dtype=float), order="C")
    U = np.array(data[list(model.inputs)].to_numpy(dtype=float).reshape(len(t), len(model.inputs)), order="C")
    Y = np.array(data[list(model.outputs)].to_numpy(dtype=float).reshape(len(t), len(model.outputs)), order="C")
    if len(t) < 2 or np.any(np.diff(t) <= 0):
        raise ValueError(f"{model.name}: time must be strictly increasing with at least 2 samples")
    if not np.all(np.isfinite(U)):
        raise ValueError(f"{model.name}: the inputs contain NaN or infinite values")
    return Arrays(t, U, Y)


# =========================================================================== generic Python EKF
def _joint_rhs(model: SDEModel, t: float, x: np.ndarray, P: np.ndarray, Phi: np.ndarray, u: np.ndarray,
               p: np.ndarray, AG: tuple[np.ndarray, np.ndarray] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    f = np.asarray(model.drift(t, x, u, p), dtype=float)
    if AG is None:
        A = np.asarray(model.drift_jacobian(t, x, u, p), dtype=float)
        G = np.asarray(model.diffusion(t, x, u, p), dtype=float).reshape(len(x), -1)
    else:
        A, G = AG
    return f, A @ P + P @ A.T + G @ G.T, A @ Phi, (A, G)


def _time_update_py(model: SDEModel, t0: float, t1: float, x: np.ndarray, P: np.ndarray, u0: np.ndarray,
                    u1: np.ndarray, p: np.ndarray, n_sub: int, foh: bool, each: bool = True
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h = (t1 - t0) / n_sub
    Phi = np.eye(len(x))
    du = (u1 - u0) if foh else np.zeros_like(u0)
    T = t1 - t0
    for j in range(n_sub):
        s = t0 + j * h
        ua = u0 + du * (j * h / T)
        um = u0 + du * ((j + 0.5) * h / T)
        ub = u0 + du * ((j + 1.0) * h / T)
        k1 = _joint_rhs(model, s, x, P, Phi, ua, p)
        ag = None if each else k1[3]
        k2 = _joint_rhs(model, s + h / 2, x + h / 2 * k1[0], P + h / 2 * k1[1], Phi + h / 2 * k1[2], um, p, ag)
        k3 = _joint_rhs(model, s + h / 2, x + h / 2 * k2[0], P + h / 2 * k2[1], Phi + h / 2 * k2[2], um, p, ag)
        k4 = _joint_rhs(model, s + h, x + h * k3[0], P + h * k3[1], Phi + h * k3[2], ub, p, ag)
        x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        P = P + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        Phi = Phi + h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
    P = 0.5 * (P + P.T)
    return x, P, Phi


def ekf_python(model: SDEModel, p: np.ndarray, arr: Arrays, *, n_sub: int = 1, foh: bool = False,
               jac_each_stage: bool | None = None) -> FilterResult:
    """Continuous-discrete EKF through the model's Python methods (the algorithm of
    :func:`ekf_compiled`)."""
    if jac_each_stage is None:
        jac_each_stage = bool(getattr(model, "jacobian_each_stage", True))
    t, U, Y = arr.t, arr.U, arr.Y
    N, ny, nx = len(t), Y.shape[1], model.n_states
    res = _alloc(N, nx, ny)
    x, P = model.initial_state(p, Y[0], U[0])
    x = np.asarray(x, dtype=float).copy()
    P = np.asarray(P, dtype=float).copy()
    nll = 0.0
    for k in range(N):
        Phi = np.eye(nx)
        if k > 0:
            x, P, Phi = _time_update_py(model, t[k - 1], t[k], x, P, U[k - 1], U[k], p, n_sub, foh, jac_each_stage)
        res.x_pred[k], res.P_pred[k], res.Phi[k] = x, P, Phi
        u = U[k]
        yh = np.asarray(model.observation(t[k], x, u, p), dtype=float)
        H = np.asarray(model.observation_jacobian(t[k], x, u, p), dtype=float).reshape(ny, nx)
        R = np.asarray(model.obs_variance(t[k], x, u, p), dtype=float).reshape(ny, ny)
        S = H @ P @ H.T + R
        res.y_pred[k], res.S[k] = yh, S
        obs = np.isfinite(Y[k])
        if obs.any():
            e = Y[k, obs] - yh[obs]
            Hs, Rs, Ss = H[obs], R[np.ix_(obs, obs)], S[np.ix_(obs, obs)]
            try:
                L = np.linalg.cholesky(Ss)
            except np.linalg.LinAlgError:
                res.nll = float("inf")
                return res
            Sinv_e = scipy.linalg.cho_solve((L, True), e)
            nll += float(np.sum(np.log(np.diag(L))) + 0.5 * e @ Sinv_e + 0.5 * obs.sum() * LOG2PI)
            K = scipy.linalg.cho_solve((L, True), Hs @ P).T
            x = x + K @ e
            IKH = np.eye(nx) - K @ Hs
            P = IKH @ P @ IKH.T + K @ Rs @ K.T
            res.innov[k, obs] = e
        res.x_filt[k], res.P_filt[k] = x, P
    res.nll = nll
    return res


def _alloc(N: int, nx: int, ny: int) -> FilterResult:
    return FilterResult(
        nll=0.0,
        x_pred=np.zeros((N, nx)), P_pred=np.zeros((N, nx, nx)),
        x_filt=np.zeros((N, nx)), P_filt=np.zeros((N, nx, nx)),
        y_pred=np.zeros((N, ny)), S=np.zeros((N, ny, ny)),
        innov=np.full((N, ny), np.nan), Phi=np.zeros((N, nx, nx)),
    )


# =========================================================================== compiled EKF
@nb.njit(cache=True)
def _sym_rhs(A: np.ndarray, P: np.ndarray, G: np.ndarray, out: np.ndarray) -> None:
    """out = A P + P A' + G G' (explicit loops: small matrices)."""
    n = A.shape[0]
    q = G.shape[1]
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(n):
                s += A[i, k] * P[k, j] + P[i, k] * A[j, k]
            for k in range(q):
                s += G[i, k] * G[j, k]
            out[i, j] = s
            out[j, i] = s


@nb.njit(cache=True)
def _matmul(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """out = A B for square matrices (explicit loops: small matrices)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += A[i, k] * B[k, j]
            out[i, j] = s


@nb.njit(cache=True)
def _update(x: np.ndarray, P: np.ndarray, yh: np.ndarray, H: np.ndarray, R: np.ndarray, y: np.ndarray,
            S_out: np.ndarray, innov: np.ndarray) -> float:
    """Data update in place (Joseph form) over the outputs present in y; returns the nll term.
    Explicit loops: the matrices are small, and BLAS/LAPACK calls cost more than the arithmetic."""
    nx = x.shape[0]
    ny = y.shape[0]
    PHt = np.zeros((nx, ny))
    for i in range(nx):
        for a in range(ny):
            s = 0.0
            for k in range(nx):
                s += P[i, k] * H[a, k]
            PHt[i, a] = s
    for a in range(ny):
        for b in range(ny):
            s = R[a, b]
            for k in range(nx):
                s += H[a, k] * PHt[k, b]
            S_out[a, b] = s
    m = 0
    idx = np.empty(ny, dtype=np.int64)
    for a in range(ny):
        if np.isfinite(y[a]):
            idx[m] = a
            m += 1
    if m == 0:
        return 0.0
    # Cholesky of the observed block
    L = np.zeros((m, m))
    for a in range(m):
        for b in range(a + 1):
            s = S_out[idx[a], idx[b]]
            for k in range(b):
                s -= L[a, k] * L[b, k]
            if a == b:
                if s <= 0.0:
                    return np.inf
                L[a, a] = np.sqrt(s)
            else:
                L[a, b] = s / L[b, b]
    e = np.empty(m)
    for a in range(m):
        e[a] = y[idx[a]] - yh[idx[a]]
        innov[idx[a]] = e[a]
    # Sinv = L^-T L^-1 via the inverse of L
    Li = np.zeros((m, m))
    for a in range(m):
        Li[a, a] = 1.0 / L[a, a]
        for b in range(a):
            s = 0.0
            for k in range(b, a):
                s -= L[a, k] * Li[k, b]
            Li[a, b] = s / L[a, a]
    Sinv = np.zeros((m, m))
    for a in range(m):
        for b in range(m):
            s = 0.0
            for k in range(max(a, b), m):
                s += Li[k, a] * Li[k, b]
            Sinv[a, b] = s
    ld = 0.0
    quad = 0.0
    for a in range(m):
        ld += np.log(L[a, a])
        z = 0.0
        for b in range(a + 1):
            z += Li[a, b] * e[b]
        quad += z * z
    # gain K = P H_s' S^-1
    K = np.zeros((nx, m))
    for i in range(nx):
        for a in range(m):
            s = 0.0
            for b in range(m):
                s += PHt[i, idx[b]] * Sinv[b, a]
            K[i, a] = s
    for i in range(nx):
        s = 0.0
        for a in range(m):
            s += K[i, a] * e[a]
        x[i] += s
    # Joseph form: P = (I - K H) P (I - K H)' + K R K'
    IKH = np.zeros((nx, nx))
    for i in range(nx):
        for j in range(nx):
            s = 1.0 if i == j else 0.0
            for a in range(m):
                s -= K[i, a] * H[idx[a], j]
            IKH[i, j] = s
    T1 = np.empty((nx, nx))
    _matmul(IKH, P, T1)
    for i in range(nx):
        for j in range(i, nx):
            s = 0.0
            for k in range(nx):
                s += T1[i, k] * IKH[j, k]
            for a in range(m):
                for b in range(m):
                    s += K[i, a] * R[idx[a], idx[b]] * K[j, b]
            P[i, j] = s
            P[j, i] = s
    return ld + 0.5 * quad + 0.5 * m * np.log(2.0 * np.pi)


@nb.njit(cache=True)
def _put_vec(dst: np.ndarray, k: int, src: np.ndarray) -> None:
    """``dst[k] = src`` for a 1-d ``src``, element by element: a slice assignment compiles numba's shape-mismatch
    message (string formatting, 4-6 s of compile per shape) into the kernel, and the EKF kernel, which is not cached,
    compiles in every process."""
    for i in range(src.shape[0]):
        dst[k, i] = src[i]


@nb.njit(cache=True)
def _put_mat(dst: np.ndarray, k: int, src: np.ndarray) -> None:
    """``dst[k] = src`` for a 2-d ``src``, element by element (:func:`_put_vec`)."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[k, i, j] = src[i, j]


@nb.njit  # not cached: dispatcher arguments break numba's cache reload (see valve_model)
def _ekf_kernel(f, jf, g, h, jh, r, ctx, t, U, Y, pc, x0, P0, n_sub, foh, jac_each_stage, x_pred,  # noqa: ANN001
                P_pred, x_filt, P_filt, y_pred, S_out, innov, Phi_out):
    N = t.shape[0]
    nx = x0.shape[0]
    x = x0.copy()
    P = P0.copy()
    nll = 0.0
    kP = np.empty((4, nx, nx))
    kF = np.empty((4, nx, nx))
    kx = np.empty((4, nx))
    Pt = np.empty((nx, nx))
    Ft = np.empty((nx, nx))
    xt = np.empty(nx)
    Phi = np.eye(nx)
    nu = U.shape[1]
    u = np.empty(nu)
    for k in range(N):
        Phi[:, :] = 0.0
        for i in range(nx):
            Phi[i, i] = 1.0
        if k > 0:
            T = t[k] - t[k - 1]
            hh = T / n_sub
            for j in range(n_sub):
                s0 = t[k - 1] + j * hh
                for st in range(4):
                    c = 0.0 if st == 0 else (0.5 if st < 3 else 1.0)
                    for i in range(nx):
                        if st == 0:
                            xt[i] = x[i]
                        else:
                            xt[i] = x[i] + c * hh * kx[st - 1, i]
                        for jj in range(nx):
                            if st == 0:
                                Pt[i, jj] = P[i, jj]
                                Ft[i, jj] = Phi[i, jj]
                            else:
                                Pt[i, jj] = P[i, jj] + c * hh * kP[st - 1, i, jj]
                                Ft[i, jj] = Phi[i, jj] + c * hh * kF[st - 1, i, jj]
                    frac = (j * hh + c * hh) / T
                    for i in range(nu):
                        u[i] = U[k - 1, i] + ((U[k, i] - U[k - 1, i]) * frac if foh else 0.0)
                    fx = f(s0 + c * hh, xt, u, pc, ctx)
                    for i in range(nx):
                        kx[st, i] = fx[i]
                    if st == 0 or jac_each_stage:
                        A = jf(s0 + c * hh, xt, u, pc, ctx)
                        G = g(s0 + c * hh, xt, u, pc, ctx)
                    _sym_rhs(A, Pt, G, kP[st])
                    _matmul(A, Ft, kF[st])
                for i in range(nx):
                    x[i] += hh / 6.0 * (kx[0, i] + 2.0 * kx[1, i] + 2.0 * kx[2, i] + kx[3, i])
                    for jj in range(nx):
                        P[i, jj] += hh / 6.0 * (kP[0, i, jj] + 2.0 * kP[1, i, jj] + 2.0 * kP[2, i, jj] + kP[3, i, jj])
                        Phi[i, jj] += hh / 6.0 * (kF[0, i, jj] + 2.0 * kF[1, i, jj] + 2.0 * kF[2, i, jj]
                                                  + kF[3, i, jj])
            for i in range(nx):
                for jj in range(i + 1, nx):
                    a = 0.5 * (P[i, jj] + P[jj, i])
                    P[i, jj] = a
                    P[jj, i] = a
        _put_vec(x_pred, k, x)
        _put_mat(P_pred, k, P)
        _put_mat(Phi_out, k, Phi)
        uk = U[k]
        yh = h(t[k], x, uk, pc, ctx)
        H = jh(t[k], x, uk, pc, ctx)
        R = r(t[k], x, uk, pc, ctx)
        _put_vec(y_pred, k, yh)
        nll += _update(x, P, yh, H, R, Y[k], S_out[k], innov[k])
        if not np.isfinite(nll):
            return np.inf
        _put_vec(x_filt, k, x)
        _put_mat(P_filt, k, P)
    return nll


def ekf_compiled(model: SDEModel, p: np.ndarray, arr: Arrays, *, n_sub: int = 1, foh: bool = False,
                 jac_each_stage: bool | None = None) -> FilterResult:
    """The EKF in the numba kernel, with the model's compiled functions. ``jac_each_stage``
    (default: the model's ``jacobian_each_stage``) evaluates the drift Jacobian and the diffusion
    at every RK4 stage (ctsmTMB's convention) or once per RK4 step (faster, the same for
    linear models)."""
    if jac_each_stage is None:
        jac_each_stage = bool(getattr(model, "jacobian_each_stage", True))
    cf = model.compiled()
    if cf is None:
        raise ValueError(f"{model.name}: the model has no compiled functions; use ekf_python")
    N, ny, nx = len(arr.t), arr.Y.shape[1], model.n_states
    x0, P0 = model.initial_state(p, arr.Y[0], arr.U[0])
    pc = np.ascontiguousarray(np.concatenate([np.asarray(p, dtype=float), model.compiled_constants()]))
    res = _alloc(N, nx, ny)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
        res.nll = float(_ekf_kernel(cf.drift, cf.drift_jacobian, cf.diffusion, cf.observation, cf.observation_jacobian,
                                    cf.obs_variance, cf.ctx, arr.t, arr.U, arr.Y, pc,
                                    np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(P0, dtype=float),
                                    int(n_sub), bool(foh), bool(jac_each_stage), res.x_pred, res.P_pred, res.x_filt,
                                    res.P_filt, res.y_pred,
                                    res.S, res.innov, res.Phi))
    return res


# =========================================================================== linear Kalman filter
def _affine_parts(model: SDEModel, t: float, p: np.ndarray, nx: int, nu: int) -> tuple[np.ndarray, np.ndarray]:
    """A = df/dx and B = [f(0, 0), df/du] of an affine drift (B's first column the constant)."""
    z = np.zeros(nx)
    u0 = np.zeros(nu)
    A = np.asarray(model.drift_jacobian(t, z, u0, p), dtype=float)
    c = np.asarray(model.drift(t, z, u0, p), dtype=float)
    B = np.empty((nx, nu + 1))
    B[:, 0] = c
    for j in range(nu):
        e = np.zeros(nu)
        e[j] = 1.0
        B[:, j + 1] = np.asarray(model.drift(t, z, e, p), dtype=float) - c
    return A, B


def _discretise_lin(A: np.ndarray, B: np.ndarray, GG: np.ndarray, dt: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation over dt: x+ = Phi x + Gam0 [1, u0] + Gam1 [0, u1 - u0] (the ramp term of
    first-order hold) and the noise covariance Q (Van Loan)."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    E = scipy.linalg.expm(M * dt)
    Phi = E[:n, :n]
    Gam0 = E[:n, n:n + m]
    # first-order hold: u(s) = u0 + (u1 - u0) s/dt; the contribution of (u1 - u0) is
    # int_0^dt e^{A(dt-s)} B s/dt ds, from the augmented system [[A, 0, B/dt], [0, 0, 0], [0, I, 0]]
    Mf = np.zeros((n + 2 * m, n + 2 * m))
    Mf[:n, :n] = A
    Mf[:n, n + m:] = B / dt
    Mf[n + m:, n:n + m] = np.eye(m)
    Ef = scipy.linalg.expm(Mf * dt)
    Gam1 = Ef[:n, n:n + m]
    V = np.zeros((2 * n, 2 * n))
    V[:n, :n] = -A
    V[:n, n:] = GG
    V[n:, n:] = A.T
    F = scipy.linalg.expm(V * dt)
    Q = F[n:, n:].T @ F[:n, n:]
    return Phi, Gam0, Gam1, 0.5 * (Q + Q.T)


@nb.njit(cache=True)
def _lkf_kernel(Phis: np.ndarray, G0s: np.ndarray, G1s: np.ndarray, Qs: np.ndarray, which: np.ndarray,
                U: np.ndarray, C: np.ndarray, D: np.ndarray, R: np.ndarray, Y: np.ndarray, x0: np.ndarray,
                P0: np.ndarray, foh: bool, x_pred: np.ndarray, P_pred: np.ndarray, x_filt: np.ndarray,
                P_filt: np.ndarray, y_pred: np.ndarray, S_out: np.ndarray, innov: np.ndarray,
                Phi_out: np.ndarray) -> float:  # pragma: no cover - compiled
    N = Y.shape[0]
    nx = x0.shape[0]
    ny = Y.shape[1]
    nu = U.shape[1]
    x = x0.copy()
    P = P0.copy()
    nll = 0.0
    w = np.empty(nu + 1)
    for k in range(N):
        if k > 0:
            j = which[k]
            Phi = Phis[j]
            w[0] = 1.0
            for i in range(nu):
                w[i + 1] = U[k - 1, i]
            xn = Phi @ x + G0s[j] @ w
            if foh:
                w[0] = 0.0
                for i in range(nu):
                    w[i + 1] = U[k, i] - U[k - 1, i]
                xn = xn + G1s[j] @ w
            x = xn
            P = Phi @ P @ Phi.T + Qs[j]
            P = 0.5 * (P + P.T)
            Phi_out[k] = Phi
        else:
            Phi_out[k] = np.eye(nx)
        x_pred[k] = x
        P_pred[k] = P
        yh = C @ x + D[k]
        for i in range(ny):
            y_pred[k, i] = yh[i]
        nll += _update(x, P, yh, C, R, Y[k], S_out[k], innov[k])
        if not np.isfinite(nll):
            return np.inf
        x_filt[k] = x
        P_filt[k] = P
    return nll


def lkf(model: SDEModel, p: np.ndarray, arr: Arrays, *, foh: bool = False) -> FilterResult:
    """Linear Kalman filter with exact discretisation (for ``model.linear``).

    The drift's matrices are read from the model at the first sample: A = df/dx, the
    constant f(t, 0, 0, p) and B = df/du, and G; the observation h(x) = C x + d(u) with
    C = dh/dx and R read at the first sample and d(u) = h(t, 0, u, p) at every sample
    (so A, B, G, C and R must not depend on time or inputs). The matrix exponentials are
    computed once per distinct sampling interval; the recursion runs in numba."""
    if not model.linear:
        raise ValueError(f"{model.name}: the linear Kalman filter needs a model with linear = True")
    t, U, Y = arr.t, arr.U, arr.Y
    N, ny, nx, nu = len(t), Y.shape[1], model.n_states, U.shape[1]
    z = np.zeros(nx)
    res = _alloc(N, nx, ny)
    x0, P0 = model.initial_state(p, Y[0], U[0])
    A, B = _affine_parts(model, float(t[0]), p, nx, nu)
    G = np.asarray(model.diffusion(float(t[0]), z, U[0], p), dtype=float).reshape(nx, -1)
    GG = G @ G.T
    dts = np.round(np.diff(t), 12)
    uniq, inv = np.unique(dts, return_inverse=True) if N > 1 else (np.zeros(0), np.zeros(0, dtype=int))
    parts = [_discretise_lin(A, B, GG, float(dt)) for dt in uniq]
    m = max(len(parts), 1)
    Phis = np.zeros((m, nx, nx))
    G0s = np.zeros((m, nx, nu + 1))
    G1s = np.zeros((m, nx, nu + 1))
    Qs = np.zeros((m, nx, nx))
    for j, (Ph, g0, g1, Q) in enumerate(parts):
        Phis[j], G0s[j], G1s[j], Qs[j] = Ph, g0, g1, Q
    which = np.zeros(N, dtype=np.int64)
    which[1:] = inv
    C = np.ascontiguousarray(np.asarray(model.observation_jacobian(float(t[0]), z, U[0], p), dtype=float)
                             .reshape(ny, nx))
    R = np.ascontiguousarray(np.asarray(model.obs_variance(float(t[0]), z, U[0], p), dtype=float).reshape(ny, ny))
    D = np.array([np.asarray(model.observation(float(t[k]), z, U[k], p), dtype=float) for k in range(N)])
    res.nll = float(_lkf_kernel(Phis, G0s, G1s, Qs, which, U, C, np.ascontiguousarray(D.reshape(N, ny)), R, Y,
                                np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(P0, dtype=float),
                                bool(foh), res.x_pred, res.P_pred, res.x_filt, res.P_filt, res.y_pred, res.S,
                                res.innov, res.Phi))
    return res


# =========================================================================== smoother and dispatch
def rts_smooth(res: FilterResult) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel smoother on a filter pass (the linearised transition ``Phi``)."""
    N = res.x_filt.shape[0]
    xs = res.x_filt.copy()
    Ps = res.P_filt.copy()
    for k in range(N - 2, -1, -1):
        Pp = res.P_pred[k + 1]
        C = np.linalg.solve(Pp.T, (res.P_filt[k] @ res.Phi[k + 1].T).T).T
        xs[k] = res.x_filt[k] + C @ (xs[k + 1] - res.x_pred[k + 1])
        Ps[k] = res.P_filt[k] + C @ (Ps[k + 1] - Pp) @ C.T
    return xs, Ps


METHODS = ("ekf", "lkf")


def run_filter(model: SDEModel, p: np.ndarray, arr: Arrays, *, method: str = "ekf", n_sub: int = 1,
               foh: bool = False, compiled: bool | None = None, fast: bool | None = None) -> FilterResult:
    """Run the filter: ``method`` "ekf" or "lkf" (linear models). For "ekf" the model's
    specialised kernel (:meth:`SDEModel.fast_filter`) runs unless ``fast=False``; otherwise
    the compiled RK4 kernel when the model has compiled functions, unless ``compiled=False``
    (then the Python EKF)."""
    p = np.asarray(p, dtype=float)
    if method == "lkf":
        return lkf(model, p, arr, foh=foh)
    if method != "ekf":
        raise ValueError(f"unknown filter method {method!r}; use one of {METHODS}")
    if fast is not False and compiled is not False:
        r = model.fast_filter(p, arr)
        if r is not None:
            return r
        if fast:
            raise ValueError(f"{model.name}: the model has no specialised filter")
    if compiled is None:
        compiled = model.compiled() is not None
    if compiled:
        return ekf_compiled(model, p, arr, n_sub=n_sub, foh=foh)
    return ekf_python(model, p, arr, n_sub=n_sub, foh=foh)


@nb.njit(cache=True)
def ou_predict(dt: float, tau: float, var: float, m: float, P: float, dt_last: float = -1.0,
               phi_last: float = 0.0) -> tuple[float, float, float]:
    """The time update over ``dt`` of an Ornstein-Uhlenbeck state (time constant ``tau``, stationary
    variance ``var``) with mean ``m`` and variance ``P``: (phi = exp(-dt / tau), the mean, the variance).
    ``phi_last``: the phi of an update over ``dt_last``, taken as it is where ``dt`` is the same (a regularly
    sampled record computes its exponential once)."""
    phi = phi_last if dt == dt_last else math.exp(-dt / tau)
    return phi, phi * m, phi * phi * P + var * (1.0 - phi * phi)


@nb.njit(cache=True)
def ou_innovation(y: float, m: float, P: float, vw: float, s: float = 0.0, Pes: float = 0.0,
                  Pss: float = 0.0) -> tuple[float, float, float]:
    """The one-step prediction of a measurement ``y = s + e + w`` (``e`` the OU state, mean ``m``, variance
    ``P``; ``w`` white of variance ``vw``; ``s`` a second state with variance ``Pss`` and covariance ``Pes``
    with ``e``, none for the scalar filter): (prediction error, its variance, the log-likelihood term)."""
    S = P + 2.0 * Pes + Pss + vw
    nu = y - s - m
    return nu, S, -0.5 * (LOG2PI + math.log(S) + nu * nu / S)


@nb.njit(cache=True)
def ou_update(nu: float, S: float, m: float, P: float, s: float = 0.0, Pes: float = 0.0,
              Pss: float = 0.0) -> tuple[float, float, float, float, float]:
    """The measurement update after :func:`ou_innovation`: (m, P, s, Pes, Pss)."""
    ke = (P + Pes) / S
    ks = (Pes + Pss) / S
    return m + ke * nu, P - ke * (P + Pes), s + ks * nu, Pes - ke * (Pes + Pss), Pss - ks * (Pes + Pss)


@nb.njit(cache=True)
def ou_loglik(t: np.ndarray, r: np.ndarray, s_w: float, s_e: float, tau_e: float,
              mask: np.ndarray, w_scale: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray]:
    """The scalar OU filter: log-likelihood of residuals r = e + w (e an Ornstein-Uhlenbeck process of
    stationary sd ``s_e`` and time constant ``tau_e``, w white of sd ``s_w``, or ``s_w w_scale[k]`` at sample k)
    over samples where ``mask``.

    The filter runs over every sample (the OU state carries across); only masked samples enter the
    likelihood and are used as observations. Returns (loglik, one-step prediction errors, their variance)."""
    n = t.shape[0]
    ve = s_e * s_e
    vw = s_w * s_w
    m = 0.0
    P = ve
    ll = 0.0
    innov = np.empty(n)
    Sout = np.empty(n)
    dt = -1.0
    phi = 0.0
    for k in range(n):
        if k > 0:
            h = t[k] - t[k - 1]
            phi, m, P = ou_predict(h, tau_e, ve, m, P, dt, phi)
            dt = h
        innov[k], Sout[k], lk = ou_innovation(r[k], m, P, vw if w_scale is None else vw * w_scale[k] * w_scale[k])
        if mask[k]:
            ll += lk
            m, P, _, _, _ = ou_update(innov[k], Sout[k], m, P)
    return ll, innov, Sout
