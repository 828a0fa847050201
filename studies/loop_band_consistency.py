"""The band's consistency on real records of one valve (docs/loops.md, "The band").

    python studies/loop_band_consistency.py --data /work/shared/data/plant_loops

A loop tag labelled sticky with several records is one valve recorded at several times. Its band (fitted on every
record, ``diagnose_loop(quantify=True)``) should then agree from record to record within its sd, if the band did not
change between the records. For every sticky tag with at least ``--min-files`` records, prints each record's band,
sd and whether the record resolves the band, and two shares: the records whose band lies within 2 sd of the median
of the tag's other records, and within 20 % of it. No label but the tag's is read, and nothing is fitted to them: a
check of the reported sd on real data, where the truth is not known.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from valve_env.loops.diagnose import diagnose_loop
from valve_env.loops.io import read_loop


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="a folder laid out like plant_loops (index.csv, <label>/<file>)")
    ap.add_argument("--min-files", type=int, default=5)
    a = ap.parse_args(argv)
    index = Path(a.data) / "index.csv"
    if not index.is_file():
        print(f"loop_band_consistency: error: {index} not found", file=sys.stderr)
        return 2
    idx = pd.read_csv(index)
    sticky = idx[idx["label"] == "stiction"]
    for tag, rows in sticky.groupby("loop_tag"):
        if len(rows) < a.min_files:
            continue
        band, sd = [], []
        for f in rows["file"]:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                st = diagnose_loop(read_loop(Path(a.data) / "stiction" / f), quantify=True).result.get("stiction")
            if not st:
                print(f"{tag} {f}: no band ({'insufficient data' if st is None else 'none'})")
                continue
            band.append(float(st["band_pct"]))
            sd.append(float(st["std_pct"]))
            print(f"{tag} {f}: band {band[-1]:.2f} +- {sd[-1]:.2f} % of OP, resolved {st.get('band_resolved')}")
        b, s = np.array(band), np.array(sd)
        others = np.array([np.median(np.delete(b, i)) for i in range(b.size)])
        print(f"{tag}: {b.size} records, band median {np.median(b):.2f} % (IQR {np.percentile(b, 25):.2f}-"
              f"{np.percentile(b, 75):.2f}); within 2 sd of the other records' median "
              f"{int(np.sum(np.abs(b - others) <= 2 * s))}/{b.size}, within 20 % of it "
              f"{int(np.sum(np.abs(b - others) <= 0.2 * others))}/{b.size}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
