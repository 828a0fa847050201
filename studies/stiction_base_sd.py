"""Whether a stiction fit's inverse-Hessian sd of the valve's own parameters covers the truth (docs/diagnosis.md,
"Known limits").

    python studies/stiction_base_sd.py --seeds 46-51

For each seed, a generated 12 h run at 10 s with a stick band (0.02-0.04 mm, in turn), diagnosed without the
bootstrap (``diagnose(df, bootstrap_B=0)``), so that the final fit's sd of sigma, F_hmax and p_bset is the
inverse-Hessian/HAC one, conditional on the band held at the slips' median (the diagnosis withholds it where the
bootstrap runs: ``valve_env.valveid.bootstrap.withhold_conditional_std``). Prints each run's cause, estimate, sd
and z = (estimate - truth) / sd, and the share within 2 sd per parameter.
"""

from __future__ import annotations

import argparse
import math
import sys

from valve_env.cliutil import int_list
from valve_env.experiment import simulate_experiment
from valve_env.params import ValveParams
from valve_env.valveid.diagnose import diagnose

BANDS = (0.02, 0.025, 0.03, 0.035, 0.04)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int_list, default=int_list("46-51"), help="e.g. 46-51 or 41,42,45")
    ap.add_argument("--hours", type=float, default=12.0)
    args = ap.parse_args(argv)
    v = ValveParams()
    truth = {"sigma": v.sigma, "F_hmax": v.F_hmax, "p_bset": v.p_bset}
    within = {k: 0 for k in truth}
    for i, seed in enumerate(args.seeds):
        band = BANDS[i % len(BANDS)]
        df = simulate_experiment(seed=seed, duration_h=args.hours, dt_s=10.0, effects={"stiction": {"band_mm": band}})
        fit = diagnose(df, bootstrap_B=0).final
        cells = []
        for k, true in truth.items():
            est, sd = float(fit.params[k]), float(fit.std.get(k, math.nan))
            z = (est - true) / sd
            within[k] += int(abs(z) <= 2.0)
            cells.append(f"{k} {est:.5g} +- {sd:.3g} (z {z:+.1f})")
        print(f"seed {seed}, band {band} mm, effects {list(fit.effects)}: " + "; ".join(cells), flush=True)
    n = len(args.seeds)
    print("within 2 sd: " + ", ".join(f"{k} {c}/{n}" for k, c in within.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
