"""Teaching example: the valve's hysteresis loop from the Dahl model.

Heats the bulb slowly from 45 to 62 degC and cools it back (quasi-static), and
plots the opening against temperature with and without friction. The loop's
width near the set point is 2 F_hmax / (A_b dp_b/dT), about 0.8 K.

    python examples/hysteresis_loop.py [--out out/hysteresis_loop.png] [--force]

The figure goes to out/hysteresis_loop.png by default, through the project's output
policy (valve_env.outputs: an existing file is replaced only with --force, written
atomically); the script names the file it wrote.
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from valve_env.outputs import OutputSet
from valve_env.params import ValveParams
from valve_env.physics import valve as v


def sweep(params: ValveParams, T_lo: float = 45.0, T_hi: float = 62.0, n: int = 2000):
    vp = params.to_array()
    T = np.concatenate([np.linspace(T_lo, T_hi, n), np.linspace(T_hi, T_lo, n)])
    F = 0.0
    x = np.empty_like(T)
    for k in range(T.size):
        F = v.dahl_update(F, T[k] - T[k - 1] if k else 0.0, vp)
        x[k] = v.opening(T[k], F, 100.0, 2.0, params.p_bset, vp)
    return T, x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/hysteresis_loop.png", help="the figure (default out/hysteresis_loop.png)")
    ap.add_argument("--force", action="store_true", help="replace an existing figure")
    args = ap.parse_args()
    outs = OutputSet(force=args.force)
    try:
        out = outs.add(args.out, "--out")
    except ValueError as exc:  # one line, exit status 2, as the thermovalve commands
        ap.exit(2, f"{ap.prog}: error: {exc}\n")
    p = ValveParams()
    T, x = sweep(p)
    T0, x0 = sweep(p.replace(F_hmax=1e-9, sigma=1e-6))
    band = v.friction_band_K(57.9, p.to_array())
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(T0, x0, "k--", lw=0.8, label="no friction")
    ax.plot(T, x, label=f"Dahl friction (loop ~{2 * band:.2f} K wide at the set point)")
    ax.set_xlabel("bulb temperature T_g [degC]")
    ax.set_ylabel("opening x [mm]")
    ax.legend()
    fig.tight_layout()
    with outs:
        outs.stage(out, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    print(f"friction band +-{band:.3f} K, gain {v.gain_mm_per_K(57.9, 100.0, p.to_array()):.4f} mm/K")
    print(outs.summary())


if __name__ == "__main__":
    main()
