"""load_run: docs/reference.md, section 2 validation with one-line errors; the input file is never changed."""

from __future__ import annotations

import gzip
import hashlib
import re
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tests.estimation.conftest import _small_run
from valve_env.data_io import MAX_GAP_S, MIN_ROWS, DataError, flow_unit_hint, load_run, zero_offset
from valve_env.params import ValveParams
from valve_env.physics.valve import opening_from_flow


def _write(df: pd.DataFrame, path: Path) -> Path:
    df.to_csv(path, index=False)
    return path


@pytest.fixture
def run_df(small_run: Callable[..., pd.DataFrame]) -> pd.DataFrame:
    return small_run(seed=4, hours=1.0)


def test_load_valid_run_keeps_extras_and_file(tmp_path: Path, run_df: pd.DataFrame) -> None:
    df = run_df.assign(comment="ok")
    path = _write(df, tmp_path / "run.csv")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    out = load_run(path)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == digest
    assert "comment" in out.columns and len(out) == len(df)
    np.testing.assert_allclose(out["x_mm"], df["x_mm"])


def test_x_derived_from_flow_where_absent(tmp_path: Path, run_df: pd.DataFrame) -> None:
    path = _write(run_df.drop(columns=["x_mm"]), tmp_path / "nox.csv")
    out = load_run(path)
    vp = ValveParams().to_array()
    np.testing.assert_allclose(out["x_mm"], opening_from_flow(run_df["q_kgh"], run_df["dp_mbar"], vp))
    # the derived opening follows the true one within the flow noise
    assert np.sqrt(np.mean((out["x_mm"] - run_df["x_mm"]) ** 2)) < 0.01
    partial = run_df.copy()
    partial.loc[3, "x_mm"] = np.nan
    out2 = load_run(_write(partial, tmp_path / "partial.csv"))
    assert np.isfinite(out2["x_mm"]).all() and out2.attrs["x_mm_derived_rows"] == 1


