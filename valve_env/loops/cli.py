"""``thermovalve loop-diagnose LOOP.csv --json OUT.json [--report DIR] [--bootstrap-test] [--force]``
(docs/loops.md)."""

from __future__ import annotations

import argparse
from typing import Any

from valve_env.cli import add_force, check_range


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "loop-diagnose",
        help="diagnose a control loop's record: stiction (with its band) or another cause",
        description="Fit a grey-box loop model (linear, backlash and stick-slip valve behind a first-order or "
        "integrating process) by maximum likelihood, compare by likelihood ratio, BIC and held-out data, "
        "and name the cause. Reads the loop CSV (time_s, sp, pv, op[, mv, mode]) or a plant-historian export.",
    )
    p.add_argument("loop", metavar="LOOP.csv", help="loop record (loop CSV or historian export)")
    p.add_argument("--json", dest="json_out", metavar="OUT.json", required=True, help="where to write the result")
    p.add_argument("--report", metavar="DIR", default=None, help="write report.md and figures into DIR")
    p.add_argument("--alpha", type=float, default=0.01, help="significance level of the likelihood-ratio test")
    p.add_argument("--bootstrap-test", action="store_true",
                   help="also run the parametric-bootstrap LR test's replicates (reported in decision.bootstrap, "
                   "not part of the decision; up to a third of the run time); without it only its LR scan is reported")
    add_force(p)
    p.set_defaults(func=_cmd)


def _cmd(args: argparse.Namespace) -> int:
    """Bad input raises (LoopDataError, OutputError, UsageError): valve_env.cli's shared handler prints
    one line and exits 2; the outputs are declared up front and written together."""
    from valve_env.loops.diagnose import diagnose
    from valve_env.loops.io import read_loop
    from valve_env.outputs import OutputSet, json_text

    check_range("--alpha", args.alpha, 0.0, 0.5, lo_open=True, hi_open=True)
    outs = OutputSet(inputs=[args.loop], force=args.force)
    json_path = outs.add(args.json_out, "--json")
    report_dir = None
    if args.report is not None:
        from valve_env.loops.report import FIGURES

        report_dir = outs.add_dir(args.report, "--report")
        for name in (*FIGURES, "report.md"):
            outs.add(report_dir / name, "report file")
    loop = read_loop(args.loop)
    diag = diagnose(loop, alpha=args.alpha, bootstrap=args.bootstrap_test)
    with outs:
        outs.write_text(json_path, json_text(diag.result))
        if report_dir is not None:
            from valve_env.loops.report import write_report

            write_report(diag, outs, report_dir)
    R = diag.result
    band = ""
    if "stiction" in R:
        band = f", band {R['stiction']['band_pct']:.3g} +/- {R['stiction']['std_pct']:.2g} % of OP"
    print(f"{loop.tag}: {R['cause']}{band}; {outs.summary()}")
    for note in R["notes"]:
        print(f"note: {note}")
    return 0


__all__ = ["register"]
