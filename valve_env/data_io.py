"""Measured valve runs (docs/reference.md, section 2): loading with validation and clear errors.

    df = load_run("run.csv")

The one validation path for a measured run: ``thermovalve fit``, ``thermovalve diagnose``
and ``thermovalve experiment`` (its output is checked before it is written) all go through
:func:`validate_run`. It checks, in order: the columns; every value numeric and finite or empty; where x_mm is
measured, an opening beyond the valve's stroke (:func:`_check_stroke`) or falling as the flow rises
(:func:`_check_opening_sign`) and a dp_mbar in another unit that the flow
through the valve characteristic shows (:func:`_check_dp_unit`); the physical ranges of :data:`RANGES` (dp_mbar > 0,
flows >= 0, static pressure > 0 and plausible, temperatures within -30..150 degC); time strictly increasing with a
plausible sampling interval (:data:`DT_RANGE_S`, no gap longer than :data:`MAX_GAP_S` in the time column, times within
:data:`MAX_ABS_TIME_S`); the record length; a temperature that moves; an opening that can be
known (a flow that is zero everywhere with no x_mm column is rejected). Each failure is one
line naming the column and the row (row 1 is the first data row; the line is the file's own). An empty cell in
a measured column (blank, a NaN marker or a historian's state: :data:`MISSING_MARKERS`) drops its row, as a
sample the logger missed (at most :data:`MAX_EMPTY_FRACTION` of the rows; the pre-processing's note names
them); an empty time_s is refused. A row that repeats the row before it in every column is dropped and named. A units
row under the header (``s, degC, degC, kg/h, mbar, bar, mm``, as loggers write one) is read as a second header line
where its units are the format's (:data:`UNITS`), and refused in one line naming the column where one is not.

The file is UTF-8, UTF-16 with its byte-order mark (a spreadsheet's "Unicode text") or Windows-1252 (a spreadsheet's
plain "CSV" save on Windows), gzip-compressed or not: :func:`read_text`. Its
dialect is read off its header (:func:`csv_dialect`): fields separated by commas, or by semicolons or tabs where
the header has no comma (a spreadsheet's export in a locale that writes a decimal comma uses ``;``, and then the
decimal comma is read too), or by runs of spaces where it has none of these (a fixed-width or space-separated
export); comment lines starting with ``#`` before the header are skipped, and so are the lines after the data that
hold none (:func:`footer_lines`: a logger's closing comment, a spreadsheet's empty formatted rows). Line numbers in
the messages are the file's own.

Required columns: time_s, T_tank_C, T_med_C, q_kgh, dp_mbar, ps_bar; optional x_mm
(where absent, or where a cell is empty, it is derived from q_kgh and dp_mbar with
:func:`valve_env.physics.valve.opening_from_flow`); extra columns are kept. Every
problem raises :class:`DataError` with one line that names it. The file is only read.
"""

from __future__ import annotations

import difflib
import io
import os
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy.stats import median_abs_deviation

from valve_env.params import ValveParams
from valve_env.physics.valve import flow_kgh, opening_from_flow

REQUIRED: tuple[str, ...] = ("time_s", "T_tank_C", "T_med_C", "q_kgh", "dp_mbar", "ps_bar")
OPTIONAL: tuple[str, ...] = ("x_mm",)
#: the loop CSV's columns (docs/reference.md, section 10; read by :mod:`valve_env.loops.io`): the four it needs, then
#: the optional measured valve position and mode. Here so that either reader can tell a file of the other format
LOOP_COLUMNS: tuple[str, ...] = ("time_s", "sp", "pv", "op", "mv", "mode")
#: the first word of a plant-historian export of a control loop (docs/reference.md, section 10)
HISTORIAN_MARK = "PROCESSDATA"
#: The shortest record that identifies the base model's parameters.
MIN_ROWS = 30
#: A temperature range below this (K) identifies nothing (no hysteresis loop, no gain).
MIN_T_RANGE_K = 0.2
#: Plausible physical ranges (lo, hi, lo_open): a domestic hot-water substation
#: (docs/cli.md; the seed paper's test rig: tank 55-65 degC, medium 60-80 degC, dp 50-300 mbar,
#: static pressure ~2-6 bar, flows up to a few hundred kg/h, stem stroke a few mm).
RANGES: dict[str, tuple[float, float, bool, str]] = {
    "T_tank_C": (-30.0, 150.0, False, "a plausible water temperature, degC"),
    "T_med_C": (-30.0, 150.0, False, "a plausible water temperature, degC"),
    "q_kgh": (0.0, 1.0e5, False, "a flow, kg/h"),
    "dp_mbar": (0.0, 1.0e4, True, "a differential pressure, mbar"),
    "ps_bar": (0.0, 100.0, True, "a static pressure, bar"),
    "x_mm": (-1.0, 50.0, False, "a valve opening, mm"),
}
#: what takes a temperature in kelvin, and one in degF, to degC
KELVIN_TO_C, FAHRENHEIT_TO_C = "subtract 273.15", "convert with (v - 32) * 5 / 9"
#: The water's density at 60 degC, kg/m3 (IAPWS-95 at 1 bar: 983.2), for the hint that takes a volume flow to kg/h.
WATER_DENSITY_60C = 983.2
#: Other units loggers write a column in (as :func:`unit_key` gives them), and how to take the column to the format's
#: unit (:data:`UNITS`): the factor that multiplies the values, or a text where no factor does (an offset; a volume
#: flow, which needs the water's density; a position in % of the stroke, which needs the valve's stroke).
CONVERSIONS: dict[str, dict[str, float | str]] = {
    "T_tank_C": {"k": KELVIN_TO_C, "kelvin": KELVIN_TO_C, "degf": FAHRENHEIT_TO_C, "f": FAHRENHEIT_TO_C},
    "q_kgh": {"kg/s": 3600.0, "kgs": 3600.0, "kg/min": 60.0, "t/h": 1000.0, "th": 1000.0,
              **{u: f"a volume flow: the mass flow is the volume flow times the water's density at its "
                    f"temperature; at 60 degC multiply by {WATER_DENSITY_60C * f:.4g}"
                 for u, f in (("m3/h", 1.0), ("m3h", 1.0), ("m³/h", 1.0), ("l/h", 1e-3), ("lh", 1e-3),
                              ("l/min", 0.06), ("lmin", 0.06), ("lpm", 0.06), ("l/s", 3.6), ("ls", 3.6))}},
    "dp_mbar": {"pa": 0.01, "kpa": 10.0, "bar": 1000.0, "bard": 1000.0, "psi": 68.94757, "psid": 68.94757,
                "mh2o": 98.0665, "mwc": 98.0665, "mmh2o": 0.0980665, "mmwc": 0.0980665},
    "ps_bar": {"pa": 1e-5, "kpa": 0.01, "kpag": 0.01, "mpa": 10.0, "mbar": 1e-3, "psi": 0.06894757,
               "psig": 0.06894757},
    "x_mm": {"um": 1e-3, "\u00b5m": 1e-3, "\u03bcm": 1e-3, "micron": 1e-3, "m": 1000.0, "cm": 10.0,
             "%": f"a position in % of the stroke: multiply by the valve's stroke in mm over 100, "
                  f"{ValveParams().stroke / 100:g} for the calibrated valve's {ValveParams().stroke:g} mm"},
}
CONVERSIONS["T_med_C"] = CONVERSIONS["T_tank_C"]  # CONVERSIONS["time_s"]: _TIME_FACTORS, below


def factor(name: str, unit: str) -> float:
    """The factor of :data:`CONVERSIONS` that takes column ``name`` from ``unit`` (as :func:`unit_key` gives it) to
    the format's unit."""
    f = CONVERSIONS[name][unit]
    assert isinstance(f, float), (name, unit)
    return f


def scale_text(factor: float) -> str:
    """``multiply by 10``, or ``divide by 1000`` for a factor below 1 whose inverse is a round number."""
    inv = 1.0 / factor
    return f"divide by {inv:g}" if factor < 1 and abs(inv - round(inv)) < 1e-9 * inv else f"multiply by {factor:g}"


class OtherUnit(NamedTuple):
    """A unit a column may arrive in instead of the format's (:data:`OTHER_UNITS`)."""

    unit: str
    #: what to do, the end of the refusal
    do: str
    #: the value in the format's unit is ``scale * value + offset``
    scale: float
    offset: float
    #: the unit is named where more than this share of the values lie outside the range as they stand
    share: float
    #: ... and only where every value is a whole number (a controller's integer register)
    integers: bool = False


#: Units a column may arrive in instead of the format's, as a refusal of its range names them (:class:`OtherUnit`):
#: the first, in order, under which every value converts into the range and more than its share of the values lie
#: outside it as they stand. A water
#: temperature in degF lies above 150 only where it is hotter than 65.6 degC, so a medium's record in degF refuses on
#: part of its rows (a quarter of a generated day's, medium 48-67 degC); a tenth of the rows keeps a few sentinels or
#: spikes of a record in degC from reading as degF. A controller's integer register holds a temperature in whole tenths
#: of a degC (526 for 52.6 degC), where a record in kelvin has decimals.
_TEMPERATURE_UNITS: tuple[OtherUnit, ...] = (
    OtherUnit("kelvin", KELVIN_TO_C, 1.0, -273.15, 0.5),
    OtherUnit("degF", f"{FAHRENHEIT_TO_C}, and the other temperature column too", 5.0 / 9.0, -160.0 / 9.0, 0.1),
    OtherUnit("tenths of a degC (a controller's integer register)", "divide by 10, and the other temperature column "
              "too", 0.1, 0.0, 0.5, integers=True))
OTHER_UNITS: dict[str, tuple[OtherUnit, ...]] = {
    "T_tank_C": _TEMPERATURE_UNITS,
    "T_med_C": _TEMPERATURE_UNITS,
    "dp_mbar": (OtherUnit("Pa", scale_text(factor("dp_mbar", "pa")), factor("dp_mbar", "pa"), 0.0, 0.5),
                OtherUnit("mbar with the sign reversed (the outlet's pressure minus the inlet's)", "negate the column",
                          -1.0, 0.0, 0.5)),
    "ps_bar": tuple(OtherUnit(u, scale_text(factor("ps_bar", u.lower())), factor("ps_bar", u.lower()), 0.0, 0.5)
                    for u in ("kPa", "Pa")),
    "q_kgh": (OtherUnit("kg/h with the sign reversed (a flow meter that counts the valve's flow as negative)",
                        "negate the column", -1.0, 0.0, 0.5),),
}
#: Units of dp_mbar that the flow can reveal where x_mm is measured (:func:`_check_dp_unit`): the name, what to do
#: and the factor to mbar. An SI logger writes Pa; the flow at a given opening grows as sqrt(dp), so a dp in Pa makes
#: the flow a tenth of what the valve characteristic gives.
DP_UNITS: tuple[tuple[str, str, float], ...] = tuple((u, scale_text(factor("dp_mbar", u.lower())),
                                                      factor("dp_mbar", u.lower())) for u in ("Pa", "kPa", "bar"))
