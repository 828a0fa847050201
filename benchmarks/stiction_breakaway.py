"""Stiction's breakaway travel S beside its slip J: the (S, J) profiles on
stick-slip runs of the independent simulator's variants ``reset``, ``sj`` and ``force`` and of the project's
generator (docs/diagnosis.md, "What ``band_mm`` is on a valve with J < S"; docs/uncertainty.md, "Stick-slip
variants (`stiction_variant`)").

Each run is drawn and diagnosed as ``benchmarks/stiction_misspecification.py`` does it (stiction the only
candidate, no bootstrap, the training part); then the profiles of S / J
(:func:`valve_env.valveid.stick_profile.sj_profile`: the open-loop one, and the one
on the stick-slip filter's likelihood, :func:`~valve_env.valveid.stick_profile.sj_filter_loglik`) and the
stick-slip check's statistic are taken at the ML estimate, and :func:`valve_env.valveid.bootstrap.breakaway_evident`
(on the filter's profile) says whether the diagnosis's bootstrap would report S or J (the slips') as the band.
Printed per run: the truth S, the slips' band J, both profiles' S / J, the filter's gain over J = S, the errors
against S, the check's statistic and the decision. ``--variants force`` runs one variant only.

    python benchmarks/stiction_breakaway.py --generator independent --runs 2 --seed 500 --json out/sb_i_500.json
    python benchmarks/stiction_breakaway.py --generator project --runs 3 --seed 20261126 --json out/sb_p.json
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from typing import Any

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from stiction_misspecification import add_misspecification, diagnose_case, study_main  # noqa: E402


def profile_case(case: dict[str, Any]) -> dict[str, Any]:
    """:func:`stiction_misspecification.run_case`'s record and the (S, J) profiles of its fit."""
    from valve_env.valveid.bootstrap import breakaway_evident, calibrated_ratio
    from valve_env.valveid.stick_profile import sj_filter_loglik, sj_profile

    out, f, d = diagnose_case(case)
    add_misspecification(out, f, d)
    med = float(out.pop("misspecification")["travel_over_slip_median"])
    model, train, fit = f.estimator.backend_, d.train, f.fit
    if not float(fit.params.get("band_mm", 0.0)) > 0.0:
        return {**out, "profile": None, "filter_profile": None, "travel_over_slip": med, "applied": False}
    t0 = time.process_time()
    p = sj_profile(model, train, fit.params)
    t1 = time.process_time()
    # the stick-slip filter's profile: the diagnosis's likelihood with slips of J < S
    pf = sj_profile(model, train, fit.params, loglik=sj_filter_loglik)
    applied = breakaway_evident(med, pf.ratio, pf.ratio_sd)
    # the band the bootstrap reports where applied: the filter's reading over its development calibration
    # (here on the ML band, the bootstrap's is bias-corrected)
    S_cal = calibrated_ratio(pf.ratio, pf.ratio_sd)[0] * pf.J_mm
    out.update({"profile": p.to_json(), "S_profile": p.S_mm, "travel_over_slip": med, "applied": applied,
                "profile_cpu_s": t1 - t0, "filter_profile": pf.to_json(), "S_filter": pf.S_mm,
                "S_reported": S_cal if applied else float(out["band"]), "filter_cpu_s": time.process_time() - t1})
    return out


def _report(a: argparse.Namespace, res: list[dict[str, Any]]) -> None:
    for r in res:
        if r["profile"] is None:
            print(f"{r['generator']:11s} {r['i']:3d} {r['variant']!s:6s} named {r['named']!s:5s} no band fitted")
            continue
        S, J = r["true_band"], r["band"]
        print(f"{r['generator']:11s} {r['i']:3d} {r['variant']!s:6s} named {r['named']!s:5s} S {S:.4f} J {J:.4f} "
              f"S/J profile {r['profile']['profile_S_over_J']:.2f} +- {r['profile']['profile_S_over_J_sd']:.2f}  "
              f"filter {r['filter_profile']['profile_S_over_J']:.2f} "
              f"(+{max(r['filter_profile']['profile_loglik'].values()):.0f})  "
              f"err: profile {r['S_profile'] / S - 1:+.0%} filter {r['S_filter'] / S - 1:+.0%} slips {J / S - 1:+.0%}  "
              f"travel/slip {r['travel_over_slip']:.2f}  band = {'S' if r['applied'] else 'J'} "
              f"({r['S_reported'] / S - 1:+.0%})")
    # the calibration of the filter's reading (bootstrap.BREAKAWAY_READ): its reading over the true S / J (over the
    # slips' J) on the force runs where the band is taken as S and the slips measured J (within a factor 2 of the
    # true S / 3), their geometric mean and the standard error of its log
    logs = [math.log(r["filter_profile"]["profile_S_over_J"] * r["band"] / r["true_band"]) for r in res
            if r["profile"] is not None and r["applied"] and r["variant"] == "force"
            and 0.5 < 3.0 * r["band"] / r["true_band"] < 2.0]
    if len(logs) >= 2:
        m, s = statistics.mean(logs), statistics.stdev(logs)
        print(f"filter's S / J over the truth where the band is S ({len(logs)} runs): "
              f"geometric mean {math.exp(m):.3f}, sd of its log {s:.3f}, standard error {s / math.sqrt(len(logs)):.3f}")


def main(argv: list[str] | None = None) -> int:
    def variants_arg(ap: argparse.ArgumentParser) -> None:
        ap.add_argument("--variants", default="", help="only these stick-slip variants (comma-separated, e.g. force)")

    def keep_variants(a: argparse.Namespace, cs: list[dict[str, Any]]) -> list[dict[str, Any]]:
        keep = {v for v in a.variants.split(",") if v}
        return [c for c in cs if not keep or c["variant"] in keep]

    return study_main(argv, __doc__, profile_case, _report, "independent", 2, variants_arg, keep_variants)


if __name__ == "__main__":
    raise SystemExit(main())
