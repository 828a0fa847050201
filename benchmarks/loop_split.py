"""Split the 46 real loops (plant_loops/index.csv) into a development set and a held-out set.

Written and run BEFORE any loop's data was looked at (only index.csv: label, file, tag).
Seeded, stratified by label, grouped by loop tag where possible: each tag goes whole to one
side (so the held-out side has valves never seen while building), except a tag holding more
than half of its label's files (2411FIC20102: 23 of 25 stiction files), whose files are split
half/half at random. Tags are visited in seeded random order and each goes to the side with
fewer files of its label so far (ties by the seeded coin).

    python benchmarks/loop_split.py /work/shared/data/plant_loops/index.csv > benchmarks/plant_loops_split.csv
"""

from __future__ import annotations

import csv
import sys
from collections import defaultdict

import numpy as np

SEED = 20261123


def split(rows: list[dict[str, str]], seed: int = SEED) -> dict[str, str]:
    rng = np.random.default_rng(seed)
    out: dict[str, str] = {}
    for label in sorted({r["label"] for r in rows}):
        by_tag: dict[str, list[str]] = defaultdict(list)
        for r in rows:
            if r["label"] == label:
                by_tag[r["loop_tag"]].append(r["file"])
        n_label = sum(len(v) for v in by_tag.values())
        count = {"dev": 0, "heldout": 0}
        tags = sorted(by_tag)
        for i in rng.permutation(len(tags)):
            files = sorted(by_tag[tags[i]])
            if len(files) > n_label / 2:
                perm = rng.permutation(len(files))
                for k, j in enumerate(perm):
                    side = "dev" if k < (len(files) + 1) // 2 else "heldout"
                    out[files[j]] = side
                    count[side] += 1
                continue
            if count["dev"] == count["heldout"]:
                side = "dev" if rng.random() < 0.5 else "heldout"
            else:
                side = "dev" if count["dev"] < count["heldout"] else "heldout"
            for f in files:
                out[f] = side
            count[side] += len(files)
    return out


def main(argv: list[str]) -> int:
    with open(argv[1], newline="") as fh:
        rows = list(csv.DictReader(fh))
    sides = split(rows)
    w = csv.writer(sys.stdout, lineterminator="\n")
    w.writerow(["label", "file", "loop_tag", "set"])
    for r in rows:
        w.writerow([r["label"], r["file"], r["loop_tag"], sides[r["file"]]])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