#: The flow-characteristic check's tolerances: the median ratio of q_kgh to the characteristic's flow is "off" beyond a
#: factor FLOW_OFF, and a unit explains it where it brings the ratio within a factor FLOW_EXPLAINED of 1 and the median
#: dp within a factor DP_PLAUSIBLE of the valve's calibration dp (dp_k_sp), where the file's own median lies outside it
#: (a valve of another Kvs at its usual dp is not taken for a unit).
FLOW_OFF, FLOW_EXPLAINED, DP_PLAUSIBLE = 2.0, 1.25, 5.0
#: The rank correlation between the opening and the flow's Kv (q / sqrt(dp)) below which the opening falls as the flow
#: rises (:func:`_check_opening_sign`): a valve passes more water the wider it opens, so measured openings correlate
#: near +1 with it, and a record whose opening hardly moves near 0.
OPENING_SIGN_CORR = -0.5
#: How far beyond the valve's stroke the opening's record may reach on a tenth of its samples (:func:`_check_stroke`): a
#: transducer's noise and overtravel stay well within it.
STROKE_MARGIN = 1.25
#: The median sampling interval must lie in this range (s).
DT_RANGE_S: tuple[float, float] = (1.0e-3, 3600.0)
#: No single interval between samples may be longer than this (s): one day.
MAX_GAP_S = 86400.0
#: A flow meter reads about 0 with its own noise where the valve is shut, partly below 0 (a magnetic or ultrasonic
#: meter without a low-flow cut-off). Flows below 0 down to this share of the record's high flow (its 99th percentile)
#: are read as 0, with a note (:func:`_zero_flow_noise`); one further below 0 is refused by the range check, which names
#: a meter that counts the flow as negative where every value would fit so.
ZERO_FLOW_NOISE_SHARE = 0.05
#: A flow meter's low-flow cut-off (a magnetic or ultrasonic meter reads 0 below a set flow, commonly 0.5-5 % of its
#: range): a record whose flow is exactly 0 on at least :data:`CUT_OFF_MIN_ROWS` rows and a share
#: :data:`CUT_OFF_MIN_SHARE` of them, and whose smallest flow above 0 is at least :data:`CUT_OFF_MIN_FLOW_SHARE` of the
#: high flow (its 99th percentile), has one (:func:`flow_cut_off`): a valve that opens from its seat passes every small
#: flow on the way, which the record then lacks. An opening derived from such a flow is only known to be below the
#: cut-off's opening where the flow reads 0; it is derived as 0 there, and a warning says so (docs/reference.md,
#: section 2; docs/diagnosis.md, "Known limits").
CUT_OFF_MIN_ROWS = 10
CUT_OFF_MIN_SHARE = 0.01
CUT_OFF_MIN_FLOW_SHARE = 0.01
#: A circulation pump that stops (at night, or in summer) leaves the valve without a differential pressure or a flow:
#: rows whose dp_mbar lies within this share of the record's median dp of 0 (either side: a transmitter's noise) and
#: whose flow is within :data:`ZERO_FLOW_NOISE_SHARE` of the high flow of 0, in stretches of at least
#: :data:`PUMP_OFF_MIN_ROWS` rows, are dropped with a note (:func:`_pump_off`): the valve's flow and force balance
#: hold no information there, and the likelihoods take the stretch as a gap. An isolated such row is a glitch, refused
#: by the range check.
PUMP_OFF_DP_SHARE = 0.05
PUMP_OFF_MIN_ROWS = 3
#: A measured opening's zero offset (:func:`zero_offset`): the rows whose flow is at most this share of the high flow
#: are the valve on its seat ...
SEAT_FLOW_SHARE = 0.01
#: ... and at least this many of them ...
SEAT_MIN_ROWS = 20
#: ... rest at an opening this many noise sd (and 1 % of the stroke) off 0, and at most this share of the stroke: a
#: transducer's zero offset, subtracted with a note
ZERO_OFFSET_NOISE = 5.0
ZERO_OFFSET_MAX_SHARE = 0.1
#: |time_s| beyond this (s, ~300 years) is not a time.
MAX_ABS_TIME_S = 1.0e10
#: The measured channels, whose empty cells drop their row (a logger that missed a value: the row is then
#: a missing sample, which the identification takes), up to :data:`MAX_EMPTY_FRACTION` of the rows.
MEASURED: tuple[str, ...] = REQUIRED[1:]
MAX_EMPTY_FRACTION = 0.10
#: A plant historian's words for a sample without a usable value, written in its place: the commonly met states
#: of the PI System's SYSTEM digital state set (AVEVA, PI Data Archive administration, "The SYSTEM digital state
#: set"), which a PI export writes into numeric columns, and the bare "Bad" of other historians.
HISTORIAN_STATES: frozenset[str] = frozenset({
    "bad", "bad input", "bad data", "i/o timeout", "no data", "pt created", "shutdown", "intf shut", "arc off-line",
    "calc failed", "comm fail", "scan off", "scan timeout", "over range", "under range", "invalid data", "configure",
})
#: A spreadsheet's error values, which an export writes where a formula had no value (Excel's and LibreOffice's).
SPREADSHEET_ERRORS: frozenset[str] = frozenset({"#n/a", "n/a", "#value!", "#div/0!", "#ref!", "#num!", "#name?",
                                                "#null!", "err:502", "err:504"})
#: A dash for no value, as a report or a formatted spreadsheet writes it: hyphen(s), en dash, em dash.
DASHES: frozenset[str] = frozenset({"-", "--", "\u2013", "\u2014"})
#: Cells read as empty (case-insensitive, after stripping): blanks, NaN markers, a dash, the historian states and a
#: spreadsheet's error values.
MISSING_MARKERS: frozenset[str] = (frozenset({"", "nan", "na", "null", "none"}) | DASHES | HISTORIAN_STATES
                                   | SPREADSHEET_ERRORS)
#: The format's unit of each column (docs/reference.md, section 2) and the ways a logger writes it, lower case with
#: spaces, brackets and the degree sign's variants removed (:func:`unit_key`). A units row under the header (a
#: logger's or a spreadsheet's second header line) is read where it names these; any other unit is refused.
UNITS: dict[str, tuple[str, frozenset[str]]] = {
    "time_s": ("s", frozenset({"s", "sec", "secs", "second", "seconds"})),
    "T_tank_C": ("degC", frozenset({"degc", "c", "celsius", "degcelsius", "oc"})),
    "T_med_C": ("degC", frozenset({"degc", "c", "celsius", "degcelsius", "oc"})),
    "q_kgh": ("kg/h", frozenset({"kg/h", "kgh", "kgh-1", "kg/hr", "kgperh"})),
    "dp_mbar": ("mbar", frozenset({"mbar", "mbarg", "mbard", "hpa"})),
    "ps_bar": ("bar", frozenset({"bar", "barg"})),
    "x_mm": ("mm", frozenset({"mm"})),
}
#: The ways a logger writes an absolute pressure in bar (:func:`unit_key`): ps_bar is the static pressure over the
#: ambient (docs/reference.md, section 1: dp_s = p_1 - p_0), and an absolute one is refused with what to subtract.
ABSOLUTE_BAR = frozenset({"bara", "barabs", "barabsolute"})
#: absolute pressures in bar or the other units of :data:`CONVERSIONS`' ps_bar
ABSOLUTE_PRESSURE = ABSOLUTE_BAR | {"psia", "kpaa", "kpaabs", "mpaa"}


def convert_to(name: str, unit: str) -> str:
    """What to do with column ``name`` given in ``unit``, a unit that is not the format's (:data:`UNITS`): the end of
    the refusal, with the factor or offset where :data:`CONVERSIONS` knows the unit."""
    want = UNITS[name][0]
    key = unit_key(unit)
    if name == "ps_bar" and key in ABSOLUTE_PRESSURE:
        return ("an absolute pressure: the format's ps_bar is the static pressure over the ambient (gauge; "
                "docs/reference.md, section 1: dp_s = p_1 - p_0); subtract the ambient pressure, about 1.013 bar")
    how = CONVERSIONS[name].get(key)
    how_text = "" if how is None else f" ({how if isinstance(how, str) else scale_text(how)})"
    return f"the format's unit is {want} (docs/reference.md, section 2); convert the column to {want}{how_text}"


def unit_name_hint(missing: str, columns: list[str]) -> str:
    """Where a required column is missing and the header has its quantity named with another unit that
    :data:`CONVERSIONS` knows (``T_tank_K``, ``dp_kPa``, ``q_m3h``, ``x_um``), the refusal's hint: which column, and
    the factor or offset to the format's unit. Else ''."""
    stem = missing.rsplit("_", 1)[0]
    for col in columns:
        m = re.match(rf"^{re.escape(stem)}[\s_.-]*(?P<u>.+)$", str(col).strip(), re.IGNORECASE)
        if not m:
            continue
        unit = m.group("u").strip("[]() \t")
        key = unit_key(unit)
        if missing == "ps_bar" and key in ABSOLUTE_PRESSURE:
            return f"; the header has {col!r}: {convert_to(missing, unit)}, and name it {missing}"
        how = CONVERSIONS[missing].get(key)
        if how is not None:
            return (f"; the header has {col!r}, {stem} in {unit}: give it as {missing} in {UNITS[missing][0]} "
                    f"({how if isinstance(how, str) else scale_text(how)})")
    return ""


def unit_key(cell: str) -> str:
    """A unit as :data:`UNITS` lists it: ``[°C]``, ``(deg C)`` and ``ºC`` all become ``degc``/``c``, ``bar(g)``
    ``barg``."""
    u = "".join(ch for ch in cell.lower() if ch not in "[]() \t\u00b7")
    return u.replace("\u00b0", "deg").replace("\u00ba", "deg").replace("\u02da", "deg").replace("\u2103", "degc")


#: a column's name with its unit after it, in brackets or after a slash (``T_tank_C [°C]``, ``q_kgh (kg/h)``,
#: ``time_s / s``)
_NAME_UNIT = re.compile(r"^(?P<name>[^\s\[\](/]+)\s*(?:\[(?P<a>[^\]]*)\]|\((?P<b>[^)]*)\)|/\s*(?P<c>.+))$")


#: a record shorter than this (s) is no valve test (its runs last hours): its time may be in minutes or hours
SHORT_SPAN_S = 600.0


def interval_problem(med: float) -> str:
    """What a refusal says of a median sampling interval ``med`` (s) outside :data:`DT_RANGE_S`, with the time unit
    that would bring it within (milliseconds, or a spreadsheet's days); '' within. The valve's and the loop's readers
    share it."""
    if DT_RANGE_S[0] <= med <= DT_RANGE_S[1]:
        return ""
    unit = "; if time_s is in milliseconds, divide it by 1000" if med > DT_RANGE_S[1] >= med / 1000.0 else \
        "; if time_s is in days (a spreadsheet's date number), multiply it by 86400" \
        if med < DT_RANGE_S[0] <= med * 86400.0 else ""
    return (f"median sampling interval {med:.3g} s is implausible (expected {DT_RANGE_S[0]:g} to {DT_RANGE_S[1]:g} s)"
            f"{unit}")


def time_unit_hint(t: np.ndarray) -> str:
    """Where the times ``t`` (s) span less than :data:`SHORT_SPAN_S`, what a message adds: the span, and to give
    time_s in seconds if it is in minutes or hours (read so, a valve's record of hours spans seconds). Else ''."""
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    if span >= SHORT_SPAN_S:
        return ""
    return (f"; the record spans {span:.3g} s over {len(t)} samples: if time_s is in minutes or hours, give it in "
            "seconds")


