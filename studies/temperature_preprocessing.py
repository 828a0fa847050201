"""Temperature pre-processing compared: TV denoising against IRW-RTS smoothing (docs/estimation.md,
"Temperature pre-processing").

The two ways the project turns a noisy temperature channel into the valve's driver
(:mod:`valve_env.valveid.temperature`): the relaxed total-variation denoising the EKF's valve
model uses (:func:`~valve_env.valveid.temperature.denoise_temperature`) and the robust
integrated-random-walk Rauch-Tung-Striebel smoother the output-error likelihood uses
(:func:`~valve_env.valveid.temperature.smooth_temperature`). Generated runs
(:func:`valve_env.experiment.simulate_experiment`, the base valve) carry the true temperature and
the true opening; per method and noise level this prints

* ``T rms mK``: RMS error of the pre-processed tank temperature against the true one;
* ``rate rms mK/h``: RMS error of its rate over each sample interval against the true rate;
* ``reversals``: sign changes of that rate per hour (the true temperature's in brackets): each
  spurious reversal resets the Dahl friction;
* ``x rms um``: RMS error of the opening simulated by the output-error engine with the *true*
  parameters from the pre-processed temperatures against the true opening (the driver's error as
  the valve sees it);
* ``s/noise``: each method's estimate of the tank channel's noise sd over the true one (TV's is
  :func:`~valve_env.valveid.temperature.noise_sd`, which sets its penalty; the smoother's is its
  fitted measurement noise, ``RunData.s_T``, which the diagnosis uses);
* with ``--fit``: the |error| (%) of sigma, F_hmax and p_bset fitted from each by output error
  (:class:`valve_env.valveid.fitting.Model`) and by the EKF
  (:class:`valve_env.ident.mle.MLEstimator`, ``ekf_*``).

    python studies/temperature_preprocessing.py --seeds 900 901 902 903 904 905
    python studies/temperature_preprocessing.py --noise 0.01 --fit
    python studies/temperature_preprocessing.py --survey 20261231 --cases 30

``--survey SEED`` is the collapse survey instead (docs/estimation.md, "Temperature
pre-processing"): the smoother on both temperature channels of the diagnosis study's randomised runs
(:func:`valve_env.experiment.random_cases`, ``--cases`` of them: 5-30 s sampling, 12-30 h, noise
0-0.01 K); per channel its noise sd over the true one (the count below 0.1, a collapse, and the
quantiles), the RMS errors of the level and of the rate over each interval against the truth, and
the CPU time.

Nothing is tuned here: both methods run with their defaults; the seeds 900-905 were not used while
building either method (their factors were set on the project's earlier runs).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import pandas as pd

from valve_env.experiment import random_cases, simulate_case, simulate_experiment
from valve_env.ident.mle import MLEstimator
from valve_env.valveid.diagnose import check_run, prepare
from valve_env.valveid.fitting import Model, RunData
from valve_env.valveid.temperature import denoise_temperature, noise_sd, smooth_temperature
from valve_env.valveid.valve_model import base_valve_model, prepare_inputs


def _rate(t: np.ndarray, T: np.ndarray) -> np.ndarray:
    return np.diff(T) / np.diff(t)


def _reversals_per_h(t: np.ndarray, T: np.ndarray) -> float:
    s = np.sign(np.diff(T))
    s = s[s != 0]
    return float(np.count_nonzero(s[1:] != s[:-1])) / ((t[-1] - t[0]) / 3600.0)


def _ekf_fit(df: pd.DataFrame, T: np.ndarray, M: np.ndarray) -> dict[str, float]:
    """The base valve's EKF fit (MLEstimator) with the given temperatures as its inputs (levels and
    their rates over each interval) in place of its own TV-denoised ones."""
    model = base_valve_model()
    t = df["time_s"].to_numpy()
    inputs = prepare_inputs(df)
    for col, rate, level in (("T_tank_s", "v_tank", T), ("T_med_s", "v_med", M)):
        inputs[col] = level
        inputs[rate] = np.r_[np.diff(level) / np.diff(t), 0.0]
    model.prepare = lambda data: data  # type: ignore[method-assign]  # the inputs are given
    return MLEstimator(model, n_starts=1, hessian=False).fit(inputs).params_


def _run(seed: int, noise: float, duration_h: float, dt_s: float, fit: bool) -> dict[str, dict[str, float]]:
    df = simulate_experiment(seed=seed, duration_h=duration_h, dt_s=dt_s, T_noise_C=noise, x_noise_mm=2.4e-3)
    t = df["time_s"].to_numpy()
    truth = df["true_T_tank_C"].to_numpy()
    truth_med = df["true_T_med_C"].to_numpy()
    data = prepare(check_run(df))
    tv = denoise_temperature(df["T_tank_C"].to_numpy(), t)[0]
    tv_med = denoise_temperature(df["T_med_C"].to_numpy(), t)[0]
    levels = {"tv": (tv, tv_med), "irw_rts": (data.T, data.M)}
    assert np.allclose(data.T, smooth_temperature(t, df["T_tank_C"].to_numpy())[0])
    model = Model(())
    v = model.valve
    values = {"sigma": v.sigma, "F_hmax": v.F_hmax, "p_bset": v.p_bset}
    x_true = df["true_x_mm"].to_numpy()
    out: dict[str, dict[str, float]] = {}
    for name, (T, M) in levels.items():
        d = RunData(data.t, data.T_raw, data.M_raw, data.x, data.dp, data.ps, np.ascontiguousarray(T), data.vT,
                    np.ascontiguousarray(M), data.vM, data.s_T, data.s_M, name)
        xs, _, _ = model.simulate(d, values)
        out[name] = {
            "T_rms_mK": 1e3 * float(np.sqrt(np.mean((T - truth) ** 2))),
            "Tmed_rms_mK": 1e3 * float(np.sqrt(np.mean((M - truth_med) ** 2))),
            "rate_rms_mK_h": 3.6e6 * float(np.sqrt(np.mean((_rate(t, T) - _rate(t, truth)) ** 2))),
            "reversals_h": _reversals_per_h(t, T),
            "true_reversals_h": _reversals_per_h(t, truth),
            "x_rms_um": 1e3 * float(np.sqrt(np.mean((xs - x_true) ** 2))),
            "s_over_noise": (noise_sd(df["T_tank_C"].to_numpy()) if name == "tv" else d.s_T) / noise,
        }
        if fit:
            est = model.fit(d, with_std=False).params
            for k, true in values.items():
                out[name][f"{k}_err_pct"] = 100.0 * abs(est[k] / true - 1.0)
            ekf = _ekf_fit(df, T, M)
            for k, true in values.items():
                out[name][f"ekf_{k}_err_pct"] = 100.0 * abs(ekf[k] / true - 1.0)
    return out


def survey(seed: int, cases: int) -> None:
    """The collapse survey: the smoother's noise sd, level and rate errors on the study's randomised runs."""
    rows = []
    cpu = 0.0
    for case in random_cases(cases, seed):
        df = simulate_case(case)
        t = df["time_s"].to_numpy()
        for col in ("T_tank_C", "T_med_C"):
            truth = df[f"true_{col}"].to_numpy()
            c0 = time.process_time()
            level, _, s, _ = smooth_temperature(t, df[col].to_numpy())
            cpu += time.process_time() - c0
            rows.append((s / case["T_noise_C"], 1e3 * float(np.sqrt(np.mean((level - truth) ** 2))),
                         3.6e6 * float(np.sqrt(np.mean((_rate(t, level) - _rate(t, truth)) ** 2)))))
    a = np.array(rows)
    q = np.quantile(a[:, 0], [0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0])
    print(f"seed {seed}, {cases} cases, {len(a)} channels: s/noise < 0.1 (collapsed) on {int((a[:, 0] < 0.1).sum())}; "
          f"quantiles 0/10/25/50/75/90/100 % {' '.join(f'{v:.3g}' for v in q)}")
    print(f"T error mK RMS mean {a[:, 1].mean():.3g} (max {a[:, 1].max():.3g}); rate error mK/h RMS mean "
          f"{a[:, 2].mean():.4g} (max {a[:, 2].max():.4g}); smoother CPU {cpu:.1f} s ({1e3 * cpu / len(a):.0f} ms "
          "per channel)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[900, 901, 902, 903, 904, 905])
    ap.add_argument("--noise", type=float, nargs="+", default=[0.001, 0.005, 0.01, 0.02])
    ap.add_argument("--duration-h", type=float, default=12.0)
    ap.add_argument("--dt-s", type=float, default=10.0)
    ap.add_argument("--fit", action="store_true",
                    help="also fit the base model by output error from each and report |error| %% of sigma, "
                         "F_hmax, p_bset")
    ap.add_argument("--survey", type=int, metavar="SEED",
                    help="run the collapse survey on the study's randomised runs of this seed instead")
    ap.add_argument("--cases", type=int, default=30, help="--survey's number of runs (two channels each)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.survey is not None:
        survey(args.survey, args.cases)
        print(f"{time.perf_counter() - t0:.0f} s")
        return 0
    keys = ["T_rms_mK", "Tmed_rms_mK", "rate_rms_mK_h", "reversals_h", "x_rms_um", "s_over_noise"]
    if args.fit:
        keys += ["sigma_err_pct", "F_hmax_err_pct", "p_bset_err_pct", "ekf_sigma_err_pct", "ekf_F_hmax_err_pct",
                 "ekf_p_bset_err_pct"]
    print(f"{len(args.seeds)} runs per noise level ({args.duration_h:g} h at {args.dt_s:g} s, seeds "
          f"{' '.join(map(str, args.seeds))}); mean over runs (max in brackets)")
    print(f"{'noise degC':>10} {'method':>8} " + " ".join(f"{k:>18}" for k in keys) + f" {'true rev/h':>10}")
    for noise in args.noise:
        rows = [_run(s, noise, args.duration_h, args.dt_s, args.fit) for s in args.seeds]
        for m in ("tv", "irw_rts"):
            cells = []
            for k in keys:
                vals = np.array([r[m][k] for r in rows])
                cells.append(f"{vals.mean():10.3g} ({vals.max():.3g})".rjust(18))
            true_rev = float(np.mean([r[m]["true_reversals_h"] for r in rows]))
            print(f"{noise:10.3g} {m:>8} " + " ".join(cells) + f" {true_rev:10.3g}")
    print(f"{time.perf_counter() - t0:.0f} s")
    return 0 if math.isfinite(t0) else 1


if __name__ == "__main__":
    raise SystemExit(main())
