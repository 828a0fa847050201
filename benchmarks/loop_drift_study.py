"""Does a drifting valve input raise the stick-slip's likelihood on the env loops? (docs/loops.md, "Loops from the
environment")

    python benchmarks/loop_drift_study.py --env-id ThermoValveStickyCirculation-v0 --seeds 0-11 --kp 5 --ti 1500

Between the recorded OP (the valve's setting) and the stem sit the bulb
temperature and the Dahl friction force, a slowly varying disturbance of the stem's input of about a sixth of the
band. This study adds that disturbance to the loop model as a state, a random walk on the valve's input,
``u[k] = OP[k] + d[k]``, ``d[k] = d[k-1] + q eps[k]``, and evaluates the exact likelihood of the stick-slip loop
with it by a bootstrap particle filter (the stick-slip state, the drift, the delay line and the process state per
particle; the AR noise's past residuals carried per particle; systematic resampling every sample). With ``q = 0``
the filter returns the output-error fit's log-likelihood exactly (every particle the same path), so the drift's
gain is measured against the same model without it.

For each record (sticky 0.1 mm and smooth stem, ``record_env_loop``) the process is the deterministic fit's at
each (S, J, direction) tried (the two best bands of the stiction fit's profile, J/S in {0, 1}, both directions),
then refitted once on the filter's mean ancestral path (one EM-like step), and the drift's sd per sample is
profiled over ``q`` in {0.03, 0.1, 0.3} times the record's resolution (the median OP move) with the innovation sd
at 1 and 0.9 of the deterministic fit's (a drift gain below zero counts as zero: q = 0 is nested). Printed per
record: the decision's cause and LR (stiction against linear, 2 ln L), then 2 ln L over the linear valve of the
deadband (J = 0) and of the stick-slip J = S, without and with the drift; and the drift's gain for the linear
valve (a drifting input behind a linear valve).
"""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

from valve_env.loops.diagnose import diagnose
from valve_env.loops.envloop import record_env_loop
from valve_env.loops.io import LoopData
from valve_env.loops.model import ProcessFit, Settings, fit_process, resolution, valve_path
from valve_env.physics.stickslip import initial_state, stick_slip_step

sys.path.insert(0, str(Path(__file__).parent))
from env_loop_study import STICKY_MM, parse_env_args  # noqa: E402

Q_FACTORS = (0.03, 0.1, 0.3)
SIGMA_FACTORS = (1.0, 0.9)
J_FRACTIONS = (0.0, 1.0)
N_BANDS = 2


@njit(cache=True)
def drift_filter(op: np.ndarray, pv: np.ndarray, base: np.ndarray, S: float, J: float, d0: float, q: float,
                 a: float, delay: float, integ: bool, xm: float, K: float, rho1: float, rho2: float, sigma: float,
                 k0: int, n_part: int, seed: int) -> tuple:  # pragma: no cover - compiled
    """Bootstrap particle filter of the loop model (valve_env.loops.model) with a random-walk drift of sd ``q``
    per sample on the valve's input; returns (log-likelihood over samples k0.., the mean ancestral valve path)."""
    np.random.seed(seed)  # noqa: NPY002 (numba: the compiled global generator, seeded per call)
    n = op.size
    dd = int(math.floor(delay))
    f = delay - dd
    L = dd + 2
    st = np.empty((n_part, 6))
    drift = np.zeros(n_part)
    hist = np.empty((n_part, L))
    w = np.empty(n_part)
    r1 = np.zeros(n_part)
    r2 = np.zeros(n_part)
    logw = np.zeros(n_part)
    s0 = initial_state(op[0], S, J, -np.inf, np.inf, d0)
    for i in range(n_part):
        for j in range(6):
            st[i, j] = s0[j]
        hist[i, :] = s0[0]
        w[i] = 0.0 if integ else s0[0]
    X = np.empty((n, n_part))
    anc = np.empty((n, n_part), dtype=np.int64)
    idx = np.empty(n_part, dtype=np.int64)
    c = -0.5 * math.log(2.0 * math.pi * sigma * sigma)
    ll = 0.0
    for k in range(n):
        for i in range(n_part):
            if k > 0:
                drift[i] += q * np.random.standard_normal()  # noqa: NPY002
                y, up, dup, us, stuck, d = stick_slip_step(op[k] + drift[i], st[i, 0], st[i, 1], st[i, 2], st[i, 3],
                                                           st[i, 4], st[i, 5], S, J, -np.inf, np.inf)
                st[i, 0], st[i, 1], st[i, 2], st[i, 3], st[i, 4], st[i, 5] = y, up, dup, us, stuck, d
                for j in range(L - 1, 0, -1):
                    hist[i, j] = hist[i, j - 1]
                hist[i, 0] = y
                uk = hist[i, dd] if f == 0.0 else (1.0 - f) * hist[i, dd] + f * hist[i, dd + 1]
                w[i] = w[i] + uk - xm if integ else a * w[i] + (1.0 - a) * uk
            X[k, i] = st[i, 0]
            r = pv[k] - K * w[i] - base[k]
            if k >= k0:
                e = r - rho1 * r1[i] - rho2 * r2[i]
                logw[i] = c - 0.5 * e * e / (sigma * sigma)
            r2[i] = r1[i]
            r1[i] = r
        if k >= k0:
            m = logw.max()
            tot = 0.0
            for i in range(n_part):
                logw[i] = math.exp(logw[i] - m)
                tot += logw[i]
            ll += m + math.log(tot / n_part)
            u = np.random.random() / n_part  # noqa: NPY002
            j = 0
            cw = logw[0] / tot
            for i in range(n_part):  # systematic resampling
                while u > cw and j < n_part - 1:
                    j += 1
                    cw += logw[j] / tot
                idx[i] = j
                u += 1.0 / n_part
            anc[k] = idx
            st = st[idx].copy()
            hist = hist[idx].copy()
            drift = drift[idx].copy()
            w = w[idx].copy()
            r1 = r1[idx].copy()
            r2 = r2[idx].copy()
    xh = np.zeros(n)
    cur = np.arange(n_part)
    for k in range(n - 1, -1, -1):
        if k >= k0:
            cur = anc[k][cur]
        for i in range(n_part):
            xh[k] += X[k, cur[i]]
        xh[k] /= n_part
    return ll, xh


