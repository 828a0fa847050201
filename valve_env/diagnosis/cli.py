"""``thermovalve diagnose`` and ``thermovalve experiment`` (docs/reference.md, sections 4 and 7).

Every failure the user can cause ends with one line on stderr that names the
problem and a non-zero exit status; input files are never written.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from valve_env.effects import REGISTRY as EFFECTS

EXIT_BAD_INPUT = 2
EXIT_ERROR = 1


def _fail(msg: str, code: int = EXIT_BAD_INPUT) -> int:
    print(f"thermovalve: error: {msg}", file=sys.stderr)
    return code


def register(subparsers: Any) -> None:
    """Add the ``diagnose`` and ``experiment`` sub-commands."""
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
                   help="fraction at the end of RUN.csv held out for validation when --validate is absent (0.25)")
    d.add_argument("--alpha", type=float, default=0.001, help="significance level of the likelihood-ratio test")
    d.add_argument("--effects", default=None, metavar="A,B,...", help="candidate effects (default: all)")
    d.add_argument("--report", default=None, metavar="REPORT.md",
                   help="the human report (default: beside OUT.json, OUT.md with PNG figures)")
    d.add_argument("--no-report", action="store_true", help="write the JSON only")
    d.add_argument("--bootstrap", type=int, default=16, metavar="B",
                   help="bootstrap replicates for the named effects' sd (0: inverse Hessian/HAC, "
                   "faster but optimistic)")
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
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--hours", type=float, default=24.0)
    e.add_argument("--dt", type=float, default=10.0, help="sampling interval, s")
    e.add_argument("--effect", action="append", default=[], metavar="NAME:key=value",
                   help="switch on an effect, e.g. sensor_lag:tau_s=60 (repeatable)")
    e.add_argument("--T-noise", dest="T_noise", type=float, default=0.01, help="temperature noise sd, degC")
    e.add_argument("--x-noise", dest="x_noise", type=float, default=2.4e-3, help="opening noise sd, mm")
    e.add_argument("--jitter", type=float, default=0.0, help="uneven sampling, fraction of dt (< 0.5)")
    e.add_argument("--no-truth", action="store_true", help="leave out the true_* columns")
    e.add_argument("--out", required=True, metavar="RUN.csv")
    e.add_argument("--force", action="store_true", help="overwrite an existing output file")
    e.set_defaults(func=_cmd_experiment)


def _cmd_experiment(args: argparse.Namespace) -> int:
    from valve_env.experiment import parse_effect, simulate_experiment
    from valve_env.params import ConfigError

    out = Path(args.out)
    if out.exists() and not args.force:
        return _fail(f"{out} exists; use --force to overwrite it")
    try:
        effects: dict[str, dict[str, float]] = {}
        for text in args.effect:
            name, pars = parse_effect(text)
            if name in effects:
                raise ConfigError(f"effect {name!r} given twice")
            effects[name] = pars
        df = simulate_experiment(seed=args.seed, duration_h=args.hours, dt_s=args.dt, effects=effects,
                                 T_noise_C=args.T_noise, x_noise_mm=args.x_noise, jitter=args.jitter)
    except ConfigError as exc:
        return _fail(str(exc))
    except MemoryError:
        return _fail(f"out of memory for {args.hours:g} h at {args.dt:g} s", EXIT_ERROR)
    if args.no_truth:
        df = df[[c for c in df.columns if not c.startswith("true_")]]
    try:
        if out.parent and not out.parent.exists():
            return _fail(f"directory {out.parent} does not exist")
        df.to_csv(out, index=False, float_format="%.9g")
    except OSError as exc:
        return _fail(f"cannot write {out}: {exc.strerror or exc}")
    desc = ", ".join(f"{k}({', '.join(f'{p}={v:g}' for p, v in d.items())})" for k, d in effects.items()) or "none"
    print(f"wrote {out}: {len(df)} samples, {args.hours:g} h at {args.dt:g} s, effects: {desc}")
    return 0


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from valve_env.diagnosis.diagnose import DiagnosisError, diagnose_files

    out = Path(args.json_out)
    for path in (args.run, args.validate):
        if path is not None and Path(path).resolve() == out.resolve():
            return _fail(f"--json {out} would overwrite the input {path}")
    if not out.parent.is_dir():
        return _fail(f"cannot write {out}: directory {out.parent} does not exist")
    if out.is_dir():
        return _fail(f"cannot write {out}: is a directory")
    if not 0.05 <= args.holdout <= 0.5:
        return _fail(f"--holdout must be in [0.05, 0.5], got {args.holdout}")
    if not 0 < args.alpha < 0.5:
        return _fail(f"--alpha must be in (0, 0.5), got {args.alpha}")
    if args.bootstrap < 0:
        return _fail(f"--bootstrap must be >= 0, got {args.bootstrap}")
    effects = None
    if args.effects:
        effects = [s.strip() for s in args.effects.split(",") if s.strip()]
    from valve_env.outputs import OutputError, OutputSet

    valve_outs = OutputSet(inputs=[args.run, args.validate, args.json_out], force=getattr(args, "force", False))
    try:  # declared before the work (docs/reference.md, "The valve file")
        valve_out = valve_outs.add(args.valve_out, "--valve-out") if args.valve_out else None
    except OutputError as exc:
        return _fail(str(exc))
    try:
        result = diagnose_files(args.run, validate=args.validate, holdout=args.holdout, alpha=args.alpha,
                                effects=effects, bootstrap_B=args.bootstrap)
    except DiagnosisError as exc:
        return _fail(str(exc))
    except MemoryError:
        return _fail("out of memory", EXIT_ERROR)
    except Exception as exc:  # noqa: BLE001 - never a bare traceback; name the failure in one line
        return _fail(f"diagnosis failed: {type(exc).__name__}: {' '.join(str(exc).split())}", EXIT_ERROR)
    try:
        out.write_text(json.dumps(_clean(result.to_json()), indent=2) + "\n")
    except OSError as exc:
        return _fail(f"cannot write {out}: {exc.strerror or exc}")
    if not args.no_report:
        from valve_env.diagnosis.report import write_report

        report = Path(args.report) if args.report else out.with_suffix(".md")
        try:
            write_report(result, report)
        except OSError as exc:
            return _fail(f"cannot write the report {report}: {exc.strerror or exc}")
        except Exception as exc:  # noqa: BLE001 - the JSON is written; report the failure in one line
            return _fail(f"report failed: {type(exc).__name__}: {' '.join(str(exc).split())}", EXIT_ERROR)
        print(f"report: {report}")
    if valve_out is not None:
        from valve_env.valvefile import write_valve

        try:
            write_valve(valve_outs, valve_out, result.final.params,
                        {e: {k: result.final.params[k] for k in EFFECTS[e].param_names} for e in result.selected},
                        source=f"diagnosed by thermovalve diagnose {args.run}: cause {result.cause}")
            valve_outs.commit()
        except (OSError, ValueError) as exc:
            return _fail(f"cannot write {valve_out}: {exc}")
        print(f"valve file: {valve_out}")
    print(result.summary())
    return 0


def _clean(obj: Any) -> Any:
    """JSON has no NaN/inf: write them as null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj
