"""Reading and checking loop records: both formats, the one-line errors, manual-mode segments."""

from __future__ import annotations

import gzip
import re
from collections.abc import Callable
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from valve_env.loops.io import LoopDataError, read_loop

DATA = Path(__file__).parents[1] / "data" / "plant_loops"
STICKY = DATA / "2411FIC20102_1008_1552.txt"


def _write_csv(path: Path, n: int = 300, **override: np.ndarray) -> Path:
    t = np.arange(n) * 10.0
    cols = {"time_s": t, "sp": np.full(n, 50.0), "pv": 50.0 + np.sin(t / 300.0),
            "op": 40.0 + 5.0 * np.cos(t / 300.0)}
    cols.update(override)
    names = list(cols)
    rows = [",".join(names)] + [",".join(f"{cols[c][i]:.6g}" for c in names) for i in range(n)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_historian_export_is_read() -> None:
    loop = read_loop(STICKY)
    assert loop.tag == "2411FIC20102"
    assert loop.n == 751
    assert loop.dt == pytest.approx(10.0)
    assert 20.0 < loop.op.mean() < 30.0 and 95.0 < loop.pv.mean() < 110.0
    assert loop.notes == []


def test_loop_csv_round_trip(tmp_path: Path) -> None:
    loop = read_loop(STICKY)
    p = tmp_path / "loop.csv"
    p.write_text(loop.to_csv_text())
    again = read_loop(p)
    np.testing.assert_allclose(again.op, loop.op, rtol=1e-9)
    np.testing.assert_allclose(again.pv, loop.pv, rtol=1e-9)


@pytest.mark.parametrize(("override", "needle"), [
    ({"pv": np.where(np.arange(300) % 5 == 2, np.nan, 50.0)},
     r"60 of 300 samples \(20%\) miss a value \(column pv first, at sample 3\); at most 10%"),
    ({"pv": np.where(np.arange(300) == 17, np.inf, 50.0)}, "column pv has 1 NaN/infinite"),
    ({"time_s": np.r_[np.arange(100) * 10.0, np.arange(200) * 10.0]}, "time is not strictly increasing at sample 101"),
    # a time in milliseconds or in a spreadsheet's days: read as seconds, the loop's dynamics would be 1000 times off
    # (a 10 s record in ms was named aggressive_tuning where the record in s is external_oscillation)
    ({"time_s": np.arange(300) * 10000.0}, r"column time_s: median sampling interval 1e\+04 s is implausible "
                                           r"\(expected 0.001 to 3600 s\); if time_s is in milliseconds, divide it by "
                                           r"1000$"),
    ({"time_s": np.arange(300) * 10.0 / 86400.0}, r"if time_s is in days \(a spreadsheet's date number\), "
                                                 r"multiply it by 86400$"),
])
def test_bad_records_name_the_problem(tmp_path: Path, override: dict, needle: str) -> None:
    p = _write_csv(tmp_path / "bad.csv", **override)
    with pytest.raises(LoopDataError, match=needle) as exc:
        read_loop(p)
    assert "\n" not in str(exc.value)


def test_samples_missing_a_value_are_dropped_and_resampled_over(tmp_path: Path) -> None:
    """A historian that did not store a value (an empty cell, a NaN marker): the sample is dropped with a note and
    the record resampled onto its interval, so the loop keeps its grid."""
    p = _write_csv(tmp_path / "gaps.csv", pv=np.where(np.isin(np.arange(300), [17, 18, 200]), np.nan, 50.0))
    text = p.read_text().replace(",nan,", ",,", 1).replace(",nan,", ",#N/A,", 1)
    p.write_text(text)
    loop = read_loop(p)
    assert loop.n == 300 and loop.dt == pytest.approx(10.0) and np.isfinite(loop.pv).all()
    assert any(n.startswith("dropped 3 sample(s) with a missing value (first: column pv at sample 18)")
               for n in loop.notes)


def test_op_in_engineering_units_is_scaled_by_its_range(tmp_path: Path) -> None:
    """An OP beyond -10..110 % (a DCS exporting engineering units) is mapped onto 0-100 % by its observed range,
    with a note naming the range; an OP within it is read as it is."""
    op = 1040.0 + 5.0 * np.cos(np.arange(300) / 30.0)
    loop = read_loop(_write_csv(tmp_path / "eu.csv", op=op))
    assert loop.op_scaled_from == pytest.approx((op.min(), op.max()))
    assert loop.op.min() == pytest.approx(0.0) and loop.op.max() == pytest.approx(100.0)
    np.testing.assert_allclose(loop.op, 100.0 * (op - op.min()) / np.ptp(op), atol=0.1)  # the CSV holds 6 digits
    assert any("scaled by its observed range" in n and "1035" in n for n in loop.notes)
    plain = read_loop(_write_csv(tmp_path / "pct.csv"))
    assert plain.op_scaled_from is None and plain.notes == []
    # an OP within 0-1 throughout may be a fraction: read as %, and said
    frac = read_loop(_write_csv(tmp_path / "frac.csv", op=0.4 + 0.05 * np.cos(np.arange(300) / 30.0)))
    assert frac.op_scaled_from is None and frac.op.max() < 1.0
    assert any("if the export gives OP as a fraction" in n for n in frac.notes)


def test_a_historians_sentinels_and_gross_spikes_are_read_as_missing(tmp_path: Path) -> None:
    """-9999 where the historian had no value, and a spike of ten times the PV, in short isolated runs: read as
    missing, with a note naming the samples, and the record resampled over them. Left in, one -9999 in the OP made
    the OP's observed range its scale (every band in % of a 10,000-unit range)."""
    n = 300
    pv = 50.0 + np.sin(np.arange(n) * 10.0 / 300.0)
    op = 40.0 + 5.0 * np.cos(np.arange(n) * 10.0 / 300.0)
    bad_pv = np.where(np.isin(np.arange(n), [40, 41]), -9999.0, np.where(np.arange(n) == 150, 10.0 * pv, pv))
    bad_op = np.where(np.arange(n) == 0, -9999.0, op)  # the first sample too
    loop = read_loop(_write_csv(tmp_path / "sentinel.csv", pv=bad_pv, op=bad_op))
    clean = read_loop(_write_csv(tmp_path / "clean.csv", pv=pv, op=op))
    assert loop.op_scaled_from is None
    assert loop.notes[0].startswith("read 4 value(s) far outside their column's record as missing")
    assert "pv at sample(s) 41, 42, 151 (-9999 first)" in loop.notes[0] and "op at sample(s) 1 (-9999" in loop.notes[0]
    assert loop.pv.min() > 48.9 and loop.pv.max() < 51.1 and loop.op.min() > 34.9
    np.testing.assert_allclose(loop.pv[60:140], clean.pv[61:141], atol=1e-4)  # the grid starts at the second sample
    assert clean.notes == []
    held = np.full(n, 50.0)  # a set point held throughout (its central width 0): a sentinel in it is still one
    loop = read_loop(_write_csv(tmp_path / "held.csv", sp=np.where(np.arange(n) == 200, -9999.0, held)))
    assert loop.notes[0].startswith("read 1 value(s)") and "sp at sample(s) 201 (-9999 first)" in loop.notes[0]


def test_an_operators_brief_set_point_change_is_kept(tmp_path: Path) -> None:
    """A set point held for most of the record and changed by an operator for two samples (0.6 and 0.2 below it,
    within the PV's swing): before, its central width was 0, so any change was 'far outside', and the change was read
    as a historian's sentinel, dropped, and resampled over; now the PV's width is the set point's floor."""
    n = 300
    sp = np.full(n, 50.0)
    sp[120:122] = [49.4, 49.8]
    loop = read_loop(_write_csv(tmp_path / "bump.csv", sp=sp))
    assert loop.notes == [] and loop.n == n and loop.sp.min() == pytest.approx(49.4)


@pytest.mark.parametrize("kind", ["kick", "frequent", "long"])
def test_what_may_be_the_plants_own_is_kept(tmp_path: Path, kind: str) -> None:
    """A controller's kick at a set-point step rises and decays through its neighbours; excursions on more than 1 % of
    the samples, or longer than three samples, may be the plant's: each is kept as recorded."""
    n = 300
    op = 40.0 + 0.5 * np.cos(np.arange(n) * 10.0 / 300.0)
    if kind == "kick":
        op[150:157] += np.array([6.0, 14.0, 11.0, 7.0, 4.0, 2.0, 1.0])
    elif kind == "frequent":
        op[np.arange(10, n, 25)] = 90.0  # 12 of 300 samples: 4 %
    else:
        op[100:104] = 90.0
    loop = read_loop(_write_csv(tmp_path / f"{kind}.csv", op=op))
    assert loop.notes == [] and loop.op.max() == pytest.approx(op.max(), rel=1e-5)


def test_short_record_is_read_and_missing_column_refused(tmp_path: Path) -> None:
    """A well-formed short record is read (the diagnosis names it insufficient_data); a malformed file is refused."""
    assert read_loop(_write_csv(tmp_path / "short.csv", n=50)).n == 50
    with pytest.raises(LoopDataError, match="a record needs at least two"):
        read_loop(_write_csv(tmp_path / "one.csv", n=1))
    p = tmp_path / "nocol.csv"
    p.write_text("time_s,sp,pv\n0,1,2\n")
    with pytest.raises(LoopDataError, match=r"missing column\(s\) op \(need time_s, sp, pv, op\)$"):
        read_loop(p)
    # a historian's clock instead of time_s: the refusal names the clock column and what to give
    clock = tmp_path / "clock.csv"
    clock.write_text("stamp,sp,pv,op\n" + "".join(f"2026-03-01 06:{m:02d}:00,1,2,{40 + m % 3}\n" for m in range(30)))
    with pytest.raises(LoopDataError, match=r"missing column\(s\) time_s .*; column 'stamp' holds date-times"):
        read_loop(clock)
    rows = "".join(f"01.03.2026;06:{m:02d}:00;1;2;{40 + m % 3}\n" for m in range(30))
    clock.write_text("Date;Time;sp;pv;op\n" + rows)
    with pytest.raises(LoopDataError, match=r"columns 'Date' and 'Time' hold a date and a time of day"):
        read_loop(clock)
    upper = tmp_path / "upper.csv"  # a name in another case: the refusal names it
    upper.write_text("time_s,SP,PV,OP\n" + "".join(f"{10 * k},1,2,{40 + k % 3}\n" for k in range(30)))
    with pytest.raises(LoopDataError, match=r"missing column\(s\) sp, pv, op .*; the header has 'SP', 'PV', 'OP': "
                                            r"rename them sp, pv, op"):
        read_loop(upper)
    # a unit after an underscore (before: the missing columns named, with no hint)
    upper.write_text("time_s,sp_degC,pv_degC,op_pct\n" + "".join(f"{10 * k},1,2,{40 + k % 3}\n" for k in range(30)))
    with pytest.raises(LoopDataError, match=r"missing column\(s\) sp, pv, op .*; the header has 'sp_degC', 'pv_degC', "
                                            r"'op_pct': if these are sp, pv, op with a unit, name them sp, pv, op, or "
                                            r"give the unit in brackets \('sp \[degC\]', which is read\)$"):
        read_loop(upper)


def test_every_missing_column_is_named_at_once(tmp_path: Path) -> None:
    """A header whose names are all in another case or spelling (``Time (s), SP, PV, OP``) is told every rename in
    one line, not one per attempt (before, only time_s's)."""
    upper = _write_text(tmp_path / "upper.csv", "Time (s),SP,PV,OP\n" + "".join(f"{10 * k},1,2,{40 + k % 3}\n"
                                                                               for k in range(30)))
    with pytest.raises(LoopDataError, match=r"missing column\(s\) time_s, sp, pv, op .*; the header has 'Time \(s\)', "
                                            r"'SP', 'PV', 'OP': rename them time_s, sp, pv, op \(names are exact\)$"):
        read_loop(upper)
    mixed = _write_text(tmp_path / "mixed.csv", "time_min,Setpoint,PV,op\n" + "".join(
        f"{k},1,2,{40 + k % 3}\n" for k in range(30)))
    with pytest.raises(LoopDataError, match=r"the header has 'time_min', a time not in seconds: .*; if 'Setpoint' is "
                                            r"the set point, name it sp .*; the header has 'PV': rename it pv"):
        read_loop(mixed)


def test_columns_named_by_their_historian_tags_are_named_in_the_refusal(tmp_path: Path) -> None:
    """A loop CSV whose columns carry the historian's tag names (``FIC101.SP``, ``FIC101.PV``, ``FIC101.OP``; a DCS's
    ``.SV`` and ``.MV`` alike) is told which to rename (before: the missing columns alone), and one loop's where the
    header holds two loops' tags."""
    body = "".join(f"{10 * k},1,2,{40 + k % 3},3,4,5\n" for k in range(30))
    one = _write_text(tmp_path / "one.csv", "time_s,FIC101.SP,FIC101.PV,FIC101.OP,T1,T2,T3\n" + body)
    with pytest.raises(LoopDataError, match=r"missing column\(s\) sp, pv, op .*; the header has 'FIC101.SP', "
                                            r"'FIC101.PV', 'FIC101.OP', tag names as a historian writes them: rename "
                                            r"them sp, pv, op \(names are exact\)$"):
        read_loop(one)
    two = _write_text(tmp_path / "two.csv", "time_s,sp,FIC101.PV,FIC101.MV,FIC102.PV,FIC102.OP,T3\n" + body)
    with pytest.raises(LoopDataError, match=r"missing column\(s\) pv, op .*; the header has 'FIC101.PV', 'FIC101.MV', "
                                            r"tag names .*: rename them pv, op \(names are exact\); the header holds 2 "
                                            r"loops' tags \(FIC101, FIC102\): give one loop's$"):
        read_loop(two)


@pytest.mark.parametrize("tag", ["{c}", "FIC101.{C}"])
def test_a_long_export_is_refused_naming_its_channel_column(tmp_path: Path, tag: str) -> None:
    """A historian's long (narrow) export, one row per channel and time with the channel in a ``tag`` column (PI's
    ``FIC101.PV`` or pandas' melt), is refused telling to give one column per channel (before: the missing columns
    alone)."""
    rows = [f"{10 * k},{tag.format(c=c, C=c.upper())},{v}" for c, v in (("sp", 1), ("pv", 2), ("op", 40))
            for k in range(30)]
    p = _write_text(tmp_path / "long.csv", "time_s,tag,value\n" + "\n".join(rows) + "\n")
    with pytest.raises(LoopDataError, match=r"missing column\(s\) sp, pv, op .*; column 'tag' names the channels "
                                            r"\(op, pv, sp\) row by row, a long export: give one column per channel"):
        read_loop(p)


def test_manual_mode_dropped_with_a_note(tmp_path: Path) -> None:
    mode = np.ones(400)
    mode[:60] = 0.0
    loop = read_loop(_write_csv(tmp_path / "m.csv", n=400, mode=mode))
    assert loop.n == 340
    assert loop.time_s[0] == 0.0
    assert any("manual mode" in note for note in loop.notes)
    mode[150:] = 0.0  # a short automatic stretch is kept (the diagnosis names it insufficient_data)
    assert read_loop(_write_csv(tmp_path / "m2.csv", n=400, mode=mode)).n == 90


def _write_historian(path: Path, rows: list[tuple[str, float, float, float, int]]) -> Path:
    """A small synthetic export in the historian format of tests/data/plant_loops (5 header lines)."""
    head = ["PROCESSDATA\tX Data\tyyyy-MM-dd HH:mm:ss", f"8\t10\t2024-01-01 00:00:00\t{len(rows)}",
            "tagname\tX.MV\tX.PV\tX.SV\tX.MODE\tbOpOFL\tbPvOFL\tbSpOFL\tbAutOFL", "desc\tOP\tPV\tSP\tAut\ta\tb\tc\td",
            "fsMax=1\tfsMin=0"]
    body = [f"{ts}\t{op:.6f}\t{pv:.6f}\t{sp:.6f}\t{mode}\t0\t0\t0\t0" for ts, op, pv, sp, mode in rows]
    path.write_text("\r\n".join(head + body) + "\r\n")
    return path


def _rows(n: int = 300) -> list[tuple[str, float, float, float, int]]:
    from datetime import datetime, timedelta

    t0 = datetime(2024, 1, 1)
    return [((t0 + timedelta(seconds=10 * k)).strftime("%Y-%m-%d %H:%M:%S"), 40.0 + 5.0 * np.cos(k / 30.0),
             50.0 + np.sin(k / 30.0), 50.0, 1) for k in range(n)]


def test_a_value_the_historians_status_flag_marks_is_read_as_missing(tmp_path: Path) -> None:
    """The export's status flags (``bOpOFL``, ``bPvOFL``, ``bSpOFL``) mark a value that is not a new sample (it repeats
    the one before it): read as missing, so the loop is resampled over it, with a note. Where more samples are flagged
    than may be missing (10 %), the values are kept as exported, and the note says so (the record is not refused)."""
    rows = _rows()
    text = _write_historian(tmp_path / "plain.txt", rows).read_text().splitlines()
    # samples (0-based) whose OP and PV the historian held at the value before them (a run of three repeats its first)
    # and flagged
    for k in (100, 101, 102, 200):
        f, b = text[5 + k].split("\t"), text[5 + k - 1].split("\t")
        f[1], f[2], f[5], f[6] = b[1], b[2], "1", "1"
        text[5 + k] = "\t".join(f)
    path = tmp_path / "flagged.txt"
    path.write_text("\r\n".join(text))
    loop, plain = read_loop(path), read_loop(tmp_path / "plain.txt")
    assert loop.n == plain.n == 300
    assert loop.notes[0] == ("4 sample(s) carry a value the export's status flags mark (OP 4, PV 4; first at sample "
                             "101): read as missing, as a flagged value repeats the one before it and is not a new "
                             "sample")
    # resampled over: between the unflagged neighbours, close to the true values, not held at the value before
    true_op = np.array([r[1] for r in rows])
    assert np.abs(loop.op[100:103] - true_op[100:103]).max() < 0.05
    assert np.abs(np.array([float(text[5 + k].split("\t")[1]) for k in (100, 101, 102)]) - true_op[100:103]).max() > 0.1
    text = (tmp_path / "plain.txt").read_text().splitlines()
    many = [*text[:5], *["\t".join([*ln.split("\t")[:5], "1", "0", "0", "0"]) if j % 5 == 0 else ln
                         for j, ln in enumerate(text[5:])]]
    (tmp_path / "many.txt").write_text("\r\n".join(many))
    loop = read_loop(tmp_path / "many.txt")
    assert loop.n == 300 and np.array_equal(loop.op, plain.op)
    assert loop.notes == ["60 sample(s) carry a value the export's status flags mark (OP 60): too many to read as "
                          "missing, read as exported (a flagged value repeats the one before it)"]


def test_repeated_timestamps_are_merged_with_a_note(tmp_path: Path) -> None:
    rows = _rows()
    rows.insert(31, rows[30])                                  # an exact duplicate row
    ts, op, pv, sp, mode = rows[101]
    rows.insert(102, (ts, op + 2.0, pv + 1.0, sp, mode))       # a second, different value in the same second
    loop = read_loop(_write_historian(tmp_path / "dup.txt", rows))
    assert loop.n == 300 and loop.dt == pytest.approx(10.0)
    assert np.all(np.diff(loop.time_s) > 0)
    assert loop.op[100] == pytest.approx(op + 1.0, abs=1e-6) and loop.pv[100] == pytest.approx(pv + 0.5, abs=1e-6)
    assert loop.op[30] == pytest.approx(rows[30][1], abs=1e-6)
    assert loop.notes == ["merged 2 row(s) repeating a timestamp (first at sample 31): 1 exact duplicate(s) "
                          "dropped, 1 group(s) of differing rows averaged"]
    # the same rule for the loop CSV; time that goes backwards stays the one-line error
    t = np.r_[np.arange(150), 149, np.arange(150, 300)] * 10.0
    assert read_loop(_write_csv(tmp_path / "dup.csv", n=301, time_s=t)).n == 300
    back = _rows()
    back[50], back[51] = back[51], back[50]
    with pytest.raises(LoopDataError, match="time is not strictly increasing at sample 52") as exc:
        read_loop(_write_historian(tmp_path / "back.txt", back))
    assert "\n" not in str(exc.value)


def test_a_column_named_twice_is_refused(tmp_path: Path) -> None:
    """A header that names pv twice: which copy is the signal? (the reader took the first silently)."""
    p = _write_csv(tmp_path / "twice.csv")
    lines = p.read_text().splitlines()
    p.write_text("\n".join([lines[0] + ",pv"] + [line + ",1" for line in lines[1:]]) + "\n")
    with pytest.raises(LoopDataError, match="names column.s. pv more than once"):
        read_loop(p)
    # extra columns are ignored, so two of one name (two comments, two empty names of trailing separators) are read
    plain = read_loop(_write_csv(tmp_path / "plain.csv"))
    for extra, cells in ((",note,note", ",a,b"), (",,", ",,")):
        p.write_text("\n".join([lines[0] + extra] + [line + cells for line in lines[1:]]) + "\n")
        loop = read_loop(p)
        assert np.array_equal(loop.op, plain.op) and np.array_equal(loop.pv, plain.pv)


@pytest.mark.parametrize(("sep", "decimal", "comments"),
                         [(";", ",", ""), ("\t", ".", "# exported by DCS X\n# unit: %\n"), (";", ",", "sep=;\n"),
                          ("|", ".", "sep=|;;;\n")])
def test_a_loop_csv_of_another_locale_is_read_as_written(tmp_path: Path, sep: str, decimal: str, comments: str) -> None:
    """Semicolons or tabs with a decimal comma, comment lines before the header, and a spreadsheet's line naming the
    separator (``sep=;``, ``sep=|`` with a sheet's empty cells): the same loop as the comma file (a field read with
    the wrong dialect would miss its columns or fail to parse)."""
    plain = read_loop(_write_csv(tmp_path / "plain.csv"))
    text = (tmp_path / "plain.csv").read_text().replace(",", sep)
    if decimal == ",":
        text = text.replace(".", ",")
    other = read_loop(_write_text(tmp_path / "other.csv", comments + text))
    for c in ("time_s", "sp", "pv", "op"):
        np.testing.assert_array_equal(getattr(other, c), getattr(plain, c))
    lines = (comments + text).splitlines()
    row = len(comments.splitlines()) + 6  # the file's line of the fifth sample
    lines[row - 1] = sep.join([*lines[row - 1].split(sep)[:-1], "4O"])  # op, the last column, mistyped
    bad = "\n".join(lines) + "\n"
    with pytest.raises(LoopDataError, match=rf"line {row}, column op: '4O'"):
        read_loop(_write_text(tmp_path / "bad.csv", bad))


def test_comment_and_empty_lines_among_a_loops_data_are_skipped_and_noted(tmp_path: Path) -> None:
    """A logger's comment among the data (``# restarted``) and an empty line: the same loop, a note naming the
    comment's line, and a bad cell after them named by the file's own line."""
    plain = read_loop(_write_csv(tmp_path / "plain.csv"))
    lines = (tmp_path / "plain.csv").read_text().splitlines()
    edited = [*lines[:40], "", *lines[40:80], "# logger restarted, 10:12", *lines[80:]]
    loop = read_loop(_write_text(tmp_path / "commented.csv", "\n".join(edited) + "\n"))
    assert loop.n == plain.n and np.array_equal(loop.op, plain.op) and np.array_equal(loop.pv, plain.pv)
    assert "1 comment line(s) among the data (lines 82): skipped" in loop.notes
    edited[149] = ",".join([*edited[149].split(",")[:-1], "4O"])  # op on the file's line 150
    with pytest.raises(LoopDataError, match=r"line 150, column op: '4O'"):
        read_loop(_write_text(tmp_path / "bad.csv", "\n".join(edited) + "\n"))


def test_a_repeated_header_a_dash_and_fortran_exponents_in_a_loop_are_read(tmp_path: Path) -> None:
    """A loop CSV whose logger wrote its header again after a restart (skipped, with a note naming the line), a dash
    for a missing value (a missing sample) and numbers with a Fortran program's exponent (``4.0D+01``): the same loop.
    """
    plain = read_loop(_write_csv(tmp_path / "plain.csv"))
    lines = (tmp_path / "plain.csv").read_text().splitlines()
    edited = [*lines[:120], lines[0], *lines[120:]]
    loop = read_loop(_write_text(tmp_path / "restarted.csv", "\n".join(edited) + "\n"))
    assert loop.n == plain.n and np.array_equal(loop.op, plain.op) and np.array_equal(loop.pv, plain.pv)
    assert "1 line(s) among the data repeat the header (lines 121): skipped" in loop.notes
    fortran = [lines[0]] + [",".join(f"{float(c):.12E}".replace("E", "D") for c in ln.split(",")) for ln in lines[1:]]
    loop = read_loop(_write_text(tmp_path / "fortran.csv", "\n".join(fortran) + "\n"))
    assert loop.n == plain.n and np.allclose(loop.op, plain.op, rtol=1e-11) and np.allclose(loop.pv, plain.pv)
    dashed = [ln.split(",") for ln in lines]
    dashed[100][2] = "-"  # pv
    loop = read_loop(_write_text(tmp_path / "dashed.csv", "\n".join(",".join(r) for r in dashed) + "\n"))
    assert any("missing value" in note for note in loop.notes)


def test_a_last_line_cut_off_mid_write_and_nul_padding_end_a_loop_with_a_note(tmp_path: Path) -> None:
    """A logger stopped mid-write: a loop CSV's or a historian export's last line holds fewer fields (it was refused,
    'line 302: 2 fields, the header has 4'), and the file may end in the NUL bytes of a preallocated file (refused as
    not text). Both are dropped with a note: the same loop. A short line before the last is still refused."""
    plain = read_loop(_write_csv(tmp_path / "plain.csv"))
    text = (tmp_path / "plain.csv").read_text()
    (tmp_path / "cut.csv").write_bytes(text.encode() + b"3000,50" + bytes(512))
    loop = read_loop(tmp_path / "cut.csv")
    assert loop.n == plain.n and np.array_equal(loop.op, plain.op) and np.array_equal(loop.pv, plain.pv)
    assert loop.notes[:2] == [
        "512 NUL byte(s) at the end of the file (space a logger preallocated and never wrote, as a power loss leaves "
        "a file on an SD card), dropped",
        "the last line (line 302) holds 2 of the 4 fields: a record cut off mid-write (a logger stopped or lost "
        "power), perhaps within a number, so it is dropped whole"]
    lines = text.splitlines()
    (tmp_path / "mid.csv").write_text("\n".join([*lines[:100], "990,50", *lines[100:]]) + "\n")
    with pytest.raises(LoopDataError, match=r"mid.csv line 101: 2 fields, the header has 4$"):
        read_loop(tmp_path / "mid.csv")
    hist = _write_historian(tmp_path / "plain.txt", _rows())
    (tmp_path / "cut.txt").write_text(hist.read_text() + "2024-01-01 00:")
    loop, whole = read_loop(tmp_path / "cut.txt"), read_loop(hist)
    assert loop.n == whole.n == 300 and np.array_equal(loop.op, whole.op)
    assert loop.notes == [f"the last line (line {5 + 300 + 1}) holds 1 of the 9 fields: a record cut off mid-write (a "
                          "logger stopped or lost power), perhaps within a number, so it is dropped whole"]


def test_a_loops_time_in_minutes_by_name_and_rows_newest_first_are_named(tmp_path: Path) -> None:
    """A loop's time column named ``time_min`` is named with its factor to seconds; rows newest first, and a time that
    starts again (two files joined), are named."""
    lines = _write_csv(tmp_path / "plain.csv").read_text().splitlines()
    renamed = [lines[0].replace("time_s", "time_min"), *lines[1:]]
    with pytest.raises(LoopDataError, match=r"the header has 'time_min', a time not in seconds: give it as time_s in "
                                            r"seconds \(multiply by 60\)$"):
        read_loop(_write_text(tmp_path / "min.csv", "\n".join(renamed) + "\n"))
    with pytest.raises(LoopDataError, match=r"not strictly increasing at sample 2 .*; the rows run newest first"):
        read_loop(_write_text(tmp_path / "newest.csv", "\n".join([lines[0], *lines[:0:-1]]) + "\n"))
    with pytest.raises(LoopDataError, match=r"not strictly increasing at sample 41 .*; the time starts again there"):
        read_loop(_write_text(tmp_path / "reset.csv", "\n".join([*lines[:41], *lines[1:]]) + "\n"))
    t = np.arange(600) * 10.0
    with pytest.raises(LoopDataError, match=r"not strictly increasing at sample 451 .*; the time goes back by an hour "
                                            r"there \(times from a clock on local time"):
        read_loop(_write_csv(tmp_path / "local.csv", n=600, time_s=np.where(t >= 4500.0, t - 3600.0, t)))


def _write_text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_units_row_under_the_header_is_read_and_noted(tmp_path: Path) -> None:
    """A loop CSV with a second header line of units reads as the same loop with a note; sp and pv may be in the
    plant's units, time_s must be seconds (else one line)."""
    plain = read_loop(_write_csv(tmp_path / "plain.csv", n=120))
    lines = (tmp_path / "plain.csv").read_text().splitlines()
    p = tmp_path / "units.csv"
    p.write_text("\n".join([lines[0], "s,m3/h,m3/h,%", *lines[1:]]) + "\n")
    loop = read_loop(p)
    assert loop.n == plain.n and np.array_equal(loop.op, plain.op) and np.array_equal(loop.pv, plain.pv)
    assert loop.notes[0] == ("line 2 is a units row (time_s [s], sp [m3/h], pv [m3/h], op [%]): read as a second "
                             "header line")
    p.write_text("\n".join([lines[0], "min,m3/h,m3/h,%", *lines[1:]]) + "\n")
    with pytest.raises(LoopDataError, match=r"line 2 is a units row, and time_s is given in 'min': give it in second"):
        read_loop(p)
    p.write_text("\n".join([lines[0], "0,m3/h,oops,%", *lines[1:]]) + "\n")  # a number in it: a bad data line
    with pytest.raises(LoopDataError, match=r"line 2, column sp: 'm3/h' is not a number"):
        read_loop(p)


def test_a_mode_by_name_and_a_spreadsheets_error_values_are_read(tmp_path: Path) -> None:
    """A historian exports the controller's mode as a state's name (AUTO, CAS, MAN; the Fieldbus modes RCAS, OOS,
    IMAN): automatic and the cascades are 1, manual, out of service and initialisation manual 0; a logical column's
    True 1, as its number is. A spreadsheet's
    error value (#N/A, #DIV/0!) is a missing sample; other text in mode is refused."""
    mode = np.ones(400)
    mode[:60] = 0.0
    numeric = read_loop(_write_csv(tmp_path / "m.csv", n=400, mode=mode))
    lines = (tmp_path / "m.csv").read_text().splitlines()
    names = ["MAN" if k < 20 else "OOS" if k < 30 else "Manual" if k < 50 else "IMAN" if k < 60 else "AUTO" if k < 200
             else "cas" if k < 300 else "RCAS" for k in range(400)]
    p = tmp_path / "named.csv"
    rows = [ln.rsplit(",", 1)[0] + "," + m for ln, m in zip(lines[1:], names, strict=True)]
    p.write_text("\n".join([lines[0], *rows]) + "\n")
    named = read_loop(p)
    assert named.n == numeric.n == 340 and np.array_equal(named.op, numeric.op)
    logical = [ln.rsplit(",", 1)[0] + "," + ("True" if m == 1.0 else "FALSE") for ln, m in zip(lines[1:], mode,
                                                                                              strict=True)]
    p.write_text("\n".join([lines[0], *logical]) + "\n")  # a logical column (before: 'True' is not a number)
    assert np.array_equal(read_loop(p).op, numeric.op)
    errs = [ln.split(",") for ln in (tmp_path / "m.csv").read_text().splitlines()]
    errs[100][2], errs[250][3] = "#N/A", "#DIV/0!"  # pv, op
    p.write_text("\n".join(",".join(r) for r in errs) + "\n")
    assert any("missing value" in note for note in read_loop(p).notes)
    bad = [*lines[:5], lines[5].rsplit(",", 1)[0] + ",Standby", *lines[6:]]
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(LoopDataError, match=r"line 6, column mode: 'Standby' is not a number"):
        read_loop(p)
    semi = [ln.replace(",", ";") for ln in lines]  # a decimal point in every cell, and one with a comma
    semi[7] = ";".join([*semi[7].split(";")[:3], semi[7].split(";")[3].replace(".", ","), *semi[7].split(";")[4:]])
    p.write_text("\n".join(semi) + "\n")
    with pytest.raises(LoopDataError, match=r"line 8, column op: '[\d,]+' is not a number; it has a decimal comma"):
        read_loop(p)
    pct = [*lines[:9], ",".join([*lines[9].split(",")[:3], lines[9].split(",")[3] + " %", *lines[9].split(",")[4:]]),
           *lines[10:]]  # a formatted cell: the unit after the number
    p.write_text("\n".join(pct) + "\n")
    with pytest.raises(LoopDataError, match=r"line 10, column op: '[\d.]+ %' is not a number; the cell carries its "
                                            r"unit \('%'\)"):
        read_loop(p)


@pytest.mark.parametrize("kind", ["utf16_tabs", "spaces", "footer", "empty_sheet_rows", "gzip"])
def test_a_loop_as_other_programs_save_it_is_read_as_written(tmp_path: Path, kind: str) -> None:
    """A spreadsheet's "Unicode text" save (UTF-16, tabs), a space-separated export, a closing comment and a
    spreadsheet's empty formatted rows after the data: the same record as the comma file."""
    plain = read_loop(_write_csv(tmp_path / "plain.csv", n=120))
    text = (tmp_path / "plain.csv").read_text()
    p = tmp_path / "other.txt"
    if kind == "utf16_tabs":
        p.write_text(text.replace(",", "\t"), encoding="utf-16")
    elif kind == "spaces":
        p.write_text(text.replace(",", "   "))
    elif kind == "footer":
        p.write_text(text + "# end of export\n")
    elif kind == "gzip":
        p = tmp_path / "plain.csv.gz"
        p.write_bytes(gzip.compress(text.encode()))
    else:
        p.write_text(text.replace(",", ";") + ";;;\n;;;\n")
    loop = read_loop(p)
    assert loop.tag == ("plain" if kind == "gzip" else "other")
    assert loop.n == plain.n and all(np.array_equal(getattr(loop, c), getattr(plain, c))
                                     for c in ("time_s", "sp", "pv", "op"))


def test_units_after_the_names_in_a_loop_header_are_read(tmp_path: Path) -> None:
    """``time_s [s], sp [m3/h], pv [m3/h], op [%]``: the same record, with a note; a time in another unit is refused."""
    plain = read_loop(_write_csv(tmp_path / "plain.csv", n=120))
    lines = (tmp_path / "plain.csv").read_text().splitlines()
    p = tmp_path / "named.csv"
    p.write_text("\n".join(["time_s [s],sp (m3/h),pv / m3/h,op [%]", *lines[1:]]) + "\n")
    loop = read_loop(p)
    assert np.array_equal(loop.pv, plain.pv) and np.array_equal(loop.op, plain.op)
    assert loop.notes == ["the header gives units after the names (time_s [s], sp [m3/h], pv [m3/h], op [%]): read "
                          "as the names"]
    stamped = [ln.split(",", 1) for ln in lines[1:]]
    p.write_text("\n".join(["time_s,sp,pv,op", *(f"2026-03-01 06:{int(float(t)) // 60:02d}:{int(float(t)) % 60:02d},"
                                                   f"{rest}" for t, rest in stamped)]) + "\n")
    with pytest.raises(LoopDataError, match=r"column time_s holds date-times \('2026-03-01 06:00:00'\): give the "
                                            r"time as seconds"):
        read_loop(p)
    p.write_text("\n".join(["time_s [min],sp,pv,op", *lines[1:]]) + "\n")
    with pytest.raises(LoopDataError, match=r"the header gives time_s in 'min': give it in seconds$"):
        read_loop(p)


@pytest.mark.parametrize("kind", ["gzip", "utf16", "bom"])
def test_a_historian_export_saved_otherwise_is_read(tmp_path: Path, kind: str) -> None:
    """The historian's export compressed, saved as UTF-16 or with a UTF-8 byte-order mark: the same record."""
    plain = read_loop(STICKY)
    text = STICKY.read_text()
    p = tmp_path / "export.txt"
    if kind == "gzip":
        p.write_bytes(gzip.compress(STICKY.read_bytes()))
    else:
        p.write_text(text, encoding="utf-16" if kind == "utf16" else "utf-8-sig")
    loop = read_loop(p)
    assert loop.tag == plain.tag and np.array_equal(loop.op, plain.op) and np.array_equal(loop.pv, plain.pv)


@pytest.mark.parametrize(("pattern", "strftime"), [
    ("dd.MM.yyyy HH:mm:ss", "%d.%m.%Y %H:%M:%S"),  # a European DCS's export
    ("MM/dd/yyyy hh:mm:ss tt", "%m/%d/%Y %I:%M:%S %p"),
    ("yyyy-MM-dd'T'HH:mm:ss.fff", "%Y-%m-%dT%H:%M:%S.000"),
    ("yyyy-MM-dd HH:mm:ss", "%Y-%m-%d %H:%M:%S.000"),  # fractional seconds the declaration does not give
])
def test_a_historian_export_reads_its_timestamps_by_the_format_line_1_declares(tmp_path: Path, pattern: str,
                                                                               strftime: str) -> None:
    """Line 1 of the export declares its timestamps' format (``yyyy-MM-dd HH:mm:ss`` in the shared loops): another
    declared format (.NET or Java letters, a quoted literal) is read by it, and the default with fractional seconds
    is read too; a timestamp in none of them is refused in one line naming the formats."""
    from datetime import datetime

    from valve_env.loops.io import time_format

    plain = read_loop(STICKY)
    lines = STICKY.read_text().splitlines()
    head = lines[0].split("\t")
    head[2] = pattern
    rows = []
    for ln in lines[5:]:
        f = ln.split("\t")
        f[0] = datetime.strptime(f[0], "%Y-%m-%d %H:%M:%S").strftime(strftime)
        rows.append("\t".join(f))
    p = tmp_path / "export.txt"
    p.write_text("\n".join(["\t".join(head), *lines[1:5], *rows]) + "\n")
    loop = read_loop(p)
    assert np.array_equal(loop.time_s, plain.time_s) and np.array_equal(loop.op, plain.op)
    assert time_format("HH:mm:ss") is None and time_format("yyyy-MM-dd HH:mm:ss zzz") is None
    rows[0] = "\t".join(["8 Oct 2024 13:45", *rows[0].split("\t")[1:]])
    p.write_text("\n".join(["\t".join(head), *lines[1:5], *rows]) + "\n")
    with pytest.raises(LoopDataError, match=r"line 6: timestamp '8 Oct 2024 13:45' is neither in the format line 1 "
                                            r"declares \(.*\) nor in YYYY-MM-DD HH:MM:SS\[\.fff\] \(with a T for the "
                                            r"space, or / for the -, or ISO 8601 with its UTC offset, \+08:00 or "
                                            r"Z\)$"):
        read_loop(p)


def test_a_stray_quote_spoils_its_own_line_only(tmp_path: Path) -> None:
    """A quote left open in one line of a long loop CSV is refused naming that line. Read as one CSV stream, the
    quote ran over every later line into one field until Python's csv field limit (128 KB) failed without naming
    the file or the line (exit status 1)."""
    n = 4507  # about 150 KB: past the field limit from line 101 on
    lines = ["time_s,sp,pv,op"] + [f"{10 * i},50,{50 + np.sin(i / 20):.4f},{40 + np.cos(i / 20):.4f}" for i in range(n)]
    lines[100] = lines[100].replace(",50,", ',"50,', 1)
    p = tmp_path / "quote.csv"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(LoopDataError, match=r"quote\.csv line 101: 2 fields, the header has 4"):
        read_loop(p)
    lines[100] = lines[100].replace('"', "")
    p.write_text("\n".join(lines) + "\n")
    assert read_loop(p).n == n


def test_an_op_at_its_limit_on_many_samples_is_noted(tmp_path: Path) -> None:
    """A controller that saturates (OP at 100 % or 0 %, or at the observed end of an OP in engineering units, on more
    than 5 % of the samples) leaves the loop open there: a note says so. A sinusoidal OP passing its extremes is not
    flagged."""
    wave = 60.0 + 50.0 * np.cos(np.arange(300) / 30.0)
    loop = read_loop(_write_csv(tmp_path / "sat.csv", op=np.minimum(wave, 100.0)))
    share = np.mean(np.minimum(wave, 100.0) >= 99.95)
    assert share > 0.05
    assert any(n.startswith(f"OP sits at 100 % on {share:.0%} of the samples: the controller saturates") for n in
               loop.notes)
    eu = read_loop(_write_csv(tmp_path / "sat_eu.csv", op=1000.0 + 4.0 * np.maximum(wave, 30.0)))
    assert eu.op_scaled_from is not None
    assert any(n.startswith("OP sits at its observed minimum on") for n in eu.notes)
    assert not any("saturates" in n for n in read_loop(_write_csv(tmp_path / "wave.csv", op=50.0 + 40.0 * np.cos(
        np.arange(300) / 30.0))).notes)


@pytest.mark.parametrize("tags", ["x.mv\tx.pv\tx.sv\tx.mode", "X.OP\tX.PV\tX.SP\tX.MODE"])
def test_a_historians_tags_in_lower_case_or_as_op_and_sp_are_read(tmp_path: Path, tags: str) -> None:
    """Tag suffixes in lower case, or ``.OP`` and ``.SP`` as other control systems name the controller output and the
    set point: the same record as the format's ``.MV`` and ``.SV``; a tag list that lacks one is refused in one line
    that names what is missing and what was read."""
    plain = read_loop(_write_historian(tmp_path / "plain.txt", _rows()))
    text = (tmp_path / "plain.txt").read_text().replace("X.MV\tX.PV\tX.SV\tX.MODE", tags)
    loop = read_loop(_write_text(tmp_path / "other.txt", text))
    assert loop.tag.upper() == plain.tag == "X"
    for c in ("time_s", "sp", "pv", "op"):
        np.testing.assert_array_equal(getattr(loop, c), getattr(plain, c))
    no_sp = text.replace(tags.split("\t")[2], "X.TEMP")
    with pytest.raises(LoopDataError, match=r"line 3: no [xX]\.SV/\.SP \(set point\) among the tags \(read: "
                                            r"'[xX]\.(mv|OP)', "):
        read_loop(_write_text(tmp_path / "no_sp.txt", no_sp))


def test_an_export_without_its_description_or_scale_line_or_with_a_mode_by_name_is_read(tmp_path: Path) -> None:
    """An export that leaves out line 4 (``desc ...``) or line 5 (``fsMax=...``): its first sample was taken for a
    header line (the loop came out one sample short); now the data start at the first of lines 4 and 5 that begins
    with a timestamp. A MODE written as a name (``AUTO``, as the loop CSV reads it) was refused as not a number."""
    plain = read_loop(_write_historian(tmp_path / "plain.txt", _rows()))
    lines = (tmp_path / "plain.txt").read_text().splitlines()
    for name, kept in (("nodesc.txt", [*lines[:3], *lines[4:]]), ("nofs.txt", [*lines[:4], *lines[5:]]),
                       ("neither.txt", [*lines[:3], *lines[5:]]),
                       ("auto.txt", [*lines[:5], *[ln.replace("\t1\t0\t0\t0\t0", "\tAUTO\t0\t0\t0\t0")
                                                   for ln in lines[5:]]])):
        loop = read_loop(_write_text(tmp_path / name, "\r\n".join(kept) + "\r\n"))
        assert loop.n == plain.n == 300 and np.array_equal(loop.op, plain.op), name
        assert np.array_equal(loop.time_s, plain.time_s), name


def test_an_export_of_several_loops_is_read_for_the_loop_tag_chooses(tmp_path: Path) -> None:
    """A historian export whose line 3 names two loops' tags (Y's first): without ``tag``, refused in one line naming
    the loops; with it, each column is the chosen tag's own, and the flags that follow its columns are its flags.
    Before, the first .MV, .PV and .SV found were read whatever their tag: OP of one loop against PV of another."""
    plain = _write_historian(tmp_path / "plain.txt", _rows())
    lines = plain.read_text().splitlines()
    other = [(ts, 60.0, 20.0, 20.0, 1) for ts, *_ in _rows()]
    y = _write_historian(tmp_path / "y.txt", other).read_text().splitlines()
    joined = [lines[0], lines[1],
              "tagname\tY.MV\tY.PV\tY.SV\tY.MODE\tbOpOFL\tbPvOFL\tbSpOFL\tbAutOFL\t"
              "X.MV\tX.PV\tX.SV\tX.MODE\tbOpOFL\tbPvOFL\tbSpOFL\tbAutOFL",
              lines[3] + "\t" + "\t".join(lines[3].split("\t")[1:]), lines[4],
              *[a + "\t" + "\t".join(b.split("\t")[1:]) for a, b in zip(y[5:], lines[5:], strict=True)]]
    path = _write_text(tmp_path / "two.txt", "\r\n".join(joined) + "\r\n")
    with pytest.raises(LoopDataError, match=r"two.txt line 3: the export holds 2 loops \(Y, X\): choose one with "
                                            r"--tag$"):
        read_loop(path)
    x, whole = read_loop(path, tag="x"), read_loop(plain)
    assert x.tag == "X" and np.array_equal(x.op, whole.op) and np.array_equal(x.pv, whole.pv)
    assert np.array_equal(read_loop(path, tag="Y").op, np.full(300, 60.0))
    with pytest.raises(LoopDataError, match=r"line 3: no loop 'Z' among the tags \(loops: Y, X\)$"):
        read_loop(path, tag="Z")
    with pytest.raises(LoopDataError, match=r"a loop CSV holds one loop; --tag chooses the loop of a historian export"):
        read_loop(_write_csv(tmp_path / "loop.csv"), tag="X")
    flagged = [*joined[:5], *[ln if j != 100 else "\t".join([*ln.split("\t")[:13], "1", "1", "0", "0"])
                              for j, ln in enumerate(joined[5:])]]
    x = read_loop(_write_text(tmp_path / "flagged.txt", "\r\n".join(flagged) + "\r\n"), tag="X")
    assert x.notes[0].startswith("1 sample(s) carry a value the export's status flags mark (OP 1, PV 1; first at "
                                 "sample 101)")


@pytest.mark.parametrize(("names", "pattern"), [
    ({"op": "CO"}, r"missing column\(s\) op \(need time_s, sp, pv, op\); if 'CO' is the controller output \(%\), name "
                   r"it op \(names are exact: docs/reference.md, section 10\)$"),
    ({"sp": "Set Point", "pv": "measurement", "op": "output"},
     r"missing column\(s\) sp, pv, op .*; if 'Set Point' is the set point, name it sp; if 'measurement' is the process "
     r"variable, name it pv; if 'output' is the controller output \(%\), name it op \(names are exact"),
    # a historian's .MV is the controller output, the loop CSV's mv the measured valve position: asked, not guessed
    ({"op": "mv"}, r"missing column\(s\) op .*; 'mv' is the measured valve position in a loop CSV; if it is the "
                   r"controller output \(a historian's .MV\), name it op"),
    # a name whose meaning differs between conventions gets no guess
    ({"op": "y"}, r"missing column\(s\) op \(need time_s, sp, pv, op\)$"),
])
def test_a_loop_csv_with_another_tools_column_names_is_refused_naming_them(tmp_path: Path, names: dict[str, str],
                                                                          pattern: str) -> None:
    """Column names other tools write (``CO``, ``setpoint``, ``output``; a historian's ``MV`` for the output): the
    refusal of the missing columns names the header's column that is likely meant, in one line."""
    lines = _write_csv(tmp_path / "plain.csv").read_text().splitlines()
    header = ",".join(names.get(c, c) for c in lines[0].split(","))
    with pytest.raises(LoopDataError, match=pattern) as err:
        read_loop(_write_text(tmp_path / "named.csv", "\n".join([header, *lines[1:]]) + "\n"))
    assert "\n" not in str(err.value)


def _historian_variant(text: str, kind: str) -> str:
    """The shared sticky loop's export (CRLF, tabs) as another locale or a spreadsheet's save writes it."""
    lines = text.split("\r\n")
    head, data = lines[:5], lines[5:]
    if kind == "decimal_comma":  # the values in a decimal-comma locale (the header's scale line keeps its points)
        return "\r\n".join(head + [ln.replace(".", ",") for ln in data])
    if kind == "semicolon_decimal_comma":  # a German spreadsheet's CSV save
        return "\r\n".join(ln.replace("\t", ";") for ln in head + [ln.replace(".", ",") for ln in data])
    if kind == "comma":  # a spreadsheet's CSV save
        return "\r\n".join(ln.replace("\t", ",") for ln in lines)
    if kind == "iso_t":  # ISO 8601's T between date and time
        return "\r\n".join(head + [ln.replace(" ", "T", 1) for ln in data])
    assert kind == "slashes"  # a year-first date with slashes
    return "\r\n".join(head + [ln.replace("-", "/", 2) for ln in data])


@pytest.mark.parametrize("kind", ["decimal_comma", "semicolon_decimal_comma", "comma", "iso_t", "slashes"])
def test_a_historian_export_in_another_locale_or_saved_by_a_spreadsheet_is_read(tmp_path: Path, kind: str) -> None:
    """The export with decimal commas, its fields separated by ';' or ',' (a spreadsheet's CSV save), or timestamps
    with ISO 8601's T or a year-first date with slashes: the same record as the export. Before, each was refused: 'has
    a decimal comma where the file's other numbers have a decimal point' (the only points were in the header's scale
    line), 'no <tag>.MV ... among the tags (read: none)', or the timestamp not in YYYY-MM-DD HH:MM:SS."""
    plain = read_loop(STICKY)
    p = tmp_path / "export.txt"
    p.write_bytes(_historian_variant(STICKY.read_bytes().decode("utf-8"), kind).encode("utf-8"))
    loop = read_loop(p)
    assert loop.tag == plain.tag and loop.n == plain.n
    for c in ("time_s", "sp", "pv", "op"):
        np.testing.assert_array_equal(getattr(loop, c), getattr(plain, c))
    saved = [n for n in loop.notes if "a spreadsheet's save" in n]
    assert len(saved) == (kind in ("semicolon_decimal_comma", "comma"))


def test_an_output_given_in_ma_is_read_as_percent(tmp_path: Path) -> None:
    """OP (or MV) given as a 4-20 mA signal's current, its unit in the header (``op [mA]``) or in a units row: read as
    % by (mA - 4) / 16 x 100, with a note. Before, the unit was read and dropped, and 4-20 lay within the range of a %
    OP: every band came out 16 % of its size."""
    n = 300
    op_pct = 40.0 + 5.0 * np.cos(np.arange(n) * 10.0 / 300.0)
    plain = read_loop(_write_csv(tmp_path / "pct.csv", op=op_pct))
    ma = 4.0 + op_pct * 0.16
    named = _write_csv(tmp_path / "ma.csv", op=ma)
    lines = named.read_text().splitlines()
    named.write_text("\n".join([lines[0].replace("op", "op [mA]"), *lines[1:]]) + "\n")
    row = tmp_path / "row.csv"
    row.write_text("\n".join([lines[0], "s,degC,degC,mA", *lines[1:]]) + "\n")
    for p in (named, row):
        loop = read_loop(p)
        np.testing.assert_allclose(loop.op, plain.op, atol=1e-3)
        assert any(nt.startswith("op is given in mA (a 4-20 mA signal)") for nt in loop.notes)


def test_a_valve_run_is_told_to_go_to_fit_or_diagnose(tmp_path: Path) -> None:
    """A measured valve run given to loop-diagnose is told which commands read it (before: the missing columns
    alone)."""
    run = tmp_path / "run.csv"
    run.write_text("time_s,T_tank_C,T_med_C,q_kgh,dp_mbar,ps_bar,x_mm\n" + "".join(
        f"{10 * k},{55 + k % 3},70,120,100,2,0.{k % 5}\n" for k in range(40)))
    with pytest.raises(LoopDataError, match=r"missing column\(s\) sp, pv, op .*; the header is a measured valve run's "
                                            r"\(docs/reference.md, section 2\): identify it with thermovalve fit or "
                                            r"thermovalve diagnose$"):
        read_loop(run)


def test_a_spreadsheets_save_that_rewrote_the_timestamps_is_refused_saying_so(tmp_path: Path) -> None:
    """A spreadsheet that saves the export (';' for the tabs) rewrites its timestamps in its locale, without the
    seconds ('08.10.2024 13:45'): the refusal names the timestamp and says what the save did."""
    lines = STICKY.read_bytes().decode("utf-8").split("\r\n")
    stamp = re.compile(r"^(\d{4})-(\d\d)-(\d\d) (\d\d:\d\d):\d\d")
    data = [stamp.sub(lambda m: f"{m[3]}.{m[2]}.{m[1]} {m[4]}", ln) for ln in lines[5:]]
    p = tmp_path / "saved.txt"
    p.write_text("\r\n".join(ln.replace("\t", ";") for ln in lines[:5] + data))
    with pytest.raises(LoopDataError, match=r"line 6: timestamp '08\.10\.2024 13:45' is neither in the format line 1 "
                                            r"declares .*; a spreadsheet that saves the export rewrites its "
                                            r"timestamps"):
        read_loop(p)


def _restamped(tmp_path: Path, name: str, stamp: Callable[[datetime], str], start: datetime) -> Path:
    """The sticky export with its samples taken every 10 s from ``start`` (a clock that ran on, naive) and each
    timestamp written by ``stamp``."""
    lines = STICKY.read_text().splitlines()
    rows = []
    for i, ln in enumerate(lines[5:]):
        f = ln.split("\t")
        f[0] = stamp(start + timedelta(seconds=10 * i))
        rows.append("\t".join(f))
    p = tmp_path / name
    p.write_text("\n".join([*lines[:5], *rows]) + "\n")
    return p


def _local(change: datetime, hour: int) -> Callable[[datetime], str]:
    """A local clock that moves by ``hour`` at ``change`` (the true time of the change)."""
    return lambda t: (t + timedelta(hours=hour) if t >= change else t).strftime("%Y-%m-%d %H:%M:%S")


def test_a_historian_export_on_local_time_runs_on_across_a_change_of_summer_time(tmp_path: Path) -> None:
    """An export on a local clock: at the end of summer time (Europe, 27 Oct 2024, 03:00 back to 02:00) the hour
    repeats, at its start (31 Mar 2024, 02:00 on to 03:00) an hour is skipped. Both are read as the clock's change,
    with a note: the record the same as the export's own, which ran on. An hour's jump by day, or forward on a
    weekday, is no change of summer time: back is refused naming the hour, forward is a gap."""
    plain = read_loop(STICKY)
    for start, change, hour in ((datetime(2024, 10, 27, 2, 10), datetime(2024, 10, 27, 3), -1),
                                (datetime(2024, 3, 31, 1, 10), datetime(2024, 3, 31, 2), 1)):
        loop = read_loop(_restamped(tmp_path, f"local{hour}.txt", _local(change, hour), start))
        assert np.array_equal(loop.time_s, plain.time_s) and np.array_equal(loop.op, plain.op)
        assert np.array_equal(loop.pv, plain.pv)
        which = "back after 2024-10-27 02:59:50" if hour < 0 else "forward after 2024-03-31 01:59:50"
        assert any(f"jump by an hour at night ({which} (sample 300))" in n and "change of summer time" in n
                   for n in loop.notes), loop.notes
    by_day = datetime(2024, 10, 22, 14, 10)  # a Tuesday
    with pytest.raises(LoopDataError, match=r"not strictly increasing at sample 301 .*; the time goes back by an "
                                            r"hour there"):
        read_loop(_restamped(tmp_path, "day_back.txt", _local(by_day + timedelta(minutes=50), -1), by_day))
    night = datetime(2024, 10, 22, 2, 10)
    gap = read_loop(_restamped(tmp_path, "weekday_on.txt", _local(night + timedelta(minutes=50), 1), night))
    assert gap.time_s[-1] == plain.time_s[-1] + 3600.0
    assert not any("summer time" in n for n in gap.notes) and any("resampled" in n for n in gap.notes)


def test_a_historian_export_with_utc_offsets_is_read(tmp_path: Path) -> None:
    """ISO 8601 timestamps with their UTC offset (an export in UTC, 'Z', or with its zone, '+08:00') are read, and
    times count as the clock ran across a change of the offset (+02:00 to +01:00 at the end of summer time). A
    timestamp without an offset among them is refused in one line."""
    plain = read_loop(STICKY)
    start = datetime(2024, 10, 27, 2, 10)
    change = datetime(2024, 10, 27, 3)  # on the summer clock: 01:00 UTC
    for name, stamp in (("z", lambda t: f"{t:%Y-%m-%dT%H:%M:%S}Z"), ("cst", lambda t: f"{t:%Y-%m-%dT%H:%M:%S}+08:00"),
                        ("cet", lambda t: (f"{t:%Y-%m-%dT%H:%M:%S}+02:00" if t < change else
                                           f"{t - timedelta(hours=1):%Y-%m-%dT%H:%M:%S}+01:00"))):
        loop = read_loop(_restamped(tmp_path, f"{name}.txt", stamp, start))
        assert np.array_equal(loop.time_s, plain.time_s) and np.array_equal(loop.op, plain.op), name
        assert not any("summer time" in n for n in loop.notes), name
    p = _restamped(tmp_path, "mixed.txt", lambda t: f"{t:%Y-%m-%dT%H:%M:%S}" + ("Z" if t < change else ""), start)
    with pytest.raises(LoopDataError, match=r"line 306: timestamp '2024-10-27T03:00:00' is not in the format of the "
                                            r"first \('2024-10-27T02:10:00Z'\)$"):
        read_loop(p)


def test_tags_on_their_own_times_are_read_on_common_rows(tmp_path: Path) -> None:
    """An export of several tags on the union of their timestamps: the sticky record's OP scanned every 5 s (its
    values at the record's 10 s, and others between), its PV every 10 s, its set point stored on change only. It is
    read on the PV's rows, the OP there and the set point held, with a note: the record as exported at 10 s, and the
    same diagnosis. A PV scanned with the OP that stops for a fifth of the record (an outage, not a slower scan) is
    still refused."""
    from valve_env.loops.diagnose import diagnose_loop

    plain = read_loop(STICKY)
    n = plain.time_s.size
    t = np.arange(2 * n - 1) * 5.0
    op = np.interp(t, plain.time_s, plain.op) + np.where(np.arange(t.size) % 2 == 1, 0.3, 0.0)
    pv = np.where(np.arange(t.size) % 2 == 0, np.interp(t, plain.time_s, plain.pv), np.nan)
    sp_full = np.interp(t, plain.time_s, plain.sp)
    changed = np.r_[True, np.diff(sp_full) != 0] & (np.arange(t.size) % 2 == 0)
    sp = np.where(changed, sp_full, np.nan)

    def cell(v: float) -> str:
        return "" if np.isnan(v) else repr(float(v))

    rows = ["time_s,sp,pv,op", *(f"{t[i]:g},{cell(sp[i])},{cell(pv[i])},{cell(op[i])}" for i in range(t.size))]
    p = tmp_path / "union.csv"
    p.write_text("\n".join(rows) + "\n")
    loop = read_loop(p)
    assert np.array_equal(loop.time_s, plain.time_s)
    assert np.allclose(loop.pv, plain.pv, rtol=0, atol=1e-12) and np.allclose(loop.op, plain.op, rtol=0, atol=1e-12)
    assert np.allclose(loop.sp, plain.sp, rtol=0, atol=1e-12)
    note = next(x for x in loop.notes if x.startswith("the tags are on their own times"))
    assert f"sp has a value on {int(changed.sum())} of {t.size} rows, held" in note
    assert f"pv has a value on {n} of {t.size} rows (one in 2, median): the record is read on those rows" in note
    read, exported = diagnose_loop(loop).result, diagnose_loop(plain).result
    assert read["cause"] == exported["cause"]
    assert read["detection"]["features"] == exported["detection"]["features"]
    out = np.interp(t, plain.time_s, plain.pv)
    out[200:500] = np.nan  # a PV scanned with the OP, its transmitter out for 25 min
    rows = ["time_s,sp,pv,op", *(f"{t[i]:g},{cell(sp_full[i])},{cell(out[i])},{cell(op[i])}" for i in range(t.size))]
    p.write_text("\n".join(rows) + "\n")
    with pytest.raises(LoopDataError, match=r"miss a value \(column pv first, at sample 201\); at most 10% may$"):
        read_loop(p)


def test_a_pv_stored_on_change_is_held_from_each_value_to_the_next(tmp_path: Path) -> None:
    """An export on the union of the tags' timestamps whose PV a historian stored on change (a dead band of one sd of
    its sample-to-sample moves), empty between: the PV is held from each stored value to the next, on every row,
    with a note. Before, its values, at irregular rows, were read as a slower scan, and the record was cut to them."""
    from valve_env.studies.conventions import store_on_change

    plain = read_loop(STICKY)
    held = store_on_change(plain.pv, float(np.std(np.diff(plain.pv))))
    stored = np.r_[True, held[1:] != held[:-1]]
    columns = zip(plain.time_s.tolist(), plain.sp.tolist(), held.tolist(), plain.op.tolist(), stored, strict=True)
    rows = ["time_s,sp,pv,op", *(f"{t:g},{sp!r},{repr(pv) if keep else ''},{op!r}" for t, sp, pv, op, keep in columns)]
    p = tmp_path / "on_change.csv"
    p.write_text("\n".join(rows) + "\n")
    loop = read_loop(p)
    assert np.array_equal(loop.time_s, plain.time_s)
    assert np.array_equal(loop.pv, held) and np.array_equal(loop.op, plain.op)
    note = next(x for x in loop.notes if x.startswith("the tags are on their own times"))
    assert f"pv has a value on {int(stored.sum())} of {plain.time_s.size} rows, held from each to the next" in note