#: Flow units a logger writes where q_kgh is asked for, and their factor to kg/h (water): what
#: :func:`flow_unit_hint` tries where the opening derived from the flow cannot be right.
FLOW_UNITS: tuple[tuple[str, float], ...] = (("l/min", 60.0), ("m^3/h", 1000.0), ("kg/s", 3600.0))


def opening_derived(run: pd.DataFrame) -> bool:
    """Whether a validated run's whole opening was derived from its flow (:func:`validate_run`: no x_mm column, so
    ``x_mm_derived_rows`` counts every row); a few empty cells of a measured x_mm do not make it so."""
    return int(run.attrs.get("x_mm_derived_rows", 0)) == len(run)


def flow_unit_hint(q_kgh: np.ndarray, dp_mbar: np.ndarray, valve: ValveParams | None = None) -> str:
    """What a refusal of a run whose opening is derived from the flow (no x_mm column) adds where the derived opening
    hardly moves or cannot be fitted: the flow units of :data:`FLOW_UNITS` under which the derived opening would span
    at least a tenth of the stroke with at most a fifth of the rows at the stroke's end. Else ''."""
    v = valve or ValveParams()
    vp = v.to_array()
    fits = []
    for unit, a in FLOW_UNITS:
        x = opening_from_flow(a * np.asarray(q_kgh, dtype=float), np.asarray(dp_mbar, dtype=float), vp)
        if np.ptp(x) >= 0.1 * v.stroke and np.mean(x >= 0.999 * v.stroke) <= 0.2:
            fits.append(f"{unit} (multiply by {a:g}: the opening would span {np.ptp(x):.2g} mm of the {v.stroke:g} mm "
                        "stroke)")
    if not fits:
        return ""
    return "; the opening is derived from q_kgh and dp_mbar (no x_mm column): if q_kgh is in " + " or ".join(fits)


#: A tank's median temperature above this (degC) is hotter than a vented hot-water tank holds (water boils at
#: 100 degC at 1 atm); :func:`temperature_unit_hint` then reads the temperatures as degF.
TANK_HOT_C = 95.0


def temperature_unit_hint(T_tank_C: np.ndarray) -> str:
    """What a refusal or a fit-bound note adds where the tank's median temperature exceeds :data:`TANK_HOT_C` and reads
    as a hot-water tank's in degF (20-90 degC converted): temperatures in degF within the range check's 150 pass it
    (a tank at 52 degC is 126 degF) and leave the valve's set point unidentified. Else ''."""
    med = float(np.nanmedian(np.asarray(T_tank_C, dtype=float)))
    as_c = (med - 32.0) * 5.0 / 9.0
    if not (med > TANK_HOT_C and 20.0 <= as_c <= 90.0):
        return ""
    return (f"; T_tank_C's median {med:.4g} lies above {TANK_HOT_C:g} degC, hotter than a vented hot-water tank holds: "
            f"if the temperatures are in degF (the median would be {as_c:.3g} degC), convert both columns with "
            "(v - 32) * 5 / 9")


def header_units(header: list[str], names: tuple[str, ...]) -> dict[str, tuple[str, str]]:
    """The header's columns written as one of the format's ``names`` with a unit after it, as loggers label a column
    (``T_tank_C [°C]``): {the column as written: (the name, the unit)}. Both readers check the unit and read the
    name."""
    out = {}
    for col in header:
        m = _NAME_UNIT.match(str(col).strip())
        if m and m["name"] in names:
            out[str(col)] = (m["name"], (m["a"] or m["b"] or m["c"] or "").strip())
    return out


class DataError(ValueError):
    """A measured run that cannot be used; the message is one line naming the problem."""


#: a number written with a decimal comma (``52,61``, ``-0,5``, ``1,2e-3``)
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$")
#: a number written with a decimal point
_DECIMAL_POINT = re.compile(r"^[+-]?\d*\.\d+([eE][+-]?\d+)?$")
#: a number with its thousands grouped by points, as a spreadsheet in a decimal-comma locale writes a formatted
#: cell (``1.234,5``, ``12.500``)
_GROUPED = re.compile(r"^[+-]?\d{1,3}(\.\d{3})+(,\d+)?$")
#: a number whose thousands a comma groups, with a decimal point (``1,003.709``: a spreadsheet's "1000 separator")
_COMMA_GROUPED = re.compile(r"^[+-]?\d{1,3}(,\d{3})+\.\d*$")


def decimal_mark_hint(cell: str) -> str:
    """What a refusal of ``cell`` as not a number adds where the cell is a number written with a decimal comma
    (``0,0033``, ``1.234,5``) in a file whose other numbers have a decimal point (a spreadsheet that exported some
    columns as text): which mark is meant is not known, so the file is not read. Where a comma groups the thousands of
    a number with a decimal point (``1,003.709``), or the cell carries its unit after the number (``243.9 kg/h``),
    it says so. Else ''."""
    c = cell.strip()
    if _DECIMAL_COMMA.match(c) or (_GROUPED.match(c) and "," in c):
        return "; it has a decimal comma where the file's other numbers have a decimal point: write every number " \
               "with one decimal mark"
    if _COMMA_GROUPED.match(c):
        return "; a comma groups its thousands (a spreadsheet's thousands separator): write numbers without it"
    m = _NUMBER_THEN_TEXT.match(c)
    if m:
        return (f"; the cell carries its unit ({m.group(2)!r}), as a formatted spreadsheet cell does: write the "
                "numbers alone (a unit may follow the column's name in the header)")
    return ""


#: a number with a Fortran program's double-precision exponent, ``D`` for ``E`` (``1.25D+01``)
_FORTRAN_EXPONENT = re.compile(r"^([-+]?(?:\d+\.?\d*|\.\d+))[dD]([-+]?\d+)$")


def fortran_exponent(cell: str) -> str:
    """A number written with a Fortran program's double-precision exponent (``1.25D+01``) as Python reads it
    (``1.25E+01``); other text as it is."""
    return _FORTRAN_EXPONENT.sub(r"\1E\2", cell)


#: a number followed by text, as a formatted cell writes a unit after its value (``243.9 kg/h``, ``52.3°C``)
_NUMBER_THEN_TEXT = re.compile(r"^([-+]?(?:\d+(?:[.,]\d*)?|[.,]\d+)(?:[eE][-+]?\d+)?)\s*([^\d\s.,+-].*)$")


def decimal_comma(cell: str) -> str:
    """A number written in a decimal-comma locale (``52,61``, ``1.234,5``) as Python reads it (``52.61``, ``1234.5``):
    the points that group thousands dropped, the decimal comma made a point. Other text is returned as it is, with
    any comma made a point."""
    if _GROUPED.match(cell.strip()):
        cell = cell.replace(".", "")
    return cell.replace(",", ".")


@dataclass(frozen=True)
class CsvDialect:
    """How a measured CSV text is written: ``skip`` comment lines (``#``) or empty lines before the header, the
    field ``sep`` (``" "``: runs of white space) and the ``decimal`` mark. ``header_line`` is the header's line
    number in the file (1-based)."""

    skip: int = 0
    sep: str = ","
    decimal: str = "."

    @property
    def header_line(self) -> int:
        return self.skip + 1

    def split(self, line: str) -> list[str]:
        """A line's fields, stripped (no quoting: for the header and the dialect's checks)."""
        return [f.strip().strip('"') for f in (line.split() if self.sep == " " else line.split(self.sep))]

    def cells(self, line: str) -> list[str]:
        """A line's fields as CSV reads them, unstripped: a quoted field is one field whatever it holds, and a stray
        quote spoils its own line only."""
        import csv

        return line.split() if self.sep == " " else next(csv.reader([line], delimiter=self.sep), [])

    @property
    def pandas_sep(self) -> str:
        return r"\s+" if self.sep == " " else self.sep


#: the first bytes of files that are not text, and what to do (:func:`read_text`)
NOT_TEXT: dict[bytes, str] = {
    b"PK\x03\x04": "a zip archive (a spreadsheet's workbook, .xlsx or .ods?): save the sheet as CSV",
    b"\xd0\xcf\x11\xe0": "an Office binary file (an .xls workbook?): save the sheet as CSV",
}


def read_text(p: Path) -> tuple[str, int]:
    """A text file's content and the number of NUL bytes dropped from its end: gzip-compressed or not (an archived
    logger file, ``run.csv.gz``), UTF-16 where it starts with UTF-16's byte-order mark (a spreadsheet's "Unicode
    text" save), else UTF-8 (a byte-order mark dropped), else Windows-1252 (a spreadsheet's plain "CSV" save on
    Windows writes ``°C`` so). NUL bytes that end the file are the space a logger preallocated and never wrote (a
    file on an SD card cut off by a power loss reads so): they are dropped and counted, the caller notes them. Raises
    UnicodeDecodeError for a file that is none of these or holds a NUL byte before its end, and ValueError naming a
    workbook (:data:`NOT_TEXT`)."""
    import gzip

    raw = p.read_bytes()
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError) as exc:
            raise ValueError(f"a gzip file that does not decompress ({exc})") from None
    what = next((w for magic, w in NOT_TEXT.items() if raw.startswith(magic)), None)
    if what:
        raise ValueError(f"not a text file but {what}")
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return raw.decode("utf-16"), 0
    text = raw.rstrip(b"\x00")
    nul = len(raw) - len(text)
    if b"\x00" in text:
        raise UnicodeDecodeError("utf-8", raw, raw.index(b"\x00"), raw.index(b"\x00") + 1, "a NUL byte: not text")
    try:
        return text.decode("utf-8-sig"), nul
    except UnicodeDecodeError:
        return text.decode("cp1252"), nul


def nul_note(n: int) -> str:
    """The note of ``n`` NUL bytes dropped from a file's end (:func:`read_text`), the same in both readers."""
    return (f"{n} NUL byte(s) at the end of the file (space a logger preallocated and never wrote, as a power loss "
            "leaves a file on an SD card), dropped")


def cut_line_note(line: int, fields: int, of: int) -> str:
    """The note of a last line cut off mid-write, dropped (both readers)."""
    return (f"the last line (line {line}) holds {fields} of the {of} fields: a record cut off mid-write (a logger "
            "stopped or lost power), perhaps within a number, so it is dropped whole")


def is_comment(cells: list[str]) -> bool:
    """Whether a line's fields are a comment: a first field starting with ``#`` that is not a spreadsheet's error
    value (``#N/A``: :data:`MISSING_MARKERS`)."""
    return bool(cells) and cells[0].startswith("#") and cells[0].lower() not in MISSING_MARKERS


def footer_lines(lines: list[str], dialect: CsvDialect) -> int:
    """How many lines at the end of a text hold no data: empty, only separators (a spreadsheet's empty formatted
    rows) or a comment (:func:`is_comment`)."""
    k = 0
    for line in reversed(lines[dialect.skip + 1:]):
        cells = dialect.split(line)
        if all(not c for c in cells) or is_comment(cells):
            k += 1
        else:
            break
    return k


#: a spreadsheet's first line that names the field separator (``sep=;``, ``"sep=,"``), followed by nothing but
#: separators (a sheet's empty cells)
_SEP_LINE = re.compile(r'^\s*"?sep=([,;\t|])"?[,;\t|]*\s*$', re.IGNORECASE)


