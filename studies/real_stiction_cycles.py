"""Period and controller-output swing of real sticky control loops (docs/tasks.md, plausibility of
ThermoValveStickyValve-v0's limit cycle).

    python studies/real_stiction_cycles.py DIR

DIR holds the labelled plant loops of StictionGPT (Xue et al. 2025; see that folder's SOURCE.md):
``DIR/stiction/*.txt``, tab-separated historian exports (5 header lines; columns time, OP %, PV, SP).
Per record: the period (the first autocorrelation peak of the control error after its first zero
crossing, 10 s samples) and the 5-95 % range of OP; printed per loop and over all records.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from statsmodels.tsa.stattools import acf


def cycles(directory: Path) -> pd.DataFrame:
    rows = []
    for f in sorted((directory / "stiction").glob("*.txt")):
        d = pd.read_csv(f, sep="\t", skiprows=5, header=None)
        op, pv, sp = (d[i].to_numpy(float) for i in (1, 2, 3))
        e = pv - sp
        a = acf(e - e.mean(), nlags=min(len(e) - 1, 400))
        z = int(np.argmax(a < 0))
        if z == 0:
            continue
        p = z + int(np.argmax(a[z:]))
        rows.append({"loop": f.name.split("_")[0], "period_min": p * 10 / 60, "acf_peak": a[p],
                     "op_p2p_pct": np.percentile(op, 95) - np.percentile(op, 5)})
    return pd.DataFrame(rows)


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not (Path(argv[0]) / "stiction").is_dir():
        print("usage: python studies/real_stiction_cycles.py DIR (with DIR/stiction/*.txt)", file=sys.stderr)
        return 2
    df = cycles(Path(argv[0]))
    print(df.groupby("loop").median().round(2))
    q = df[["period_min", "op_p2p_pct"]].quantile([0.25, 0.5, 0.75]).round(2)
    print(f"{len(df)} records; quartiles:\n{q}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
