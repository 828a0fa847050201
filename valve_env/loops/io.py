"""Reading and checking control-loop records (docs/loops.md, "Input formats").

Two formats are read:

* the project's loop CSV: a header row with ``time_s, sp, pv, op`` and optionally ``mv``
  (measured valve position, %) and ``mode`` (1 = automatic); extra columns are ignored;
* the plant-historian export of the real loops in ``tests/data/plant_loops`` (tab-separated,
  5 header lines, then ``timestamp  OP  PV  SP  MODE  flags...``; the tag names in line 3 end
  in ``.MV`` (controller output), ``.PV``, ``.SV`` (set point) and ``.MODE``).

Rows that repeat a timestamp (historian exports do: duplicate rows, two values stored in one second)
are merged with a note: exact duplicates dropped, differing rows averaged
(:func:`merge_repeated_timestamps`); time that goes backwards stays an error.

An export of tags on their own times (the union of their timestamps, a tag's cell empty where it has no sample) is
read on common rows, with a note (:func:`tags_on_own_times`). Samples that miss a value (an empty cell or a NaN
marker, :data:`MISSING_MARKERS`, or a historian value whose status flag is set, :func:`historian_flags`) are dropped
with a note, up to
:data:`MAX_MISSING_FRACTION` of them, and the record is resampled over them. A value far outside its column's record
(a historian's sentinel such as -9999, or a gross spike), in short isolated runs, is read as missing, with a note
naming the samples (:func:`gross_outliers`).

Every problem with a record raises :class:`LoopDataError` whose message is one line naming the
problem (too many missing values, an infinite one, non-increasing time, a missing column, ...). A well-formed
record that cannot decide is read:
one that is merely short, or whose OP or PV holds one value throughout (a historian's frozen tag, a closed loop
at rest), and the diagnosis names it ``insufficient_data`` with the reason (valve_env.loops.diagnose). Samples
in manual mode are dropped with a note (the longest automatic stretch is kept). An OP outside the range a
controller output in % can take (some DCS exports give OP in engineering units) is scaled by its observed range
onto 0-100 %, with a note (:attr:`LoopData.op_scaled_from`).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from functools import partial
from pathlib import Path
from typing import NoReturn

import numpy as np

from valve_env.data_io import (
    HISTORIAN_MARK,
    LOOP_COLUMNS,
    UNITS,
    clock_in_time_s,
    clock_time_hint,
    csv_dialect,
    cut_line_note,
    decimal_comma,
    decimal_mark,
    decimal_mark_hint,
    footer_lines,
    fortran_exponent,
    header_units,
    interval_problem,
    is_comment,
    long_format_hint,
    name_key,
    nul_note,
    other_format_hint,
    own_rates,
    read_text,
    rename_hint,
    short_list,
    text_cells,
    time_name_hint,
    time_order_hint,
    unit_key,
)
from valve_env.data_io import MISSING_MARKERS as RUN_MISSING_MARKERS

#: the loop CSV's columns (docs/reference.md, section 10): the four it needs, then the optional measured valve
#: position and mode
COLUMNS: tuple[str, ...] = LOOP_COLUMNS
REQUIRED_COLUMNS: tuple[str, ...] = COLUMNS[:4]

#: Names other tools give the loop CSV's columns (docs/reference.md, section 10), compared by their letters and digits
#: in lower case: a refusal of the missing column names the header's column that is likely meant. ``mv`` is the loop
#: CSV's own name for the measured valve position, but a historian's ``.MV`` is the controller output
#: (:data:`HISTORIAN_SUFFIXES`), so a file with ``mv`` and no ``op`` is asked which it is. Names whose meaning differs
#: between conventions (``y`` is the measurement in English texts and the controller output in German ones; ``cv``)
#: are not guessed at.
LOOP_SYNONYMS: dict[str, tuple[str, ...]] = {
    "sp": ("setpoint", "setpt", "spt", "sv", "setvalue", "ref", "reference", "target", "r", "sollwert"),
    "pv": ("processvalue", "processvariable", "measurement", "meas", "measured", "istwert"),
    "op": ("co", "controlleroutput", "controllerout", "output", "out", "u", "mv"),
}
#: what each of :data:`LOOP_SYNONYMS`' columns is, for the refusal
LOOP_MEANINGS = {"sp": "the set point", "pv": "the process variable", "op": "the controller output (%)"}


def synonym_hint(missing: list[str], header: list[str]) -> str:
    """Where the loop CSV's columns ``missing`` are absent and the header has names other tools give them
    (:data:`LOOP_SYNONYMS`), the refusal's hint naming each such column and what to rename it to. Else ''."""
    found = [(c, h) for c in missing for h in header if name_key(h) in LOOP_SYNONYMS.get(c, ())]
    if not found:
        return ""
    parts = []
    for c, h in found:
        if name_key(h) == "mv":
            parts.append(f"'{h}' is the measured valve position in a loop CSV; if it is the controller output (a "
                         f"historian's .MV), name it op")
        else:
            parts.append(f"if '{h}' is {LOOP_MEANINGS[c]}, name it {c}")
    return "; " + "; ".join(parts) + " (names are exact: docs/reference.md, section 10)"


def _suffixed(column: str, header: list[str]) -> str | None:
    """The header's name that is ``column`` followed by a unit or qualifier after ``_``, ``.``, ``-`` or a space
    (``pv_degC``, ``op_pct``, ``sp.m3h``), if one; else None."""
    pattern = re.compile(rf"{re.escape(column)}[\s_.-]+\S{{1,12}}", re.IGNORECASE)
    return next((h for h in header if pattern.fullmatch(h.strip())), None)


def tag_name_hint(missing: list[str], header: list[str]) -> str:
    """Where the loop CSV's columns ``missing`` are absent and the header names them as a historian names its tags
    (``FIC101.SP``, ``FIC101.PV``, ``FIC101.OP``; ``.SV`` and ``.MV`` too: :data:`HISTORIAN_SUFFIXES`), the refusal's
    hint: rename them, one loop's where the header holds several. Else ''."""
    loops = {t: roles for t, roles in historian_loops([h.strip() for h in header]).items()
             if any(c in roles for c in missing)}
    if not loops:
        return ""
    roles = next(iter(loops.values()))
    found = [(c, header[roles[c]].strip()) for c in missing if c in roles]
    many = (f"; the header holds {len(loops)} loops' tags ({', '.join(loops)}): give one loop's" if len(loops) > 1
            else "")
    return (f"; the header has {', '.join(repr(h) for _, h in found)}, tag names as a historian writes them: rename "
            f"{'it' if len(found) == 1 else 'them'} {', '.join(c for c, _ in found)} (names are exact){many}")


