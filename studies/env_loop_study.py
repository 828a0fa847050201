"""Env-loop records diagnosed, sticky against smooth (docs/loops.md, "Loops from the
environment").

    python studies/env_loop_study.py --env-id ThermoValveStickyCirculation-v0 --seeds 100-111 --kp 5 --ti 1500
    python studies/env_loop_study.py --seeds 0-11 --hours 24

For each seed: a record with a 0.1 mm stem band and one with a smooth stem (``record_env_loop``), each diagnosed
(``valve_env.loops.diagnose``); prints one line per record (the cause, the band when named, the detection's
probability of stiction, the CPU seconds of the diagnosis alone and of the whole record), the counts named
stiction and every cause's count. ``--kp``/``--ti`` override the PI's stored gains (both or neither); ``--hours``
and ``--warmup-h`` are the record's length and the warm-up before it (``record_env_loop``'s defaults)."""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

from valve_env.cliutil import int_list
from valve_env.loops.detect import DEFAULT_RULE, RULES
from valve_env.loops.diagnose import diagnose_loop
from valve_env.loops.envloop import ENV_ID, RECORD_H, WARMUP_H, record_env_loop

STICKY_MM = 0.1


def parse_env_args(description: str, argv: list[str] | None) -> tuple[argparse.Namespace, list[int]]:
    """The env-loop studies' command line (this script and loop_drift_study.py): ``--env-id``, ``--seeds``,
    ``--kp``/``--ti`` (both or neither), ``--hours`` (> 0)/``--warmup-h`` (>= 0); returns the arguments and the
    seeds."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--env-id", default=ENV_ID)
    ap.add_argument("--seeds", default="0-5", help="a range A-B or a comma list")
    ap.add_argument("--kp", type=float, default=None, help="PI gain, K of setting per K")
    ap.add_argument("--ti", type=float, default=None, help="PI integral time, s")
    ap.add_argument("--hours", type=float, default=RECORD_H, help="record length, h (30 s samples)")
    ap.add_argument("--warmup-h", type=float, default=WARMUP_H, help="warm-up before the record, h")
    ap.add_argument("--f-hmax", type=float, default=None,
                    help="the valve's Dahl friction F_hmax, N, on both stems (default: the paper's 1.31)")
    ap.add_argument("--rule", choices=RULES, default=DEFAULT_RULE,
                    help="loop-diagnose's detection rule (default horch; the acceptance is the learned rule's)")
    a = ap.parse_args(argv)
    if not (a.hours > 0.0 and a.warmup_h >= 0.0):
        ap.error(f"--hours must be > 0 and --warmup-h >= 0, got {a.hours:g} and {a.warmup_h:g}")
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
            t0 = time.process_time()
            loop = record_env_loop(band, seed=seed, hours=a.hours, warmup_h=a.warmup_h, env_id=a.env_id, Kp=a.kp,
                                   Ti_s=a.ti, F_hmax=a.f_hmax)
            t1 = time.process_time()
            res = diagnose_loop(loop, rule=a.rule).result
            t2 = time.process_time()
            cause = str(res["cause"])
            named[band] += cause == "stiction"
            causes[band][cause] += 1
            band_txt = f", {res['stiction']['label']}" if cause == "stiction" else ""
            prob = res["detection"]["probability"] if "detection" in res else float("nan")
            print(f"seed {seed} band {band:g} mm: {cause}{band_txt} (probability of stiction {prob:.2f}; "
                  f"CPU {t2 - t1:.1f} s diagnosis, {t2 - t0:.1f} s in all)", flush=True)
    n = len(seeds)
    print(f"{a.env_id}, {a.hours:g} h records after {a.warmup_h:g} h, PI "
          f"{'stored' if a.kp is None else f'Kp {a.kp:g}, Ti {a.ti:g} s'}: sticky named stiction "
          f"{named[STICKY_MM]}/{n}, smooth named stiction {named[0.0]}/{n}")
    for band, label in ((STICKY_MM, "sticky"), (0.0, "smooth")):
        print(f"{label} causes: " + ", ".join(f"{c} {k}" for c, k in causes[band].most_common()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