def test_a_row_with_an_empty_measured_cell_is_dropped(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A logger that missed a value: the row is a missing sample, named by its number in the file."""
    partial = run_df.copy()
    partial.loc[[3, 9], "T_med_C"] = np.nan
    partial.loc[12, "ps_bar"] = np.nan
    out = load_run(_write(partial, tmp_path / "partial.csv"))
    assert len(out) == len(run_df) - 3 and np.isfinite(out[["T_med_C", "ps_bar"]].to_numpy()).all()
    assert out.attrs["rows_dropped_empty"] == [4, 10, 13]
    assert out.attrs["file_rows"][:5] == [1, 2, 3, 5, 6]


def test_a_historians_state_in_place_of_a_value_is_a_missing_sample(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A PI export writes a SYSTEM digital state where a sample has no usable value: read as an empty cell (its
    row dropped and named); other text is still refused."""
    export = run_df.astype({"T_med_C": object, "dp_mbar": object})
    export.loc[5, "T_med_C"] = "I/O Timeout"
    export.loc[17, "dp_mbar"] = " bad input "
    out = load_run(_write(export, tmp_path / "pi.csv"))
    assert len(out) == len(run_df) - 2 and out.attrs["rows_dropped_empty"] == [6, 18]
    export.loc[40, "T_med_C"] = "#N/A"  # and a spreadsheet's error value
    export.loc[41, "dp_mbar"] = "#DIV/0!"
    out = load_run(_write(export, tmp_path / "pi1.csv"))
    assert out.attrs["rows_dropped_empty"] == [6, 18, 41, 42]
    export.loc[30, "dp_mbar"] = "Tuesday"
    with pytest.raises(DataError, match=r"non-numeric value 'Tuesday' in column 'dp_mbar' at row 31"):
        load_run(_write(export, tmp_path / "pi2.csv"))


@pytest.mark.parametrize(("mutate", "pattern"), [
    (lambda d: d.drop(columns=["dp_mbar"]), r"missing column 'dp_mbar'"),
    # a logger's clock instead of seconds: the refusal says which column and what to give
    (lambda d: d.assign(stamp=pd.Timestamp("2026-03-01 06:00") + pd.to_timedelta(d.time_s, unit="s"))
     .drop(columns=["time_s"]), r"missing column 'time_s' .*; column 'stamp' holds date-times: give the time as "
                                r"seconds in a column time_s"),
    (lambda d: d.assign(stamp="01.03.2026 " + (d.time_s // 3600 + 10).astype(int).astype(str) + ":00")
     .drop(columns=["time_s"]), r"column 'stamp' holds date-times"),
    (lambda d: d.drop(columns=["time_s"]), r"missing column 'time_s' \(required: [a-zA-Z_, ]+\)$"),
    # a logger's date and time of day in two columns: both are named (before: 'date' alone, as date-times)
    (lambda d: d.assign(date="2026-03-01", clock=(pd.Timestamp("2026-03-01 06:00")
                                                  + pd.to_timedelta(d.time_s, unit="s")).dt.strftime("%H:%M:%S"))
     .drop(columns=["time_s"]),
     r"columns 'date' and 'clock' hold a date and a time of day: give the time as seconds in a column time_s, e\.g\. "
     r"t = pd\.to_datetime\(date \+ ' ' \+ clock\)"),
    (lambda d: d.assign(time_s=(pd.Timestamp("2026-03-01 06:00") + pd.to_timedelta(d.time_s, unit="s")).astype(str)),
     r"column 'time_s' holds date-times \('2026-03-01 06:00:00'\): give the time as seconds from any origin"),
    # a name in another case or spelling: the refusal names the header's column
    (lambda d: d.rename(columns={"T_tank_C": "T_Tank_C"}),
     r"missing column 'T_tank_C' .*; the header has 'T_Tank_C': rename it T_tank_C \(names are exact\)$"),
    # every missing column's hint at once (before: the first missing column's alone)
    (lambda d: d.rename(columns={"T_tank_C": "T_Tank_C", "q_kgh": "Q_kgh", "T_med_C": "T_med_K"})
     .assign(T_med_K=lambda e: e.T_med_K + 273.15),
     r"missing columns 'T_tank_C', 'T_med_C', 'q_kgh' \(required: .*\); the header has 'T_med_K', T_med in K: give it "
     r"as T_med_C in degC \(subtract 273.15\); the header has 'T_Tank_C', 'Q_kgh': rename them T_tank_C, q_kgh "
     r"\(names are exact\)$"),
    # a clock named like time_s is a clock, not a name to correct (before: 'rename it')
    (lambda d: d.assign(Time=pd.Timestamp("2026-03-01 06:00") + pd.to_timedelta(d.time_s, unit="s"))
     .drop(columns=["time_s"]), r"missing column 'time_s' .*; column 'Time' holds date-times: give the time as "),
    # a long export (one row per channel and time): one column per channel
    (lambda d: d.melt(id_vars="time_s", var_name="channel", value_name="value"),
     r"missing columns 'T_tank_C', .*; column 'channel' names the channels \(T_med_C, T_tank_C, dp_mbar, ps_bar, "
     r"q_kgh\) row by row, a long export: give one column per channel"),
    (lambda d: d.assign(time_h=d.time_s / 3600.0).drop(columns=["time_s"]),
     r"; the header has 'time_h', a time not in seconds: give it as time_s in seconds \(multiply by 3600\)$"),
    (lambda d: d.assign(time_x=d.time_s).drop(columns=["time_s"]),
     r"; the header has 'time_x': if that is time_s in s, rename it \(names are exact\)$"),
    (lambda d: d.assign(time_s=d.time_s * 1000.0),
     r"median sampling interval 1e\+04 s is implausible \(expected 0.001 to 3600 s\); if time_s is in milliseconds, "
     r"divide it by 1000$"),
    # a column in another unit: the refusal says which and what to do
    (lambda d: d.assign(T_med_C=d.T_med_C + 273.15), r"column T_med_C, row 1 \(line 2\): .* out of range .*; every "
                                                     r"value reads as kelvin: subtract 273.15$"),
    (lambda d: d.assign(ps_bar=d.ps_bar * 100.0), r"every value reads as kPa: divide by 100$"),
    (lambda d: d.assign(ps_bar=d.ps_bar * 1e5), r"every value reads as Pa: divide by 100000$"),
    (lambda d: d.assign(time_s=46082.25 + d.time_s / 86400.0),
     r"median sampling interval 0.000116 s is implausible .*; if time_s is in days \(a spreadsheet's date number\), "
     r"multiply it by 86400$"),
    # a Unix time in milliseconds, or datetime64's nanoseconds: the unit under which it is plausible seconds
    (lambda d: d.assign(time_s=(1.7e12 + d.time_s * 1e3).astype("int64")),
     r"1.7e\+12 s is not a plausible time \(\|time_s\| <= 1e\+10 s\); if time_s is in milliseconds \(a Unix time\?\), "
     r"divide by 1000$"),
    (lambda d: d.assign(time_s=(1.7e18 + d.time_s * 1e9).astype("int64")),
     r"; if time_s is in nanoseconds \(a Unix time\?\), divide by 1e\+09$"),
    (lambda d: d.assign(time_s=1e16 + d.time_s), r"is not a plausible time \(\|time_s\| <= 1e\+10 s\)$"),
    # a logger's spikes out of the physical range: every row is named
    (lambda d: d.assign(x_mm=lambda x: x.x_mm.where(~x.index.isin([3, 9, 20]), -1.004)),
     r"column x_mm, row 4 \(line 5\): -1.004 is out of range \(must be >= -1 and <= 50: [^)]*\); "
     r"2 more row\(s\): 10, 21$"),
    (lambda d: d.astype({"q_kgh": object}).assign(q_kgh=lambda x: x.q_kgh.where(x.index != 7, "abc")),
     r"non-numeric value 'abc' in column 'q_kgh' at row 8"),
    (lambda d: d.assign(T_med_C=lambda x: x.T_med_C.where((x.index < 4) | (x.index % 5 != 0), np.nan)),
     r"have an empty cell in a measured column \(the first: 'T_med_C' at row 6, line 7\); at most 10%"),
    (lambda d: d.assign(time_s=lambda x: x.time_s.where(x.index != 4, np.nan)), r"NaN .* column 'time_s' at row 5"),
    (lambda d: d.assign(time_s=lambda x: x.time_s.where(x.index != 10, 0.0)), r"time_s is not increasing at row 11"),
    (lambda d: d.iloc[:5], rf"too short a record, 5 rows; at least {MIN_ROWS}"),
    (lambda d: d.assign(T_tank_C=55.0), r"constant .* identifies nothing"),
])
def test_bad_input_one_line(tmp_path: Path, run_df: pd.DataFrame, mutate: Callable[[pd.DataFrame], pd.DataFrame],
                            pattern: str) -> None:
    path = _write(mutate(run_df), tmp_path / "bad.csv")
    with pytest.raises(DataError, match=pattern) as info:
        load_run(path)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, ValueError)


def test_missing_and_empty_files(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no such file"):
        load_run(tmp_path / "nope.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(DataError, match="empty"):
        load_run(tmp_path / "empty.csv")


def test_a_decimal_comma_locales_thousands_points_are_read(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A spreadsheet in a decimal-comma locale writes a formatted cell with points between the thousands (1.234,5 and
    12.500): the same run as the plain file."""
    from valve_env.data_io import decimal_comma

    assert [decimal_comma(c) for c in ("52,61", "1.234,5", "-12.500", "1.2345", "abc")] == \
        ["52.61", "1234.5", "-12500", "1.2345", "abc"]
    df = run_df.copy()
    df["q_kgh"] = np.round(df["q_kgh"] * 10.0, 2)  # above 1000 kg/h
    df.loc[4, "q_kgh"] = 1500.0  # a whole number: 1.500
    plain = load_run(_write(df, tmp_path / "plain.csv"))
    text = df.to_csv(index=False, sep=";", decimal=",")
    lines = text.splitlines()
    col = list(df.columns).index("q_kgh")
    for i in range(1, len(lines)):
        cells = lines[i].split(";")
        whole, _, frac = cells[col].partition(",")
        cells[col] = f"{int(whole):,}".replace(",", ".") + (f",{frac}" if frac.strip("0") else "")
        lines[i] = ";".join(cells)
    assert lines[5].split(";")[col] == "1.500" and any("." in ln.split(";")[col] for ln in lines[1:])
    path = tmp_path / "grouped.csv"
    path.write_text("\n".join(lines) + "\n")
    pd.testing.assert_frame_equal(load_run(path), plain)


def test_a_file_with_both_decimal_marks_is_refused_saying_so(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A spreadsheet that kept some columns as text writes them with a decimal point and its own numbers with a
    comma: which mark a cell means is not known, so the file is refused in one line that says so."""
    text = run_df.to_csv(index=False, sep=";")
    lines = text.splitlines()
    col = list(run_df.columns).index("x_mm")
    for i in range(1, len(lines)):
        cells = lines[i].split(";")
        cells[col] = cells[col].replace(".", ",")
        lines[i] = ";".join(cells)
    path = tmp_path / "mixed.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"in column 'x_mm' at row 1 \(line 2\); it has a decimal comma where the "
                                        r"file's other numbers have a decimal point") as info:
        load_run(path)
    assert "\n" not in str(info.value)


def test_a_thousands_separator_is_named(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A spreadsheet's "1000 separator" (``1,234.5``, quoted in a comma-separated file) is refused in one line that
    names it, at the first cell that has one."""
    df = run_df.astype({"q_kgh": object})
    df["q_kgh"] = [f"{v * 1e4:,.3f}" for v in run_df["q_kgh"]]  # scaled into the thousands: the refusal reads the text
    first = next(i for i, v in enumerate(df["q_kgh"]) if "," in v)
    path = tmp_path / "grouped.csv"
    df.to_csv(path, index=False)
    with pytest.raises(DataError, match=rf"in column 'q_kgh' at row {first + 1} \(line {first + 2}\); a comma groups "
                                        r"its thousands \(a spreadsheet's thousands separator\): write numbers "
                                        r"without it$"):
        load_run(path)


def test_cells_that_carry_a_unit_are_read_or_named(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A formatted spreadsheet cell writes its unit after the number (``243.918 kg/h``, ``52.3°C``): cells that carry
    the format's own unit are read as their numbers, with a note; another unit, or text that is no unit, is refused
    in one line that names it and what to do; a loop record's cell is named the same way (tests/loops)."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    path = tmp_path / "units.csv"
    for col, fmt in (("q_kgh", "{:.6f} kg/h"), ("T_tank_C", "{:.6f} \u00b0C"), ("dp_mbar", "{:.6f}mbar")):
        df = run_df.astype({col: object})
        df[col] = [fmt.format(v) for v in run_df[col]]
        df.loc[3, col] = ""  # an empty cell stays empty
        df.to_csv(path, index=False, encoding="utf-8")
        out = load_run(path)
        assert out[col].to_numpy()[:3] == pytest.approx(run_df[col].to_numpy()[:3], rel=1e-4)
        assert out.attrs["units_in_cells"] == {col: fmt.format(1.0).split("1.", 1)[1].lstrip("0123456789 ")}
        _, notes = preprocess_run(out)
        assert any(line.startswith(f"the cells of {col}: the format's units") for line in describe(notes))
    df = run_df.astype({"T_tank_C": object})
    df["T_tank_C"] = [f"{v * 1.8 + 32:.2f} \u00b0F" for v in run_df["T_tank_C"]]  # another unit: named, not read
    df.to_csv(path, index=False, encoding="utf-8")
    with pytest.raises(DataError, match=r"in column 'T_tank_C' at row 1 \(line 2\); the cell carries its unit "
                                        r"\('\u00b0F'\), as a formatted spreadsheet cell does: write the numbers "
                                        r"alone \(a unit may follow the column's name in the header\)$"):
        load_run(path)
    from valve_env.data_io import decimal_mark_hint

    assert decimal_mark_hint("I/O Timeout") == "" and decimal_mark_hint("5 5") == ""


@pytest.mark.parametrize(("sep", "decimal", "comments"), [
    (";", ",", ""), ("\t", ".", ""), (",", ".", "# rig 2, valve 7\n\n# logged every 10 s\n"), (";", ".", "# export\n"),
    # a spreadsheet's line that names the separator (Excel's sep=): here a header with no semicolon to go by
    (";", ",", "sep=;\n"), ("\t", ".", '"sep=\t"\n'),
])
def test_a_run_of_another_locale_is_read_as_written(tmp_path: Path, run_df: pd.DataFrame, sep: str, decimal: str,
                                                    comments: str) -> None:
    """A spreadsheet's export in a locale with a decimal comma (semicolons), a tab-separated file, comment lines
    and a spreadsheet's separator line (``sep=;``) before the header give the same run as the comma file; a bad cell
    is named by the file's own line."""
    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    text = comments + run_df.to_csv(index=False, sep=sep, decimal=decimal)
    path = tmp_path / "other.csv"
    path.write_text(text)
    pd.testing.assert_frame_equal(load_run(path), plain)
    lines = text.splitlines()
    line = len(comments.splitlines()) + 9  # the file's line of row 8
    cells = lines[line - 1].split(sep)
    cells[list(run_df.columns).index("q_kgh")] = "abc"
    lines[line - 1] = sep.join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=rf"'abc' in column 'q_kgh' at row 8 \(line {line}\)"):
        load_run(path)


@pytest.mark.parametrize("kind", ["utf16_tabs", "windows_1252", "spaces", "fixed_width", "footer", "empty_sheet_rows",
                                  "gzip"])
def test_a_run_as_other_programs_save_it_is_read_as_written(tmp_path: Path, run_df: pd.DataFrame, kind: str) -> None:
    """A spreadsheet's "Unicode text" save (UTF-16 with its byte-order mark, tabs), a space-separated or fixed-width
    export, a logger's closing comment and a spreadsheet's empty formatted rows after the data: the same run as the
    comma file; a bad cell in a space-separated file is named by its line."""
    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    path = tmp_path / "other.txt"
    if kind == "utf16_tabs":
        path.write_text(run_df.to_csv(index=False, sep="\t"), encoding="utf-16")
        assert path.read_bytes()[:2] in (b"\xff\xfe", b"\xfe\xff")
    elif kind == "windows_1252":  # a spreadsheet's plain "CSV" save on Windows: its units row's degree sign
        lines = run_df.to_csv(index=False, sep=";", decimal=",").splitlines()
        units = ";".join({"time_s": "s", "T_tank_C": "°C", "T_med_C": "°C"}.get(c, "") for c in run_df.columns)
        path.write_bytes("\r\n".join([lines[0], units, *lines[1:]]).encode("cp1252"))
        assert b"\xb0C" in path.read_bytes()
    elif kind == "spaces":
        path.write_text(run_df.to_csv(index=False, sep=" "))
    elif kind == "fixed_width":  # right-aligned columns, every number in full
        path.write_text(run_df.to_string(index=False, float_format=lambda v: f"{v:.17g}") + "\n")
    elif kind == "footer":
        path.write_text(run_df.to_csv(index=False) + "# end of export, 361 rows\n\n#\n")
    elif kind == "gzip":  # an archived logger file
        path = tmp_path / "run.csv.gz"
        path.write_bytes(gzip.compress(run_df.to_csv(index=False).encode()))
    else:
        path.write_text(run_df.to_csv(index=False, sep=";", decimal=",") + ";;;;;;\n" * 3)
    out = load_run(path)
    pd.testing.assert_frame_equal(out if kind != "windows_1252" else out.reset_index(drop=True), plain,
                                  check_like=True)
    if kind == "spaces":
        lines = path.read_text().splitlines()
        cells = lines[8].split(" ")
        cells[list(run_df.columns).index("q_kgh")] = "abc"
        lines[8] = " ".join(cells)
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(DataError, match=r"'abc' in column 'q_kgh' at row 8 \(line 9\)"):
            load_run(path)


def _skipped_and_noted(path: Path, edited: list[str], plain: pd.DataFrame, what: str, line: int) -> list[str]:
    """Write ``edited`` to ``path`` and read it: the same run as ``plain``, with the ``what`` note naming the file's
    ``line`` (in the run's attrs and in the pre-processing's notes); returns the notes as the report describes them."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    path.write_text("\n".join(edited) + "\n")
    out = load_run(path)
    pd.testing.assert_frame_equal(out, plain, check_like=True)
    assert out.attrs[what] == [line]
    notes = preprocess_run(out)[1]
    assert [n["lines"] for n in notes if n["what"] == what] == [[line]]
    assert not any(n["what"] == what for n in preprocess_run(plain)[1])
    return describe(notes)


def test_comment_and_empty_lines_among_the_data_are_skipped_and_lines_named_as_in_the_file(
        tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A logger's comment among the data (``# logger restarted``), an empty line, a line of spaces and a
    spreadsheet's emptied row (separators only) are skipped: the same run, a ``comment_lines`` note naming the
    comment's line, and a bad cell after them named by the file's own line (rows are counted without them)."""
    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    lines = (tmp_path / "plain.csv").read_text().splitlines()
    # line 1 the header; an empty line, a line of spaces and an emptied row before data row 50, the comment before
    # data row 100
    edited = [*lines[:50], "", "   ", "," * (len(run_df.columns) - 1), *lines[50:99], "# logger restarted, 10:12",
              *lines[99:]]
    path = tmp_path / "commented.csv"
    described = _skipped_and_noted(path, edited, plain, "comment_lines", 103)
    assert "1 comment line(s) among the data skipped (lines 103)" in described
    cells = edited[200].split(",")  # data row 196: the file's line 201
    cells[list(run_df.columns).index("T_tank_C")] = "999"
    edited[200] = ",".join(cells)
    path.write_text("\n".join(edited) + "\n")
    with pytest.raises(DataError, match=r"column T_tank_C, row 196 \(line 201\): 999 is out of range"):
        load_run(path)
    cells[list(run_df.columns).index("T_tank_C")] = "abc"
    edited[200] = ",".join(cells)
    path.write_text("\n".join(edited) + "\n")
    with pytest.raises(DataError, match=r"'abc' in column 'T_tank_C' at row 196 \(line 201\)"):
        load_run(path)


def test_a_repeated_header_line_among_the_data_is_skipped_and_noted(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A logger that writes its header again after a restart (or two logs joined) repeats the header line among the
    data: skipped, with a ``header_lines`` note naming the file's line; a bad cell after it is named by its own line.
    Before, the repeated header was refused as a non-numeric value 'time_s'."""
    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    lines = (tmp_path / "plain.csv").read_text().splitlines()
    edited = [*lines[:150], lines[0], *lines[150:]]  # the header again as the file's line 151
    path = tmp_path / "restarted.csv"
    described = _skipped_and_noted(path, edited, plain, "header_lines", 151)
    assert "1 repeated header line(s) among the data skipped (lines 151)" in described
    cells = edited[200].split(",")  # data row 199: the file's line 201
    cells[list(run_df.columns).index("T_tank_C")] = "abc"
    edited[200] = ",".join(cells)
    path.write_text("\n".join(edited) + "\n")
    with pytest.raises(DataError, match=r"'abc' in column 'T_tank_C' at row 199 \(line 201\)"):
        load_run(path)
    joined = [*lines, *lines]  # two logs joined whose times start again: refused by the times, not read as one
    path.write_text("\n".join(joined) + "\n")
    with pytest.raises(DataError, match=r"time_s is not increasing at row \d+ \(line \d+\)"):
        load_run(path)


def test_a_last_line_cut_off_mid_write_and_nul_padding_are_dropped_and_noted(tmp_path: Path,
                                                                             run_df: pd.DataFrame) -> None:
    """A logger that stopped or lost power mid-write leaves its last line short, perhaps cut within its time (which
    read '2161' then passed for a time out of order: 'sort them by time_s'), and a file on an SD card that was
    preallocated ends in NUL bytes (refused as not text). Both are dropped with a note: the same run as the plain
    file. A NUL byte before the end is still refused, and a short line among the data is not taken for a cut one."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    text = (tmp_path / "plain.csv").read_text()
    lines = text.splitlines()
    n = len(lines)
    for tail in (lines[-1][:4], lines[-1][:len(lines[-1]) // 2]):
        path = tmp_path / "cut.csv"
        path.write_bytes(("\n".join([*lines, tail])).encode() + bytes(4096))
        out = load_run(path)
        pd.testing.assert_frame_equal(out, plain, check_like=True)
        notes = preprocess_run(out)[1]
        cut = [nt for nt in notes if nt["what"] == "last_line_cut"]
        assert [(nt["line"], nt["of"]) for nt in cut] == [(n + 1, len(run_df.columns))]
        assert cut[0]["fields"] < len(run_df.columns)
        assert [nt["bytes"] for nt in notes if nt["what"] == "nul_padding"] == [4096]
        assert f"line {n + 1}: the last line, cut off mid-write" in "\n".join(describe(notes))
    assert not {"last_line_cut", "nul_padding"} & {nt["what"] for nt in preprocess_run(plain)[1]}
    (tmp_path / "nul.csv").write_bytes(text.encode()[:300] + b"\x00" + text.encode()[300:])
    with pytest.raises(DataError, match=r"a NUL byte: not text at byte 300\)$"):
        load_run(tmp_path / "nul.csv")
    # a quoted separator in the line before the last (a status column's text) does not make the last one look cut
    quoted = [lines[0] + ",status", *[ln + ",OK" for ln in lines[1:-2]], lines[-2] + ',"ALARM, high"',
              lines[-1] + ",OK"]
    (tmp_path / "quoted.csv").write_text("\n".join(quoted) + "\n")
    out = load_run(tmp_path / "quoted.csv")
    assert len(out) == len(plain) and "last_line_cut" not in out.attrs
    short = [*lines[:100], lines[100][:4], *lines[101:]]  # data row 100 cut: a missed sample, dropped as such
    (tmp_path / "short.csv").write_text("\n".join(short) + "\n")
    notes = preprocess_run(load_run(tmp_path / "short.csv"))[1]
    assert [nt["rows"] for nt in notes if nt["what"] == "rows_dropped"] == [[100]]
    assert not any(nt["what"] == "last_line_cut" for nt in notes)


def test_a_dash_fortran_exponents_and_a_reversed_dp_are_read_or_named(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A dash for no value (``-``, ``--``, en or em dash, as a report or a formatted spreadsheet writes it) is a
    missing sample; a Fortran program's exponent (``5.29D+01``) reads as the number; a dp measured the other way
    round (every value negative) is refused in one line that says to negate it."""
    dashed = run_df.astype({"T_med_C": object, "ps_bar": object})
    for row, mark in zip((5, 17, 30, 44), ("-", "--", "\u2013", "\u2014"), strict=True):
        dashed.loc[row, "T_med_C" if row < 30 else "ps_bar"] = mark
    out = load_run(_write(dashed, tmp_path / "dashed.csv"))
    assert out.attrs["rows_dropped_empty"] == [6, 18, 31, 45]
    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    fortran = tmp_path / "fortran.csv"
    fortran.write_text("\n".join([",".join(run_df.columns)] + [",".join(f"{v:.15E}".replace("E", "D") for v in r)
                                                              for r in run_df.to_numpy()]) + "\n")
    pd.testing.assert_frame_equal(load_run(fortran), plain, check_like=True, check_dtype=False)
    with pytest.raises(DataError, match=r"column dp_mbar, row 1 \(line 2\): -[\d.]+ is out of range .* every value "
                                        r"reads as mbar with the sign reversed .*: negate the column$"):
        load_run(_write(run_df.assign(dp_mbar=-run_df.dp_mbar), tmp_path / "reversed.csv"))
    few = run_df.assign(dp_mbar=run_df.dp_mbar.where(~run_df.index.isin([3, 9]), -100.0))  # two bad rows only
    with pytest.raises(DataError, match=r"row 4 .* 1 more row\(s\): 10$"):
        load_run(_write(few, tmp_path / "few.csv"))


def test_a_time_in_another_unit_by_name_and_rows_newest_first_are_named(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A time column named in another unit (``time_h``, ``t_min``, ``time_ms``) is named with its factor to seconds,
    where before the refusal offered to rename it as if it were in seconds; rows newest first (some historians'
    export) or shuffled are named as such, and so are two logs joined whose times start again (a logger's clock reset)
    or overlap (two exports that share rows)."""
    for name, do in (("time_h", "multiply by 3600"), ("t_min", "multiply by 60"), ("time_ms", "divide by 1000")):
        with pytest.raises(DataError, match=rf"missing column 'time_s' .*; the header has '{name}', a time not in "
                                            rf"seconds: give it as time_s in seconds \({do}\)$"):
            load_run(_write(run_df.rename(columns={"time_s": name}), tmp_path / "t.csv"))
    with pytest.raises(DataError, match=r"not increasing at row 2 \(line 3\) .*; the rows run newest first"):
        load_run(_write(run_df.iloc[::-1], tmp_path / "newest.csv"))
    shuffled = run_df.iloc[np.random.default_rng(0).permutation(len(run_df))]
    with pytest.raises(DataError, match=r"not increasing at row .*; the rows are out of time order"):
        load_run(_write(shuffled, tmp_path / "shuffled.csv"))
    with pytest.raises(DataError, match=rf"at row {len(run_df) + 1} .*; the time starts again there \(a logger's "
                                        r"clock reset, or files joined whose times each start at 0\?\)"):
        load_run(_write(pd.concat([run_df, run_df]), tmp_path / "joined.csv"))
    with pytest.raises(DataError, match=r"at row 31 .*; the rows from there repeat 5 time\(s\) of the rows before "
                                        r"them \(two exports joined with an overlap\?\): drop the repeated rows$"):
        load_run(_write(pd.concat([run_df.iloc[:30], run_df.iloc[25:]]), tmp_path / "overlap.csv"))
    # times from a clock on local time: at the end of summer time they go back by an hour (before, named an overlap
    # of joined exports, whose advice, to drop the repeated rows, would lose an hour of samples)
    t = np.arange(len(run_df)) * 20.0
    local = run_df.assign(time_s=np.where(np.arange(len(run_df)) >= 250, t - 3600.0, t))
    with pytest.raises(DataError, match=r"at row 251 .*; the time goes back by an hour there \(times from a clock on "
                                        r"local time, at the end of summer time\?\): give the times in UTC, or add "
                                        r"3600 s to the times from there$"):
        load_run(_write(local, tmp_path / "local.csv"))
    # the same within the record's first hour, where the time goes back to before its start (before, named a restart)
    early = run_df.assign(time_s=np.where(np.arange(len(run_df)) >= 150, t - 3600.0, t))
    with pytest.raises(DataError, match=r"at row 151 .*; the time goes back by an hour there"):
        load_run(_write(early, tmp_path / "early.csv"))


def test_a_workbook_is_refused_saying_to_save_it_as_csv(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A spreadsheet's workbook given where a CSV file is wanted (an .xlsx is a zip archive, an .xls an Office binary
    file): one line saying what it is and to save the sheet as CSV; a broken gzip file, one line."""
    path = tmp_path / "run.xlsx"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("xl/worksheets/sheet1.xml", "<worksheet/>")
    with pytest.raises(DataError, match=r"run.xlsx: not a text file but a zip archive \(a spreadsheet's workbook, "
                                        r"\.xlsx or \.ods\?\): save the sheet as CSV$"):
        load_run(path)
    (tmp_path / "run.xls").write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(504))
    with pytest.raises(DataError, match=r"an Office binary file \(an \.xls workbook\?\): save the sheet as CSV$"):
        load_run(tmp_path / "run.xls")
    (tmp_path / "run.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(32))
    with pytest.raises(DataError, match=r"run.png: not a text file \(neither UTF-8, UTF-16 with a byte-order mark nor "
                                        r"Windows-1252: a NUL byte: not text at byte 8\)$"):
        load_run(tmp_path / "run.png")
    (tmp_path / "cut.csv.gz").write_bytes(gzip.compress(run_df.to_csv(index=False).encode())[:200])
    with pytest.raises(DataError, match=r"cut.csv.gz: a gzip file that does not decompress \(") as info:
        load_run(tmp_path / "cut.csv.gz")
    assert "\n" not in str(info.value)


def test_units_after_the_names_in_the_header_are_read(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A logger's header that gives each column's unit after its name (``T_tank_C [°C]``, ``q_kgh (kg/h)``,
    ``time_s / s``): the same run, with a note; a name with another unit is refused in one line naming the unit to
    convert to."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    units = {"time_s": "/ s", "T_tank_C": "[°C]", "T_med_C": "(degC)", "q_kgh": "[kg/h]", "dp_mbar": "(mbar)",
             "ps_bar": "[bar]", "x_mm": "[mm]"}
    named = run_df.rename(columns={c: f"{c} {u}" for c, u in units.items()})
    out = load_run(_write(named, tmp_path / "named.csv"))
    pd.testing.assert_frame_equal(out, plain, check_like=True)
    assert out.attrs["units_in_header"]["T_med_C"] == "degC"
    notes = preprocess_run(out)[1]
    assert [nt["what"] for nt in notes][:1] == ["units_in_header"]
    assert "the header: the format's units after the names; read as the names" in describe(notes)
    with pytest.raises(DataError, match=r"column 'dp_mbar \[Pa\]' gives dp_mbar in 'Pa': the format's unit is mbar "
                                        r"\(docs/reference.md, section 2\); convert the column to mbar \(divide by "
                                        r"100\)$"):
        load_run(_write(run_df.rename(columns={"dp_mbar": "dp_mbar [Pa]"}), tmp_path / "pa.csv"))


@pytest.mark.parametrize("sep", [",", ";"])
def test_a_units_row_under_the_header_is_read_as_a_second_header_line(tmp_path: Path, run_df: pd.DataFrame,
                                                                      sep: str) -> None:
    """A logger's second header line with the format's units (in the ways loggers write them) gives the same run as
    the file without it, the row numbers counted from the line after it, and a note; another unit is refused in one
    line naming the column and the unit to convert to."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    plain = load_run(_write(run_df, tmp_path / "plain.csv"))
    units = {"time_s": "s", "T_tank_C": "[°C]", "T_med_C": "deg C", "q_kgh": "kg/h", "dp_mbar": "mbar",
             "ps_bar": "bar(g)", "x_mm": "(mm)"}
    decimal = "," if sep == ";" else "."
    lines = run_df.to_csv(index=False, sep=sep, decimal=decimal).splitlines()
    row = sep.join(units.get(c, "") for c in run_df.columns)
    path = tmp_path / "units.csv"
    path.write_text("\n".join([lines[0], row, *lines[1:]]) + "\n", encoding="utf-8")
    out = load_run(path)
    pd.testing.assert_frame_equal(out[plain.columns].reset_index(drop=True), plain, check_like=True, check_dtype=False)
    assert out.attrs["units_row"] == {"line": 2, "units": units}
    notes = preprocess_run(out)[1]
    assert [nt["line"] for nt in notes if nt["what"] == "units_row"] == [2]
    assert any(line.startswith("line 2: a units row") for line in describe(notes))
    # a bad cell is named by its row after the units row and by the file's own line
    bad = [lines[0], row, *lines[1:]]
    cells = bad[9].split(sep)  # the file's line 10: row 8
    cells[list(run_df.columns).index("q_kgh")] = "abc"
    bad[9] = sep.join(cells)
    path.write_text("\n".join(bad) + "\n", encoding="utf-8")
    with pytest.raises(DataError, match=r"'abc' in column 'q_kgh' at row 8 \(line 10\)"):
        load_run(path)
    for col, unit, want, how in (("dp_mbar", "Pa", "mbar", "divide by 100"),
                                 ("T_med_C", "K", "degC", "subtract 273.15"),
                                 ("time_s", "ms", "s", "divide by 1000"),
                                 ("x_mm", "%", "mm", "a position in % of the stroke: .* over 100, 0.02 for the "
                                                     "calibrated valve's 2 mm"),
                                 ("x_mm", "furlong", "mm", None)):
        other = sep.join({**units, col: unit}.get(c, "") for c in run_df.columns)
        path.write_text("\n".join([lines[0], other, *lines[1:]]) + "\n", encoding="utf-8")
        end = rf" \({how}\)$" if how else "$"  # a unit without a known factor: the unit to convert to, alone
        with pytest.raises(DataError, match=rf"line 2 is a units row, and column {col} is given in '{unit}': the "
                                            rf"format's unit is {want} .*convert the column to {want}{end}"):
            load_run(path)


def test_temperatures_in_whole_tenths_of_a_degree_are_named(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A controller's integer register holds a temperature in tenths of a degC (526 for 52.6 degC): the range refusal
    names the unit; a record in kelvin, which has decimals, is still named kelvin, and one rounded to whole kelvin
    (where both would fit) too, as the first unit that fits."""
    tenths = run_df.assign(T_tank_C=(run_df.T_tank_C * 10).round(), T_med_C=(run_df.T_med_C * 10).round())
    with pytest.raises(DataError, match=r"column T_tank_C, row 1 .*; every value reads as tenths of a degC \(a "
                                        r"controller's integer register\): divide by 10, and the other temperature "
                                        r"column too$"):
        load_run(_write(tenths, tmp_path / "tenths.csv"))
    for kelvin in (run_df.T_tank_C + 273.15, (run_df.T_tank_C + 273.15).round()):
        with pytest.raises(DataError, match=r"every value reads as kelvin: subtract 273.15$"):
            load_run(_write(run_df.assign(T_tank_C=kelvin), tmp_path / "k.csv"))


def test_an_absolute_static_pressure_is_refused_with_what_to_subtract(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """ps_bar is the static pressure over the ambient (dp_s = p_1 - p_0 in the force balance): a units row or a header
    that gives it in bar absolute is refused, naming the ambient pressure to subtract (a bar(a) column read as gauge
    moves the stem seal's force by the ambient's 1 bar); bar(g) is read."""
    path = tmp_path / "run.csv"
    lines = run_df.to_csv(index=False).splitlines()
    units = {c: "" for c in run_df.columns} | {"time_s": "s", "T_tank_C": "degC", "ps_bar": "bar(a)"}
    path.write_text("\n".join([lines[0], ",".join(units[c] for c in run_df.columns), *lines[1:]]) + "\n")
    with pytest.raises(DataError, match=r"column ps_bar is given in 'bar\(a\)': an absolute pressure: the format's "
                                        r"ps_bar is the static pressure over the ambient .*subtract the ambient "
                                        r"pressure, about 1.013 bar$"):
        load_run(path)
    for unit in ("bara", "bar abs"):
        run_df.rename(columns={"ps_bar": f"ps_bar [{unit}]"}).to_csv(path, index=False)
        with pytest.raises(DataError, match=rf"gives ps_bar in '{unit}': an absolute pressure"):
            load_run(path)
    run_df.rename(columns={"ps_bar": "ps_bar [barg]"}).to_csv(path, index=False)
    assert load_run(path)["ps_bar"].to_numpy() == pytest.approx(run_df["ps_bar"].to_numpy())


@pytest.mark.parametrize(("column", "new", "scale", "hint"), [
    ("T_tank_C", "T_tank_K", lambda v: v + 273.15, "T_tank in K: give it as T_tank_C in degC (subtract 273.15)"),
    ("T_med_C", "T_med_degF", lambda v: v * 1.8 + 32, r"T_med in degF: give it as T_med_C in degC (convert with "
                                                      r"(v - 32) \* 5 / 9)"),
    ("dp_mbar", "dp_kPa", lambda v: v / 10, "dp in kPa: give it as dp_mbar in mbar (multiply by 10)"),
    ("dp_mbar", "dp [Pa]", lambda v: v * 100, "dp in Pa: give it as dp_mbar in mbar (divide by 100)"),
    ("ps_bar", "ps_kPa", lambda v: v * 100, "ps in kPa: give it as ps_bar in bar (divide by 100)"),
    ("ps_bar", "ps_psia", lambda v: v * 14.5 + 14.7, "an absolute pressure: .* subtract the ambient pressure, about "
                                                     "1.013 bar, and name it ps_bar"),
    ("q_kgh", "q_m3h", lambda v: v / 983.2, "q in m3h: give it as q_kgh in kg/h (a volume flow: .*; at 60 degC "
                                            "multiply by 983.2)"),
    ("q_kgh", "q (l/min)", lambda v: v / 59.0, "q in l/min: give it as q_kgh in kg/h (a volume flow: .*; at 60 "
                                               "degC multiply by 58.99)"),
    ("q_kgh", "q_kgs", lambda v: v / 3600, "q in kgs: give it as q_kgh in kg/h (multiply by 3600)"),
])
def test_a_column_named_in_another_unit_is_refused_with_its_conversion(tmp_path: Path, run_df: pd.DataFrame,
                                                                       column: str, new: str,
                                                                       scale: Callable[[pd.Series], pd.Series],
                                                                       hint: str) -> None:
    """A logger that names a channel with its own unit (``T_tank_K``, ``dp_kPa``, ``q_m3h``) gets the missing column's
    refusal with the column it has and the factor or offset to the format's unit, in one line."""
    df = run_df.assign(**{new: scale(run_df[column])}).drop(columns=[column])
    with pytest.raises(DataError, match=rf"missing column '{column}' .*; the header has {re.escape(repr(new))}"
                                        rf"(, |: ){hint.replace('(', '[(]').replace(')', '[)]')}$") as err:
        load_run(_write(df, tmp_path / "unit.csv"))
    assert "\n" not in str(err.value)


def test_an_opening_named_in_another_unit_is_not_read_and_a_warning_says_so(tmp_path: Path,
                                                                            run_df: pd.DataFrame) -> None:
    """The opening is optional, so an ``x_um`` column is an extra column and the opening is derived from the flow (as
    without it); the pre-processing note says which column was left unread and how to give it, marked for the console
    (``warn``), where a column named otherwise gets no such note."""
    from valve_env.valveid.preprocess import preprocess_run

    df = run_df.assign(x_um=run_df.x_mm * 1000.0).drop(columns=["x_mm"])
    out = load_run(_write(df, tmp_path / "um.csv"))
    plain = load_run(_write(run_df.drop(columns=["x_mm"]), tmp_path / "none.csv"))
    np.testing.assert_array_equal(out["x_mm"].to_numpy(), plain["x_mm"].to_numpy())  # derived, x_um unread
    note = next(nt for nt in preprocess_run(out)[1] if nt["what"] == "x_mm_derived")
    assert note.get("warn") is True
    assert note["why"].endswith("; the header has 'x_um', x in um: give it as x_mm in mm (divide by 1000), to read "
                                "the measured opening instead (the column is not read)")
    other = load_run(_write(run_df.assign(x_pos=run_df.x_mm).drop(columns=["x_mm"]), tmp_path / "pos.csv"))
    note = next(nt for nt in preprocess_run(other)[1] if nt["what"] == "x_mm_derived")
    assert "warn" not in note and "x_pos" not in note["why"]


def test_a_record_of_minutes_or_hours_read_as_seconds_is_named(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A time column in hours read as seconds makes an hour's run span a second: the pre-processing notes it (`fit`
    warns on the console) and `diagnose`'s refusal says what to give; a record of an hour gets no such note."""
    from valve_env.valveid.diagnose import DiagnosisError, check_run
    from valve_env.valveid.preprocess import describe, preprocess_run

    hours = run_df.assign(time_s=run_df.time_s / 3600.0)
    notes = preprocess_run(load_run(_write(hours, tmp_path / "h.csv")))[1]
    short = [nt for nt in notes if nt["what"] == "short_span"]
    assert len(short) == 1 and short[0]["why"].endswith("if time_s is in minutes or hours, give it in seconds")
    assert any(line.startswith("time: the record spans 1 s") for line in describe(notes))
    assert not [nt for nt in preprocess_run(load_run(_write(run_df, tmp_path / "s.csv")))[1]
                if nt["what"] == "short_span"]
    with pytest.raises(DiagnosisError, match=r"needs at least 1.9 h\); the record spans 1 s over \d+ samples: if "
                                             r"time_s is in minutes or hours, give it in seconds$"):
        check_run(hours, "h.csv")


@pytest.fixture(scope="module")
def open_run() -> pd.DataFrame:
    """A run whose valve opens (the first hour of :func:`run_df`'s is closed throughout)."""
    return _small_run(seed=4, hours=4.0)


@pytest.mark.parametrize(("mutate", "pattern"), [
    # a dp in another unit, shown by the flow through the valve characteristic at the measured opening: a dp of 80 mbar
    # in Pa stays within the range of a dp in mbar on every row
    (lambda d: d.assign(dp_mbar=d.dp_mbar * 100.0),
     r"column dp_mbar reads as Pa: the flow q_kgh is 0.1 times what x_mm and dp_mbar give .*; divide by 100$"),
    (lambda d: d.assign(dp_mbar=d.dp_mbar * 80.0), r"reads as Pa: .* would be 80 mbar .*; divide by 100$"),
    (lambda d: d.assign(dp_mbar=d.dp_mbar * 0.1), r"reads as kPa: the flow q_kgh is 3.16 times .*; multiply by 10$"),
    (lambda d: d.assign(dp_mbar=d.dp_mbar * 0.001),
     r"reads as bar: the flow q_kgh is 31.6 times .*; multiply by 1000$"),
    # an opening beyond the valve's 2 mm stroke: a position transmitter's % of the stroke (within the 50 mm range where
    # the valve opens to less than half its stroke), or um
    (lambda d: d.assign(x_mm=d.x_mm * 50.0 * 0.5),
     r"column x_mm reaches .* mm \(its 99th percentile\), beyond the valve's 2 mm stroke .*; if x_mm is in % of the "
     r"stroke, multiply by 0.02$"),
    (lambda d: d.assign(x_mm=d.x_mm * 1000.0),
     r"beyond the valve's 2 mm stroke .*; if x_mm is in um, multiply by 0.001$"),
    # a logger's sentinel on a few rows is named by its rows, not taken for a unit
    (lambda d: d.assign(x_mm=d.x_mm.where(d.index % 60 != 0, 99999.0)),
     r"column x_mm, row 1 \(line 2\): 99999 is out of range .*; 24 more row\(s\): 61, 121, "),
    # a closing travel logged as the opening (a transmitter mounted the other way)
    (lambda d: d.assign(x_mm=2.0 - d.x_mm),
     r"column x_mm falls as the flow rises \(rank correlation -[01]\.\d\d .*\): if x_mm is the closing travel, "
     r"give the opening \(2 mm - x_mm\)$"),
])
def test_an_opening_or_dp_in_another_unit_is_named(tmp_path: Path, open_run: pd.DataFrame,
                                                     mutate: Callable[[pd.DataFrame], pd.DataFrame],
                                                     pattern: str) -> None:
    with pytest.raises(DataError, match=pattern):
        load_run(_write(mutate(open_run), tmp_path / "bad.csv"))


def test_a_valve_of_another_size_at_its_usual_dp_is_not_taken_for_a_unit(tmp_path: Path, open_run: pd.DataFrame
                                                                         ) -> None:
    """A flow a tenth of the characteristic's at a plausible dp (a smaller valve than the calibrated one) loads; so does
    a dp in Pa without a measured opening, where nothing shows the unit but the range."""
    out = load_run(_write(open_run.assign(q_kgh=open_run.q_kgh * 0.1), tmp_path / "small_valve.csv"))
    np.testing.assert_allclose(out["dp_mbar"], open_run["dp_mbar"])
    low = open_run.assign(dp_mbar=open_run.dp_mbar * 80.0).drop(columns=["x_mm"])
    assert load_run(_write(low, tmp_path / "no_x.csv"))["dp_mbar"].median() > 7000.0


def test_a_flow_unit_is_named_where_it_would_make_the_derived_opening_move(open_run: pd.DataFrame) -> None:
    """Without x_mm, a flow in l/min, m^3/h or kg/s derives an opening that hardly moves; the hint names the units
    under which it would span at least a tenth of the stroke, and nothing for a flow in kg/h."""
    q, dp = open_run["q_kgh"].to_numpy(), open_run["dp_mbar"].to_numpy()
    assert flow_unit_hint(q, dp) == ""
    assert "if q_kgh is in l/min (multiply by 60: the opening would span" in flow_unit_hint(q / 60.0, dp)
    assert " or " not in flow_unit_hint(q / 60.0, dp)
    assert "m^3/h (multiply by 1000" in flow_unit_hint(q / 1000.0, dp)
    assert "kg/s (multiply by 3600" in flow_unit_hint(q / 3600.0, dp)


def test_temperatures_in_degf_are_named(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A record in degF: a medium hotter than 65.6 degC lies above the range check's 150 on part of its rows, and the
    refusal names degF where every value converts into the range and more than a tenth of them lie outside it. A record
    in degC with a few spikes beyond 150 is refused by its rows without the unit. Within 150 (a tank at 126 degF), the
    tank's median above 95 degC reads as degF (temperature_unit_hint), which fit's and diagnose's notes add."""
    from valve_env.data_io import TANK_HOT_C, temperature_unit_hint

    f = run_df.assign(T_tank_C=run_df.T_tank_C * 1.8 + 32.0,
                      T_med_C=np.linspace(55.0, 75.0, len(run_df)) * 1.8 + 32.0)
    assert 0.1 < np.mean(f.T_med_C > 150.0) < 0.5  # a quarter of the rows
    with pytest.raises(DataError, match=r"column T_med_C, .* every value reads as degF: convert with \(v - 32\) \* 5 / "
                                        r"9, and the other temperature column too$"):
        load_run(_write(f, tmp_path / "f.csv"))
    spiked = run_df.assign(T_med_C=run_df.T_med_C.where(~run_df.index.isin([3, 9, 20]), 160.0))
    with pytest.raises(DataError, match=r"row 4 .* 2 more row\(s\): 10, 21$"):
        load_run(_write(spiked, tmp_path / "spiked.csv"))
    assert temperature_unit_hint(run_df.T_tank_C.to_numpy()) == ""
    hint = temperature_unit_hint(np.full(50, 126.0))
    assert hint.startswith(f"; T_tank_C's median 126 lies above {TANK_HOT_C:g} degC")
    assert "the median would be 52.2 degC" in hint
    assert temperature_unit_hint(np.full(50, 140.0)) != "" and temperature_unit_hint(np.full(50, 200.0)) == ""


def test_a_flow_meters_noise_about_zero_is_read_as_no_flow(tmp_path: Path, open_run: pd.DataFrame) -> None:
    """A flow meter without a low-flow cut-off reads a shut valve as 0 plus its noise, partly below 0: those flows are
    read as 0 with a note (kept when the run is checked again, as diagnose does), where the record was refused as out
    of range; a flow further below 0 is still refused, and a record whose every flow is negative is named as a meter
    that counts the flow as negative."""
    from valve_env.data_io import validate_run
    from valve_env.valveid.preprocess import describe, preprocess_run

    q = open_run.q_kgh.to_numpy()
    noisy = q + np.random.default_rng(0).normal(0.0, 0.5, q.size)
    assert (noisy < 0).sum() > 10 and q.min() >= 0
    out = load_run(_write(open_run.assign(q_kgh=noisy), tmp_path / "noisy.csv"))
    np.testing.assert_allclose(out.q_kgh.to_numpy(), np.where(noisy < 0, 0.0, noisy), rtol=1e-8)
    notes = [nt for nt in preprocess_run(out)[1] if nt["what"] == "q_zero_noise"]
    assert len(notes) == 1 and notes[0]["rows"] == int((noisy < 0).sum())
    assert notes[0]["lowest_kgh"] == pytest.approx(noisy.min(), rel=1e-6)
    assert any(line.startswith(f"q_kgh: {notes[0]['rows']} flow(s) below 0") for line in describe(notes))
    again = preprocess_run(validate_run(preprocess_run(out)[0], "again"))[1]
    assert [nt["rows"] for nt in again if nt["what"] == "q_zero_noise"] == [notes[0]["rows"]]
    # further below 0 than a meter's noise: refused by the range check, as before
    deep = noisy.copy()
    deep[40] = -0.2 * np.percentile(q, 99)
    with pytest.raises(DataError, match=r"column q_kgh, row \d+ \(line \d+\): -[\d.]+ is out of range .* more row"):
        load_run(_write(open_run.assign(q_kgh=deep), tmp_path / "deep.csv"))
    with pytest.raises(DataError, match=r"every value reads as kg/h with the sign reversed .*: negate the column$"):
        load_run(_write(open_run.assign(q_kgh=-q - 1.0), tmp_path / "negated.csv"))
    # the last shut row before the valve opens (an open row beside it) is still a shut valve's noise
    edge = q.copy()
    k = int(np.flatnonzero(q[1:-1] < 0.01 * np.percentile(q, 99))[0]) + 1  # a shut row; the one after it opens
    edge[k], edge[k + 1] = -0.3, 0.5 * np.percentile(q, 99)
    assert load_run(_write(open_run.assign(q_kgh=edge), tmp_path / "edge.csv")).attrs["q_zero_noise"]["rows"] == 1
    # a small negative flow between open rows is a glitch, not a shut valve's noise
    glitch = q.copy()
    j = int(np.argmax(q[1:-1])) + 1
    glitch[j] = -1.0
    with pytest.raises(DataError, match=rf"column q_kgh, row {j + 1} \(line {j + 2}\): -1 is out of range"):
        load_run(_write(open_run.assign(q_kgh=glitch), tmp_path / "glitch.csv"))


def test_an_opening_with_the_other_sign_is_told_to_be_negated(tmp_path: Path, open_run: pd.DataFrame) -> None:
    """An opening that falls as the flow rises: at or below 0 on most flowing rows it is one measured with the other
    sign (negate it); within the stroke it is a closing travel (stroke - x)."""
    with pytest.raises(DataError, match=r"column x_mm falls as the flow rises .*: if x_mm is the opening measured "
                                        r"with the other sign \(at or below 0 on \d+% of these rows\), negate it$"):
        load_run(_write(open_run.assign(x_mm=-open_run.x_mm), tmp_path / "neg.csv"))
    with pytest.raises(DataError, match=r"if x_mm is the closing travel, give the opening \(2 mm - x_mm\)$"):
        load_run(_write(open_run.assign(x_mm=2.0 - open_run.x_mm), tmp_path / "travel.csv"))


def test_a_flow_meters_low_flow_cut_off_is_named_where_the_opening_is_derived(tmp_path: Path,
                                                                              open_run: pd.DataFrame) -> None:
    """A meter that reads 0 below a set flow (a low-flow cut-off) leaves the opening derived from the flow unknown
    below the cut-off's: with no x_mm the record gets a warning note (``q_cut_off``) naming the cut-off, the rows and
    that opening; with x_mm measured, or with a meter's noise about 0 (no gap above 0), none. Before, nothing was
    said, and a valve without an effect was named stiction on such a record (the corpus's KNOWN_WRONG)."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    q = open_run.q_kgh.to_numpy()
    high = float(np.percentile(q, 99))
    cut = np.where(q < 0.03 * high, 0.0, q)
    assert 10 < int((cut == 0).sum()) < q.size
    derived = load_run(_write(open_run.assign(q_kgh=cut).drop(columns=["x_mm"]), tmp_path / "cut.csv"))
    notes = [nt for nt in preprocess_run(derived)[1] if nt["what"] == "q_cut_off"]
    assert len(notes) == 1 and notes[0]["warn"] and notes[0]["rows"] == int((cut == 0).sum())
    assert notes[0]["cut_off_kgh"] == pytest.approx(cut[cut > 0].min())
    assert 0.0 < notes[0]["x_below_mm"] < 0.2
    assert any(line.startswith(f"q_kgh: 0 in {notes[0]['rows']} row(s), never between 0 and") for line in
               describe(notes))
    measured = load_run(_write(open_run.assign(q_kgh=cut), tmp_path / "measured.csv"))
    assert "q_cut_off" not in measured.attrs
    noisy = np.maximum(q + np.random.default_rng(0).normal(0.0, 0.5, q.size), 0.0)  # zero noise: no gap above 0
    assert "q_cut_off" not in load_run(_write(open_run.assign(q_kgh=noisy).drop(columns=["x_mm"]),
                                              tmp_path / "noisy.csv")).attrs


def _pump_stopped(run: pd.DataFrame, seed: int) -> tuple[pd.DataFrame, np.ndarray]:
    """``run`` with the pump off for 40 rows from a third of the way in (dp 0 with a transmitter's 0.3 mbar of noise,
    no flow), and those rows."""
    off = np.zeros(len(run), dtype=bool)
    off[len(run) // 3:len(run) // 3 + 40] = True
    dp = run.dp_mbar.to_numpy().copy()
    dp[off] = np.random.default_rng(seed).normal(0.0, 0.3, int(off.sum()))
    return run.assign(dp_mbar=dp, q_kgh=np.where(off, 0.0, run.q_kgh)), off


def test_a_pump_that_stops_leaves_a_gap(tmp_path: Path, open_run: pd.DataFrame) -> None:
    """A circulation pump that stops (dp and flow about 0 for a stretch; a transmitter's noise either side of 0) is
    read: those rows are dropped with a note naming them, and the likelihoods take the stretch as a gap; before, the
    record was refused as out of range. A single such row is still a refused glitch, and so is a dp below 0 beyond a
    transmitter's noise."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    n = len(open_run)
    stopped, off = _pump_stopped(open_run, 1)
    out = load_run(_write(stopped, tmp_path / "stopped.csv"))
    assert len(out) == n - 40 and out.attrs["rows_dropped_pump_off"] == list(range(n // 3 + 1, n // 3 + 41))
    checked, notes = preprocess_run(out)
    off_note = next(nt for nt in notes if nt["what"] == "pump_off")
    assert off_note["rows"] == 40 and off_note["stretches"] == 1
    assert any(nt["what"] == "gap" for nt in notes)
    assert any(line.startswith("dp_mbar: the pump off in 1 stretch(es), 40 row(s) dropped") for line in describe(notes))
    glitch = open_run.assign(dp_mbar=np.where(np.arange(n) == n // 2, 0.0, open_run.dp_mbar),
                             q_kgh=np.where(np.arange(n) == n // 2, 0.0, open_run.q_kgh))
    with pytest.raises(DataError, match=rf"column dp_mbar, row {n // 2 + 1} .*: 0 is out of range"):
        load_run(_write(glitch, tmp_path / "glitch.csv"))
    deep = stopped.assign(dp_mbar=np.where(off, -20.0, stopped.dp_mbar))
    with pytest.raises(DataError, match=r"column dp_mbar, row \d+ .*: -20 is out of range"):
        load_run(_write(deep, tmp_path / "deep.csv"))


def test_a_pump_off_for_over_a_day_is_a_gap_the_run_is_still_read_with(tmp_path: Path, open_run: pd.DataFrame) -> None:
    """The rows of a pump off for longer than a day (a summer's stop) are dropped when the run is read, which leaves
    more than a day between two of its rows; checked again (preprocess_run, as fit and diagnose do), such a run was
    refused as 'a gap of 1.2e+05 s after the previous sample' at a row whose time has none in the file (diagnose's
    check_run; fit read it). A gap in the file's own time column is still refused, a repeated row beside it or not."""
    from valve_env.data_io import validate_run
    from valve_env.valveid.diagnose import check_run

    n = len(open_run)
    slow = open_run.assign(time_s=np.arange(n) * 3000.0)  # 50 min a row: 40 rows are 33 h
    stopped, _ = _pump_stopped(slow, 2)
    out = load_run(_write(stopped, tmp_path / "summer.csv"))
    assert float(np.diff(out.time_s).max()) > MAX_GAP_S
    assert len(validate_run(out)) == n - 40 and len(check_run(out)) == n - 40
    t = slow.time_s.to_numpy().copy()
    t[n // 2:] += MAX_GAP_S
    gap = pd.concat([slow.assign(time_s=t).iloc[:n // 2], slow.assign(time_s=t).iloc[n // 2 - 1:]]).sort_index(
        kind="stable")  # the row before the gap written twice, which the reader drops as a repeat
    with pytest.raises(DataError, match=rf"column time_s, row {n // 2 + 2} .*: a gap of .* after the previous sample"):
        load_run(_write(gap, tmp_path / "gap.csv"))


def test_a_control_loops_file_is_told_to_go_to_loop_diagnose(tmp_path: Path) -> None:
    """A loop CSV (sp, pv, op) or a plant-historian export given to fit or diagnose is told which command reads it;
    before, the loop CSV got the missing columns alone and the export 'not a readable CSV file (Error tokenizing
    data ...)'."""
    loop = tmp_path / "loop.csv"
    loop.write_text("time_s,sp,pv,op\n" + "".join(f"{10 * k},50,{50 + k % 3},{40 + k % 5}\n" for k in range(40)))
    with pytest.raises(DataError, match=r"missing columns 'T_tank_C', .*; the header is a control loop's record "
                                        r"\(sp, pv, op: docs/reference.md, section 10\): diagnose it with thermovalve "
                                        r"loop-diagnose$"):
        load_run(loop)
    export = Path(__file__).parents[1] / "data" / "plant_loops" / "2411FIC20102_1008_1552.txt"
    with pytest.raises(DataError, match=r"a plant-historian export of a control loop \(first word PROCESSDATA\), not "
                                        r"a measured valve run: diagnose it with thermovalve loop-diagnose$"):
        load_run(export)


@pytest.mark.parametrize(("unit", "factor"), [("kg/s", 3600.0), ("l/min", 60.0)])
def test_a_flow_in_another_unit_beside_a_measured_opening_is_warned_of(tmp_path: Path, open_run: pd.DataFrame,
                                                                       unit: str, factor: float) -> None:
    """A flow in kg/s or l/min under q_kgh, with x_mm measured: the measured opening is used, so the run is read, but
    a warning note names the unit the flow reads as against x_mm and dp_mbar through the valve characteristic (before,
    nothing was said, and where x_mm was empty the opening was derived from the wrong flow). The run as written gets
    no such note."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    assert "q_other_unit" not in load_run(_write(open_run, tmp_path / "plain.csv")).attrs
    run = load_run(_write(open_run.assign(q_kgh=open_run.q_kgh / factor), tmp_path / "other.csv"))
    notes = [nt for nt in preprocess_run(run)[1] if nt["what"] == "q_other_unit"]
    assert len(notes) == 1 and notes[0]["warn"] and notes[0]["unit"] == unit
    assert notes[0]["ratio"] == pytest.approx(1.0 / factor, rel=0.1)
    assert any(line.startswith(f"q_kgh: {notes[0]['ratio']:.3g} times the flow") for line in describe(notes))


def test_an_opening_transducers_zero_offset_is_taken_out(tmp_path: Path, open_run: pd.DataFrame) -> None:
    """An opening whose transducer's zero reads off (the valve on its seat, its flow about 0, reads +-0.03 mm instead
    of 0): the offset is subtracted, with a note naming it. Before, nothing was said or done, and fit's RMS rose
    fivefold with residuals that were not white, with no cause named. The run as written, the same run under a flow
    meter's low-flow cut-off (openings near the seat read as flow 0), a valve held open while the pump is turned down,
    and an opening off by more than a transducer's zero are left as they are."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    assert "x_mm_zero_offset" not in load_run(_write(open_run, tmp_path / "plain.csv")).attrs
    q = open_run.q_kgh.to_numpy()
    cut = open_run.assign(q_kgh=np.where(q < 0.03 * np.percentile(q, 99), 0.0, q))
    assert "x_mm_zero_offset" not in load_run(_write(cut, tmp_path / "cut.csv")).attrs
    # a pump turned down for a third of the record (dp at 0.1 mbar, the flow with it) under a valve held open at
    # 0.15 mm, the valve never on its seat: its flow is about 0 there, but the opening is not a zero offset
    rng = np.random.default_rng(3)
    low = np.arange(900) >= 600
    x = np.where(low, 0.15, 0.6 + 0.4 * np.sin(np.arange(900) / 50.0)) + rng.normal(0.0, 0.0024, 900)
    flow, dp = np.where(low, 0.2, 40.0 + 300.0 * x), np.where(low, 0.1, 100.0)
    assert zero_offset(x, flow, np.full(900, 100.0), 2.0) is not None  # taken for the seat without the dp
    assert zero_offset(x, flow, dp, 2.0) is None
    # an opening off by 0.3 mm on the seat is not a transducer's zero (15 % of the stroke): left as it is
    far = load_run(_write(open_run.assign(x_mm=open_run.x_mm + 0.3), tmp_path / "far.csv"))
    assert "x_mm_zero_offset" not in far.attrs
    for offset in (0.03, -0.03):
        run = load_run(_write(open_run.assign(x_mm=open_run.x_mm + offset), tmp_path / "offset.csv"))
        notes = [nt for nt in preprocess_run(run)[1] if nt["what"] == "x_mm_zero_offset"]
        assert len(notes) == 1 and notes[0]["warn"] and notes[0]["offset_mm"] == pytest.approx(offset, abs=0.003)
        np.testing.assert_allclose(run.x_mm, open_run.x_mm + offset - notes[0]["offset_mm"], atol=1e-12)
        assert any(line.startswith(f"x_mm: rests at {notes[0]['offset_mm']:.3g} mm") and line.endswith("subtracted")
                   for line in describe(notes))


def test_channels_stored_on_change_are_held_from_each_value_to_the_next(tmp_path: Path, run_df: pd.DataFrame) -> None:
    """A historian's export on the union of times that writes a channel only where its value changed, empty between:
    the medium temperature held by a thermostat in noiseless steps (a value on 3 rows) and the rig's pressures at
    their set values (a value on the first row only). Each is held from each value to the next, with a note, and the
    run is the one with the values written on every row. Before, the medium temperature's 3 rows were read as a slower
    logger's (the run cut to them) and a pressure written once was refused for its empty cells. A channel missing a
    third of its cells at random is still refused."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    full = run_df[[c for c in run_df.columns if not c.startswith("true_")]].copy()
    t = full["time_s"].to_numpy()
    full["T_med_C"] = np.where(t < 1200.0, 70.0, np.where(t < 2400.0, 75.0, 72.5))
    full["dp_mbar"], full["ps_bar"] = 100.0, 2.0
    changes = full.copy()
    for c in ("T_med_C", "dp_mbar", "ps_bar"):
        v = full[c].to_numpy()
        changes.loc[np.r_[False, v[1:] == v[:-1]], c] = np.nan
    run, written = load_run(_write(changes, tmp_path / "changes.csv")), load_run(_write(full, tmp_path / "full.csv"))
    assert len(run) == len(written) == len(full)
    for c in ("time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm"):
        assert np.array_equal(run[c].to_numpy(), written[c].to_numpy()), c
    assert run.attrs["own_rates"]["channel"] is None
    assert run.attrs["own_rates"]["held"] == {"T_med_C": 3, "dp_mbar": 1, "ps_bar": 1}
    _, notes = preprocess_run(run)
    own = next(n for n in notes if n["what"] == "own_rates")
    assert f"T_med_C has a value on 3 of {len(full)} rows, held from each to the next (stored on change)" in own["why"]
    assert "channels on their own times: T_med_C, dp_mbar, ps_bar stored on change, held" in describe(notes)
    missing = full.copy()
    missing.loc[np.random.default_rng(0).random(len(full)) < 1 / 3, "T_tank_C"] = np.nan
    with pytest.raises(DataError, match=r"have an empty cell in a measured column \(the first: 'T_tank_C'"):
        load_run(_write(missing, tmp_path / "missing.csv"))


def test_channels_logged_at_their_own_rates_are_read_on_the_slowest_ones_rows(tmp_path: Path,
                                                                               run_df: pd.DataFrame) -> None:
    """A logger that writes each channel at its own rate on the union of their times, empty where a channel has no
    sample: the temperatures every 20 s, the flow and pressures every 10 s. The run is read on the temperatures' rows,
    with a note, and is the run as logged every 20 s; with the supply temperature logged 10 s after the tank's, it is
    interpolated linearly on the tank's rows. An outage of a channel logged with the others is refused as before."""
    from valve_env.valveid.preprocess import describe, preprocess_run

    base = run_df[[c for c in run_df.columns if not c.startswith("true_")]]
    t = base["time_s"].to_numpy()
    every = base.iloc[::2].reset_index(drop=True)
    union = base.copy()
    union.loc[union.index % 2 == 1, ["T_tank_C", "T_med_C"]] = np.nan
    run = load_run(_write(union, tmp_path / "union.csv"))
    assert np.array_equal(run["time_s"].to_numpy(), every["time_s"].to_numpy())
    for c in ("T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar", "x_mm"):
        assert np.allclose(run[c].to_numpy(), every[c].to_numpy(), rtol=1e-12, atol=0), c
    _, notes = preprocess_run(run)
    own = next(n for n in notes if n["what"] == "own_rates")
    assert (own["channel"], own["rows"], own["of"], own["every_rows"]) == ("T_tank_C", len(every), len(base), 2.0)
    assert own["dropped_rows"][:3] == [2, 4, 6]
    assert any(line.startswith("channels on their own times: read on the") for line in describe(notes))
    shifted = union.copy()
    shifted["T_med_C"] = np.where(union.index % 2 == 1, base["T_med_C"], np.nan)
    run = load_run(_write(shifted, tmp_path / "shifted.csv"))  # T_med_C has one value fewer: its rows are read
    assert np.array_equal(run["time_s"].to_numpy(), t[1::2])
    assert np.allclose(run["T_med_C"].to_numpy(), base["T_med_C"].to_numpy()[1::2], rtol=1e-12, atol=0)
    halfway = 0.5 * (base["T_tank_C"].to_numpy()[0:-1:2] + base["T_tank_C"].to_numpy()[2::2])
    assert np.allclose(run["T_tank_C"].to_numpy(), halfway, rtol=1e-9, atol=0)
    assert (run.attrs["own_rates"]["channel"], run.attrs["own_rates"]["interpolated"]) == ("T_med_C", ["T_tank_C"])
    out = base.copy()
    out.loc[40:80, "T_med_C"] = np.nan  # the sensor out for a while, every other channel logged
    with pytest.raises(DataError, match=r"have an empty cell in a measured column \(the first: 'T_med_C' at row 41"):
        load_run(_write(out, tmp_path / "outage.csv"))
