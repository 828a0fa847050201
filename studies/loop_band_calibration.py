"""Calibrate the band's model-error sd (``valve_env.loops.diagnose.BAND_REL_SD``) on simulated sticky loops
(docs/loops.md, "Band uncertainty").

    python studies/loop_band_calibration.py --seeds 0-299

For the sticky loops among ``valve_env.loops.sim.random_case``'s seeds (development seeds: the detector's training
range, never the benchmark's evaluation seeds), fits the band (``diagnose_loop(..., quantify=True)``) and prints, for
each candidate relative model-error sd, the 1-sd and 2-sd coverage of the true band, and the share of bands within
20 % of the truth (which the sd does not change). The sd's other terms (profile likelihood, sampling offset) are
taken as fitted.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from valve_env.cliutil import int_list
from valve_env.loops.diagnose import BAND_REL_SD, SAMPLING_SD_SHARE, diagnose_loop
from valve_env.loops.sim import random_case, simulate_case


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0-299")
    a = ap.parse_args(argv)
    rows = []
    for seed in int_list(a.seeds):
        case = random_case(seed)
        if case["label"] != "stiction":
            continue
        loop, _ = simulate_case(case)
        st = diagnose_loop(loop, quantify=True).result["stiction"]
        other = st["std_pct"] ** 2 - (BAND_REL_SD * st["band_pct"]) ** 2
        rows.append((case["S"], st["band_pct"], max(other, 0.0)))
    S, B, O = (np.array([r[i] for r in rows]) for i in range(3))
    err = np.abs(B - S)
    print(f"{len(rows)} sticky loops of seeds {a.seeds}; within 20 % of the truth: "
          f"{100 * np.mean(err <= 0.2 * S):.1f} %; median |error| {100 * np.median(err / S):.0f} %; "
          f"sampling-offset share {SAMPLING_SD_SHARE:g}")
    for rel in (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5):
        sd = np.sqrt(O + (rel * B) ** 2)
        print(f"  BAND_REL_SD {rel:4.2f}: 1-sd coverage {100 * np.mean(err <= sd):5.1f} %, 2-sd coverage "
              f"{100 * np.mean(err <= 2 * sd):5.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
