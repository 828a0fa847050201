"""Env-loop records diagnosed, sticky against smooth (issue 21's acceptance; docs/loops.md, "Loops from the
environment").

    python benchmarks/env_loop_study.py --env-id ThermoValveStickyCirculation-v0 --seeds 100-111 --kp 5 --ti 1500

For each seed: a record with a 0.1 mm stem band and one with a smooth stem (``record_env_loop``), each diagnosed
(``valve_env.loops.diagnose``); prints one line per record (the cause, the band when named, the seat the
nonlinear valves were fitted on), the counts named stiction and every cause's count. ``--kp``/``--ti`` override
the PI's stored gains (both or neither)."""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

from valve_env.cli import int_list
from valve_env.loops.diagnose import diagnose
from valve_env.loops.envloop import ENV_ID, record_env_loop

STICKY_MM = 0.1


def parse_env_args(description: str, argv: list[str] | None) -> tuple[argparse.Namespace, list[int]]:
    """The env-loop studies' command line (this script and loop_drift_study.py): ``--env-id``, ``--seeds``,
    ``--kp``/``--ti`` (both or neither); returns the arguments and the seeds."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--env-id", default=ENV_ID)
    ap.add_argument("--seeds", default="0-5", help="a range A-B or a comma list")
    ap.add_argument("--kp", type=float, default=None, help="PI gain, K of setting per K")
    ap.add_argument("--ti", type=float, default=None, help="PI integral time, s")
    a = ap.parse_args(argv)
    if (a.kp is None) != (a.ti is None):
        ap.error("give both --kp and --ti, or neither")
    try:
        return a, int_list(a.seeds)
    except ValueError:
        ap.error(f"--seeds must be A-B or a comma list of integers, got {a.seeds!r}")


def main(argv: list[str] | None = None) -> int:
    a, seeds = parse_env_args(__doc__.splitlines()[0], argv)
    named = {STICKY_MM: 0, 0.0: 0}
    causes: dict[float, Counter[str]] = {STICKY_MM: Counter(), 0.0: Counter()}
    for seed in seeds:
        for band in (STICKY_MM, 0.0):
            t0 = time.perf_counter()
            res = diagnose(record_env_loop(band, seed=seed, env_id=a.env_id, Kp=a.kp, Ti_s=a.ti)).result
            cause = str(res["cause"])
            named[band] += cause == "stiction"
            causes[band][cause] += 1
            seat = res["decision"]["seat"]["nonlinear_pct"]
            band_txt = f", band {res['stiction']['band_pct']:.2f} % of OP" if cause == "stiction" else ""
            print(f"seed {seed} band {band:g} mm: {cause}{band_txt} (seat of the nonlinear valves "
                  f"{'none' if seat is None else format(seat, '.2f') + ' %'}; {time.perf_counter() - t0:.1f} s)",
                  flush=True)
    n = len(seeds)
    print(f"{a.env_id}, PI {'stored' if a.kp is None else f'Kp {a.kp:g}, Ti {a.ti:g} s'}: sticky named stiction "
          f"{named[STICKY_MM]}/{n}, smooth named stiction {named[0.0]}/{n}")
    for band, label in ((STICKY_MM, "sticky"), (0.0, "smooth")):
        print(f"{label} causes: " + ", ".join(f"{c} {k}" for c, k in causes[band].most_common()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
