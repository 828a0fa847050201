"""A probe, not a method: does a static curve given to every loop candidate take a smooth env record's band away
and leave a sticky one's? (docs/loops.md, "Loops from the environment".)

    python benchmarks/loop_static_curve_probe.py --records 2:0,10:0,0:0.1,1:0.1 [--hours 24]

Each record ``SEED:BAND_MM`` is the mid-stroke task's 24 h PI record (ThermoValveStickyCirculation-v0, Kp 5, Ti
1500 s), diagnosed as it is (``valve_env.loops.diagnose``). The diagnosis's linear
fit and its better nonlinear fit (backlash or stiction, by likelihood) are then refitted at their own process
structure (lag, delay, disturbance basis, AR order) with one more regressor: the centred square of the valve path
through the same process filter (a Hammerstein term). Printed: the unadjusted LR of the nonlinear valve over the
linear one, without and with that term. Crude on purpose: neither the band nor the process structure is searched
again with the term, so the second figure is not nested and can be negative.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np

from valve_env.loops.diagnose import diagnose
from valve_env.loops.envloop import record_env_loop
from valve_env.loops.io import LoopData
from valve_env.loops.model import Settings, ValveFit, _filtered, refit_gain


def loglik(loop: LoopData, fit: ValveFit, s: Settings, static_curve: bool) -> float:
    """The log-likelihood of ``fit`` refitted at its process structure (``model.refit_gain``: gain, disturbance and
    noise), with or without the static curve as one more column of the disturbance basis."""
    x = fit.path(loop.op)
    pf = fit.process
    if static_curve:
        xc = x - x.mean()
        w2 = _filtered(np.ascontiguousarray(xc * xc), pf.a, pf.delay, pf.integrating)  # through the process's filter
        pf = replace(pf, basis=np.column_stack([pf.basis, w2 / max(float(np.std(w2)), 1e-12)]))
    return refit_gain(loop.pv, x, pf, s, s.k0, loop.n).loglik


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default="2:0,10:0,0:0.1,1:0.1", help="SEED:BAND_MM, comma separated")
    ap.add_argument("--hours", type=float, default=24.0)
    a = ap.parse_args(argv)
    try:
        records = [(int(p.split(":")[0]), float(p.split(":")[1])) for p in a.records.split(",")]
    except (ValueError, IndexError):
        ap.error(f"--records must be SEED:BAND_MM pairs separated by commas, got {a.records!r}")
    if not a.hours > 0.0:
        ap.error(f"--hours must be > 0, got {a.hours:g}")
    for seed, band in records:
        loop = record_env_loop(band, seed=seed, hours=a.hours, warmup_h=3.0, env_id="ThermoValveStickyCirculation-v0",
                               Kp=5.0, Ti_s=1500.0)
        d = diagnose(loop)
        lin = d.fits["linear"]
        nl = max((d.fits[k] for k in ("backlash", "stiction")), key=lambda f: f.process.loglik)
        lr = [2.0 * (loglik(loop, nl, d.settings, c) - loglik(loop, lin, d.settings, c)) for c in (False, True)]
        print(f"seed {seed} band {band:g} mm: named {d.cause}; better nonlinear valve {nl.valve} S {nl.S:.2f} % of OP; "
              f"LR {lr[0]:.1f} without the static curve, {lr[1]:.1f} with it", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
