"""A PI loop on a sticky valve limit-cycles: period and amplitude in the stem and the outlet, and the rise
in reversals and travel, against the same loop on a valve without stiction.

    python studies/stiction_limit_cycle.py [--seeds 101,102,103] [--bands 0.02,0.04,0.1] [--json OUT.json]

ThermoValve-v0 (the PI trims the valve's temperature setting; the project's tuned gains,
valve_env/data/controllers.yaml), a day of the EU tapping cycle M, seeded; stiction's band 0.02, 0.04 and
0.1 mm = 1, 2 and 5 % of the 2 mm stroke, the range the control-valve literature reports for real
valves (0.5-5 % of travel: Choudhury et al. 2005; Jelali & Huang 2010; docs/reference.md). The
oscillation is measured over the day minus its first 2 h, on the signals freed of their 2-hour
moving average (the draws' slow swings): its period is the first peak of the autocorrelation of the
stem position (lags 2-120 min), its amplitude half the median peak-to-peak range per period.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import valve_env  # noqa: F401 - registers the ids
from valve_env.controllers import make_controller
from valve_env.outputs import OutputSet

ENV_ID = "ThermoValve-v0"
DT_S = 30.0


def run_day(band: float, seed: int, profile: str = "M") -> dict[str, Any]:
    kw: dict[str, Any] = {"valve": {"effects": {"stiction": {"band_mm": band}}}} if band > 0 else {}
    kw["tapping_profile"] = profile
    env = gym.make(ENV_ID, **kw)
    ctrl = make_controller("pi", ENV_ID)
    obs, _ = env.reset(seed=seed)
    state, start = None, np.ones(1, bool)
    x, T = [], []
    while True:
        a, state = ctrl.predict(obs[None], state, start, deterministic=True)
        start = np.zeros(1, bool)
        obs, _, _, trunc, info = env.step(a[0])
        x.append(info["x_mm"])
        T.append(float(obs[0]))
        if trunc:
            return {"x": np.array(x), "T": np.array(T), "kpis": info["kpis"]}


def _detrend(y: np.ndarray, window: int) -> np.ndarray:
    k = np.ones(window) / window
    return y - np.convolve(np.pad(y, window // 2, mode="edge"), k, mode="same")[window // 2: window // 2 + y.size]


def oscillation(y: np.ndarray, lag_lo: int = 4, lag_hi: int = 240) -> tuple[float, float]:
    """(period s, amplitude) of the dominant oscillation of ``y`` (30 s samples); nan if none."""
    z = _detrend(y, int(7200 / DT_S))
    z = z - z.mean()
    if not np.any(z):
        return float("nan"), 0.0
    ac = np.correlate(z, z, mode="full")[z.size - 1:] / (z @ z)
    seg = ac[lag_lo:lag_hi]
    peaks = [i for i in range(1, seg.size - 1) if seg[i] >= seg[i - 1] and seg[i] >= seg[i + 1] and seg[i] > 0.1]
    if not peaks:
        return float("nan"), float(np.std(z) * np.sqrt(2.0))
    p = lag_lo + peaks[0]
    ranges = [np.ptp(z[i:i + p]) for i in range(0, z.size - p, p)]
    return p * DT_S, 0.5 * float(np.median(ranges))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="101,102,103")
    ap.add_argument("--bands", default="0.02,0.04,0.1")
    ap.add_argument("--profile", default="M", help="tapping profile (M, or none: only the standing losses)")
    ap.add_argument("--json", default=None, metavar="OUT.json")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    bands = [0.0] + [float(b) for b in args.bands.split(",")]
    outs = OutputSet(force=args.force)
    out_path = outs.add(args.json) if args.json else None
    skip = int(7200 / DT_S)
    rows: list[dict[str, Any]] = []
    print(f"{'band mm':>8} {'seed':>5} {'x period min':>13} {'x amp mm':>9} {'T period min':>13} {'T amp K':>8} "
          f"{'reversals':>9} {'travel mm':>9} {'rmse K':>7}")
    for band in bands:
        for seed in seeds:
            r = run_day(band, seed, args.profile)
            px, ax = oscillation(r["x"][skip:])
            pt, at = oscillation(r["T"][skip:])
            row = {"band_mm": band, "seed": seed, "x_period_s": px, "x_amplitude_mm": ax, "T_period_s": pt,
                   "T_amplitude_K": at, **{k: r["kpis"][k] for k in ("reversals", "travel_mm", "rmse_K")}}
            rows.append(row)
            print(f"{band:8.3f} {seed:5d} {px / 60:13.1f} {ax:9.4f} {pt / 60:13.1f} {at:8.3f} "
                  f"{row['reversals']:9.0f} {row['travel_mm']:9.2f} {row['rmse_K']:7.3f}")
    base = [r for r in rows if r["band_mm"] == 0.0]
    print("\nmeans over seeds (ratio to the valve without stiction):")
    for band in bands[1:]:
        rs = [r for r in rows if r["band_mm"] == band]
        m = {k: float(np.nanmean([r[k] for r in rs])) for k in rs[0] if k not in ("band_mm", "seed")}
        b = {k: float(np.mean([r[k] for r in base])) for k in m}
        print(f"  band {band:.3f} mm: stem period {m['x_period_s'] / 60:.1f} min, amplitude {m['x_amplitude_mm']:.4f} "
              f"mm; outlet period {m['T_period_s'] / 60:.1f} min, amplitude {m['T_amplitude_K']:.3f} K; reversals "
              f"x{m['reversals'] / b['reversals']:.2f}, travel x{m['travel_mm'] / b['travel_mm']:.2f}, rmse "
              f"{m['rmse_K']:.3f} K (no stiction {b['rmse_K']:.3f} K)")
    if out_path is not None:
        doc = {"env": ENV_ID, "controller": "pi", "profile": args.profile, "rows": rows}
        outs.write_text(out_path, json.dumps(doc, indent=2))
        outs.commit()
        print(f"wrote {Path(out_path)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