def csv_dialect(lines: list[str]) -> CsvDialect:
    """The dialect of a CSV text from its first lines: comment (``#``) and empty lines before the header are skipped;
    the separator is a comma where the header has one, else a semicolon or a tab where it has one of those, else runs
    of spaces where it has any; with another separator than a comma the decimal mark is a comma where the data lines
    write numbers with a comma and none with a decimal point (points that group thousands, ``1.234,5``, are read as
    such: :func:`decimal_comma`). A spreadsheet's separator line before the header (``sep=;``, which Excel reads
    and writes: :data:`_SEP_LINE`) names the separator and is skipped. A text that fits none of these is read as
    commas (its columns then go missing, one line)."""
    skip = 0
    while skip < len(lines) and (not lines[skip].strip() or lines[skip].lstrip().startswith("#")):
        skip += 1
    named = _SEP_LINE.match(lines[skip]) if skip < len(lines) else None
    skip += bool(named)
    header = lines[skip] if skip < len(lines) else ""
    sep = named.group(1) if named else "," if "," in header else ";" if ";" in header else "\t" if "\t" in header \
        else " " if len(header.split()) > 1 else ","
    decimal = "."
    if sep != ",":
        decimal = decimal_mark([f for line in lines[skip + 1:skip + 51] for f in CsvDialect(skip, sep).split(line)])
    return CsvDialect(skip=skip, sep=sep, decimal=decimal)


def decimal_mark(fields: list[str]) -> str:
    """The decimal mark of a text's number ``fields``: ``,`` where some are written with a decimal comma and none
    with a decimal point (a point in a number grouped by thousands, 1.234,5 and 12.500, is not one), else ``.``."""
    comma = any(_DECIMAL_COMMA.match(f) or (_GROUPED.match(f) and "," in f) for f in fields)
    return "," if comma and not any(_DECIMAL_POINT.match(f) and not _GROUPED.match(f) for f in fields) else "."


def load_run(path: str | os.PathLike[str], valve: ValveParams | None = None) -> pd.DataFrame:
    """Read and validate a docs/reference.md, section 2 CSV file; returns a DataFrame (float columns for
    the reference (docs/reference.md) names, x_mm derived where absent, extra columns kept as read)."""
    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file")
    if p.is_dir():
        raise DataError(f"{p}: is a directory, not a CSV file")
    try:
        text, nul = read_text(p)
        lines = text.splitlines()
    except UnicodeDecodeError as exc:
        raise DataError(f"{p}: not a text file (neither UTF-8, UTF-16 with a byte-order mark nor Windows-1252: "
                        f"{exc.reason} at byte {exc.start})") from exc
    except ValueError as exc:  # a workbook, or a broken gzip file
        raise DataError(f"{p}: {exc}") from exc
    if lines and lines[0].startswith(HISTORIAN_MARK):
        raise DataError(f"{p}: a plant-historian export of a control loop (first word {HISTORIAN_MARK}), not a "
                        "measured valve run: diagnose it with thermovalve loop-diagnose")
    dialect = csv_dialect(lines[:64])
    body = lines[dialect.skip:len(lines) - footer_lines(lines, dialect)]
    # the data lines as the file numbers them (1-based): an empty line (or one of separators only, a spreadsheet's
    # emptied row) or a comment among the data (a logger's "# restarted") is left out, so every message names the
    # file's own line; so is a line that repeats the header (a logger that writes it again after a restart)
    row_lines, comments, headers, data = [], [], [], body[:1]
    header = dialect.split(body[0]) if body else []
    for j, line in enumerate(body[1:], start=dialect.header_line + 1):
        cells = dialect.split(line)
        if all(not c for c in cells):
            continue
        if is_comment(cells):
            comments.append(j)
            continue
        if cells == header:
            headers.append(j)
            continue
        row_lines.append(j)
        data.append(line)
    # a last line with fewer fields than the one before it was cut off mid-write (a logger stopped or lost power),
    # perhaps within a number, so none of its cells is taken
    fields = [len(dialect.cells(line)) for line in data[-2:]]
    cut = len(data) > 2 and fields[1] < fields[0]
    if cut:
        cut_line, cut_fields = row_lines.pop(), (fields[1], fields[0])
        data.pop()
    try:
        raw = pd.read_csv(io.StringIO("\n".join(data)), dtype=str, keep_default_na=False, skipinitialspace=True,
                          sep=dialect.pandas_sep, skip_blank_lines=False)
    except pd.errors.EmptyDataError as exc:
        raise DataError(f"{p}: the file is empty") from exc
    except pd.errors.ParserError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(f"{p}: not a readable CSV file ({first})") from exc
    _check_header(p, dialect, body[0] if body else "")
    if dialect.decimal != ".":
        raw = raw.apply(lambda col: col.map(decimal_comma))
    raw.attrs["header_line"] = dialect.header_line
    raw.attrs["row_lines"] = row_lines
    if comments:
        raw.attrs["comment_lines"] = comments
    if headers:
        raw.attrs["header_lines"] = headers
    if nul:
        raw.attrs["nul_padding"] = nul
    if cut:
        raw.attrs["last_line_cut"] = {"line": cut_line, "fields": cut_fields[0], "of": cut_fields[1]}
    return validate_run(raw, source=str(p), valve=valve)


def _check_header(p: Path, dialect: CsvDialect, line: str) -> None:
    """Refuse a header that names one of the format's columns twice: pandas renames the second copy (``T_tank_C.1``),
    so :func:`validate_run` would silently take the first. Extra columns are ignored (docs/reference.md, section 2),
    so two of them of one name (a logger's two ``comment`` columns, two empty names from trailing separators) are
    not refused. ``line``: the header's line."""
    header = [c.strip() for c in dialect.cells(line)]
    dup = sorted({c for c in header if c in (*REQUIRED, *OPTIONAL) and header.count(c) > 1})
    if dup:
        raise DataError(f"{p}: duplicate column(s) {dup} in the header")


def clock_time_hint(columns: dict[str, list[str]]) -> str:
    """Where a record has no ``time_s`` but a column of date-times (a logger's or historian's clock), the
    refusal's hint: the time is seconds from any origin in ``time_s`` (SPEC sections 2 and 10), so that column
    must be converted. ``columns``: each column's first cells, as text."""
    heads = {col: pd.Series([str(c).strip() for c in cells if c is not None and str(c).strip()][:5], dtype=str)
             for col, cells in columns.items()}
    dated = [col for col, head in heads.items() if not head.empty and head.str.contains(r"\d[-/.:]\d", regex=True).all()
             and not pd.to_numeric(head, errors="coerce").notna().all()  # numbers, not clock times
             and pd.to_datetime(head, errors="coerce", format="mixed").notna().all()]
    dates = [c for c in dated if not heads[c].str.contains(":").any()]
    clocks = [c for c in dated if heads[c].str.fullmatch(_CLOCK).all()]
    if dates and clocks:  # a logger's date and time of day in two columns
        return (f"; columns {dates[0]!r} and {clocks[0]!r} hold a date and a time of day: give the time as seconds in "
                f"a column time_s, e.g. t = pd.to_datetime({dates[0]} + ' ' + {clocks[0]}), (t - t[0]).total_seconds()")
    if dated:
        return (f"; column {dated[0]!r} holds date-times: give the time as seconds in a column time_s, "
                f"e.g. (t - t[0]).total_seconds()")
    return ""


#: a time of day alone (``08:00``, ``08:00:10``, ``08:00:10.5``)
_CLOCK = r"\d{1,2}:\d{2}(?::\d{2}(?:[.,]\d+)?)?"


#: a time column named with a unit other than seconds (``time_min``, ``t_h``, ``Time [ms]`` spelled ``time_ms``)
_TIME_NAME = re.compile(r"^(?:time|t|elapsed)[\s_.-]*(?P<u>ms|msec|millis|min|mins|minutes|h|hr|hrs|hours|d|days)$",
                        re.IGNORECASE)
#: each such unit's factor to seconds
_TIME_FACTORS = {"ms": 1e-3, "msec": 1e-3, "millis": 1e-3, "min": 60.0, "mins": 60.0, "minutes": 60.0, "h": 3600.0,
                 "hr": 3600.0, "hrs": 3600.0, "hours": 3600.0, "d": 86400.0, "days": 86400.0}
CONVERSIONS["time_s"] = dict(_TIME_FACTORS)


def time_name_hint(columns: list[str]) -> str:
    """Where a record has no ``time_s`` but a time column named in another unit (``time_min``, ``t_h``,
    ``time_ms``), the refusal's hint: the time is seconds in ``time_s`` (SPEC sections 2 and 10), and the factor.
    Else ''."""
    for col in columns:
        m = _TIME_NAME.match(str(col).strip())
        if m:
            do = scale_text(_TIME_FACTORS[m.group("u").lower()])
            return f"; the header has {col!r}, a time not in seconds: give it as time_s in seconds ({do})"
    return ""


#: finer time units a logger or a program writes (a Unix time in ms, or pandas' datetime64 in ns), and their factor
FINE_TIME_UNITS: tuple[tuple[str, float], ...] = (("milliseconds", 1e-3), ("microseconds", 1e-6), ("nanoseconds", 1e-9))


def fine_time_hint(t: np.ndarray) -> str:
    """Where times ``t`` beyond :data:`MAX_ABS_TIME_S` would be plausible seconds in a finer unit (a Unix time in
    milliseconds, 1.7e12; datetime64's nanoseconds, 1.7e18): every value within it and the median interval within
    :data:`DT_RANGE_S`, the refusal's hint naming the first such unit. Else ''."""
    t = np.asarray(t, dtype=float)
    t = t[np.isfinite(t)]
    if t.size < 2:
        return ""
    for unit, f in FINE_TIME_UNITS:
        dt = float(np.median(np.diff(t))) * f
        if np.all(np.abs(t) * f <= MAX_ABS_TIME_S) and DT_RANGE_S[0] <= dt <= DT_RANGE_S[1]:
            return f"; if time_s is in {unit} (a Unix time?), {scale_text(f)}"
    return ""


def time_order_hint(t: np.ndarray) -> str:
    """Where the times ``t`` do not increase, what the refusal adds where the cause is the rows' order: a
    newest-first export (every time below the one before), rows out of order whose times, sorted, are distinct, a
    time that starts again (two increasing parts, the second from at most the first's start), a time that goes back
    by an hour (a local clock at the end of summer time) or two parts whose times overlap (files joined). Which rows
    are meant is then clear, but the file's own order is not changed behind its back. Else ''."""
    t = np.asarray(t, dtype=float)
    t = t[np.isfinite(t)]
    if t.size < 3:
        return ""
    if np.all(np.diff(t) < 0):
        return "; the rows run newest first, as some historians export them: sort them by time_s, oldest first"
    if np.all(np.diff(np.sort(t)) > 0):
        return "; the rows are out of time order, with no time repeated: sort them by time_s"
    drops = np.flatnonzero(np.diff(t) <= 0)
    if drops.size == 1 and np.all(np.diff(t[drops[0] + 1:]) > 0):  # two increasing parts
        before, after = t[:drops[0] + 1], t[drops[0] + 1:]
        dt = float(np.median(np.diff(before))) if before.size > 1 else 0.0
        # back by an hour, unless the second part starts where the first did (a restart of an hour-long record)
        if dt > 0 and abs(before[-1] + dt - after[0] - 3600.0) <= 0.5 * dt and after[0] != before[0]:
            return ("; the time goes back by an hour there (times from a clock on local time, at the end of summer "
                    "time?): give the times in UTC, or add 3600 s to the times from there")
        if after[0] <= before[0]:
            return ("; the time starts again there (a logger's clock reset, or files joined whose times each start "
                    "at 0?): make it run on, adding the last time before it and one interval to the times from there")
        shared = int(np.isin(after, before).sum())
        if shared:
            return (f"; the rows from there repeat {shared} time(s) of the rows before them (two exports joined with "
                    "an overlap?): drop the repeated rows")
    return ""