def unit_suffix_hint(missing: list[str], header: list[str]) -> str:
    """Where the loop CSV's columns ``missing`` are absent and the header has each followed by a unit after an
    underscore (``pv_degC``, ``op_pct``), the refusal's hint: name them so, with the unit in brackets if wanted
    (``pv [degC]``, which is read). Else ''."""
    found = [(c, h) for c in missing if (h := _suffixed(c, header))]
    if not found:
        return ""
    have, want = ", ".join(repr(h) for _, h in found), ", ".join(c for c, _ in found)
    example = next(h for _, h in found)
    c0 = next(c for c, _ in found)
    return (f"; the header has {have}: if {'that is' if len(found) == 1 else 'these are'} {want} with a unit, "
            f"name {'it' if len(found) == 1 else 'them'} {want}, or give the unit in brackets "
            f"('{c0} [{example.strip()[len(c0) + 1:]}]', which is read)")


#: the shortest record, in samples, that is diagnosed (about 40 min at 10 s); a shorter one is read, and diagnosed
#: ``insufficient_data``
MIN_SAMPLES = 240
#: OP whose range is below this (in %) is constant: the record is diagnosed ``insufficient_data``
MIN_OP_RANGE_PCT = 1e-3
#: the widest controller output read as %: 0-100 % and the overdrive some DCSs allow beyond it (Honeywell
#: TDC/Experion: OP limits -6.9 to 106.9 %); an OP beyond it is in engineering units and is scaled by its observed
#: range (docs/loops.md, "Input formats")
OP_RANGE_PCT = (-10.0, 110.0)
#: the share of samples that may miss a value (an empty cell or a NaN marker: a sample the historian did not
#: store) before the record is refused; such samples are dropped and the record resampled over them
MAX_MISSING_FRACTION = 0.10
#: cells read as a missing value (case-insensitive): the valve runs' reader's (a spreadsheet's #N/A included)
MISSING_MARKERS = RUN_MISSING_MARKERS
#: a mode column written as the controller's mode by name, as a historian exports a digital state: automatic and
#: cascade (the loop closed, its set point from another loop) are 1, manual 0; a logical True is 1, as its number is
MODE_NAMES: dict[str, float] = {"auto": 1.0, "aut": 1.0, "automatic": 1.0, "cas": 1.0, "casc": 1.0, "cascade": 1.0,
                                "man": 0.0, "manual": 0.0, "hand": 0.0,
                                # the Foundation Fieldbus block modes (as DeltaV and other DCSs export them): remote
                                # cascade closes the loop; out of service, initialisation manual, local override,
                                # remote output and tracking hold or set the output from elsewhere
                                "rcas": 1.0, "oos": 0.0, "iman": 0.0, "lo": 0.0, "rout": 0.0, "trk": 0.0,
                                "track": 0.0, "tracking": 0.0,
                                # a logical column (pandas writes True/False, a spreadsheet TRUE/FALSE): 1 = automatic
                                "true": 1.0, "false": 0.0}


#: a sample lies far outside its column's own record (:func:`gross_outliers`) where it is this many times the width of
#: the column's central 90 % (its 5 and 95 percentiles) beyond that range: a historian's sentinel (-9999, 99999)
#: or a gross spike, which no loop's motion makes
GROSS_RANGES = 3.0
#: such samples are treated as missing only in runs of at most this many consecutive samples ...
GROSS_MAX_RUN = 3
#: ... and only up to this share of the samples; a longer or more frequent excursion is left as recorded
GROSS_MAX_FRACTION = 0.01
#: An OP within this (% of OP) of 0 or 100 % sits at its limit; a share of the samples above
#: :data:`SATURATION_SHARE` there gets a note (a saturated controller's loop is open). Of the 46 shared loops none comes
#: within it on more than 1 % of its samples, and of 400 simulated ones (seeds 0-199, with and without the plant's
#: habits) none on more than 5 %.
SATURATED_PCT = 0.05
SATURATION_SHARE = 0.05


class LoopDataError(ValueError):
    """A loop record that cannot be diagnosed; the message is one line naming the problem."""


