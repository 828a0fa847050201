"""Loop records written the ways plants write them, several conventions at once, through ``loop-diagnose`` as a user
calls it: a result with finite numbers (the cause one of the format's), or a refusal in one line (exit 2).

The reader's tests (tests/loops/test_io.py) take each convention alone; here they are stacked on simulated loops of
wide variety (:func:`valve_env.loops.sim.random_case`): a historian's states and repeated rows, a spreadsheet's
semicolons, decimal commas, units row and error values, a mode by name, rounding, storage on change (the value held, or
empty between changes), jitter, dropped samples, OP as a fraction, in engineering units or in mA, a logical mode,
extra columns in any order, another interval, a short record, a logger's comment lines among the data and a
historian's -9999 sentinels.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from valve_env.cli import main
from valve_env.loops.diagnose import CAUSES
from valve_env.loops.sim import random_case, simulate_case
from valve_env.studies.conventions import store_on_change

#: the conventions of a loop record's file (:func:`loop_file`)
LOOP_CONVENTIONS = ("quantised", "stored_on_change", "dropped_10", "jitter_20", "op_fraction", "op_eng", "sheet",
                    "mode_names", "extra_columns", "historian", "every_other", "first_40_min", "logger_comments",
                    "sentinels", "op_ma", "mode_logical", "own_times", "pv_on_change")


def loop_file(df: pd.DataFrame, names: list[str], rng: np.random.Generator) -> str:
    """The loop record ``df`` (time_s, sp, pv, op) as a file under the conventions ``names``."""
    span = float(np.ptp(df.pv)) or 1.0
    if "every_other" in names:  # another interval
        df = df.iloc[::2].reset_index(drop=True)
    if "first_40_min" in names:  # a record shorter than the test needs
        df = df[df.time_s <= df.time_s.iloc[0] + 2400.0].reset_index(drop=True)
    if "quantised" in names:  # a historian's rounding to about a twentieth of the PV's span, OP to 0.1 %
        q = 10.0 ** math.floor(math.log10(span / 20.0))
        df = df.assign(pv=np.round(df.pv / q) * q, sp=np.round(df.sp / q) * q, op=np.round(df.op, 1))
    if "stored_on_change" in names:  # an exception deadband of 2 % of the span
        df = df.assign(pv=store_on_change(df.pv.to_numpy(), span / 50.0))
    if "jitter_20" in names:
        dt = float(np.median(np.diff(df.time_s)))
        t = df.time_s.to_numpy() + rng.uniform(-0.1, 0.1, len(df)) * dt
        df = df.assign(time_s=np.round(t, 3))
    if "dropped_10" in names:
        df = df.drop(index=rng.choice(np.arange(1, len(df) - 1), size=len(df) // 10, replace=False))
        df = df.reset_index(drop=True)
    if "op_fraction" in names:
        df = df.assign(op=df.op / 100.0)
    elif "op_eng" in names:  # OP in engineering units: a flow controller's output as its set point, 0-250 m3/h
        df = df.assign(op=2.5 * df.op)
    elif "op_ma" in names:  # OP as a 4-20 mA signal's current, its unit in the header (or the units row)
        df = df.assign(op=4.0 + 0.16 * df.op)
    df = df.astype(object)
    if "mode_names" in names:  # manual for the first tenth
        df["mode"] = np.where(np.arange(len(df)) < len(df) // 10, "MAN", "AUTO")
    elif "mode_logical" in names:  # a logical column, as pandas writes one
        df["mode"] = np.where(np.arange(len(df)) < len(df) // 10, "False", "True")
    if "own_times" in names:  # tags on the union of their timestamps: the PV on every other row, the SP on change
        sp = df["sp"].to_numpy(dtype=float)
        df.loc[np.arange(len(df)) % 2 == 1, "pv"] = ""
        df.loc[np.r_[False, sp[1:] == sp[:-1]], "sp"] = ""
    elif "pv_on_change" in names:  # the PV stored on change (2 % of its span), exported on the union of the tags'
        held = store_on_change(df["pv"].to_numpy(dtype=float), span / 50.0)  # times: empty between its changes
        df["pv"] = held.astype(object)
        df.loc[np.r_[False, held[1:] == held[:-1]], "pv"] = ""
    if "extra_columns" in names:
        df["timestamp"] = (pd.Timestamp("2026-03-01") + pd.to_timedelta(df.time_s.astype(float), unit="s")).astype(str)
        df["quality"] = "Good"
        df["T_amb"] = np.round(20.0 + rng.normal(0.0, 0.3, len(df)), 2)
        cols = list(df.columns)
        rng.shuffle(cols)
        df = df[cols]
    if "historian" in names:  # a PI historian's states in place of values, and rows written twice
        for c in ("pv", "op"):
            rows = rng.choice(np.arange(1, len(df) - 1), size=max(1, len(df) // 200), replace=False)
            df.loc[rows, c] = rng.choice(["I/O Timeout", "Bad Input", "No Data"], size=rows.size)
        twice = rng.choice(np.arange(1, len(df) - 1), size=max(1, len(df) // 100), replace=False)
        df = df.iloc[np.sort(np.concatenate([np.arange(len(df)), twice]))].reset_index(drop=True)
    if "sentinels" in names:  # a historian's -9999 where it had no value, on two isolated samples of PV and one of OP
        for c, k in (("pv", 2), ("op", 1)):
            rows = rng.choice(np.arange(5, len(df) - 5, 10), size=k, replace=False)
            df.loc[rows, c] = -9999.0
    sep, comma = (";", True) if "sheet" in names else (",", False)
    if "sheet" in names:  # a spreadsheet's error values
        rows = rng.choice(np.arange(1, len(df) - 1), size=max(1, len(df) // 300), replace=False)
        df.loc[rows, "pv"] = "#N/A"

    def cell(v: object) -> str:
        if isinstance(v, (float, int, np.floating, np.integer)):
            text = f"{float(v):.10g}"
            return text.replace(".", ",") if comma else text
        return str(v)

    ma = "op_ma" in names and not {"op_fraction", "op_eng"} & set(names)
    lines = [sep.join("op [mA]" if ma and c == "op" and "sheet" not in names else str(c) for c in df.columns)]
    if "sheet" in names:  # its units row
        units = {"time_s": "s", "sp": "m3/h", "pv": "m3/h", "op": "mA" if ma else "%"}
        lines.append(sep.join(units.get(str(c), "") for c in df.columns))
    lines += [sep.join(cell(v) for v in row) for row in df.itertuples(index=False)]
    if "logger_comments" in names:  # a logger's restarts among the data, one with an empty line after it
        n = len(lines)
        lines.insert(2 * n // 3, "")
        lines.insert(2 * n // 3, "# logger restarted")
        lines.insert(n // 3, "# logger restarted")
    return "\n".join(lines) + "\n"


@pytest.mark.slow
@settings(max_examples=10, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(names=st.lists(st.sampled_from(LOOP_CONVENTIONS), min_size=2, max_size=4, unique=True),
       seed=st.integers(0, 10_000), plant=st.booleans(), quantify=st.booleans())
@example(names=["historian", "mode_names", "quantised", "sheet", "stored_on_change"], seed=13, plant=False,
         quantify=True)
@example(names=["first_40_min", "jitter_20", "op_fraction"], seed=5, plant=True, quantify=False)
@example(names=["sentinels", "op_eng", "dropped_10"], seed=7, plant=False, quantify=True)
@example(names=["op_ma", "sheet", "mode_logical"], seed=17, plant=True, quantify=True)
def test_stacked_loop_conventions_give_finite_results_or_refuse_in_one_line(
        tmp_path_factory: pytest.TempPathFactory, capsys: pytest.CaptureFixture[str], names: list[str], seed: int,
        plant: bool, quantify: bool) -> None:
    loop, _ = simulate_case(random_case(seed, plant=plant))
    df = pd.DataFrame({"time_s": loop.time_s, "sp": loop.sp, "pv": loop.pv, "op": loop.op})
    tmp = tmp_path_factory.mktemp("loop")
    path = tmp / "loop.csv"
    path.write_text(loop_file(df, names, np.random.default_rng(seed)))
    out = tmp / "out.json"
    code = main(["loop-diagnose", str(path), "--json", str(out), "--report", str(tmp / "rep")]
                + (["--quantify"] if quantify else []))
    err = capsys.readouterr().err
    if code == 0:
        text = out.read_text()
        assert "NaN" not in text and "Infinity" not in text
        res = json.loads(text)
        assert res["cause"] in CAUSES
        if "stiction" in res:
            assert all(math.isfinite(v) for v in res["stiction"].values() if isinstance(v, float))
        assert (tmp / "rep" / "report.md").stat().st_size > 0
    else:
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("thermovalve: error: "), err
        assert not re.search(r"\b\w+Error\b", lines[0].split(": ", 2)[-1].split(" ")[0]), err


def test_the_loop_file_conventions_are_read(tmp_path: Path) -> None:
    """Each convention above alone gives a file the reader takes, with what it read other than data noted (the
    property test stacks them on files a user could write)."""
    from valve_env.loops.io import read_loop

    loop, _ = simulate_case(random_case(11))
    df = pd.DataFrame({"time_s": loop.time_s, "sp": loop.sp, "pv": loop.pv, "op": loop.op})
    noted = {"dropped_10": "resampled", "jitter_20": "resampled", "op_eng": "engineering units",
             "op_fraction": "within 0 to 1", "sheet": "units row", "mode_names": "manual mode",
             "historian": "missing value", "logger_comments": "comment line(s) among the data",
             "sentinels": "far outside their column's record", "op_ma": "4-20 mA", "mode_logical": "manual mode",
             "own_times": "on their own times", "pv_on_change": "held from each to the next"}
    for name in LOOP_CONVENTIONS:
        p = tmp_path / f"{name}.csv"
        p.write_text(loop_file(df, [name], np.random.default_rng(11)))
        read = read_loop(p)
        assert read.n >= (200 if name == "first_40_min" else 0.4 * loop.n), name
        if name in noted:
            assert any(noted[name] in note for note in read.notes), (name, read.notes)
