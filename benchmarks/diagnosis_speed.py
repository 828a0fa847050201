"""Speed of the diagnosis, bootstrap included (the goal: 24 h at 10 s diagnosed in at most 30 s; docs/diagnosis.md,
"Speed").

Times full diagnoses (every candidate, hold-out validation, forward selection and the model-based
bootstrap of each named effect, at the bootstrap size ``thermovalve diagnose`` uses by default) of
generated 24 h runs at 10 s: no effect, a sensor lag and stiction (:func:`valve_env.bench.bench_diagnosis`,
which ``thermovalve bench`` runs too). Numba's compilation is timed apart, first.

    python benchmarks/diagnosis_speed.py [--seed 2024] [--bootstrap B]
    python benchmarks/diagnosis_speed.py --first-run [--seed 2024]

``--first-run`` times what a new install's first diagnosis costs instead: ``thermovalve diagnose`` of one generated
run in a fresh interpreter with an empty numba cache (every kernel compiles), then again with the cache that run
left (the kernels load), each as wall and CPU seconds of the child process, at diagnose's defaults.

Prints one line per case (wall and CPU seconds) and the slowest against the target; the machine's
load average is printed too. The project's machine is shared: under load the wall time measures the
other jobs, and the process's CPU time is what the wall time is on a core of its own.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def first_run(seed: int) -> int:
    """Time ``thermovalve diagnose`` in a fresh interpreter, with an empty numba cache and then with the cache it
    left; print one line each."""
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run.csv"
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"))
        cli = [sys.executable, "-m", "valve_env.cli"]
        # run from the temporary directory: ``-m`` puts the working directory first on the path
        subprocess.run([*cli, "experiment", "--seed", str(seed), "--out", str(run)], env=env, check=True,
                       stdout=subprocess.DEVNULL, cwd=tmp)
        for label in ("empty cache (compiles)", "cache of that run"):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run([*cli, "diagnose", str(run), "--json", str(Path(tmp) / "d.json"), "--force"],
                           env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp)
            wall = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            print(f"first diagnosis of 24 h at 10 s, seed {seed}, {label}: wall {wall:.1f} s, CPU {cpu:.1f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    from valve_env.bench import DIAGNOSIS_TARGET_S as TARGET_S
    from valve_env.bench import bench_diagnosis, default_bootstrap_b

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--bootstrap", type=int, default=None,
                    help=f"bootstrap replicates (default: diagnose's default, {default_bootstrap_b()})")
    ap.add_argument("--first-run", action="store_true",
                    help="time a new install's first diagnosis instead (empty numba cache, then warm)")
    a = ap.parse_args(argv)
    if a.first_run:
        return first_run(a.seed)
    if a.bootstrap is not None and a.bootstrap < 0:
        print(f"thermovalve: error: --bootstrap must be >= 0, got {a.bootstrap}", file=sys.stderr)
        return 2
    load0 = os.getloadavg()[0]
    r = bench_diagnosis(seed=a.seed, bootstrap_B=a.bootstrap)
    load1 = os.getloadavg()[0]
    print(f"diagnosis of {r['hours']:g} h at {r['dt_s']:g} s ({r['samples']} samples), bootstrap B = "
          f"{r['bootstrap_B']}, seed {a.seed}; numba warm-up {r['warmup_compile_s']:.1f} s; "
          f"load average {load0:.1f} -> {load1:.1f}")
    for name, c in r["diagnosis_cases"].items():
        print(f"  {name:<12} wall {c['wall_s']:6.1f} s  CPU {c['cpu_s']:6.1f} s  named {c['cause']:<14} "
              f"fits {c['fits']:>2}  bootstraps {c['bootstraps']}")
    print(f"slowest {r['diagnosis_wall_s']:.1f} s wall against the target of {TARGET_S:g} s: "
          f"{'met' if r['diagnosis_within_target'] else 'NOT met'}; slowest CPU time {r['diagnosis_cpu_s']:.1f} s "
          f"({'within' if r['diagnosis_cpu_s'] <= TARGET_S else 'over'} the target on a core of its own)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