@dataclass
class LoopData:
    """A control loop's record on a uniform time grid (s, engineering units, % for op/mv)."""

    time_s: np.ndarray
    sp: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    mv: np.ndarray | None = None
    tag: str = ""
    source: str = ""
    notes: list[str] = field(default_factory=list)
    #: the observed OP range (min, max) in the export's units when OP was scaled onto 0-100 % by it; None when OP was
    #: read as % (docs/loops.md, "Input formats")
    op_scaled_from: tuple[float, float] | None = None

    @property
    def dt(self) -> float:
        return float(np.median(np.diff(self.time_s)))

    @property
    def n(self) -> int:
        return int(self.time_s.size)

    def to_csv_text(self) -> str:
        """The record as the project's loop CSV."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        cols = list(REQUIRED_COLUMNS) + (["mv"] if self.mv is not None else [])
        w.writerow(cols)
        arrs = [self.time_s, self.sp, self.pv, self.op] + ([self.mv] if self.mv is not None else [])
        for row in zip(*arrs, strict=True):
            w.writerow([f"{v:.10g}" for v in row])
        return buf.getvalue()


def _float(text: str, where: str) -> float:
    if text.lower() in MISSING_MARKERS:
        return math.nan
    try:
        return float(text)
    except ValueError:
        pass
    try:  # only where float() fails: a Fortran program's exponent (1.25D+01)
        return float(fortran_exponent(text))
    except ValueError:
        raise LoopDataError(f"{where}: {text!r} is not a number{decimal_mark_hint(text)}") from None


def _cell_value(column: str, cell: str, where: str) -> float:
    """A cell of either format as a number: a mode may be written as a name (:data:`MODE_NAMES`), the rest by
    :func:`_float`."""
    if column == "mode" and cell.lower() in MODE_NAMES:
        return MODE_NAMES[cell.lower()]
    return _float(cell, where)


def _text_lines(p: Path) -> tuple[list[str], list[str]]:
    """The lines of a loop record's file (:func:`valve_env.data_io.read_text`: UTF-8, UTF-16 or Windows-1252,
    gzip-compressed or not) and the note of NUL bytes dropped from its end; a file that is not text is refused in
    one line."""
    try:
        text, nul = read_text(p)
        return text.splitlines(), [nul_note(nul)] if nul else []
    except UnicodeDecodeError:
        raise LoopDataError(f"{p}: not a text file") from None
    except ValueError as exc:  # a workbook, or a broken gzip file
        raise LoopDataError(f"{p}: {exc}") from None
    except OSError as exc:
        raise LoopDataError(f"{p}: cannot read ({exc.strerror or exc})") from None


def read_loop_csv(path: str | Path, lines: list[str] | None = None) -> tuple[dict[str, np.ndarray], str, list[str]]:
    """Columns of a loop CSV (docs/reference.md, section 10) as float arrays, the tag (the file stem) and the notes
    of what was read as other than data (a units row under the header: :func:`_units_row`). ``lines``: the file's,
    where they have been read."""
    p = Path(path)
    lines, read_notes = _text_lines(p) if lines is None else (lines, [])
    # commas, or semicolons, tabs (with a decimal comma) or spaces, after '#' comments; a footer left out
    dialect = csv_dialect(lines[:64])
    text = lines[dialect.skip:len(lines) - footer_lines(lines, dialect)]
    # each line its own row: a loop CSV holds no field across lines, and a stray quote then spoils its own line
    # (named below by its number) instead of running to the file's end
    rows = [dialect.cells(ln) for ln in text]
    if not rows:
        raise LoopDataError(f"{p}: empty file")
    header = written = [h.strip() for h in rows[0]]
    named = header_units(header, COLUMNS)
    t = next((u for n, u in named.values() if n == "time_s"), None)
    if t is not None and unit_key(t) not in UNITS["time_s"][1]:
        raise LoopDataError(f"{p}: the header gives time_s in {t!r}: give it in seconds")
    header = [named[h][0] if h in named else h for h in header]
    # which copy is the signal? (csv would silently take the first); extra columns are ignored, twice or not
    twice = sorted({h for h in header if h in COLUMNS and header.count(h) > 1})
    if twice:
        raise LoopDataError(f"{p}: the header names column(s) {', '.join(twice)} more than once")
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        # every missing column's hint at once: its time unit or clock, the name another tool gives it, or its name
        # in another case or spelling
        time_hint = (time_name_hint(header) or clock_time_hint(
            {h: [r[j] for r in rows[1:6] if j < len(r)] for j, h in enumerate(header)})) if "time_s" in missing else ""
        other = [c for c in missing if c != "time_s" or not time_hint]
        told = [c for c in other if synonym_hint([c], header)]
        suffixed = [c for c in other if c not in told and _suffixed(c, header)]
        tagged = [c for c in other if c not in told and c not in suffixed and tag_name_hint([c], header)]
        hint = (long_format_hint(missing, {h: [r[j] for r in rows[1:] if j < len(r)] for j, h in enumerate(header)})
                if len(missing) > 1 else "")
        hint = other_format_hint(header, "loop") or hint or (
            time_hint + synonym_hint(told, header) + unit_suffix_hint(suffixed, header) + tag_name_hint(tagged, header)
            + rename_hint([c for c in other if c not in told and c not in suffixed and c not in tagged], header,
                          COLUMNS))
        raise LoopDataError(f"{p}: missing column(s) {', '.join(missing)} (need time_s, sp, pv, op){hint}")
    wanted = [c for c in COLUMNS if c in header]
    idx: dict[str, int] = {c: header.index(c) for c in wanted}
    cols: dict[str, list[float]] = {c: [] for c in wanted}
    body = rows[1:]
    units = _units_row(body[0], idx, p, dialect.header_line + 1) if body else {}
    notes: list[str] = list(read_notes)
    if named:
        notes.append(f"the header gives units after the names ({', '.join(f'{n} [{u}]' for n, u in named.values())}): "
                     "read as the names")
    if units:  # a second header line: sp and pv in the plant's units (the band is in % of OP either way)
        body = body[1:]
        notes.append(f"line {dialect.header_line + 1} is a units row "
                     f"({', '.join(f'{c} [{u}]' for c, u in units.items())}): read as a second header line")
    clock = clock_in_time_s([r[idx["time_s"]] for r in body[:5] if len(r) > idx["time_s"]])
    if clock:
        raise LoopDataError(f"{p}: {clock}")
    comments: list[int] = []
    headers: list[int] = []
    last = dialect.header_line + bool(units) + len(body)  # the last line's number (a footer is left out)
    for lineno, row in enumerate(body, start=dialect.header_line + 1 + bool(units)):
        if not row or all(not x.strip() for x in row):
            continue
        if is_comment([x.strip() for x in row]):  # a logger's "# restarted" among the data
            comments.append(lineno)
            continue
        if [x.strip() for x in row] == written:  # a logger that writes its header again after a restart
            headers.append(lineno)
            continue
        if len(row) < len(header):
            if lineno == last and lineno > dialect.header_line + 1 + bool(units):
                notes.append(cut_line_note(lineno, len(row), len(header)))
                continue
            raise LoopDataError(f"{p} line {lineno}: {len(row)} fields, the header has {len(header)}")
        for c in wanted:
            cell = row[idx[c]].strip()
            cols[c].append(_cell_value(c, decimal_comma(cell) if dialect.decimal == "," else cell,
                                       f"{p} line {lineno}, column {c}"))
    for c, unit in {**dict(named.values()), **units}.items():
        if c in ("op", "mv") and unit_key(unit) == "ma" and cols[c]:  # a 4-20 mA signal's current
            cols[c] = [(v - 4.0) / 16.0 * 100.0 for v in cols[c]]
            notes.append(f"{c} is given in mA (a 4-20 mA signal): read as % by (mA - 4) / 16 x 100")
    if comments:
        notes.append(f"{len(comments)} comment line(s) among the data (lines {short_list(comments)}): skipped")
    if headers:
        notes.append(f"{len(headers)} line(s) among the data repeat the header (lines {short_list(headers)}): "
                     "skipped")
    return {c: np.asarray(v, dtype=float) for c, v in cols.items()}, Path(p.name.removesuffix(".gz")).stem, notes


def _units_row(row: list[str], idx: Mapping[str, int], p: Path, lineno: int) -> dict[str, str]:
    """The units of a units row under the header, by column, where the first data line is one: text, not numbers,
    in at least two of the columns read, none a missing marker's word only. sp, pv, op and mv may be in any unit (a
    plant's engineering units; OP's scale is read off its range, :func:`check_loop`); time_s must be seconds, else
    one line says so."""
    filled = text_cells({c: row[j] for c, j in idx.items() if j < len(row)})
    t = filled.get("time_s")
    if t is not None and unit_key(t) not in UNITS["time_s"][1]:
        raise LoopDataError(f"{p} line {lineno} is a units row, and time_s is given in {t!r}: give it in seconds")
    return filled


#: The historian export's default timestamp format (the shared loops' line 1 declares it as ``yyyy-MM-dd HH:mm:ss``)
HISTORIAN_TIME = "%Y-%m-%d %H:%M:%S"
#: the timestamps read where line 1 declares none, or one they are not in: the default, ISO 8601's T for its space,
#: and a year-first date with slashes, each with or without fractional seconds
HISTORIAN_TIMES: tuple[str, ...] = tuple(f + frac for f in (HISTORIAN_TIME, "%Y-%m-%dT%H:%M:%S", "%Y/%m/%d %H:%M:%S")
                                         for frac in ("", ".%f"))
#: a .NET/Java date pattern's tokens, longest first, and strptime's
_PATTERN_TOKENS: tuple[tuple[str, str], ...] = (
    ("yyyy", "%Y"), ("yy", "%y"), ("MM", "%m"), ("dd", "%d"), ("HH", "%H"), ("hh", "%I"), ("mm", "%M"), ("ss", "%S"),
    ("fffffff", "%f"), ("ffffff", "%f"), ("fff", "%f"), ("FFF", "%f"), ("SSS", "%f"), ("tt", "%p"), ("a", "%p"),
    ("M", "%m"), ("d", "%d"), ("H", "%H"), ("h", "%I"), ("m", "%M"), ("s", "%S"))


def time_format(pattern: str) -> str | None:
    """The strptime format of a timestamp pattern as a historian's export declares it (.NET or Java:
    ``yyyy-MM-dd HH:mm:ss``, ``dd.MM.yyyy HH:mm:ss.fff``); None where it holds no year, day, hour and minute, or a
    letter that is not a known token."""
    out, i = [], 0
    while i < len(pattern):
        if pattern[i] == "'":  # a quoted literal: 'T'
            end = pattern.find("'", i + 1)
            if end < 0:
                return None
            out.append(pattern[i + 1:end].replace("%", "%%"))
            i = end + 1
            continue
        tok = next(((t, f) for t, f in _PATTERN_TOKENS if pattern.startswith(t, i)), None)
        if tok is None:
            if pattern[i].isalpha():
                return None
            out.append("%%" if pattern[i] == "%" else pattern[i])
            i += 1
            continue
        out.append(tok[1])
        i += len(tok[0])
    fmt = "".join(out)
    return fmt if all(d in fmt for d in ("%d", "%M")) and ("%Y" in fmt or "%y" in fmt) and (
        "%H" in fmt or "%I" in fmt) else None


def _parse_stamp(text: str, fmt: str) -> datetime:
    return datetime.strptime(text.strip(), fmt)


def _parse_offset_stamp(text: str) -> datetime:
    """An ISO 8601 timestamp with its UTC offset (``+08:00``, ``Z``); ValueError for one without."""
    ts = datetime.fromisoformat(text.strip())
    if ts.tzinfo is None:
        raise ValueError(f"no UTC offset in {text!r}")
    return ts


def _stamp_reader(first_line: str, sample: str, where: str) -> Callable[[str], datetime]:
    """The function that reads the export's timestamps: by the format line 1 declares (its third field), else the
    default :data:`HISTORIAN_TIME`, with fractional seconds where the first timestamp, ``sample``, has them, else
    ISO 8601 with a UTC offset (``2024-10-08T13:45:00+08:00``, ``...Z``: an export in UTC or with its zone), whose
    times then count across a change of the offset (summer time) as the clock ran."""
    fields = first_line.split("\t")
    declared = fields[2].strip() if len(fields) > 2 else ""
    declared_fmt = time_format(declared)
    formats = [f for f in (declared_fmt, *HISTORIAN_TIMES) if f]
    for fmt in formats:
        try:
            datetime.strptime(sample.strip(), fmt)
        except ValueError:
            continue
        return partial(_parse_stamp, fmt=fmt)
    try:
        _parse_offset_stamp(sample)
    except ValueError:
        pass
    else:
        return _parse_offset_stamp
    said = f"the format line 1 declares ({declared!r}) nor in " if declared_fmt else ""
    raise LoopDataError(f"{where}: timestamp {sample!r} is neither in {said}YYYY-MM-DD HH:MM:SS[.fff] (with a T "
                        "for the space, or / for the -, or ISO 8601 with its UTC offset, +08:00 or Z)")


#: a local clock's change of summer time, as a historian's export on local time shows it: the timestamps jump by an
#: hour at night (Europe at 01:00 UTC, 02:00-03:00 local; North America, Australia and New Zealand at 02:00 or 03:00
#: local). The hour of the last timestamp before the jump lies in CLOCK_CHANGE_HOURS
CLOCK_CHANGE_S = 3600.0
CLOCK_CHANGE_HOURS = range(0, 4)


def clock_changes(t: np.ndarray, stamps: list[datetime]) -> tuple[np.ndarray, str]:
    """The times ``t`` (s, from the first of the timestamps ``stamps``) of an export on a local clock, run on across
    its changes of summer time, and the note ('' where there is none). A change is a step of the timestamps that
    differs from the record's interval (the median step, under half an hour) by an hour within half an interval,
    at night (:data:`CLOCK_CHANGE_HOURS`): back by an hour (the end of summer time: the hour repeats, which no
    logger's stop makes), and forward by an hour on a Sunday (its start: a stop of the logger for that very hour
    would read so too, and the note says what was done). The times from the step on are moved by the hour, so the
    record runs on at its interval. Timestamps with a UTC offset count as the clock ran, and are returned as they
    are."""
    t = np.asarray(t, dtype=float)
    if t.size < 3 or stamps[0].tzinfo is not None:
        return t, ""
    steps = np.diff(t)
    ahead = steps[steps > 0]
    dt = float(np.median(ahead)) if ahead.size else 0.0
    if not 0.0 < dt < CLOCK_CHANGE_S / 2:
        return t, ""
    out, said = t.copy(), []
    for i in np.flatnonzero(np.abs(np.abs(steps - dt) - CLOCK_CHANGE_S) <= dt / 2):
        before, back = stamps[int(i)], bool(steps[i] < 0)
        if before.hour not in CLOCK_CHANGE_HOURS or not (back or before.weekday() == 6):
            continue
        out[i + 1:] += (CLOCK_CHANGE_S if back else -CLOCK_CHANGE_S)
        said.append(f"{'back' if back else 'forward'} after {before:%Y-%m-%d %H:%M:%S} (sample {int(i) + 1})")
    if not said:
        return t, ""
    return out, (f"the timestamps jump by an hour at night ({'; '.join(said)}): read as a local clock's change of "
                 "summer time, the times from there are moved by the hour so that the record runs on at its "
                 f"{dt:g} s interval; if the logger stopped for that hour instead, the record is joined across it")


#: the historian export's tag suffixes of each column, in the order they are looked for, in any case: the format's
#: own (``.MV`` the controller output, ``.SV`` the set value), and ``.OP``, ``.SP`` as other control systems name them
HISTORIAN_SUFFIXES: dict[str, tuple[str, ...]] = {"op": (".MV", ".OP"), "pv": (".PV",), "sp": (".SV", ".SP"),
                                                  "mode": (".MODE",)}
#: the export's status flag of each column (line 3 ``bOpOFL``, ``bPvOFL``, ``bSpOFL``, read by prefix in any case).
#: A value whose flag is set is not a new sample: in the three shared loops' exports that set them, every flagged OP and
#: PV value after the first sample (346) repeats the value before it exactly, against 16 of the 4154 others, so it is
#: read as missing (:func:`historian_flags`)
HISTORIAN_FLAGS: dict[str, str] = {"op": "BOP", "pv": "BPV", "sp": "BSP"}


def historian_flags(cols: dict[str, np.ndarray], flagged: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], str]:
    """The historian's columns with each value its status flag marks (``flagged``: a mask per column) read as missing
    (NaN), and the note ('' where none is set). Where the samples with a flagged value exceed
    :data:`MAX_MISSING_FRACTION`, they would refuse the record: the values are kept as read, and the note says so."""
    any_flag = np.zeros(len(cols["time_s"]), dtype=bool)
    for m in flagged.values():
        any_flag |= m
    k = int(any_flag.sum())
    if not k:
        return cols, ""
    which = ", ".join(f"{c.upper()} {int(m.sum())}" for c, m in flagged.items() if m.any())
    if k > MAX_MISSING_FRACTION * any_flag.size:
        return cols, (f"{k} sample(s) carry a value the export's status flags mark ({which}): too many to read as "
                      "missing, read as exported (a flagged value repeats the one before it)")
    out = {c: np.where(flagged[c], np.nan, v) if c in flagged else v for c, v in cols.items()}
    return out, (f"{k} sample(s) carry a value the export's status flags mark ({which}; first at sample "
                 f"{int(np.flatnonzero(any_flag)[0]) + 1}): read as missing, as a flagged value repeats the one before "
                 "it and is not a new sample")


def _no_loop(p: Path, why: str) -> NoReturn:
    raise LoopDataError(f"{p} line 3: {why}")


def historian_loops(names: list[str]) -> dict[str, dict[str, int]]:
    """The loops that line 3 of a historian export names (``names``, its fields): each tag (the name before the
    suffix) with the column of each role it has (:data:`HISTORIAN_SUFFIXES`, the first suffix found, in any case),
    in the order of their first column."""
    loops: dict[str, dict[str, int]] = {}
    for role, suffixes in HISTORIAN_SUFFIXES.items():
        for sfx in suffixes:
            for i, n in enumerate(names):
                if len(n) > len(sfx) and n.upper().endswith(sfx):
                    loops.setdefault(n[:-len(sfx)], {}).setdefault(role, i)
    return dict(sorted(loops.items(), key=lambda kv: min(kv[1].values())))


def historian_separator(first_line: str) -> str:
    """The field separator of a historian export, from its first line (``PROCESSDATA`` and the export's name): the
    format's tab, or where a spreadsheet saved the export as CSV, the ``;`` or ``,`` that follows ``PROCESSDATA``."""
    after = first_line[len(HISTORIAN_MARK):len(HISTORIAN_MARK) + 1]
    return after if after in (";", ",") else "\t"


def read_historian(path: str | Path, lines: list[str] | None = None,
                   tag: str | None = None) -> tuple[dict[str, np.ndarray], str, list[str]]:
    """Columns of a plant-historian export (the format of the real loops; see the module doc), the tag and the notes
    of what was read as other than data (a last line cut off mid-write). ``lines``: the file's, where they have been
    read. An export of several loops (line 3 names the tags of more than one) is read for the loop ``tag``, and
    refused in one line that names its loops where no ``tag`` is given."""
    p = Path(path)
    lines, notes = _text_lines(p) if lines is None else (lines, [])
    if len(lines) < 6 or not lines[0].startswith(HISTORIAN_MARK):
        raise LoopDataError(f"{p}: not a historian export (first line should start with PROCESSDATA)")
    sep = historian_separator(lines[0])
    if sep != "\t":  # a spreadsheet's save of the export: its fields as the export's own tabs
        lines = ["\t".join(next(csv.reader([line], delimiter=sep), [])) for line in lines]
        notes.append(f"the export's fields are separated by {sep!r} (a spreadsheet's save), not by tabs: read so")
    names = [n.strip() for n in lines[2].split("\t")]
    loops = historian_loops(names)
    whole = [t for t, roles in loops.items() if {"op", "pv", "sp"} <= set(roles)]
    if tag is not None:
        asked, tag = tag, next((t for t in loops if t.upper() == tag.upper()), None)
        if tag is None:
            _no_loop(p, f"no loop {asked!r} among the tags (loops: {', '.join(whole) or 'none'})")
    elif len(whole) > 1:
        _no_loop(p, f"the export holds {len(whole)} loops ({', '.join(whole)}): choose one with --tag")
    else:
        tag = whole[0] if whole else next((t for t, roles in loops.items() if "op" in roles), None)
    found = loops.get(tag, {}) if tag is not None else {}
    lacking = [f"{tag if tag is not None else '<tag>'}{'/'.join(HISTORIAN_SUFFIXES[r])} ({what})" for r, what in
               (("op", "controller output"), ("pv", "process variable"), ("sp", "set point")) if r not in found]
    if lacking:
        have = ", ".join(repr(n) for n in names[1:] if n and "." in n) or "none"
        _no_loop(p, f"no {' and no '.join(lacking)} among the tags (read: {have})")
    assert tag is not None
    i_op, i_pv, i_sp, i_mode = found["op"], found["pv"], found["sp"], found.get("mode")
    # the status flags are the first that follow the loop's own columns (in a one-loop export, wherever they are)
    start = min(found.values())
    order = [*range(start, len(names)), *(range(start) if len(loops) == 1 else [])]
    flag_at: dict[str, int] = {}
    for role, prefix in HISTORIAN_FLAGS.items():
        j = next((j for j in order if names[j].upper().startswith(prefix)), None)
        if j is not None:
            flag_at[role] = j
    flags: dict[str, list[bool]] = {role: [] for role in flag_at}
    t0: datetime | None = None
    cols: dict[str, list[float]] = {"time_s": [], "sp": [], "pv": [], "op": []}
    if i_mode is not None:
        cols["mode"] = []
    stamp: Callable[[str], datetime] | None = None
    stamps: list[datetime] = []
    first = ""
    last = max((j for j, line in enumerate(lines, start=1) if line.strip()), default=0)
    begin = _historian_data_start(lines)
    # the values' decimal mark, from the data's first 50 lines (an export in a decimal-comma locale: 25,08)
    comma = decimal_mark([c.strip() for line in lines[begin:begin + 50] for c in line.split("\t")[1:]]) == ","
    for lineno, line in enumerate(lines[begin:], start=begin + 1):
        if not line.strip():
            continue
        f = line.split("\t")
        if len(f) < len(names):
            if lineno == last and lineno > begin + 1:
                notes.append(cut_line_note(lineno, len(f), len(names)))
                continue
            raise LoopDataError(f"{p} line {lineno}: {len(f)} fields, line 3 names {len(names)}")
        if stamp is None:
            try:
                stamp, first = _stamp_reader(lines[0], f[0], f"{p} line {lineno}"), f[0].strip()
            except LoopDataError as exc:
                if sep == "\t":
                    raise
                raise LoopDataError(f"{exc}; a spreadsheet that saves the export rewrites its timestamps in its own "
                                    "format, often without the seconds: export it again, or save the timestamps "
                                    "as text") from None
        try:
            ts = stamp(f[0])
        except ValueError:
            raise LoopDataError(f"{p} line {lineno}: timestamp {f[0]!r} is not in the format of the first "
                                f"({first!r})") from None
        t0 = ts if t0 is None else t0
        stamps.append(ts)
        cols["time_s"].append((ts - t0).total_seconds())
        for c, i in (("op", i_op), ("pv", i_pv), ("sp", i_sp), ("mode", i_mode)):
            if i is None:
                continue
            cell = decimal_comma(f[i].strip()) if comma else f[i].strip()
            cols[c].append(_cell_value(c, cell, f"{p} line {lineno}, column {names[i]}"))
        for c, i in flag_at.items():
            flags[c].append(f[i].strip() not in ("", "0"))
    read, note = historian_flags({c: np.asarray(v, dtype=float) for c, v in cols.items()},
                                 {c: np.asarray(v, dtype=bool) for c, v in flags.items()})
    read["time_s"], clock = clock_changes(read["time_s"], stamps)
    return read, tag, [*notes, *(n for n in (clock, note) if n)]


def _historian_data_start(lines: list[str]) -> int:
    """The index of a historian export's first data line: after the tags (line 3), its description (``desc ...``) and
    scale (``fsMax=...``) lines, or the first of lines 4 and 5 whose first field is a timestamp in the format line 1
    declares, where an export leaves either out (its first sample was taken for a header line)."""
    for j in (3, 4):
        cell = lines[j].split("\t")[0].strip() if j < len(lines) else ""
        try:
            _stamp_reader(lines[0], cell, "")(cell)
        except (LoopDataError, ValueError):
            continue
        return j
    return 5


def read_loop(path: str | Path, tag: str | None = None) -> LoopData:
    """Read either format (detected from the first line), check it, drop manual-mode samples and
    return a :class:`LoopData` on a uniform grid. ``tag``: the loop of a historian export that holds several (a
    loop CSV holds one, and takes none)."""
    p = Path(path)
    if not p.exists():
        raise LoopDataError(f"{p}: no such file")
    if p.is_dir():
        raise LoopDataError(f"{p}: is a directory")
    lines, read_notes = _text_lines(p)
    if lines and lines[0].startswith(HISTORIAN_MARK):
        cols, tag, notes = read_historian(p, lines, tag=tag)
    elif tag is not None:
        raise LoopDataError(f"{p}: a loop CSV holds one loop; --tag chooses the loop of a historian export")
    else:
        cols, tag, notes = read_loop_csv(p, lines)
    data = check_loop(cols, tag=tag, source=str(p))
    data.notes[:0] = [*read_notes, *notes]
    return data


def _longest_true_run(mask: np.ndarray) -> tuple[int, int]:
    best, start, b0 = 0, None, 0
    for i, m in enumerate(np.append(mask, False)):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start > best:
                best, b0 = i - start, start
            start = None
    return b0, b0 + best


def merge_repeated_timestamps(cols: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], str]:
    """One row per timestamp (docs/loops.md, "Input formats"): consecutive rows that repeat a timestamp
    (a historian's duplicate rows, or two values stored in the same second) become one row; exact
    duplicates are dropped and rows that differ are averaged, column by column (``mode`` too: an average
    other than 1 counts as manual). Time must be non-decreasing (checked before). Returns the merged
    columns and a note saying what was merged."""
    t = cols["time_s"]
    start = np.flatnonzero(np.r_[True, np.diff(t) != 0])
    counts = np.diff(np.r_[start, t.size])
    multi = counts > 1
    spread = np.zeros(start.size)
    out: dict[str, np.ndarray] = {}
    for c, v in cols.items():
        out[c] = np.add.reduceat(v, start) / counts
        spread = np.maximum(spread, np.maximum.reduceat(v, start) - np.minimum.reduceat(v, start))
    exact = int(np.sum(multi & (spread == 0)))
    differing = int(np.sum(multi & (spread > 0)))
    first = int(start[np.flatnonzero(multi)[0]]) + 1
    note = (f"merged {int(np.sum(counts[multi] - 1))} row(s) repeating a timestamp (first at sample {first}): "
            f"{exact} exact duplicate(s) dropped, {differing} group(s) of differing rows averaged")
    return out, note


