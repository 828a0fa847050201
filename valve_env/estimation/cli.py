"""``thermovalve fit``: the base valve model fitted to a measured run (docs/reference.md, section 7).

    thermovalve fit RUN.csv --json OUT.json [--report DIR] [--config OUT.yaml]
                            [--validate OTHER.csv] [--n-starts N] [--seed S]

writes {"params": {"sigma", "F_hmax", "p_bset"}, "std": {...}, "loglik", "rms_mm", "n", ...}.
``params`` holds ValveParams fields only, so it passes straight to
``gym.make("ThermoValve-v0", valve=params)``; ``--config`` writes ``valve: {...}`` for the
environment's YAML configuration. Bad input: exit status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Any

EXIT_BAD_INPUT = 2
EXIT_FAILED = 1


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "fit",
        help="fit the base valve model to a measured run (maximum likelihood)",
        description="Fit the base valve model (docs/reference.md, section 1) to RUN.csv (docs/reference.md, "
                    "section 2) by maximum likelihood and write the estimates as JSON.",
    )
    p.add_argument("run", metavar="RUN.csv", help="measured run (docs/reference.md, section 2 columns)")
    p.add_argument("--json", dest="json_out", metavar="OUT.json", required=True, help="where to write the result")
    p.add_argument("--report", metavar="DIR", default=None,
                   help="write figures and a markdown report (Table 4, Fig. 5-7) into DIR")
    p.add_argument("--config", metavar="OUT.yaml", default=None,
                   help="write an environment config with the fitted 'valve:' parameters")
    p.add_argument("--valve-out", metavar="VALVE.yaml", default=None,
                   help="write the fitted valve as a valve file for gym.make(id, config=VALVE.yaml) "
                   "(docs/reference.md)")
    p.add_argument("--validate", metavar="OTHER.csv", default=None,
                   help="an independent run for cross-validation (paper Fig. 7)")
    p.add_argument("--n-starts", type=int, default=3, help="optimiser starts (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the extra starts (default 0)")
    p.set_defaults(func=run_fit)


def _fail(msg: str, code: int) -> int:
    line = " ".join(str(msg).split())
    print(f"thermovalve fit: {line}", file=sys.stderr)
    return code


def run_fit(args: argparse.Namespace) -> int:
    from valve_env.data_io import DataError, load_run

    try:
        data = load_run(args.run)
        validation = load_run(args.validate) if args.validate else None
    except DataError as exc:
        return _fail(str(exc), EXIT_BAD_INPUT)
    if args.n_starts < 1:
        return _fail("--n-starts must be at least 1", EXIT_BAD_INPUT)
    from valve_env.outputs import OutputError, OutputSet

    valve_outs = OutputSet(inputs=[args.run, args.validate, args.json_out], force=getattr(args, "force", False))
    try:  # declared before the work (docs/reference.md, "The valve file")
        valve_out = valve_outs.add(args.valve_out, "--valve-out") if args.valve_out else None
    except OutputError as exc:
        return _fail(str(exc), EXIT_BAD_INPUT)
    try:
        from valve_env.estimation.report import fit_run, fit_summary, write_report

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = fit_run(data, n_starts=args.n_starts, seed=args.seed)
            summary = fit_summary(est, data, validation)
            if args.report:
                write_report(est, data, args.report, summary, validation, name=Path(args.run).stem)
                summary["report"] = str(Path(args.report) / "report.md")
        out = Path(args.json_out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(summary, indent=2, allow_nan=False))
        if args.config:
            import yaml

            cfg = Path(args.config)
            cfg.parent.mkdir(parents=True, exist_ok=True)
            cfg.write_text(yaml.safe_dump({"valve": summary["params"]}, sort_keys=False))
        if valve_out is not None:
            from valve_env.valvefile import write_valve

            write_valve(valve_outs, valve_out, summary["params"], source=f"fitted by thermovalve fit {args.run}")
            valve_outs.commit()
    except (OSError, ValueError) as exc:
        return _fail(f"{type(exc).__name__}: {exc}", EXIT_FAILED)
    p = summary["params"]
    s = summary["std"]
    print(f"sigma = {p['sigma']:.4g} ({_sd(s['sigma'])}) N/K, F_hmax = {p['F_hmax']:.4g} ({_sd(s['F_hmax'])}) N, "
          f"p_bset = {p['p_bset']:.5g} ({_sd(s['p_bset'])}) MPa; loglik {summary['loglik']:.1f}, "
          f"rms {summary['rms_mm']:.3g} mm, n {summary['n']} -> {args.json_out}")
    for m in summary["identifiability"]:
        print(f"warning: {m}", file=sys.stderr)
    return 0


def _sd(v: float | None) -> str:
    return "-" if v is None else f"{v:.2g}"