def clock_in_time_s(cells: list[str], column: str = "time_s") -> str:
    """Where the first ``cells`` of time_s are date-times (a logger's clock written into it), the refusal's text,
    naming the ``column`` as the reader writes it; else ''. Both readers refuse with it."""
    if not cells or not clock_time_hint({"time_s": cells}):
        return ""
    return (f"column {column} holds date-times ({str(cells[0]).strip()!r}): give the time as seconds from any origin, "
            "e.g. (t - t[0]).total_seconds()")


def name_key(name: str) -> str:
    """A column's name as the name hints compare it: its letters and digits, in lower case (``T Tank-C`` is
    ``ttankc``)."""
    return "".join(ch for ch in name.lower() if ch.isalnum())


def near_name_hint(missing: str, columns: list[str], taken: tuple[str, ...] = ()) -> str:
    """Where a required column is missing and the header has a name close to it (another case, spacing or
    spelling: ``T_Tank_C``, ``t tank c``, ``T_tank``), the refusal's hint naming that column; names are exact (SPEC
    sections 2 and 10). ``taken``: the format's names, which are not offered."""
    free = [c for c in columns if c not in taken]
    same = [c for c in free if name_key(c) == name_key(missing)]
    close = same or difflib.get_close_matches(missing.lower(), [c.lower() for c in free], n=1, cutoff=0.75)
    if not close:
        return ""
    if same:  # the same letters: another case or spacing
        return f"; the header has {same[0]!r}: rename it {missing} (names are exact)"
    name = next(c for c in free if c.lower() == close[0])
    unit = f" in {UNITS[missing][0]}" if missing in UNITS else ""
    return f"; the header has {name!r}: if that is {missing}{unit}, rename it (names are exact)"


def rename_hint(missing: list[str], columns: list[str], taken: tuple[str, ...] = ()) -> str:
    """The refusal's hint for every one of the ``missing`` columns that the header has under a close name
    (:func:`near_name_hint`), in one clause where several have the same letters in another case or spacing (a header
    ``Time, SP, PV, OP`` is told all four renames at once, not one per attempt). Else ''."""
    renames: list[tuple[str, str]] = []
    parts: list[str] = []
    for m in missing:
        same = [c for c in columns if c not in taken and name_key(c) == name_key(m)
                and all(c != h for h, _ in renames)]
        if same:
            if not renames:
                parts.append("")  # the renames' clause goes where the first of them stands
            renames.append((same[0], m))
        else:
            parts.append(near_name_hint(m, columns, taken))
    if len(renames) == 1:
        parts[parts.index("")] = f"; the header has {renames[0][0]!r}: rename it {renames[0][1]} (names are exact)"
    elif renames:
        parts[parts.index("")] = (f"; the header has {', '.join(repr(h) for h, _ in renames)}: rename them "
                                  f"{', '.join(m for _, m in renames)} (names are exact)")
    return "".join(parts)


def other_format_hint(columns: list[str], reader: str) -> str:
    """Where the header given to the ``reader`` (``"valve"`` or ``"loop"``) is the other format's (a control loop's
    ``sp, pv, op`` given to the valve's reader, or a valve run's ``T_tank_C ... ps_bar`` to the loop's, and none of
    the reader's own), the refusal's hint naming the command that reads it. Else ''."""
    loop, valve = (all(c in columns for c in names) for names in (LOOP_COLUMNS[1:4], REQUIRED[1:]))
    own = any(c in columns for c in (REQUIRED[1:] if reader == "valve" else LOOP_COLUMNS[1:4]))
    if reader == "valve" and loop and not own:
        return ("; the header is a control loop's record (sp, pv, op: docs/reference.md, section 10): diagnose it with "
                "thermovalve loop-diagnose")
    if reader == "loop" and valve and not own:
        return ("; the header is a measured valve run's (docs/reference.md, section 2): identify it with thermovalve "
                "fit or thermovalve diagnose")
    return ""


def long_format_hint(missing: list[str], columns: Mapping[str, Iterable[object]]) -> str:
    """Where the missing columns are named in the cells of one column (a historian's long, or narrow, export: one
    row per channel and time, the channel in a ``tag`` column, as OSIsoft PI or a pandas ``melt`` writes it), the
    refusal's hint: give one column per channel. A cell ``FIC101.PV`` names ``pv``. ``columns``: each column's
    cells. Else ''."""
    wanted = {name_key(m): m for m in missing}
    for col, cells in columns.items():
        names = set()
        for cell in cells:
            text = str(cell).strip()
            names.add(text)
            if len(names) > 200:  # a column of values, not of channel names
                break
        else:
            named = {wanted[k] for n in names for k in (name_key(n), name_key(n.rsplit(".", 1)[-1])) if k in wanted}
            if len(named) >= 2:
                return (f"; column {col!r} names the channels ({', '.join(sorted(named))}) row by row, a long export: "
                        f"give one column per channel (pandas: df.pivot(index=<time>, columns={col!r}, "
                        f"values=<value>))")
    return ""


def validate_run(data: pd.DataFrame, source: str = "data", valve: ValveParams | None = None) -> pd.DataFrame:
    """Validate a run given as a DataFrame (strings or numbers); returns a validated copy."""
    valve = valve or ValveParams()
    raw = data.copy()
    raw.columns = [str(c).strip() for c in raw.columns]
    first = int(data.attrs.get("header_line", 1)) + 1  # the file's line of the first data row
    at = data.attrs.get("row_lines")
    row_lines: list[int] = list(at) if at is not None and len(at) == len(raw) else list(range(first, first + len(raw)))
    named = header_units(list(raw.columns), (*REQUIRED, *OPTIONAL))
    for col, (name, unit) in named.items():
        if unit_key(unit) not in UNITS[name][1]:
            raise DataError(f"{source}: column {col!r} gives {name} in {unit!r}: {convert_to(name, unit)}")
    if named:
        raw = raw.rename(columns={c: n for c, (n, _) in named.items()})
        raw.attrs["units_in_header"] = dict(named.values())
    dup = sorted({c for c in raw.columns if c in (*REQUIRED, *OPTIONAL) and list(raw.columns).count(c) > 1})
    if dup:
        raise DataError(f"{source}: duplicate column(s) {dup}")
    missing = [c for c in REQUIRED if c not in raw.columns]
    if missing:
        cols = list(raw.columns)
        special = {c: (time_name_hint(cols) or clock_time_hint(
                       {str(h): raw[h].dropna().astype(str).head(5).tolist() for h in cols})) if c == "time_s"
                   else unit_name_hint(c, cols) for c in missing}
        hint = other_format_hint(cols, "valve") or (long_format_hint(missing, {str(h): raw[h].tolist() for h in cols})
                                           if len(missing) > 1 else "")
        hint = hint or "".join(special.values()) + rename_hint([c for c in missing if not special[c]], cols,
                                                      (*REQUIRED, *OPTIONAL))
        which = f"column {missing[0]!r}" if len(missing) == 1 else f"columns {', '.join(map(repr, missing))}"
        raise DataError(f"{source}: missing {which} (required: {', '.join(REQUIRED)}){hint}")
    units = _units_row(raw, source, row_lines[0] if row_lines else first)
    if units:  # a second header line: the data begin a line later, and the rows are counted from there
        raw = raw.iloc[1:].reset_index(drop=True)
        raw.attrs["units_row"] = {"line": row_lines[0], "units": units}
        row_lines = row_lines[1:]

    def first_line(i: int) -> int:
        """The file's line of row ``i + 1`` (``i`` from 0)."""
        return row_lines[i] if 0 <= i < len(row_lines) else i + (row_lines[0] if row_lines else first)

    out = raw.copy()
    clock = clock_in_time_s(raw["time_s"].head(5).astype(str).tolist(), "'time_s'")
    if clock:
        raise DataError(f"{source}: {clock}")
    in_cells: dict[str, str] = {}
    for col in (*REQUIRED, *[c for c in OPTIONAL if c in raw.columns]):
        out[col] = values = _numeric(raw[col], col, source, allow_empty=col != "time_s", line=first_line)
        if values.attrs.get("unit_in_cells"):
            in_cells[col] = values.attrs["unit_in_cells"]
    if in_cells:
        out.attrs["units_in_cells"] = in_cells
    if "x_mm" in out.columns:  # before the ranges: an opening in % or a dp in Pa passes them on some rows only
        _check_stroke(out, valve, source)
        _check_opening_sign(out, valve, source)
        _check_dp_unit(out, valve, source)
    out = _zero_flow_noise(out)
    pump_off = _pump_off(out)
    if pump_off is not None:  # left out of the checks, then dropped with the empty rows' drop (below)
        out[_PUMP_OFF] = pump_off
        out.loc[pump_off, ["dp_mbar", "q_kgh"]] = np.nan
    for col, (lo, hi, lo_open, what) in RANGES.items():
        if col in out.columns:
            _check_range(out[col].to_numpy(dtype=float), col, lo, hi, lo_open, what, source, first_line)
    n = len(out)
    if n < MIN_ROWS:
        raise DataError(f"{source}: too short a record, {n} rows; at least {MIN_ROWS} are needed")
    t = out["time_s"].to_numpy()
    far = np.flatnonzero(np.abs(t) > MAX_ABS_TIME_S)
    if far.size:
        i = int(far[0])
        raise DataError(f"{source}: column time_s, row {i + 1} (line {first_line(i)}): {t[i]:.6g} s is not a plausible "
                        f"time (|time_s| <= {MAX_ABS_TIME_S:g} s){fine_time_hint(t)}")
    out = _drop_repeated_rows(out, [c for c in (*REQUIRED, *OPTIONAL) if c in out.columns])
    t = out["time_s"].to_numpy()
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        r = _file_row(out, i)
        raise DataError(f"{source}: time_s is not increasing at row {r} (line {first_line(r - 1)}) "
                        f"({t[i - 1]:.6g} then {t[i]:.6g}); times must be strictly increasing{time_order_hint(t)}")
    dt = np.diff(t)
    bad_interval = interval_problem(float(np.median(dt)))
    if bad_interval:
        raise DataError(f"{source}: column time_s: {bad_interval}")
    gap = np.flatnonzero((dt > MAX_GAP_S) & ~_spans_dropped(out))
    if gap.size:
        i = int(gap[0]) + 1
        r = _file_row(out, i)
        raise DataError(f"{source}: column time_s, row {r} (line {first_line(r - 1)}): a gap of {dt[i - 1]:.3g} s "
                        f"after the previous sample (at most {MAX_GAP_S:g} s)")
    if _PUMP_OFF in out.columns:
        out = _drop_rows(out, out.pop(_PUMP_OFF).to_numpy(dtype=bool), "rows_dropped_pump_off")
    out = _drop_empty_rows(_own_rates(out), source, first_line)
    n = len(out)
    T = out["T_tank_C"].to_numpy()
    if float(np.max(T) - np.min(T)) < MIN_T_RANGE_K:
        raise DataError(f"{source}: T_tank_C is constant (range {np.max(T) - np.min(T):.3g} K < "
                        f"{MIN_T_RANGE_K} K): a constant temperature identifies nothing")
    q = out["q_kgh"].to_numpy()
    if "x_mm" not in out.columns and not np.any(q > 0):
        raise DataError(f"{source}: column q_kgh is 0 in every row and there is no x_mm column: "
                        "the valve opening cannot be derived")
    vp = valve.to_array()
    derived = opening_from_flow(out["q_kgh"].to_numpy(), out["dp_mbar"].to_numpy(), vp)
    if "x_mm" in out.columns:
        x = out["x_mm"].to_numpy(dtype=float)
        gap = ~np.isfinite(x)
        if gap.any():
            out["x_mm"] = np.where(gap, derived, x)
        # a run validated before keeps its count: its derived cells are filled now
        out.attrs["x_mm_derived_rows"] = int(gap.sum()) or int(data.attrs.get("x_mm_derived_rows", 0))
        offset = zero_offset(out["x_mm"].to_numpy(dtype=float), q, out["dp_mbar"].to_numpy(dtype=float),
                             float(valve.stroke))
        if offset is not None:  # the seat is 0 mm: the transducer's zero is taken out
            out["x_mm"] = out["x_mm"].to_numpy(dtype=float) - offset["offset_mm"]
            out.attrs["x_mm_zero_offset"] = offset
    else:
        out["x_mm"] = derived
        out.attrs["x_mm_derived_rows"] = n
        cut = flow_cut_off(q)
        if cut is not None:  # a flow read as 0 says only that the opening lies below the one the cut-off passes
            out.attrs["q_cut_off"] = {"rows": int(np.sum(q == 0.0)), "cut_off_kgh": cut, "x_below_mm": float(
                np.median(opening_from_flow(np.full(n, cut), out["dp_mbar"].to_numpy(), vp)))}
        # an opening measured but named in another unit (x_um, x_%) is an extra column, and so not read: a note says so
        other = unit_name_hint("x_mm", [str(c) for c in raw.columns])
        if other:
            out.attrs["x_mm_other_unit"] = other.removeprefix("; ")
    out.attrs["source"] = source
    return out.reset_index(drop=True)