def central_width(v: np.ndarray) -> float:
    """The width of the central 90 % of a channel's finite values (its 5 to 95 percentiles); 0 with fewer than 10."""
    ok = v[np.isfinite(v)]
    return float(np.subtract(*np.percentile(ok, [95.0, 5.0]))) if ok.size >= 10 else 0.0


def gross_outliers(v: np.ndarray, width: float = 0.0) -> np.ndarray:
    """The samples of a column that lie far outside its record and come back at once.

    Far: beyond the column's central 90 % (its 5 and 95 percentiles, width w: robust to the sentinels themselves) by
    more than :data:`GROSS_RANGES` w. At once: in runs of at most :data:`GROSS_MAX_RUN` samples whose neighbours on
    both sides lie within w of that range. At most :data:`GROSS_MAX_FRACTION` of the samples in all, else none:
    excursions that frequent may be the plant's. A historian writes a sentinel (-9999) where it has no value, and a
    transmitter's fault gives an isolated spike; either, left in, moves the correlations and the fit (one -9999 in an
    OP read as % made the OP's observed range its scale). A controller's kick at a set-point step also leaves the
    range for a few samples, but it rises and decays through its neighbours, which lie outside the range too, and it
    is kept. Missing values (NaN) are not counted. ``width``: a floor on w, the central width of the channels in the
    same units (:func:`check_loop`: a set point's floor is the PV's, and the other way round): a set point held for
    most of the record has w = 0, and a brief change of it by an operator is not a sentinel. Where w is 0 even so
    (every channel in those units holds one value), nothing is flagged. Returns a boolean mask."""
    ok = np.isfinite(v)
    flags = np.zeros(v.size, dtype=bool)
    if ok.sum() < 10:
        return flags
    lo, hi = (float(q) for q in np.percentile(v[ok], [5.0, 95.0]))
    w = max(hi - lo, width)
    if not w > 0.0:
        return flags
    with np.errstate(invalid="ignore"):
        far = ok & ((v < lo - GROSS_RANGES * w) | (v > hi + GROSS_RANGES * w))
        near = ok & (v >= lo - w) & (v <= hi + w)
    edges = np.diff(np.r_[0, far.astype(np.int8), 0])
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        if b - a <= GROSS_MAX_RUN and (a == 0 or near[a - 1]) and (b == v.size or near[b]):
            flags[a:b] = True
    if flags.sum() > GROSS_MAX_FRACTION * ok.sum():
        flags[:] = False
    return flags


