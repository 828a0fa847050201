"""``thermovalve loop-diagnose LOOP.csv --json OUT.json [--report DIR] [--quantify] [--tag TAG] [--force]``
(docs/loops.md)."""

from __future__ import annotations

import argparse
from typing import Any

from valve_env.cliutil import add_force, stage_progress
from valve_env.loops.detect import DEFAULT_RULE, RULES


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "loop-diagnose",
        help="diagnose a control loop's record: stiction (with its band) or another cause",
        description="Detect valve stiction with Horch's cross-correlation test (the published shape tests of He, "
        "Kano, Choudhury's bicoherence and the OP-PV ellipse reported beside it; --rule learned combines them by a "
        "rule learned on simulated loops), and quantify the band (S and J, % of OP) with a grey-box loop model "
        "fitted by maximum likelihood. Reads the loop CSV (time_s, sp, pv, op[, mv, mode]) or a plant-historian "
        "export.",
    )
    p.add_argument("loop", metavar="LOOP.csv", help="loop record (loop CSV or historian export)")
    p.add_argument("--json", dest="json_out", metavar="OUT.json", required=True, help="where to write the result")
    p.add_argument("--report", metavar="DIR", default=None, help="write report.md and figures into DIR")
    p.add_argument("--quantify", action="store_true",
                   help="fit the stick-slip band even when stiction is not detected (the cause is unchanged)")
    p.add_argument("--rule", choices=RULES, default=DEFAULT_RULE,
                   help="the detection's decision: horch (default; Horch's test as published) or learned (the "
                   "shape tests combined by a logistic regression fitted on simulated loops; docs/loops.md)")
    p.add_argument("--tag", default=None,
                   help="the loop to read from a historian export that holds several (its tag, before .MV/.PV/.SV)")
    add_force(p)
    p.set_defaults(func=_cmd)


def _cmd(args: argparse.Namespace) -> int:
    """Bad input raises (LoopDataError, OutputError, UsageError): valve_env.cli's shared handler prints
    one line and exits 2; the outputs are declared up front and written together."""
    from valve_env.loops.diagnose import diagnose_loop
    from valve_env.loops.io import read_loop
    from valve_env.loops.report import band_text
    from valve_env.outputs import OutputSet, json_text

    outs = OutputSet(inputs=[args.loop], force=args.force)
    json_path = outs.add(args.json_out, "--json")
    report_dir = None
    if args.report is not None:
        from valve_env.loops.report import FIGURES

        report_dir = outs.add_dir(args.report, "--report")
        for name in (*FIGURES, "report.md"):
            outs.add(report_dir / name, "report file")
    loop = read_loop(args.loop, tag=args.tag)
    with stage_progress(4, "loop") as tick:
        diag = diagnose_loop(loop, quantify=True if args.quantify else None, rule=args.rule, progress=tick)
    with outs:
        outs.write_text(json_path, json_text(diag.result))
        if report_dir is not None:
            from valve_env.loops.report import write_loop_report

            write_loop_report(diag, outs, report_dir)
    R = diag.result
    what = R["cause"]
    if R["cause"] == "insufficient_data":
        what += f" ({R['reason']})"
    if "stiction" in R:
        what += f"; {band_text(R['stiction'])}"
    print(f"{loop.tag}: {what}; {outs.summary()}")
    for note in R["notes"]:
        print(f"note: {note}")
    return 0


__all__ = ["register"]