def zero_offset(x: np.ndarray, q: np.ndarray, dp: np.ndarray, stroke: float) -> dict[str, float] | None:
    """A measured opening's zero offset, where the record shows one: on the rows whose flow is about 0 (at most
    :data:`SEAT_FLOW_SHARE` of the high flow, its 99th percentile) under at least half the record's median dp (so the
    valve is on its seat, which the model puts at 0 mm, and not open under a pump turned down), at least
    :data:`SEAT_MIN_ROWS` rows and 2 % of them, the opening rests at a value off 0 by more than
    :data:`ZERO_OFFSET_NOISE` times its noise and 1 % of the stroke, and by at most :data:`ZERO_OFFSET_MAX_SHARE` of
    the stroke (a transducer's zero, not another scale), and scatters about it within 3 times its noise (not a valve
    lifting under a meter's low-flow cut-off). The offset, its rows and the noise; else None. :func:`validate_run`
    subtracts it, with a note."""
    ok = np.isfinite(x) & np.isfinite(q) & np.isfinite(dp)
    if ok.sum() < SEAT_MIN_ROWS:
        return None
    xs, qs, dps = x[ok], q[ok], dp[ok]
    seat = (qs <= SEAT_FLOW_SHARE * float(np.percentile(qs, 99))) & (dps >= 0.5 * float(np.median(dps)))
    if seat.sum() < max(SEAT_MIN_ROWS, 0.02 * xs.size):
        return None
    noise = max(float(median_abs_deviation(np.diff(xs), scale="normal")) / np.sqrt(2.0), 1e-4)
    c = float(np.median(xs[seat]))
    spread = float(median_abs_deviation(xs[seat], scale="normal"))
    if not max(ZERO_OFFSET_NOISE * noise, 0.01 * stroke) < abs(c) <= ZERO_OFFSET_MAX_SHARE * stroke \
            or spread > 3.0 * noise:
        return None
    return {"offset_mm": c, "rows": int(seat.sum()), "noise_mm": noise}


def _zero_flow_noise(out: pd.DataFrame) -> pd.DataFrame:
    """``out`` with the flows below 0 read as 0 where every one lies within the meter's noise about 0, on a shut
    valve: no lower than :data:`ZERO_FLOW_NOISE_SHARE` times the record's high flow (its 99th percentile), and so is
    the flow of the row before or after it (the valve shut on at least one side; a negative flow between two open rows
    is a glitch, not a shut valve's noise). ``attrs["q_zero_noise"]`` then gives how many, the lowest and the high
    flow (a run read before keeps its own, which its attrs carry). Else ``out`` as it is, for the range check to
    refuse."""
    q = out["q_kgh"].to_numpy(dtype=float)
    below = np.isfinite(q) & (q < 0.0)
    high = float(np.nanpercentile(q, 99)) if np.isfinite(q).any() else float("nan")
    band = ZERO_FLOW_NOISE_SHARE * high
    near = ~(np.abs(q) > band)  # NaN (a missing sample) counts as near
    i = np.flatnonzero(below)
    shut = bool(np.all(near[np.maximum(i - 1, 0)] | near[np.minimum(i + 1, q.size - 1)]))
    if not below.any() or not high > 0.0 or float(q[below].min()) < -band or not shut:
        return out
    out["q_kgh"] = np.where(below, 0.0, q)
    out.attrs["q_zero_noise"] = {"rows": int(below.sum()), "lowest_kgh": float(q[below].min()), "high_kgh": high}
    return out


_PUMP_OFF = "\x00pump_off"  # a row marker no header can name


def _pump_off(out: pd.DataFrame) -> np.ndarray | None:
    """The rows of stretches in which the circulation pump was off (:data:`PUMP_OFF_DP_SHARE`), or None. Their
    threshold, the record's median dp, goes to ``attrs["pump_off"]`` with the count."""
    dp = out["dp_mbar"].to_numpy(dtype=float)
    q = out["q_kgh"].to_numpy(dtype=float)
    on = np.isfinite(dp) & (dp > 0.0)
    if not on.any() or not np.isfinite(q).any():
        return None
    med = float(np.median(dp[on]))
    band = PUMP_OFF_DP_SHARE * med
    with np.errstate(invalid="ignore"):
        off = (np.abs(dp) <= band) & (np.abs(q) <= ZERO_FLOW_NOISE_SHARE * float(np.nanpercentile(q, 99)))
    if not off.any():
        return None
    # stretches of at least PUMP_OFF_MIN_ROWS rows
    edges = np.flatnonzero(np.diff(np.concatenate([[0], off.astype(np.int8), [0]])))
    keep = np.zeros(off.size, dtype=bool)
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if b - a >= PUMP_OFF_MIN_ROWS:
            keep[a:b] = True
    if not keep.any():
        return None
    out.attrs["pump_off"] = {"rows": int(keep.sum()), "stretches": int(np.sum(np.diff(keep.astype(np.int8)) == 1)
                                                                       + keep[0]),
                             "dp_at_most_mbar": band, "median_dp_mbar": med}
    return keep


def flow_cut_off(q: np.ndarray) -> float | None:
    """The low-flow cut-off (kg/h) of the meter that recorded the flows ``q``, its smallest flow above 0, where the
    record shows one (:data:`CUT_OFF_MIN_FLOW_SHARE`); else None."""
    q = np.asarray(q, dtype=float)
    q = q[np.isfinite(q)]
    zero, pos = q == 0.0, q > 0.0
    n0 = int(zero.sum())
    if n0 < max(CUT_OFF_MIN_ROWS, CUT_OFF_MIN_SHARE * q.size) or not pos.any():
        return None
    low, high = float(q[pos].min()), float(np.percentile(q, 99))
    return low if high > 0.0 and low >= CUT_OFF_MIN_FLOW_SHARE * high else None


def censored_opening(run: pd.DataFrame) -> np.ndarray | None:
    """The rows of a validated run whose opening, derived from a flow read as 0 under a meter's low-flow cut-off
    (:func:`flow_cut_off`; the note ``q_cut_off``), is only known to lie below the cut-off's opening; None where there
    are none. The EKF likelihood takes their opening as missing
    (:func:`valve_env.valveid.valve_model.prepare_inputs`)."""
    cut = run.attrs.get("q_cut_off") or any(nt.get("what") == "q_cut_off" for nt in run.attrs.get("preprocessing", ()))
    if not cut or "q_kgh" not in run.columns:
        return None
    rows = run["q_kgh"].to_numpy(dtype=float) == 0.0
    return rows if rows.any() else None