#: the columns a historian holds from one stored value to the next (a set point and a mode change in steps); the
#: others are measurements, interpolated linearly between their stored values
HELD_COLUMNS: tuple[str, ...] = ("sp", "mode")


def tags_on_own_times(cols: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], str]:
    """The columns of an export that writes several tags on the union of their timestamps, each tag's value only
    where it has a sample (a historian's recorded values side by side: tags scanned at other rates, or stored on
    change), read on common rows (:func:`valve_env.data_io.own_rates`), and the note ('' where the record is not such
    an export). A column so is one that misses its value on more than :data:`MAX_MISSING_FRACTION` of the rows;
    :data:`HELD_COLUMNS` are held from each value to the next; the record is read on the rows of the slower of pv
    and op where one is interleaved with empty rows."""
    have = {c: cols[c] for c in COLUMNS[1:] if c in cols}
    read = own_rates(cols["time_s"], have, MAX_MISSING_FRACTION, bases=("pv", "op"), held=HELD_COLUMNS)
    if read is None:
        return cols, ""
    n = cols["time_s"].size
    said = [f"{c} has a value on {int(np.sum(~np.isnan(cols[c])))} of {n} rows, held from each to the next"
            for c in read.held]
    if read.base is not None:
        said.append(f"{read.base} has a value on {int(read.rows.sum())} of {n} rows (one in {read.every_rows:g}, "
                    "median): the record is read on those rows")
    said += [f"{c} ({int(np.sum(~np.isnan(cols[c])))} values) interpolated linearly in time on those rows"
             for c in read.interpolated]
    out = {"time_s": cols["time_s"][read.rows], **read.values}
    return out, ("the tags are on their own times (an export of several tags on the union of their timestamps, "
                 f"empty where a tag has no sample): {'; '.join(said)}")


