"""``thermovalve fit``, ``thermovalve diagnose`` and ``thermovalve experiment`` (docs/reference.md, sections
4 and 7).

    thermovalve fit RUN.csv --json OUT.json [--report DIR] [--valve-out VALVE.yaml]
                            [--validate OTHER.csv] [--n-starts N] [--seed S] [--bootstrap B | --ml]

writes {"params": {"sigma", "F_hmax", "p_bset"}, "std": {...}, "loglik", "rms_mm", "n", ...}.
By default ``params`` and ``std`` are the errors-in-variables fit's
(:func:`valve_env.valveid.eiv.fit_eiv`, B = 8 temperature-bootstrap refits), whose sd the
held-out coverage studies show calibrated at 2 sd (docs/uncertainty.md); ``--ml`` gives the plain
maximum-likelihood fit, whose inverse-Hessian sd is NOT calibrated under temperature noise.
``params`` holds ValveParams fields only, so it passes straight to
``gym.make("ThermoValve-v0", valve=params)``.

Bad input raises (the shared handler of :mod:`valve_env.cli` prints one line and exits 2);
every file goes through one :class:`valve_env.outputs.OutputSet` (checked before the long
work, never over an input, replaced only with --force, written atomically). More outputs
(e.g. a fitted valve file) join the same set in :func:`_cmd_diagnose`.
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path
from typing import Any

from valve_env.cliutil import UsageError, add_force, check_range


def register(subparsers: Any) -> None:
    """Add the ``diagnose``, ``experiment`` and ``fit`` sub-commands."""
    d = subparsers.add_parser(
        "diagnose",
        help="find what the calibrated valve model gets wrong and name the cause (docs/reference.md, section 4)",
        description="Fit the base valve model, try every named effect, and name the cause only when the gain is "
        "statistically significant and real on held-out data.",
    )
    d.add_argument("run", metavar="RUN.csv", help="measured run (docs/reference.md, section 2)")
    d.add_argument("--json", dest="json_out", metavar="OUT.json", required=True, help="where to write the result")
    d.add_argument("--validate", metavar="OTHER.csv", default=None,
                   help="an independent run for validation (default: hold out the end of RUN.csv)")
    d.add_argument("--holdout", type=float, default=0.25, metavar="FRACTION",
                   help="fraction at the end of RUN.csv held out for validation when --validate is absent")
    d.add_argument("--alpha", type=float, default=0.001, help="significance level of the likelihood-ratio test")
    d.add_argument("--effects", default=None, metavar="A,B,...", help="candidate effects (default: all)")
    d.add_argument("--report", default=None, metavar="REPORT.md|DIR",
                   help="the human report (default: beside OUT.json, OUT.md with PNG figures); a path not ending in "
                        ".md is a folder: DIR/report.md and its figures")
    d.add_argument("--no-report", action="store_true", help="write the JSON only")
    d.add_argument("--bootstrap", type=int, default=16, metavar="B",
                   help="bootstrap replicates for the named effects' sd (0: inverse Hessian/HAC, "
                   "faster but optimistic; stiction's band, measured from the slips, then has no sd)")
    add_force(d)
    d.add_argument("--valve-out", metavar="VALVE.yaml", default=None,
                   help="write the diagnosed valve (base parameters and named effects) as a valve file for "
                   "gym.make(id, config=VALVE.yaml) (docs/reference.md)")
    d.set_defaults(func=_cmd_diagnose)

    e = subparsers.add_parser(
        "experiment",
        help="simulate a measured run like the paper's experiment, with effects switched on",
        description="Temperature steps of varying speed around the set point, the medium temperature varying "
        "independently, docs/reference.md, section 2 columns and noise levels.",
    )
    e.add_argument("--seed", type=int, default=0, help="seed of the noise and the steps (>= 0)")
    e.add_argument("--hours", type=float, default=24.0, help="duration, h")
    e.add_argument("--dt", type=float, default=10.0, help="sampling interval, s")
    e.add_argument("--effect", action="append", default=[], metavar="NAME:key=value",
                   help="switch on an effect, e.g. sensor_lag:tau_s=60 (repeatable)")
    e.add_argument("--T-noise", dest="T_noise", type=float, default=0.01, help="temperature noise sd, degC")
    e.add_argument("--x-noise", dest="x_noise", type=float, default=2.4e-3, help="opening noise sd, mm")
    e.add_argument("--jitter", type=float, default=0.0, help="uneven sampling, fraction of dt (< 0.5)")
    e.add_argument("--no-truth", action="store_true", help="leave out the true_* columns")
    e.add_argument("--out", required=True, metavar="RUN.csv", help="where to write the run")
    add_force(e)
    e.set_defaults(func=_cmd_experiment)
    _register_fit(subparsers)


def _cmd_experiment(args: argparse.Namespace) -> int:
    from valve_env.data_io import validate_run
    from valve_env.experiment import parse_effect, simulate_experiment
    from valve_env.outputs import OutputSet

    if args.seed < 0:
        raise UsageError(f"--seed must be a non-negative integer, got {args.seed}")
    check_range("--hours", args.hours, 0.0, 24.0 * 366, lo_open=True)
    check_range("--dt", args.dt, 0.0, 3600.0, lo_open=True)
    check_range("--T-noise", args.T_noise, 0.0)
    check_range("--x-noise", args.x_noise, 0.0)
    check_range("--jitter", args.jitter, 0.0, 0.5, hi_open=True)
    outs = OutputSet(force=args.force)
    out = outs.add(args.out, "--out")
    effects: dict[str, dict[str, float]] = {}
    for text in args.effect:
        name, pars = parse_effect(text)
        if name in effects:
            raise UsageError(f"--effect {name!r} given twice")
        effects[name] = pars
    df = simulate_experiment(seed=args.seed, duration_h=args.hours, dt_s=args.dt, effects=effects,
                             T_noise_C=args.T_noise, x_noise_mm=args.x_noise, jitter=args.jitter)
    if args.no_truth:
        df = df[[c for c in df.columns if not c.startswith("true_")]]
    validate_run(df, source=f"the simulated run for {out}")  # the same checks fit and diagnose apply
    with outs:
        outs.stage(out, lambda tmp: df.to_csv(tmp, index=False, float_format="%.9g"))
    desc = ", ".join(f"{k}({', '.join(f'{p}={v:g}' for p, v in d.items())})" for k, d in effects.items()) or "none"
    print(f"{outs.summary()}: {len(df)} samples, {args.hours:g} h at {args.dt:g} s, effects: {desc}")
    return 0


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from valve_env.cliutil import stage_progress
    from valve_env.effects import REGISTRY as EFFECTS
    from valve_env.effects import check_effects
    from valve_env.outputs import OutputSet, json_text
    from valve_env.valveid.diagnose import diagnose, read_run

    check_range("--holdout", args.holdout, 0.05, 0.5)
    check_range("--alpha", args.alpha, 0.0, 0.5, lo_open=True, hi_open=True)
    if args.bootstrap < 0 or args.bootstrap == 1:  # one replicate has no spread: an sd of 0 and a point interval
        raise UsageError(f"--bootstrap must be 0 or at least 2, got {args.bootstrap}")
    if args.no_report and args.report:
        raise UsageError("--no-report and --report exclude each other")
    effects = None if args.effects is None else [s.strip() for s in args.effects.split(",") if s.strip()]
    if effects == []:  # an empty list would silently become every effect
        raise UsageError(f"--effects names no effect; give one or more of {', '.join(EFFECTS)}, "
                         "or leave it out for all")
    cands = check_effects(effects if effects is not None else list(EFFECTS))
    # every output checked before the long work: never an input, never replaced without --force
    outs = OutputSet(inputs=[args.run, args.validate], force=args.force)
    out = outs.add(args.json_out, "--json")
    valve_out = outs.add(args.valve_out, "--valve-out") if args.valve_out else None
    report = None
    if not args.no_report:
        from valve_env.valveid.report import FIGURE_SUFFIXES

        report = Path(args.report) if args.report else out.with_suffix(".md")
        if args.report and report.suffix.lower() != ".md":  # a folder, as fit's and loop-diagnose's --report take
            report = report / "report.md"
            outs.add_in_dir(report.parent, ["report.md", *(f"report{sfx}" for sfx in FIGURE_SUFFIXES)], "--report")
        else:
            outs.add(report, "--report" if args.report else "report (default: beside --json; give --report)")
            outs.add_in_dir(report.parent, [f"{report.stem}{sfx}" for sfx in FIGURE_SUFFIXES], "report figure")
    run = read_run(args.run)
    vdf = read_run(args.validate) if args.validate is not None else None
    total = 1 + len(cands) * 2 + 1 + (2 if args.bootstrap else 0)
    from valve_env.ident.tests import MisspecificationWarning

    # a named effect's misspecification is printed below as one 'warning:' line; Python's own print of the
    # warning (with this package's file and line) would say it twice
    with stage_progress(total, "diagnose") as tick, warnings.catch_warnings():
        warnings.simplefilter("ignore", MisspecificationWarning)
        result = diagnose(run, validate=vdf, name=str(args.run), holdout=args.holdout, alpha=args.alpha,
                          effects=cands, bootstrap_B=args.bootstrap, progress=tick)
    if valve_out is not None:
        from valve_env.valveid.diagnose import on_bound, unidentified

        # the diagnosis's clue to the record's units (diagnose.unit_clue), which it computes where either holds
        clue = "." + result.unit_clue if result.unit_clue else ""
        flat = unidentified(result.final)
        if flat:
            raise UsageError(f"{args.run}: the record does not identify {', '.join(flat)} (no finite standard error): "
                             f"no valve file can be written from it; run without --valve-out for the diagnosis{clue}")
        bound = on_bound(result.final)
        if bound:
            raise UsageError(f"{args.run}: the diagnosed model leaves {', '.join(bound)} on its fit bound (a value "
                             "outside the valve's range would fit better): no valve file can be written from it; run "
                             f"without --valve-out for the diagnosis{clue}")
    with outs:
        outs.write_text(out, json_text(result.to_json()))
        if report is not None:
            from valve_env.valveid.report import write_report

            write_report(result, outs.stage_dir(report.parent) / report.name)
        if valve_out is not None:
            from valve_env.valvefile import write_valve

            write_valve(outs, valve_out, result.final.params,
                        {e: {k: result.final.params[k] for k in EFFECTS[e].param_names} for e in result.selected},
                        source=f"diagnosed by thermovalve diagnose {args.run}: cause {result.cause}")
    print(result.summary())
    for note in [nt["why"] for nt in result.preprocessing.get("run", []) if nt.get("warn")] + result.warnings:
        print(f"warning: {note}")
    for f in result.findings:  # a named effect whose residuals say its model does not fit
        mis = (f.robust or {}).get("misspecification") or {}
        if mis.get("misspecified"):
            print(f"warning: {f.effect}: {mis['message']}")
    print(outs.summary())
    return 0


def _register_fit(subparsers: Any) -> None:
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
    p.add_argument("--bootstrap", type=int, default=None, metavar="B",
                   help="temperature-bootstrap refits in the errors-in-variables sd (default 8, the studied setting; "
                   "0: none, then the sd leaves out the temperature noise's white part; not with --ml)")
    p.add_argument("--n-starts", type=int, default=3, help="optimiser starts (>= 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the extra starts (>= 0)")
    add_force(p)
    p.set_defaults(func=run_fit)


def run_fit(args: argparse.Namespace) -> int:
    from valve_env.cliutil import progress_bar
    from valve_env.data_io import load_run, temperature_unit_hint
    from valve_env.outputs import OutputSet, json_text

    if args.n_starts < 1:
        raise UsageError(f"--n-starts must be at least 1, got {args.n_starts}")
    if args.seed < 0:
        raise UsageError(f"--seed must be a non-negative integer, got {args.seed}")
    if args.ml and args.eiv:
        raise UsageError("--ml and --eiv exclude each other (the errors-in-variables fit is the default)")
    if args.ml and args.bootstrap:  # --bootstrap 0 says what --ml does anyway
        raise UsageError("--bootstrap belongs to the errors-in-variables fit; --ml fits without it")
    if args.bootstrap is None:
        from valve_env.valveid.eiv import EIV_BOOTSTRAP_B

        args.bootstrap = EIV_BOOTSTRAP_B
    if args.bootstrap < 0 or args.bootstrap == 1:
        raise UsageError(f"--bootstrap must be 0 or at least 2, got {args.bootstrap}")
    # every output checked before the long work (never an input, never replaced without --force);
    # further outputs (e.g. a fitted valve file) join this set
    outs = OutputSet(inputs=[args.run, args.validate], force=args.force)
    json_out = outs.add(args.json_out, "--json")
    valve_out = outs.add(args.valve_out, "--valve-out") if args.valve_out else None
    report_dir = Path(args.report) if args.report else None
    if report_dir is not None:
        from valve_env.valveid.report import FIT_REPORT_FILES

        names = [*FIT_REPORT_FILES, *(["validation.png"] if args.validate else [])]
        outs.add_in_dir(report_dir, names, "--report")
    from valve_env.valveid.preprocess import preprocess_run

    data, pre = preprocess_run(load_run(args.run), source=str(args.run))
    validation = preprocess_run(load_run(args.validate), source=str(args.validate))[0] if args.validate else None
    from valve_env.valveid.fit import eiv_summary, fit_run, fit_summary
    from valve_env.valveid.report import quantisation_note, write_report

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
                write_report(est, outs.stage_dir(report_dir), data=data, summary=summary, validation=validation,
                             name=Path(args.run).stem)
                summary["report"] = str(report_dir / "report.md")
                bar.update(1)
    finally:
        bar.close()
    p = summary["params"]
    bad = [k for k, v in p.items() if not (isinstance(v, (int, float)) and math.isfinite(v))]
    if bad:
        raise UsageError(f"{args.run}: the fit gave a non-finite {bad[0]}; the run does not identify the valve")
    s = summary["std"]
    flat = [k for k in ("sigma", "F_hmax", "p_bset")
            if not (isinstance(s.get(k), (int, float)) and math.isfinite(s[k]))]
    if flat:
        # an estimate without a standard error is not a result (docs/estimation.md, "Bad input")
        other = data.attrs.get("x_mm_other_unit")
        unread = f"; no x_mm column, so the opening was derived from the flow: {other}" if other else ""
        why = next((m.split(": these parameters")[0] for m in summary["identifiability"] if any(k in m for k in flat)),
                   "no finite standard error")
        mis = summary["misspecification"]
        bound = [k for k in flat if k in est.at_bound_]
        if mis.get("misspecified") and bound:
            # the likelihood's maximum lies on a bound of a model the residuals reject: a structural misfit
            # (a 60 s sensor lag drives the paper's sigma to its lower bound, as a slow friction imitates the
            # lag), not a record too short to fit the model; the named effects are diagnose's
            p_lb = min(e["ljung_box_p"] for e in mis["outputs"].values())
            at = f"parameter {bound[0]!r} is at a bound ({est.params_[bound[0]]:.6g})"
            from valve_env.data_io import flow_unit_hint, opening_derived

            hint = flow_unit_hint(data["q_kgh"].to_numpy(), data["dp_mbar"].to_numpy()) if opening_derived(data) else ""
            hint += temperature_unit_hint(data["T_tank_C"].to_numpy())
            raise UsageError(f"{args.run}: the paper's model does not explain this record ({at}, "
                             f"and the one-step residuals are not white, Ljung-Box p = {p_lb:.2g}): "
                             f"an effect the model lacks, or too little excitation; `thermovalve diagnose "
                             f"{args.run}` tries the named effects{hint}{unread}")
        raise UsageError(f"{args.run}: the record does not identify {', '.join(flat)} ({why}); "
                         f"a longer record with wider temperature swings is needed{unread}"
                         f"{temperature_unit_hint(data['T_tank_C'].to_numpy())}")
    with outs:
        outs.write_text(json_out, json_text(summary))
        if valve_out is not None:
            from valve_env.valvefile import write_valve

            write_valve(outs, valve_out, summary["params"], source=f"fitted by thermovalve fit {args.run}")
    print(f"sigma = {p['sigma']:.4g} ({_sd(s['sigma'])}) N/K, F_hmax = {p['F_hmax']:.4g} ({_sd(s['F_hmax'])}) N, "
          f"p_bset = {p['p_bset']:.5g} ({_sd(s['p_bset'])}) MPa; loglik {summary['loglik']:.1f}, "
          f"rms {summary['rms_mm']:.3g} mm, n {summary['n']}")
    for m in summary["identifiability"]:
        print(f"warning: {m}")
    for nt in summary["preprocessing"]:
        if nt.get("warn"):
            print(f"warning: {nt['why']}")
    qnote = quantisation_note(summary)
    if qnote:
        print(f"note: {qnote}")
    if summary["misspecification"]["misspecified"]:
        print(f"warning: {summary['misspecification']['message']}")
    print(outs.summary())
    return 0


def _sd(v: float | None) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.2g}"