def drift_loglik(loop: LoopData, s: Settings, S: float, J: float, d0: float, pf: ProcessFit, q: float,
                 sigma_factor: float = 1.0, n_part: int = 256, seed: int = 1) -> tuple[float, np.ndarray]:
    """:func:`drift_filter` for the fitted process ``pf`` of the valve (S, J, d0)."""
    x = valve_path(loop.op, S, J, d0)
    return drift_filter(loop.op, loop.pv, pf.basis @ pf.weights, S, J, d0, q, pf.a, pf.delay, pf.integrating,
                        float(x.mean()), pf.K, pf.rho[0], pf.rho[1], math.sqrt(pf.rss / pf.n) * sigma_factor,
                        s.k0, n_part, seed)


def drift_gain(loop: LoopData, s: Settings, S: float, J: float, d0: float) -> float:
    """The largest log-likelihood gain of the drift over the deterministic valve (S, J, d0), over the ``q`` and
    innovation-sd grid, with the process of the deterministic fit and once refitted on the filter's path."""
    res = resolution(loop.op)
    pf0 = fit_process(loop.pv, valve_path(loop.op, S, J, d0), s)
    best = -math.inf
    for qf in Q_FACTORS:
        pf = pf0
        for _ in range(2):
            for sf in SIGMA_FACTORS:
                ll, xh = drift_loglik(loop, s, S, J, d0, pf, qf * res, sf)
                best = max(best, ll - pf0.loglik)
            pf = fit_process(loop.pv, xh, s)
    return best


def main(argv: list[str] | None = None) -> int:
    a, seeds = parse_env_args(__doc__.splitlines()[0], argv)
    gains: dict[float, list[float]] = {STICKY_MM: [], 0.0: []}
    for seed in seeds:
        for band in (STICKY_MM, 0.0):
            t0 = time.perf_counter()
            loop = record_env_loop(band, seed=seed, hours=a.hours, warmup_h=a.warmup_h, env_id=a.env_id, Kp=a.kp,
                                   Ti_s=a.ti, F_hmax=a.f_hmax)
            d = diagnose(loop)
            s = d.settings
            fit = d.fits["stiction"]
            bands = [p[0] for p in sorted(fit.profile, key=lambda p: -p[1])[:N_BANDS]]
            ll_lin = d.fits["linear"].loglik
            # per J / S: the best deterministic log-likelihood and the best with the drift, over bands and directions
            det = {fr: -math.inf for fr in J_FRACTIONS}
            drift = {fr: -math.inf for fr in J_FRACTIONS}
            for S in bands:
                for fr in J_FRACTIONS:
                    for d0 in (1.0, -1.0):
                        ll0 = fit_process(loop.pv, valve_path(loop.op, S, fr * S, d0), s).loglik
                        det[fr] = max(det[fr], ll0)
                        drift[fr] = max(drift[fr], ll0 + max(drift_gain(loop, s, S, fr * S, d0), 0.0))
            g_lin = drift_gain(loop, s, 0.0, 0.0, 1.0)
            lr = 2.0 * (fit.loglik - ll_lin)
            g = max(drift.values()) - max(det.values())
            gains[band].append(g)
            print(f"seed {seed} band {band:g} mm: {d.cause}, LR {lr:.1f}; 2 ln L over linear, J=0 / J=S: "
                  f"deterministic {2 * (det[0.0] - ll_lin):.1f} / {2 * (det[1.0] - ll_lin):.1f}, "
                  f"with drift {2 * (drift[0.0] - ll_lin):.1f} / {2 * (drift[1.0] - ll_lin):.1f}; "
                  f"linear valve's drift gain {g_lin:+.2f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    for band, v in gains.items():
        print(f"band {band:g} mm: drift gain over the deterministic stick-slip, max {max(v):+.2f}, "
              f"records with a gain above 1: {sum(x > 1.0 for x in v)}/{len(v)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