def check_loop(cols: dict[str, np.ndarray], tag: str = "", source: str = "") -> LoopData:
    """Validate raw columns (``time_s, sp, pv, op`` and optional ``mv, mode``); see the module doc."""
    where = source or "loop"
    notes: list[str] = []
    n = cols["time_s"].size
    if n < 2:
        raise LoopDataError(f"{where}: {n} sample(s): a record needs at least two")
    for c in COLUMNS:
        if c in cols:
            # a missing value is dropped below, except a missing time
            bad = np.flatnonzero(~np.isfinite(cols[c]) if c == "time_s" else np.isinf(cols[c]))
            if bad.size:
                raise LoopDataError(f"{where}: column {c} has {bad.size} NaN/infinite value(s), first at "
                                    f"sample {bad[0] + 1}")
    width: dict[str, float] = {c: central_width(cols[c]) for c in ("sp", "pv", "op", "mv") if c in cols}
    same_units: dict[str, str] = {"sp": "pv", "pv": "sp", "op": "mv", "mv": "op"}
    gross = {c: gross_outliers(cols[c], width.get(same_units[c], 0.0)) for c in width}
    if any(g.any() for g in gross.values()):
        said = []
        for c, g in gross.items():
            if g.any():
                idx = np.flatnonzero(g)
                said.append(f"{c} at sample(s) {short_list([int(i) + 1 for i in idx])} ({cols[c][idx[0]]:.6g} "
                            f"first)")
                cols = {**cols, c: np.where(g, np.nan, cols[c])}
        notes.append(f"read {sum(int(g.sum()) for g in gross.values())} value(s) far outside their column's record as "
                     f"missing (a historian's sentinel or a gross spike: beyond the central 90 % by "
                     f"{GROSS_RANGES:g} times its width): {'; '.join(said)}")
    cols, own_times = tags_on_own_times(cols)
    if own_times:
        notes.append(own_times)
        n = cols["time_s"].size
    missing = np.zeros(n, dtype=bool)
    for c in ("sp", "pv", "op", "mv", "mode"):
        if c in cols:
            missing |= np.isnan(cols[c])
    if missing.any():
        k = int(missing.sum())
        first = int(np.flatnonzero(missing)[0])
        col = next(c for c in ("sp", "pv", "op", "mv", "mode") if c in cols and np.isnan(cols[c][first]))
        if k > MAX_MISSING_FRACTION * n:
            raise LoopDataError(f"{where}: {k} of {n} samples ({k / n:.0%}) miss a value (column {col} first, at "
                                f"sample {first + 1}); at most {MAX_MISSING_FRACTION:.0%} may")
        cols = {c: v[~missing] for c, v in cols.items()}
        n = cols["time_s"].size
        notes.append(f"dropped {k} sample(s) with a missing value (first: column {col} at sample {first + 1}); "
                     "the record is resampled over them")
    dt = np.diff(cols["time_s"])
    bad = np.flatnonzero(dt < 0)
    if bad.size:
        k = int(bad[0])
        raise LoopDataError(f"{where}: time is not strictly increasing at sample {k + 2} "
                            f"(time_s {cols['time_s'][k]:g} then {cols['time_s'][k + 1]:g})"
                            f"{time_order_hint(cols['time_s'])}")
    if np.any(dt == 0):
        cols, note = merge_repeated_timestamps(cols)
        notes.append(note)
        n = cols["time_s"].size
    keep = np.ones(n, dtype=bool)
    if "mode" in cols:
        auto = cols["mode"] == 1
        if not auto.any():
            raise LoopDataError(f"{where}: the loop is never in automatic mode (mode column never 1)")
        if not auto.all():
            a, b = _longest_true_run(auto)
            notes.append(f"dropped {n - (b - a)} sample(s) outside the longest automatic-mode stretch "
                         f"(samples {a + 1}-{b} kept; {int((~auto).sum())} in manual mode)")
            keep[:] = False
            keep[a:b] = True
    t = cols["time_s"][keep]
    t = t - t[0]
    if t.size < 2:
        raise LoopDataError(f"{where}: {t.size} sample(s) in automatic mode: a record needs at least two")
    data = {c: cols[c][keep] for c in ("sp", "pv", "op", "mv") if c in cols}
    step = np.diff(t)
    h = float(np.median(step))
    bad_interval = interval_problem(h)
    if bad_interval:  # a time in milliseconds or in days: the loop's dynamics would be read a thousand times off
        raise LoopDataError(f"{where}: column time_s: {bad_interval}")
    if np.max(np.abs(step - h)) > 0.01 * h:  # uneven sampling, or samples dropped above
        grid = np.arange(0.0, t[-1] + 0.5 * h, h)
        data = {c: np.interp(grid, t, v) for c, v in data.items()}
        notes.append(f"resampled onto a uniform {h:g} s grid (sampling varied from {step.min():g} to "
                     f"{step.max():g} s)")
        t = grid
    op = data["op"]
    scaled: tuple[float, float] | None = None
    if float(np.ptp(op)) > 0 and (float(op.min()) < OP_RANGE_PCT[0] or float(op.max()) > OP_RANGE_PCT[1]):
        scaled = (float(op.min()), float(op.max()))
        op = 100.0 * (op - scaled[0]) / (scaled[1] - scaled[0])
        notes.append(f"OP runs from {scaled[0]:.6g} to {scaled[1]:.6g}, outside {OP_RANGE_PCT[0]:g} to "
                     f"{OP_RANGE_PCT[1]:g} %: read as engineering units and scaled by its observed range "
                     f"({scaled[0]:.6g} -> 0 %, {scaled[1]:.6g} -> 100 %); bands are in % of that range")
        if "mv" in data and (float(data["mv"].min()) < OP_RANGE_PCT[0] or float(data["mv"].max()) > OP_RANGE_PCT[1]):
            data["mv"] = 100.0 * (data["mv"] - scaled[0]) / (scaled[1] - scaled[0])
    elif float(np.ptp(op)) > 0 and float(op.min()) >= 0.0 and float(op.max()) <= 1.0:
        notes.append(f"OP lies within 0 to 1 throughout ({float(op.min()):.4g} to {float(op.max()):.4g}): read as %; "
                     "if the export gives OP as a fraction, the bands in % of OP are 100 times too small")
    for end, at in ((0.0, op <= SATURATED_PCT), (100.0, op >= 100.0 - SATURATED_PCT)):
        share = float(np.mean(at))
        if share > SATURATION_SHARE:
            limit = f"{end:g} %" if scaled is None else f"its observed {'minimum' if end == 0.0 else 'maximum'}"
            notes.append(f"OP sits at {limit} on {share:.0%} of the samples: the controller saturates there, the loop "
                         "is open, and the shape tests and the band's fit read those stretches as part of the loop's "
                         "behaviour; read the verdict with care")
    return LoopData(time_s=t, sp=data["sp"], pv=data["pv"], op=op, mv=data.get("mv"), tag=tag, source=source,
                    notes=notes, op_scaled_from=scaled)


__all__ = ["LoopData", "LoopDataError", "MIN_SAMPLES", "MAX_MISSING_FRACTION", "SATURATED_PCT",
           "SATURATION_SHARE", "MISSING_MARKERS", "MODE_NAMES",
           "read_loop", "read_loop_csv", "read_historian",
           "check_loop", "merge_repeated_timestamps", "gross_outliers", "GROSS_RANGES", "GROSS_MAX_RUN",
           "GROSS_MAX_FRACTION", "LOOP_SYNONYMS", "synonym_hint", "COLUMNS", "REQUIRED_COLUMNS"]