def _check_stroke(out: pd.DataFrame, valve: ValveParams, source: str) -> None:
    """Refuse an opening that reaches beyond the valve's stroke (a tenth of the samples or more above
    :data:`STROKE_MARGIN` strokes), naming the unit that would bring it within the stroke where one does: a position
    transmitter's % of the stroke, or um. The range check (:data:`RANGES`, up to 50 mm) holds for any valve; this one
    for the valve being identified, whose force balance holds only between seat and stop."""
    x = out["x_mm"].to_numpy(dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 20:
        return
    top = float(np.percentile(x, 99.0))
    reach = STROKE_MARGIN * valve.stroke
    if np.mean(x > reach) < 0.1:  # a few samples beyond: spikes or a logger's sentinel, which the ranges name by row
        return
    hint = next((f"; if x_mm is in {unit}, multiply by {a:g}" for unit, a in
                 (("% of the stroke", valve.stroke / 100.0), ("um", 1e-3)) if 0.1 * valve.stroke <= a * top <= reach),
                "")
    raise DataError(f"{source}: column x_mm reaches {top:.4g} mm (its 99th percentile), beyond the valve's "
                    f"{valve.stroke:g} mm stroke (the calibrated valve, docs/reference.md, section 1){hint}")


def _flowing(run: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """x_mm, q_kgh and dp_mbar as floats, and the rows with a flow: all three finite, q and dp positive."""
    x, q, dp = (run[c].to_numpy(dtype=float) for c in ("x_mm", "q_kgh", "dp_mbar"))
    with np.errstate(invalid="ignore"):
        return x, q, dp, np.isfinite(x) & np.isfinite(q) & np.isfinite(dp) & (q > 0) & (dp > 0)


def _check_opening_sign(out: pd.DataFrame, valve: ValveParams, source: str) -> None:
    """Refuse an opening that falls as the flow rises: the rank correlation of x_mm with the flow's Kv, q / sqrt(dp)
    (docs/reference.md, section 1), below :data:`OPENING_SIGN_CORR` on the rows with a flow. A position transmitter
    mounted the other way, or a closing travel logged as the opening, gives it; the force balance would read every
    move backwards."""
    x, q, dp, rows = _flowing(out)
    if int(rows.sum()) < 20:
        return
    rho = pd.Series(x[rows]).corr(pd.Series(q[rows] / np.sqrt(dp[rows])), method="spearman")
    if np.isfinite(rho) and rho < OPENING_SIGN_CORR:
        # an opening at or below 0 on most rows that carry a flow is one measured with the other sign, not a travel
        do = ("if x_mm is the opening measured with the other sign (at or below 0 on "
              f"{float(np.mean(x[rows] <= 0.0)):.0%} of these rows), negate it"
              if np.median(x[rows]) < 0.0 else
              f"if x_mm is the closing travel, give the opening ({valve.stroke:g} mm - x_mm)")
        raise DataError(f"{source}: column x_mm falls as the flow rises (rank correlation {rho:.2f} between x_mm and "
                        f"q_kgh / sqrt(dp_mbar) over {int(rows.sum())} rows): {do}")


def flow_ratio(run: pd.DataFrame, valve: ValveParams | None = None) -> tuple[float, int, float]:
    """The median of q_kgh / q(x_mm, dp_mbar), the flow through the valve characteristic (docs/reference.md, section 1),
    over the rows where the valve is open (x_mm above a tenth of the stroke, q > 0, dp > 0): about 1 for the valve's own
    record. Returns (ratio, rows, median dp over them); (nan, 0, nan) without such rows."""
    v = valve or ValveParams()
    x, q, dp, rows = _flowing(run)
    with np.errstate(invalid="ignore"):
        rows &= x > 0.1 * v.stroke
    n = int(rows.sum())
    if n == 0:
        return float("nan"), 0, float("nan")
    return float(np.median(q[rows] / flow_kgh(x[rows], dp[rows], v.to_array()))), n, float(np.median(dp[rows]))


def _check_dp_unit(out: pd.DataFrame, valve: ValveParams, source: str) -> None:
    """Refuse a dp_mbar in another unit (:data:`DP_UNITS`) where the measured opening and flow show it, and note a
    q_kgh in another (:data:`FLOW_UNITS`).

    With x_mm measured, q_kgh, x_mm and dp_mbar are redundant through the valve characteristic (docs/reference.md,
    section 1: q = 31.62 Kv(x) sqrt(dp)). On the rows where the valve is open (x above a tenth of the stroke, q > 0),
    the median of q / q(x, dp) is about 1 for the valve's own data. Where it is off by more than :data:`FLOW_OFF`
    and a unit of :data:`DP_UNITS` brings both it and the median dp to plausible values (:data:`FLOW_EXPLAINED`,
    :data:`DP_PLAUSIBLE`), the record is refused in one line naming the unit: a dp 100 times too large moves the
    force balance's pressure terms, and the diagnosis would name an effect for it. Other mismatches pass: the
    opening is measured, and the characteristic is used only where it is not."""
    ratio, n, dp_med = flow_ratio(out, valve)
    if n < 20 or abs(np.log(ratio)) <= np.log(FLOW_OFF):
        return
    dp_cal = valve.dp_k_sp * 1.0e4  # MPa -> mbar

    def plausible(d: float) -> bool:
        return abs(np.log(d / dp_cal)) <= np.log(DP_PLAUSIBLE)

    if dp_cal > 0 and not plausible(dp_med):
        for unit, do, a in DP_UNITS:
            if abs(np.log(ratio / np.sqrt(a))) <= np.log(FLOW_EXPLAINED) and plausible(a * dp_med):
                raise DataError(f"{source}: column dp_mbar reads as {unit}: the flow q_kgh is {ratio:.3g} times what "
                                f"x_mm and dp_mbar give through the valve characteristic (median over {n} rows "
                                f"with the valve open), and the median dp {dp_med:.5g} would be {a * dp_med:.3g} mbar "
                                f"against the valve's calibration {dp_cal:.4g} mbar; {do}")
    # a flow in another unit under q_kgh (kg/s, l/min): with x_mm measured the flow is not read, but where x_mm is
    # empty the opening derived from it would be wrong; a warning note (attrs["q_other_unit"]) says so
    for unit, a in FLOW_UNITS:
        if abs(np.log(ratio * a)) <= np.log(FLOW_EXPLAINED):
            out.attrs["q_other_unit"] = {"unit": unit, "factor": a, "ratio": float(ratio), "open_rows": int(n)}
            return


def _units_row(raw: pd.DataFrame, source: str, first: int) -> dict[str, str]:
    """The units of a units row under the header, by column, where the first data row is one: text, not numbers, in
    every column of the format it fills (at least two of them), one of them a unit. {} where it is not. Raises
    :class:`DataError` naming the first column whose unit is not the format's (:data:`UNITS`), with what to do."""
    if len(raw) < 2:
        return {}
    filled = text_cells({c: str(raw[c].iloc[0]) for c in (*REQUIRED, *OPTIONAL) if c in raw.columns})
    if not filled:
        return {}
    if not any(unit_key(v) in ways for v in filled.values() for _, ways in UNITS.values()):
        return {}  # text that names no unit at all: left for the numeric check to refuse as it is
    for c, v in filled.items():
        if unit_key(v) not in UNITS[c][1]:
            raise DataError(f"{source}: line {first} is a units row, and column {c} is given in {v!r}: "
                            f"{convert_to(c, v)}")
    return filled


def text_cells(cells: dict[str, str]) -> dict[str, str]:
    """A row's cells by column, stripped, where the row may be a units row: text, not numbers, in at least two of
    its columns (cells empty or a missing marker's word left out); else {}. Both readers' units rows start here."""
    filled = {c: v.strip() for c, v in cells.items() if v.strip().lower() not in MISSING_MARKERS}
    return filled if len(filled) >= 2 and not any(is_number(v) for v in filled.values()) else {}


def is_number(cell: str) -> bool:
    """Whether a cell reads as a number, with a decimal point or comma."""
    try:
        float(fortran_exponent(cell.strip()).replace(",", "."))
    except ValueError:
        return False
    return True


def short_list(numbers: list[int], most: int = 10) -> str:
    """``3, 9, 12, ...``: the first ``most`` row or line numbers of a note, an ellipsis where there are more."""
    return ", ".join(map(str, numbers[:most])) + (", ..." if len(numbers) > most else "")


def _default_line(i: int) -> int:
    """The file's line of row ``i + 1`` (``i`` from 0) of a file with a one-line header and nothing else."""
    return i + 2


def _file_row(out: pd.DataFrame, i: int) -> int:
    """The file's row number (1 = the first data row) of the run's ``i``-th row, where rows were dropped."""
    rows = out.attrs.get("file_rows")
    return int(rows[i]) if rows else i + 1


def _drop_rows(out: pd.DataFrame, drop: np.ndarray, key: str) -> pd.DataFrame:
    """The run without the rows of mask ``drop``, their file numbers in ``attrs[key]`` and each kept row's in
    ``attrs["file_rows"]`` (1 = the first data row, through any rows dropped before), so that the pre-processing
    names rows as they are in the file."""
    rows = out.attrs.get("file_rows") or list(range(1, len(out) + 1))
    kept = out.loc[~drop].reset_index(drop=True)
    kept.attrs = {**out.attrs, key: [int(rows[j]) for j in np.flatnonzero(drop)],
                  "file_rows": [int(rows[j]) for j in np.flatnonzero(~drop)]}
    return kept


def _spans_dropped(out: pd.DataFrame) -> np.ndarray:
    """For each pair of consecutive rows of a run read before, whether it spans rows that reading dropped with the
    pump off or an empty cell: such a gap is the file's rows, not its time column's (checked on the first read)."""
    a = out.attrs
    rows = a.get("file_rows")
    dropped = np.sort(np.asarray([*a.get("rows_dropped_pump_off", ()), *a.get("rows_dropped_empty", ())], dtype=float))
    if rows is None or len(rows) != len(out) or not dropped.size:
        return np.zeros(max(len(out) - 1, 0), dtype=bool)
    r = np.asarray(rows, dtype=float)
    return np.searchsorted(dropped, r[1:]) > np.searchsorted(dropped, r[:-1], side="right")


def _drop_repeated_rows(out: pd.DataFrame, columns: list[str]) -> pd.DataFrame:
    """The run without the rows that repeat the row before them in every column it reads, time included: a
    logger or an export that wrote one sample twice, named in ``attrs["rows_repeated"]``. A time repeated with
    other values is left for the time check to refuse: which of the two is the sample is not known."""
    v = out[columns].to_numpy(dtype=float)
    same = np.zeros(len(out), dtype=bool)
    same[1:] = np.all((v[1:] == v[:-1]) | (np.isnan(v[1:]) & np.isnan(v[:-1])), axis=1)
    return _drop_rows(out, same, "rows_repeated") if same.any() else out


def _drop_empty_rows(out: pd.DataFrame, source: str, line: Callable[[int], int] = _default_line) -> pd.DataFrame:
    """The run without its rows that hold an empty cell in a measured channel (at most
    :data:`MAX_EMPTY_FRACTION` of them, else one line naming the first), named in ``attrs["rows_dropped_empty"]``."""
    empty = np.zeros(len(out), dtype=bool)
    for col in MEASURED:
        empty |= ~np.isfinite(out[col].to_numpy(dtype=float))
    if not empty.any():
        return out
    k, n = int(empty.sum()), len(out)
    i = int(np.flatnonzero(empty)[0])
    col = next(c for c in MEASURED if not np.isfinite(float(out[c].iloc[i])))
    if k > MAX_EMPTY_FRACTION * n:
        r = _file_row(out, i)
        raise DataError(f"{source}: {k} of {n} rows ({k / n:.0%}) have an empty cell in a measured column (the first: "
                        f"{col!r} at row {r}, line {line(r - 1)}); at most {MAX_EMPTY_FRACTION:.0%} of the rows may")
    return _drop_rows(out, empty, "rows_dropped_empty")


@dataclass(frozen=True)
class OwnRates:
    """Channels logged at their own rates on the union of their times, read on common rows (:func:`own_rates`)."""

    #: the rows read (a mask of the record's rows)
    rows: np.ndarray
    #: each channel's values on those rows: as logged, interpolated or held
    values: dict[str, np.ndarray]
    #: the channel whose rows are read (None: every row), and the median spacing of its values, rows
    base: str | None
    every_rows: float
    #: the channels interpolated linearly in time on those rows, and those held from each value to the next
    interpolated: list[str]
    held: list[str]


#: a channel stored on change has no change much smaller than its typical one (its dead band): the 5 % quantile of the
#: changes from one value to the next at least this share of their median (0.52-0.71 on temperatures stored with a
#: 0.02-0.1 K dead band; 0.05-0.12 on noisy or smooth ones logged slower or with cells missing at random)
ON_CHANGE_SMALLEST_SHARE = 0.3
#: ... or its values lie at least this many rows apart (median): a value held for long (a thermostat's, a set value)
ON_CHANGE_SPACING_ROWS = 10.0
#: a logger's own slower rate shows in this many spacings between values or more (fewer values than the reader's
#: shortest record could not be read on their own rows anyway)
ON_CHANGE_RATE_VALUES = 10


def stored_on_change(y: np.ndarray) -> bool:
    """Whether a channel ``y`` (NaN on the rows where it has no value) is stored on change: a historian writes a value
    only where the channel moved by more than its dead band, and the channel held that value until the next. It has
    a value on at most two rows, or its values are not most of them one and the same number of rows apart (a logger's
    own slower rate is, where there are :data:`ON_CHANGE_RATE_VALUES` spacings to tell), no two successive values are
    alike, and either no change is much smaller than the typical one
    (:data:`ON_CHANGE_SMALLEST_SHARE`) or the values lie far apart (:data:`ON_CHANGE_SPACING_ROWS`)."""
    rows = np.flatnonzero(~np.isnan(y))
    if rows.size < 3:
        return rows.size > 0
    gaps = np.diff(rows)
    counts = np.bincount(gaps)
    if gaps.size >= ON_CHANGE_RATE_VALUES and counts.argmax() >= 2 and counts.max() >= 0.5 * gaps.size:
        return False
    change = np.abs(np.diff(y[rows]))
    if not np.all(change > 0):
        return False
    return bool(np.quantile(change, 0.05) >= ON_CHANGE_SMALLEST_SHARE * np.median(change)
                or np.median(gaps) >= ON_CHANGE_SPACING_ROWS)


def own_rates(t: np.ndarray, cols: Mapping[str, np.ndarray], max_empty: float, bases: Iterable[str] | None = None,
              held: Iterable[str] = ()) -> OwnRates | None:
    """A record whose logger or historian writes each channel at its own rate on the union of their times (each
    channel's value only where it has a sample, empty, NaN, elsewhere: tags scanned at other rates, or stored on
    change), read on common rows; None where no channel is logged so, or where time ``t`` does not increase.

    A channel is logged so where it is empty on more than ``max_empty`` of the rows (fewer are missing samples, for
    the reader's own rule) and has a value. A ``held`` channel (a set point, a mode: changed in steps), or one stored
    on change (:func:`stored_on_change`), keeps each value until the next, its first back to the start. Any other is
    read so where its values interleave with the
    empty rows (their median spacing two rows or more: a slower rate; a stretch of empty rows is an outage, and stays
    empty). The record is read on the rows of the slowest of those among ``bases`` (default: any; the fewest values),
    or on every row where there is none; each other interleaved channel without a value on some of those rows is
    interpolated linearly in time there between its own values (empty outside their span). Used by both readers: a
    valve run (``data_io``) and a loop record (``loops.io``)."""
    t = np.asarray(t, dtype=float)
    n = t.size
    if n < 3 or not np.all(np.diff(t) > 0):
        return None
    held = tuple(held)
    have = {c: ~np.isnan(np.asarray(v, dtype=float)) for c, v in cols.items()}
    sparse = [c for c, m in have.items() if (~m).sum() > max_empty * n and m.any()]

    def spacing(c: str) -> float:
        gaps = np.diff(np.flatnonzero(have[c]))
        return float(np.median(gaps)) if gaps.size else 0.0

    steps = [c for c in sparse if c in held or stored_on_change(np.asarray(cols[c], dtype=float))]
    own = [c for c in sparse if c not in steps and spacing(c) >= 2.0]
    if not (own or steps):
        return None
    values = {c: np.asarray(v, dtype=float) for c, v in cols.items()}
    for c in steps:
        last = np.maximum.accumulate(np.where(have[c], np.arange(n), -1))
        values[c] = values[c][np.where(last < 0, int(np.flatnonzero(have[c])[0]), last)]
    slow = [c for c in own if bases is None or c in tuple(bases)]
    base = min(slow, key=lambda c: int(have[c].sum())) if slow else None
    rows = have[base] if base is not None else np.ones(n, dtype=bool)
    values = {c: v[rows] for c, v in values.items()}
    interpolated = []
    for c in own:
        m, at = have[c], t[rows]
        if c == base or m[rows].all():
            continue
        values[c] = np.where((at >= t[m][0]) & (at <= t[m][-1]), np.interp(at, t[m], cols[c][m]), np.nan)
        interpolated.append(c)
    return OwnRates(rows, values, base, spacing(base) if base is not None else 1.0, interpolated, steps)


def _own_rates(out: pd.DataFrame) -> pd.DataFrame:
    """The run of a logger that writes its measured channels at their own rates on the union of their times, read on
    the rows of the slowest (:func:`own_rates`), a channel stored on change held from each value to the next; the run
    as it is where no channel is logged so. The rows without the slowest's value are dropped (named in
    ``attrs["rows_dropped_own_rates"]``), and ``attrs["own_rates"]`` says which channel gave the rows (None: every
    row), which were interpolated and which held, with their values' count (the note ``own_rates``). x_mm is not
    read so: its empty cells are derived from the flow, as in any run."""
    read = own_rates(out["time_s"].to_numpy(dtype=float), {c: out[c].to_numpy(dtype=float) for c in MEASURED},
                     MAX_EMPTY_FRACTION)
    if read is None:
        return out
    out = out.copy()
    held = {c: int(np.sum(np.isfinite(out[c].to_numpy(dtype=float)))) for c in read.held}
    for c in (*read.interpolated, *read.held):
        v = out[c].to_numpy(dtype=float, copy=True)
        v[read.rows] = read.values[c]
        out[c] = v
    out.attrs["own_rates"] = {"channel": read.base, "every_rows": read.every_rows, "rows": int(read.rows.sum()),
                              "of": len(out), "interpolated": read.interpolated, "held": held}
    return _drop_rows(out, ~read.rows, "rows_dropped_own_rates")


def _check_range(v: np.ndarray, col: str, lo: float, hi: float, lo_open: bool, what: str, source: str,
                 line: Callable[[int], int] = _default_line) -> None:
    known = np.isfinite(v)  # empty cells: an opening derived from the flow, a measured channel's row dropped
    with np.errstate(invalid="ignore"):
        below = v <= lo if lo_open else v < lo
        bad = np.flatnonzero(known & (below | (v > hi)))
    if bad.size:
        i = int(bad[0])
        bound = f"{'>' if lo_open else '>='} {lo:g} and <= {hi:g}"
        rows = ", ".join(str(int(j) + 1) for j in bad[1:6]) + (", ..." if bad.size > 6 else "")
        more = f"; {bad.size - 1} more row(s): {rows}" if bad.size > 1 else ""
        x = v[known]

        def fits(o: OtherUnit) -> bool:
            y = o.scale * x + o.offset
            return (bad.size > o.share * x.size and bool(np.all((y > lo) & (y <= hi)))
                    and (not o.integers or bool(np.all(x == np.round(x)))))

        unit = next((f"; every value reads as {o.unit}: {o.do}" for o in OTHER_UNITS.get(col, ()) if fits(o)), "")
        raise DataError(f"{source}: column {col}, row {i + 1} (line {line(i)}): {v[i]:.6g} is out of range "
                        f"(must be {bound}: {what}){more}{unit}")


def _unit_in_cells(s: pd.Series, name: str) -> tuple[pd.Series, str] | None:
    """Where every cell of ``s`` (text, the empty ones left out) that is not a number is a number followed by one and
    the same unit of the format's column ``name`` (:data:`UNITS`: ``243.9 kg/h``, ``52.3 °C``, as a formatted
    spreadsheet cell writes it), the cells' numbers and that unit as written; else None."""
    if name not in UNITS:
        return None
    parts = s.str.extract(_NUMBER_THEN_TEXT)
    written = parts[1].dropna().str.strip()
    if written.empty or written.map(unit_key).nunique() != 1 or unit_key(written.iloc[0]) not in UNITS[name][1]:
        return None
    return parts[0].where(parts[1].notna(), s), str(written.iloc[0])


def _numeric(col: pd.Series, name: str, source: str, allow_empty: bool, line: Callable[[int], int] = _default_line
             ) -> pd.Series:
    """The column's numbers (empty cells NaN where ``allow_empty``); cells that carry the format's own unit after
    their number are read as the number, the unit in the result's ``attrs["unit_in_cells"]``."""
    unit = ""
    if not pd.api.types.is_numeric_dtype(col):
        s = col.astype(str).str.strip()
        empty = s.str.lower().isin(MISSING_MARKERS)
        num = pd.to_numeric(s.where(~empty, None), errors="coerce")
        nonnum = num.isna() & ~empty
        if nonnum.any():  # a Fortran program's exponent: 1.25D+01
            num[nonnum] = pd.to_numeric(s[nonnum].map(fortran_exponent), errors="coerce")
            nonnum = num.isna() & ~empty
        own = _unit_in_cells(s.where(nonnum), name) if nonnum.any() else None
        if own is not None:
            num = pd.to_numeric(own[0].where(~empty, None), errors="coerce")
            nonnum, unit = num.isna() & ~empty, own[1]
        if nonnum.any():
            i = int(np.flatnonzero(nonnum.to_numpy())[0])
            raise DataError(f"{source}: non-numeric value {col.iloc[i]!r} in column {name!r} "
                            f"at row {i + 1} (line {line(i)}){decimal_mark_hint(str(col.iloc[i]))}")
        bad = empty.to_numpy()
    else:
        num = pd.to_numeric(col, errors="coerce")
        bad = ~np.isfinite(num.to_numpy(dtype=float))
    vals = num.to_numpy(dtype=float)
    inf = np.isinf(vals)
    if inf.any():
        i = int(np.flatnonzero(inf)[0])
        raise DataError(f"{source}: infinite value in column {name!r} at row {i + 1} (line {line(i)})")
    if bad.any() and not allow_empty:
        i = int(np.flatnonzero(bad)[0])
        raise DataError(f"{source}: NaN (empty or missing value) in column {name!r} at row {i + 1} (line {line(i)})")
    out = pd.Series(vals, index=col.index, name=name)
    if unit:
        out.attrs["unit_in_cells"] = unit
    return out


__all__ = ["LOOP_COLUMNS", "HISTORIAN_MARK", "other_format_hint", "DataError", "CsvDialect", "csv_dialect",
           "read_text", "footer_lines", "NOT_TEXT", "load_run", "validate_run", "REQUIRED", "OPTIONAL", "MIN_ROWS",
           "MIN_T_RANGE_K", "RANGES", "OTHER_UNITS", "OtherUnit", "ABSOLUTE_BAR", "convert_to", "DP_UNITS",
           "FLOW_OFF", "FLOW_EXPLAINED", "DP_PLAUSIBLE", "STROKE_MARGIN", "OPENING_SIGN_CORR", "DT_RANGE_S",
           "MAX_GAP_S", "MAX_ABS_TIME_S", "ZERO_FLOW_NOISE_SHARE", "MEASURED", "MAX_EMPTY_FRACTION",
           "MISSING_MARKERS", "HISTORIAN_STATES", "decimal_mark", "SPREADSHEET_ERRORS", "UNITS", "clock_time_hint",
           "clock_in_time_s", "name_key", "near_name_hint", "short_list", "unit_name_hint", "CONVERSIONS",
           "scale_text", "unit_key", "header_units", "time_unit_hint", "interval_problem", "flow_unit_hint",
           "FLOW_UNITS", "flow_ratio", "opening_derived", "flow_cut_off", "censored_opening", "PUMP_OFF_DP_SHARE",
           "CUT_OFF_MIN_FLOW_SHARE", "SHORT_SPAN_S", "TANK_HOT_C", "temperature_unit_hint", "text_cells", "is_number",
           "decimal_comma", "decimal_mark_hint", "fortran_exponent", "DASHES", "time_name_hint", "time_order_hint",
           "zero_offset", "SEAT_FLOW_SHARE", "SEAT_MIN_ROWS", "ZERO_OFFSET_NOISE", "ZERO_OFFSET_MAX_SHARE"]
