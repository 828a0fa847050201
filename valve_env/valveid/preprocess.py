"""Pre-processing of a validated measured run: the conventions of measured data (docs/reference.md, section 2).

    df, notes = preprocess_run(load_run("run.csv"))

A run that :func:`valve_env.data_io.validate_run` accepts may still be recorded the way real
channels are: quantised, held constant or stored on change, without noise, with jittered or
missing samples, one long gap, or a few isolated spikes. Both identification paths (``fit`` and
``diagnose``) pass the validated run through :func:`preprocess_run` before any likelihood, so that
each convention is handled once, here, and reported:

* **temperature channels** (``T_tank_C``, ``T_med_C``): the noise level the smoothers and the
  bootstrap use comes from :func:`~valve_env.valveid.temperature.channel_noise` (never 0 or NaN:
  the quantisation sd q / sqrt(12) of a quantised or held channel, a resolution floor for a
  noiseless one). The data are not changed; the note says which level was used and why.
* **isolated spikes** (one sample far from both neighbours, which agree) in the temperature and
  pressure channels, and glitches of the opening far larger than a stem can move out and back between
  two samples: replaced by the mean of the two neighbours, and each one named by its row. More
  than :data:`MAX_SPIKE_FRACTION` of a channel's samples is not "a few": the run is refused in one
  line naming the first rows.
* **a units row** under the header, which :func:`~valve_env.data_io.validate_run` reads as a second header line
  where its units are the format's: the note gives the line and the units.
* **comment lines among the data** (a logger's ``# restarted``), which :func:`~valve_env.data_io.load_run` skips
  as it skips empty lines: the note gives their lines (rows are counted without them; every message names the
  file's own line).
* **rows written twice** (every column the same as the row before, time included), which
  :func:`~valve_env.data_io.validate_run` drops: the note names them.
* **rows with an empty cell** in a measured channel, which :func:`~valve_env.data_io.validate_run` drops as
  samples the logger missed: the note names them (every row number in the notes is the file's).
* **an opening derived from the flow** (no ``x_mm`` column, or empty cells in it, which
  :func:`~valve_env.data_io.validate_run` fills from ``q_kgh`` and ``dp_mbar`` with the valve
  characteristic): the note says in how many rows. Where the flow meter has a low-flow cut-off (``q_cut_off``,
  :func:`~valve_env.data_io.flow_cut_off`, a warning), the opening derived as 0 where the flow reads 0 only lies
  below the cut-off's opening: a stick band about that size may be named where there is none, or missed.
* **irregular sampling and gaps**: the likelihoods integrate over each interval as it is, so the
  data are not changed; the note gives the interval's spread, the rows missing against the median
  interval and the longest gap (nothing is filled in).

Every note is a JSON-ready dict with ``what`` (``noise_level``, ``units_row``, ``units_in_header``,
``units_in_cells``, ``nul_padding``, ``last_line_cut``, ``comment_lines``, ``header_lines``, ``rows_repeated``,
``rows_dropped``, ``own_rates``, ``spikes_replaced``, ``q_zero_noise``, ``q_cut_off``, ``pump_off``, ``x_mm_derived``,
``irregular_sampling``, ``gap``,
``short_span``), the
``channel`` where it applies, and ``why``. The ``fit`` and ``diagnose`` JSON carry them under ``preprocessing``, and
their reports print them; a note a user must not miss (a record of seconds, not hours; an opening measured in another
unit and so not read) has ``warn: true``, and the console prints it as a warning. A run that passes through here
twice (read and checked, then diagnosed) keeps the first pass's notes of what was changed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from valve_env.data_io import (
    PUMP_OFF_DP_SHARE,
    ZERO_FLOW_NOISE_SHARE,
    DataError,
    cut_line_note,
    nul_note,
    short_list,
    time_unit_hint,
)
from valve_env.valveid.stiction import opening_noise
from valve_env.valveid.temperature import channel_noise, noise_sd

#: the temperature channels whose noise level the likelihoods need
TEMPERATURE_CHANNELS: tuple[str, ...] = ("T_tank_C", "T_med_C")
#: the channels searched for isolated spikes (the opening, x_mm, with its own threshold: :data:`X_SPIKE_RANGE`)
SPIKE_CHANNELS: tuple[str, ...] = ("T_tank_C", "T_med_C", "dp_mbar", "ps_bar", "x_mm")
#: a spike departs from the mean of its neighbours by more than this many noise sd ...
SPIKE_SD = 12.0
#: ... and by more than this (in the channel's unit: K for temperatures; relative for the pressures)
SPIKE_MIN = {"T_tank_C": 0.5, "T_med_C": 0.5, "dp_mbar": 0.1, "ps_bar": 0.1}
#: an opening's spike must also depart by more than this share of the opening's range (its 1st to 99th
#: percentile). A sticky stem moves out and back between two samples only by slipping twice, which
#: needs the demand to reverse by that much within two intervals; the stick bands of docs/reference.md,
#: section 3 are 0.5-5 % of the stroke, so a slip pair stays far below it while a transducer's glitch
#: (often to full scale) does not
X_SPIKE_RANGE = 0.25
#: notes that say what the pre-processing changed (kept when a checked run is checked again)
CHANGE_NOTES: tuple[str, ...] = ("units_row", "units_in_header", "units_in_cells", "nul_padding", "last_line_cut",
                                 "comment_lines", "header_lines", "rows_repeated", "rows_dropped", "spikes_replaced",
                                 "x_mm_derived", "q_zero_noise", "q_cut_off", "pump_off", "own_rates")
#: the most spikes a channel may have (a share of its samples) before the run is refused
MAX_SPIKE_FRACTION = 0.005
#: an interval longer than this many median intervals is a gap worth a note
GAP_FACTOR = 5.0


def find_spikes(y: np.ndarray, threshold: float) -> np.ndarray:
    """Rows (0-based) of isolated one-sample spikes: ``y[i]`` departs from the mean of its two
    neighbours by more than ``threshold`` on the same side of both, while the neighbours agree to within
    half that departure (a step, whose neighbours differ by its size, is not a spike)."""
    y = np.asarray(y, dtype=float)
    if y.size < 3:
        return np.array([], dtype=int)
    left, mid, right = y[:-2], y[1:-1], y[2:]
    dev = mid - 0.5 * (left + right)
    same_side = np.sign(mid - left) == np.sign(mid - right)
    agree = np.abs(right - left) < 0.5 * np.abs(dev)
    return np.flatnonzero((np.abs(dev) > threshold) & same_side & agree) + 1


def _spike_threshold(channel: str, y: np.ndarray) -> float:
    if channel == "x_mm":
        lo, hi = np.percentile(y, [1.0, 99.0])
        return max(SPIKE_SD * math.sqrt(1.5) * noise_sd(y), X_SPIKE_RANGE * float(hi - lo))
    if channel in TEMPERATURE_CHANNELS:
        sd = channel_noise(_without_spikes(y)).sd
        return max(SPIKE_SD * math.sqrt(1.5) * sd, SPIKE_MIN[channel])
    level = float(np.median(np.abs(y)))
    return max(SPIKE_SD * math.sqrt(1.5) * noise_sd(y), SPIKE_MIN[channel] * level)


def _without_spikes(y: np.ndarray) -> np.ndarray:
    """A rough copy without gross one-sample outliers (3-point median where a sample departs from it
    by more than 1 unit), for the noise level the spike threshold rests on."""
    if y.size < 3:
        return y
    med = np.median(np.stack([y[:-2], y[1:-1], y[2:]]), axis=0)
    out = y.copy()
    far = np.abs(y[1:-1] - med) > 1.0
    out[1:-1][far] = med[far]
    return out


def preprocess_run(df: pd.DataFrame, source: str = "run") -> tuple[pd.DataFrame, list[dict[str, Any]]]:
    """The validated run with isolated spikes replaced, and the notes of what was found and done
    (see the module doc). Raises :class:`~valve_env.data_io.DataError` (one line) where a channel
    holds more than a few spikes. ``df`` is not changed."""
    out = df.copy()
    # a run checked before (``df.attrs["preprocessing"]``) keeps what that pass changed: the data it
    # holds now no longer shows it
    notes: list[dict[str, Any]] = [nt for nt in df.attrs.get("preprocessing", []) if nt["what"] in CHANGE_NOTES]
    done = {(nt["what"], nt.get("channel")) for nt in notes}
    n = len(out)
    file_rows = df.attrs.get("file_rows")  # where validation dropped rows: each row's number in the file

    def row(i: int) -> int:
        return int(file_rows[i]) if file_rows is not None else i + 1

    units = df.attrs.get("units_row")
    if units and ("units_row", None) not in done:
        given = ", ".join(f"{c} [{u}]" for c, u in units["units"].items())
        notes.append({"what": "units_row", "channel": None, "line": int(units["line"]), "units": dict(units["units"]),
                      "why": f"line {units['line']} is a units row ({given}), the format's own units: read as a second "
                             "header line (row 1 is the line after it)"})
    named = df.attrs.get("units_in_header")
    if named and ("units_in_header", None) not in done:
        given = ", ".join(f"{c} [{u}]" for c, u in named.items())
        notes.append({"what": "units_in_header", "channel": None, "units": dict(named),
                      "why": f"the header gives the format's own units after the names ({given}): read as the names"})
    in_cells = df.attrs.get("units_in_cells")
    if in_cells and ("units_in_cells", None) not in done:
        given = ", ".join(f"{c} [{u}]" for c, u in in_cells.items())
        notes.append({"what": "units_in_cells", "channel": None, "units": dict(in_cells),
                      "why": f"the cells carry the format's own units after their numbers ({given}), as a formatted "
                             "spreadsheet cell does: read as the numbers"})
    comments = df.attrs.get("comment_lines", [])
    if comments and ("comment_lines", None) not in done:
        notes.append({"what": "comment_lines", "channel": None, "lines": list(comments),
                      "why": f"{len(comments)} comment line(s) (starting with '#') among the data (line numbers as in "
                             "the file), skipped; rows are counted without them"})
    nul = df.attrs.get("nul_padding", 0)
    if nul and ("nul_padding", None) not in done:
        notes.append({"what": "nul_padding", "channel": None, "bytes": int(nul), "why": nul_note(int(nul))})
    cut = df.attrs.get("last_line_cut")
    if cut and ("last_line_cut", None) not in done:
        notes.append({"what": "last_line_cut", "channel": None, **cut,
                      "why": cut_line_note(cut["line"], cut["fields"], cut["of"])})
    headers = df.attrs.get("header_lines", [])
    if headers and ("header_lines", None) not in done:
        notes.append({"what": "header_lines", "channel": None, "lines": list(headers),
                      "why": f"{len(headers)} line(s) among the data repeat the header (a logger that writes it again "
                             "after a restart, or logs joined; line numbers as in the file), skipped; rows are counted "
                             "without them"})
    repeated = df.attrs.get("rows_repeated", [])
    if repeated and ("rows_repeated", None) not in done:
        notes.append({"what": "rows_repeated", "channel": None, "rows": list(repeated),
                      "why": f"{len(repeated)} row(s) that repeat the row before them in every column, time included "
                             "(row numbers as in the file), dropped as one sample written twice"})
    own = df.attrs.get("own_rates")
    if own and ("own_rates", own["channel"]) not in done:
        said = [f"{c} has a value on {k} of {own['of']} rows, held from each to the next (stored on change)"
                for c, k in own.get("held", {}).items()]
        if own["channel"] is not None:
            said.append(f"the run is read on the {own['rows']} rows where the slowest, {own['channel']}, has a value "
                        f"(one row in {own['every_rows']:g})")
        said += [f"{c} interpolated linearly in time there between its own values" for c in own["interpolated"]]
        notes.append({"what": "own_rates", **own, "dropped_rows": list(df.attrs.get("rows_dropped_own_rates", [])),
                      "why": "the channels are logged on the union of their times, each empty where it has no sample "
                             "(at its own rate, or stored on change): " + "; ".join(said)})
    dropped = df.attrs.get("rows_dropped_empty", [])
    if dropped and ("rows_dropped", None) not in done:
        notes.append({"what": "rows_dropped", "channel": None, "rows": list(dropped),
                      "why": f"{len(dropped)} row(s) with an empty cell in a measured column (row numbers as in "
                             "the file), dropped as samples the logger missed"})
    zero = df.attrs.get("q_zero_noise")
    if zero and ("q_zero_noise", "q_kgh") not in done:
        notes.append({"what": "q_zero_noise", "channel": "q_kgh", **zero,
                      "why": f"{zero['rows']} flow(s) below 0, down to {zero['lowest_kgh']:.3g} kg/h, within a flow "
                             f"meter's noise about 0 (at most {ZERO_FLOW_NOISE_SHARE:.0%} of the record's high flow, "
                             f"{zero['high_kgh']:.4g} kg/h), read as 0"})
    off = df.attrs.get("pump_off")
    if off and ("pump_off", "dp_mbar") not in done:
        rows = df.attrs.get("rows_dropped_pump_off", [])
        notes.append({"what": "pump_off", "channel": "dp_mbar", **off, "dropped_rows": list(rows),
                      "why": f"{off['rows']} row(s) in {off['stretches']} stretch(es) with dp_mbar within "
                             f"{off['dp_at_most_mbar']:.3g} mbar of 0 ({PUMP_OFF_DP_SHARE:.0%} of the record's median "
                             f"dp, {off['median_dp_mbar']:.4g} mbar) and no flow: the circulation pump was off. They "
                             "are dropped, and the likelihoods take each stretch as a gap"})
    cut = df.attrs.get("q_cut_off")
    if cut and ("q_cut_off", "q_kgh") not in done:
        notes.append({"what": "q_cut_off", "channel": "q_kgh", **cut,
                      "why": f"the flow reads 0 in {cut['rows']} row(s) and never between 0 and "
                             f"{cut['cut_off_kgh']:.3g} kg/h: a flow meter's low-flow cut-off. The opening derived "
                             f"from the flow there is only known to be below about {cut['x_below_mm']:.3g} mm: fit "
                             "takes it as missing; diagnose reads it as 0, so a stick band up to about that size may "
                             "be named where there is none, or missed. Give the measured opening x_mm, or the meter's "
                             "reading without the cut-off", "warn": True})
    q_unit = df.attrs.get("q_other_unit")
    if q_unit and ("q_other_unit", "q_kgh") not in done:
        notes.append({"what": "q_other_unit", "channel": "q_kgh", **q_unit,
                      "why": f"q_kgh is {q_unit['ratio']:.3g} times the flow that x_mm and dp_mbar give through the "
                             f"valve characteristic (median over {q_unit['open_rows']} rows with the valve open): it "
                             f"reads as {q_unit['unit']} (multiply by {q_unit['factor']:g}). The measured opening is "
                             "used, not the flow, except where x_mm is empty", "warn": True})
    zero = df.attrs.get("x_mm_zero_offset")
    if zero and ("x_mm_zero_offset", "x_mm") not in done:
        notes.append({"what": "x_mm_zero_offset", "channel": "x_mm", **zero,
                      "why": f"x_mm rests at {zero['offset_mm']:.3g} mm (median; noise sd {zero['noise_mm']:.2g} mm) "
                             f"on the {zero['rows']} rows whose flow is about 0, where the valve sits on its seat "
                             "(0 mm in the model): the opening transducer's zero reads off, and the offset is "
                             "subtracted from every row", "warn": True})
    derived = int(df.attrs.get("x_mm_derived_rows", 0))
    if derived and ("x_mm_derived", "x_mm") not in done:
        other = df.attrs.get("x_mm_other_unit")
        notes.append({"what": "x_mm_derived", "channel": "x_mm", "rows": derived,
                      "why": ("no x_mm column" if derived == n else f"x_mm empty in {derived} of {n} rows")
                      + ": the opening is derived from q_kgh and dp_mbar with the valve characteristic "
                        "(docs/reference.md, section 2)"
                      + (f"; {other}, to read the measured opening instead (the column is not read)" if other else ""),
                      **({"warn": True} if other else {})})
    for ch in SPIKE_CHANNELS:
        if ch not in out.columns:
            continue
        y = out[ch].to_numpy(dtype=float)
        rows = find_spikes(y, _spike_threshold(ch, y))
        if rows.size == 0:
            continue
        if rows.size > max(3, int(MAX_SPIKE_FRACTION * n)):
            first = ", ".join(str(row(int(r))) for r in rows[:5])
            raise DataError(f"{source}: column {ch} has {rows.size} isolated spikes (rows {first}, ...): more than "
                            f"a few ({MAX_SPIKE_FRACTION:.1%} of the rows); remove them or clean the channel")
        y = y.copy()
        y[rows] = 0.5 * (y[rows - 1] + y[rows + 1])
        out[ch] = y
        notes.append({"what": "spikes_replaced", "channel": ch, "rows": [row(int(r)) for r in rows],
                      "why": f"{rows.size} isolated one-sample spike(s) (row numbers as in the file, 1 = first data "
                             "row), each replaced by the mean of its two neighbours"})
        done.add(("spikes_replaced", ch))
    for ch in TEMPERATURE_CHANNELS:
        if ch in out.columns:
            notes.append({"what": "noise_level", **channel_noise(out[ch].to_numpy(dtype=float)).describe(ch)})
    if "x_mm" in out.columns:
        xn = opening_noise(out["x_mm"].to_numpy(dtype=float))
        if xn.method != "mad" or xn.level_sd is not None:  # a noisy opening's one sd is the fit's own s_w
            notes.append({"what": "noise_level", **xn.describe()})
    t = out["time_s"].to_numpy(dtype=float)
    short = time_unit_hint(t)
    if short:
        notes.append({"what": "short_span", "channel": None, "seconds": float(t[-1] - t[0]),
                      "why": f"a valve's test runs for hours{short}", "warn": True})
    if n > 2:
        dt = np.diff(t)
        med = float(np.median(dt))
        cv = float(np.std(dt) / med) if med > 0 else 0.0
        missing = int(max(0, round((t[-1] - t[0]) / med) + 1 - n)) if med > 0 else 0
        if cv > 0.01 or missing > 0:
            notes.append({"what": "irregular_sampling", "median_interval_s": med, "interval_cv": round(cv, 4),
                          "rows_missing": missing,
                          "why": "the likelihoods integrate over each interval as it is; nothing is interpolated"})
        big = np.flatnonzero(dt > GAP_FACTOR * med)
        if big.size:
            i = int(big[np.argmax(dt[big])])
            notes.append({"what": "gap", "after_row": row(i), "seconds": float(dt[i]), "count": int(big.size),
                          "why": f"{big.size} interval(s) longer than {GAP_FACTOR:g} median intervals, the longest "
                                 f"{dt[i]:.0f} s after row {row(i)}; the model is simulated across it from the "
                                 "interpolated temperatures, nothing is filled in"})
    out.attrs["preprocessing"] = notes
    return out, notes


def _row_list(rows: list[int]) -> str:
    """``rows 3, 9, ...``: the first ten row numbers of a note."""
    return f"rows {short_list(rows)}"


def describe(notes: list[dict[str, Any]]) -> list[str]:
    """One line per note, for the reports."""
    lines = []
    for nt in notes:
        what = nt["what"]
        if what == "noise_level" and "noise_sd_mm" in nt:
            lines.append(f"x_mm: noise sd {nt['noise_sd_mm']:.3g} mm from {nt['why']}")
        elif what == "noise_level":
            lines.append(f"{nt['channel']}: noise sd {nt['noise_sd_C']:.3g} degC from {nt['why']}"
                         + (f"; {nt['held_fraction']:.0%} of consecutive samples equal" if nt["held_fraction"] > 0.5
                            else ""))
        elif what == "spikes_replaced":
            lines.append(f"{nt['channel']}: {len(nt['rows'])} isolated spike(s) replaced by the mean of their "
                         f"neighbours ({_row_list(nt['rows'])})")
        elif what == "units_row":
            lines.append(f"line {nt['line']}: a units row, the format's units; read as a second header line")
        elif what == "units_in_header":
            lines.append("the header: the format's units after the names; read as the names")
        elif what == "units_in_cells":
            lines.append(f"the cells of {', '.join(nt['units'])}: the format's units after the numbers; read as the "
                         "numbers")
        elif what == "comment_lines":
            lines.append(f"{len(nt['lines'])} comment line(s) among the data skipped (lines {short_list(nt['lines'])})")
        elif what == "nul_padding":
            lines.append(f"{nt['bytes']} NUL byte(s) at the end of the file dropped")
        elif what == "last_line_cut":
            lines.append(f"line {nt['line']}: the last line, cut off mid-write ({nt['fields']} of {nt['of']} fields), "
                         "dropped")
        elif what == "header_lines":
            lines.append(f"{len(nt['lines'])} repeated header line(s) among the data skipped (lines "
                         f"{short_list(nt['lines'])})")
        elif what == "rows_repeated":
            lines.append(f"{len(nt['rows'])} repeated row(s) dropped ({_row_list(nt['rows'])})")
        elif what == "own_rates":
            parts = [f"{', '.join(nt['held'])} stored on change, held"] if nt.get("held") else []
            if nt["channel"] is not None:
                parts.append(f"read on the {nt['rows']} rows of {nt['channel']}"
                             + (f", {', '.join(nt['interpolated'])} interpolated there" if nt["interpolated"] else ""))
            lines.append("channels on their own times: " + "; ".join(parts))
        elif what == "rows_dropped":
            lines.append(f"{len(nt['rows'])} row(s) with an empty cell dropped ({_row_list(nt['rows'])})")
        elif what == "q_zero_noise":
            lines.append(f"q_kgh: {nt['rows']} flow(s) below 0, down to {nt['lowest_kgh']:.3g} kg/h, read as 0 (a "
                         "meter's noise about 0)")
        elif what == "pump_off":
            lines.append(f"dp_mbar: the pump off in {nt['stretches']} stretch(es), {nt['rows']} row(s) dropped "
                         f"({_row_list(nt['dropped_rows'])})")
        elif what == "q_cut_off":
            lines.append(f"q_kgh: 0 in {nt['rows']} row(s), never between 0 and {nt['cut_off_kgh']:.3g} kg/h (a "
                         f"low-flow cut-off): the opening derived as 0 there lies anywhere below about "
                         f"{nt['x_below_mm']:.3g} mm")
        elif what == "q_other_unit":
            lines.append(f"q_kgh: {nt['ratio']:.3g} times the flow x_mm and dp_mbar give; it reads as {nt['unit']} "
                         f"(multiply by {nt['factor']:g}); the measured opening is used")
        elif what == "x_mm_zero_offset":
            lines.append(f"x_mm: rests at {nt['offset_mm']:.3g} mm where the flow is about 0 (the seat, 0 mm in "
                         "the model): a transducer's zero offset, subtracted")
        elif what == "x_mm_derived":
            lines.append(f"x_mm: derived from the flow in {nt['rows']} row(s) ({nt['why'].split(':')[0]})")
        elif what == "irregular_sampling":
            lines.append(f"sampling: median interval {nt['median_interval_s']:.3g} s, spread {nt['interval_cv']:.1%}, "
                         f"{nt['rows_missing']} row(s) missing against it; nothing interpolated")
        elif what == "short_span":
            lines.append(f"time: the record spans {nt['seconds']:.3g} s; if time_s is in minutes or hours, give it in "
                         "seconds")
        elif what == "gap":
            lines.append(f"gap: {nt['seconds']:.0f} s after row {nt['after_row']} ({nt['count']} gap(s) in all); "
                         "nothing filled in")
    return lines


__all__ = ["preprocess_run", "describe", "find_spikes", "SPIKE_CHANNELS", "X_SPIKE_RANGE", "CHANGE_NOTES",
           "TEMPERATURE_CHANNELS", "MAX_SPIKE_FRACTION", "GAP_FACTOR"]
