"""``thermovalve fit``: the base valve model fitted to a measured run (docs/reference.md, section 7).

    thermovalve fit RUN.csv --json OUT.json [--report DIR] [--valve-out VALVE.yaml]
                            [--validate OTHER.csv] [--n-starts N] [--seed S] [--bootstrap B | --ml]

writes {"params": {"sigma", "F_hmax", "p_bset"}, "std": {...}, "loglik", "rms_mm", "n", ...}.
By default ``params`` and ``std`` are the errors-in-variables fit's
(:func:`valve_env.valveid.eiv.fit_eiv`, B = 8 temperature-bootstrap refits), whose sd the
held-out coverage studies show calibrated at 2 sd (docs/uncertainty.md); ``--ml`` gives the plain
maximum-likelihood fit, whose inverse-Hessian sd is NOT calibrated under temperature noise.
``params`` holds ValveParams fields only, so it passes straight to
``gym.make("ThermoValve-v0", valve=params)``; ``--config`` writes ``valve: {...}`` for the
environment's YAML configuration. Bad input: exit status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path
from typing import Any

from valve_env.cli import UsageError, add_force

#: the files ``--report DIR`` writes (valve_env.valveid.fit_report.write_report)
REPORT_FILES: tuple[str, ...] = ("report.md", "fit.png", "phase.png", "whiteness.png")


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "fit",
        help="fit the base valve model to a measured run (maximum likelihood)",
        description="Fit the base valve model (docs/reference.md, section 1) to RUN.csv (docs/reference.md, "
                    "section 2) by maximum likelihood and write the estimates as JSON. RUN.csv is validated exactly as "
                    "'thermovalve diagnose' validates it (valve_env.data_io).",
    )
    p.add_argument("run", metavar="RUN.csv", help="measured run (docs/reference.md, section 2 columns)")
    p.add_argument("--json", dest="json_out", metavar="OUT.json", required=True, help="where to write the result")
    p.add_argument("--report", metavar="DIR", default=None,
                   help="write figures and a markdown report (Table 4, Fig. 5-7) into DIR")
    p.add_argument("--valve-out", metavar="VALVE.yaml", default=None,
                   help="write the fitted valve as a valve file for gym.make(id, config=VALVE.yaml) "
                   "(docs/reference.md)")
    p.add_argument("--validate", metavar="OTHER.csv", default=None,
                   help="an independent run for cross-validation (paper Fig. 7)")
    p.add_argument("--eiv", action="store_true",
                   help="errors in variables (the default; kept for old command lines)")
    p.add_argument("--ml", action="store_true",
                   help="the plain maximum-likelihood fit alone (faster): params the relaxed-denoiser ML estimates, "
                   "std the inverse Hessian, which is NOT calibrated under temperature noise (docs/uncertainty.md)")
    p.add_argument("--bootstrap", type=int, default=8, metavar="B",
                   help="temperature-bootstrap refits in the errors-in-variables sd (default 8, the studied setting; "
                   "0: none, then the sd leaves out the temperature noise's white part)")
    p.add_argument("--n-starts", type=int, default=3, help="optimiser starts (>= 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the extra starts (>= 0)")
    add_force(p)
    p.set_defaults(func=run_fit)


def run_fit(args: argparse.Namespace) -> int:
    from valve_env.cli import progress_bar
    from valve_env.data_io import load_run
    from valve_env.outputs import OutputSet, json_text

    if args.n_starts < 1:
        raise UsageError(f"--n-starts must be at least 1, got {args.n_starts}")
    if args.seed < 0:
        raise UsageError(f"--seed must be a non-negative integer, got {args.seed}")
    if args.bootstrap < 0 or args.bootstrap == 1:
        raise UsageError(f"--bootstrap must be 0 or at least 2, got {args.bootstrap}")
    if args.ml and args.eiv:
        raise UsageError("--ml and --eiv exclude each other (the errors-in-variables fit is the default)")
    # every output checked before the long work (never an input, never replaced without --force);
    # further outputs (e.g. a fitted valve file) join this set
    outs = OutputSet(inputs=[args.run, args.validate], force=args.force)
    json_out = outs.add(args.json_out, "--json")
    valve_out = outs.add(args.valve_out, "--valve-out") if args.valve_out else None
    report_dir = Path(args.report) if args.report else None
    if report_dir is not None:
        names = [*REPORT_FILES, *(["validation.png"] if args.validate else [])]
        outs.add_in_dir(report_dir, names, "--report")
    from valve_env.valveid.preprocess import preprocess_run

    data, pre = preprocess_run(load_run(args.run), source=str(args.run))
    validation = preprocess_run(load_run(args.validate), source=str(args.validate))[0] if args.validate else None
    from valve_env.valveid.fit_report import eiv_summary, fit_run, fit_summary, write_report

    bar = progress_bar(3 if report_dir is not None else 2, desc="fit", unit="step")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if not args.ml:
                from valve_env.valveid.eiv import fit_eiv

                eiv = fit_eiv(data, n_starts=args.n_starts, seed=args.seed, B=args.bootstrap)
                est = eiv.estimator
                bar.update(1)
                summary = eiv_summary(eiv, data, validation)
            else:
                est = fit_run(data, n_starts=args.n_starts, seed=args.seed)
                bar.update(1)
                summary = fit_summary(est, data, validation)
                summary["std_method"] = ("inverse Hessian (ML, --ml): not calibrated under temperature noise "
                                         "(2-sd coverage of sigma 7 % on the independent simulator, "
                                         "docs/uncertainty.md)")
            summary["preprocessing"] = pre
            bar.update(1)
            if report_dir is not None:
                write_report(est, data, outs.stage_dir(report_dir), summary, validation, name=Path(args.run).stem)
                summary["report"] = str(report_dir / "report.md")
                bar.update(1)
    finally:
        bar.close()
    p = summary["params"]
    bad = [k for k, v in p.items() if not (isinstance(v, (int, float)) and math.isfinite(v))]
    if bad:
        raise UsageError(f"{args.run}: the fit gave a non-finite {bad[0]}; the run does not identify the valve")
    with outs:
        outs.write_text(json_out, json_text(summary))
        if valve_out is not None:
            from valve_env.valvefile import write_valve

            write_valve(outs, valve_out, summary["params"], source=f"fitted by thermovalve fit {args.run}")
    s = summary["std"]
    print(f"sigma = {p['sigma']:.4g} ({_sd(s['sigma'])}) N/K, F_hmax = {p['F_hmax']:.4g} ({_sd(s['F_hmax'])}) N, "
          f"p_bset = {p['p_bset']:.5g} ({_sd(s['p_bset'])}) MPa; loglik {summary['loglik']:.1f}, "
          f"rms {summary['rms_mm']:.3g} mm, n {summary['n']}")
    for m in summary["identifiability"]:
        print(f"warning: {m}")
    if summary["misspecification"]["misspecified"]:
        print(f"warning: {summary['misspecification']['message']}")
    print(outs.summary())
    return 0


def _sd(v: float | None) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.2g}"
