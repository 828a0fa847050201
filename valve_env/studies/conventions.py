"""The conventions of measured data, applied to a simulated run (docs/reference.md, section 2).

Real measurement channels are quantised, held constant or stored on change, sampled with jitter,
lose rows, carry spikes and arrive with extra columns in any order. The identification must take
all of them; this module turns a run of either simulator (:mod:`valve_env.experiment`,
:mod:`valve_env.studies.independent`) into such a run, so that tests and studies can feed it
data whose conventions it was not built around.

    df = simulate_experiment(seed=3, duration_h=4)
    foreign = apply_convention(df, "stepped_medium", rng=np.random.default_rng(3))

Each :class:`Convention` is a measurement transform: it changes how the truth was recorded, not
the truth. Where it needs the truth (a noiseless or stepped channel is the true signal recorded
without noise) it takes the simulator's ``true_*`` columns. The truth columns are dropped from
the result unless ``keep_truth``.

:data:`CONVENTIONS` lists them by name; ``tests/studies/test_foreign_data.py`` (the foreign-data
corpus) and ``studies/foreign_data.py`` (confusion and coverage on each) run on them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from valve_env.data_io import MEASURED
from valve_env.scenario import ou_path

TEMPERATURES: tuple[str, ...] = ("T_tank_C", "T_med_C")


def _truth(df: pd.DataFrame, col: str) -> np.ndarray:
    """The true signal behind a measured column (the simulators' ``true_*`` columns); dp and ps are
    constant in both simulators, so their truth is the median of the measured channel."""
    tc = f"true_{col}"
    if tc in df.columns:
        return df[tc].to_numpy(dtype=float)
    if col in ("dp_mbar", "ps_bar"):
        return np.full(len(df), float(np.median(df[col].to_numpy(dtype=float))))
    raise KeyError(f"the run has no {tc} column: a noiseless {col} needs the simulator's truth")


def quantise(df: pd.DataFrame, step: float, columns: tuple[str, ...] = TEMPERATURES) -> pd.DataFrame:
    """Each column rounded to a multiple of ``step`` (a sensor or logger resolution)."""
    out = df.copy()
    for c in columns:
        out[c] = np.round(out[c].to_numpy(dtype=float) / step) * step
    return out


def store_on_change(y: np.ndarray, deadband: float) -> np.ndarray:
    """A historian's dead-band compression, held between stored values: a sample is stored where it
    differs from the last stored value by more than ``deadband``; the record holds the last stored
    value in between."""
    out = np.empty_like(y)
    last = y[0]
    for i, v in enumerate(y):
        if abs(v - last) > deadband:
            last = v
        out[i] = last
    return out


def stepped(df: pd.DataFrame, column: str, deadband: float, resolution: float = 0.01) -> pd.DataFrame:
    """``column`` recorded without noise and stored on change (``deadband``, K), at ``resolution``:
    a rig that holds the medium temperature by thermostat and logs its set value, or a historian's
    compression of a noiseless channel. Most consecutive samples are then identical."""
    out = df.copy()
    held = store_on_change(_truth(df, column), deadband)
    out[column] = np.round(held / resolution) * resolution
    return out


def noiseless(df: pd.DataFrame, columns: tuple[str, ...]) -> pd.DataFrame:
    """Each column replaced by its true signal (a channel recorded without noise, in full precision)."""
    out = df.copy()
    for c in columns:
        out[c] = _truth(df, c)
    return out


def flow_zero_noise(df: pd.DataFrame, rng: np.random.Generator, sd_kgh: float = 0.5) -> pd.DataFrame:
    """The flow read by a meter without a low-flow cut-off: white noise of ``sd_kgh`` added to every reading, so a
    shut valve reads about 0, partly below 0 (a magnetic or ultrasonic meter's zero noise; 0.5 kg/h is 0.1-0.2 % of
    the runs' high flows). It loses information where the opening is derived from the flow: near the seat the
    derived opening is noisier."""
    out = df.copy()
    out["q_kgh"] = out["q_kgh"].to_numpy(dtype=float) + rng.normal(0.0, sd_kgh, len(out))
    return out


def flow_cut_off(df: pd.DataFrame, share: float = 0.03) -> pd.DataFrame:
    """The flow read by a meter with a low-flow cut-off: every flow below ``share`` of the run's high flow (its 99th
    percentile) read as 0 (magnetic and ultrasonic meters cut off at 0.5-5 % of their range). It loses information
    where the opening is derived from the flow: near the seat the derived opening is only known to be below the
    cut-off's."""
    q = df["q_kgh"].to_numpy(dtype=float)
    return df.assign(q_kgh=np.where(q < share * np.percentile(q, 99), 0.0, q))


def pump_off(df: pd.DataFrame, hours: float, rng: np.random.Generator, dp_noise_mbar: float = 0.3) -> pd.DataFrame:
    """The circulation pump off for ``hours`` at a random place in the middle 60 % of the record: dp_mbar 0 with a
    transmitter's noise of ``dp_noise_mbar``, and no flow (the rig's night setback). The opening and the temperatures
    are left as recorded."""
    t = df["time_s"].to_numpy(dtype=float)
    span = t[-1] - t[0]
    start = t[0] + span * (0.2 + 0.6 * rng.random()) - hours * 1800.0
    off = (t >= start) & (t < start + hours * 3600.0)
    dp = df["dp_mbar"].to_numpy(dtype=float).copy()
    dp[off] = rng.normal(0.0, dp_noise_mbar, int(off.sum()))
    return df.assign(dp_mbar=dp, q_kgh=np.where(off, 0.0, df["q_kgh"].to_numpy(dtype=float)))


def held_constant(df: pd.DataFrame, column: str) -> pd.DataFrame:
    """``column`` exactly constant (its median): a rig that holds an input fixed and logs its set value.

    Only for a channel whose truth is constant (dp_mbar, ps_bar in both simulators): holding a
    channel that moved would record a false input."""
    truth = _truth(df, column)
    if float(np.ptp(truth)) > 1e-9 * max(1.0, float(np.max(np.abs(truth)))):
        raise ValueError(f"{column} moves in this run: holding it constant would record a false input")
    out = df.copy()
    out[column] = float(truth[0])
    return out


def drop_rows(df: pd.DataFrame, fraction: float, rng: np.random.Generator) -> pd.DataFrame:
    """``fraction`` of the rows (never the first or the last) removed at random."""
    n = len(df)
    k = int(round(fraction * n))
    drop = rng.choice(np.arange(1, n - 1), size=min(k, n - 2), replace=False)
    return df.drop(index=df.index[drop]).reset_index(drop=True)


def gap(df: pd.DataFrame, hours: float, rng: np.random.Generator) -> pd.DataFrame:
    """One gap of ``hours`` (the rows inside it removed), placed at random in the middle 60 % of the record
    (a logger that stopped for a while)."""
    t = df["time_s"].to_numpy(dtype=float)
    span = t[-1] - t[0]
    width = hours * 3600.0
    start = t[0] + float(rng.uniform(0.2, 0.8)) * span - 0.5 * width
    keep = (t < start) | (t > start + width)
    return df[keep].reset_index(drop=True)


def resample(df: pd.DataFrame, dt_s: float) -> pd.DataFrame:
    """Every k-th row kept, k = round(dt_s / the run's interval): a logger at a longer interval."""
    t = df["time_s"].to_numpy(dtype=float)
    k = max(1, int(round(dt_s / float(np.median(np.diff(t))))))
    return df.iloc[::k].reset_index(drop=True)


def truncate(df: pd.DataFrame, hours: float) -> pd.DataFrame:
    """The first ``hours`` of the record."""
    t = df["time_s"].to_numpy(dtype=float)
    return df[t <= t[0] + hours * 3600.0].reset_index(drop=True)


def slow_noise(df: pd.DataFrame, rng: np.random.Generator, column: str = "T_tank_C", sd: float = 0.02,
               tau_s: float = 120.0) -> pd.DataFrame:
    """``column`` read with slow noise added: a first-order (Ornstein-Uhlenbeck) error of stationary sd ``sd`` (the
    column's unit) and correlation time ``tau_s``, sampled exactly at the record's times
    (:func:`valve_env.scenario.ou_path`). A tank's sensor away from the valve's bulb reads the water's local mixing
    and stratification so, and a transmitter's electronics drift so: an error that the white-noise models of the
    pre-processing leave in the smoothed temperature."""
    t = df["time_s"].to_numpy(dtype=float)
    e = ou_path(rng, t.size, np.diff(t), float(tau_s), sd)
    return df.assign(**{column: df[column].to_numpy(dtype=float) + e})


def spikes(df: pd.DataFrame, count: int, rng: np.random.Generator, column: str = "T_tank_C",
           size: float = 3.0) -> pd.DataFrame:
    """``count`` isolated one-sample spikes of +-``size`` (the column's unit) at random rows away from the
    ends (an electrical glitch). ``df.attrs["spike_rows"]`` lists their positions (0-based)."""
    out = df.copy()
    n = len(out)
    rows = np.sort(rng.choice(np.arange(5, n - 5), size=count, replace=False))
    y = out[column].to_numpy(dtype=float).copy()
    y[rows] += size * rng.choice([-1.0, 1.0], size=count)
    out[column] = y
    out.attrs["spike_rows"] = [int(r) for r in rows]
    return out


def extra_columns(df: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """Extra columns a logger adds (a timestamp string, a status flag, another sensor) and the columns
    in a random order."""
    out = df.copy()
    n = len(out)
    out["timestamp"] = pd.Timestamp("2026-01-05 06:00:00") + pd.to_timedelta(out["time_s"], unit="s")
    out["status"] = np.where(rng.random(n) < 0.01, "WARN", "OK")
    out["T_return_C"] = np.round(40.0 + rng.normal(0.0, 0.3, n), 2)
    cols = list(out.columns)
    rng.shuffle(cols)
    return out[cols]


def historian_export(df: pd.DataFrame, rng: np.random.Generator, repeated: float = 0.01, states: float = 0.004
                     ) -> pd.DataFrame:
    """A historian's export: ``repeated`` of the rows written twice, and in each measured column ``states`` of
    the cells holding a PI System state instead of a value (``I/O Timeout``, ``Bad Input``, ``No Data``: a
    sample without a usable value), at random rows away from the ends."""
    n = len(df)
    out = df.copy()
    for col in MEASURED:
        rows = rng.choice(np.arange(1, n - 1), size=max(1, int(round(states * n))), replace=False)
        out[col] = out[col].astype(object)
        out.loc[rows, col] = rng.choice(["I/O Timeout", "Bad Input", "No Data"], size=rows.size)
    twice = np.sort(rng.choice(np.arange(1, n - 1), size=max(1, int(round(repeated * n))), replace=False))
    order = np.sort(np.concatenate([np.arange(n), twice]))
    return out.iloc[order].reset_index(drop=True)


#: the units a spreadsheet export writes on the line under the header (:func:`spreadsheet_export`)
_SHEET_UNITS: dict[str, str] = {"time_s": "s", "T_tank_C": "°C", "T_med_C": "°C", "q_kgh": "kg/h", "dp_mbar": "mbar",
                                "ps_bar": "bar", "x_mm": "mm"}


def _sheet_number(v: float, digits: int) -> str:
    """A number as a spreadsheet in a decimal-comma locale writes a formatted cell: points between the thousands,
    a decimal comma, at most ``digits`` decimals (``12.340``, ``52,6137``)."""
    text = f"{v:,.{digits}f}".rstrip("0").rstrip(".") if digits else f"{v:,.0f}"
    return text.replace(",", "_").replace(".", ",").replace("_", ".")


def _sheet_cell(v: object) -> str:
    """A cell as the spreadsheet writes it: a number formatted (:func:`_sheet_number`, 6 decimals), text (a
    historian's state in a column it wrote) as it is."""
    try:
        return _sheet_number(float(v), 6)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return str(v)


def spreadsheet_export(df: pd.DataFrame, rng: np.random.Generator, errors: float = 0.003) -> pd.DataFrame:
    """A run saved from a spreadsheet in a decimal-comma locale: fields separated by semicolons (``attrs["csv_sep"]``
    for the writer), numbers with a decimal comma and points between the thousands (the time, 21.600 s), a units row
    under the header, and in each measured column ``errors`` of the cells an error value (``#N/A``, ``#DIV/0!``) at
    random rows away from the ends. The values keep 6 decimals, as a cell formatted so would; text cells (a
    historian's states) are written as they are."""
    n = len(df)
    out = pd.DataFrame({c: [_sheet_cell(v) for v in df[c]] for c in df.columns})
    for col in MEASURED:
        rows = rng.choice(np.arange(1, n - 1), size=max(1, int(round(errors * n))), replace=False)
        out.loc[rows, col] = rng.choice(["#N/A", "#DIV/0!"], size=rows.size)
    units = pd.DataFrame([{c: _SHEET_UNITS.get(c, "") for c in out.columns}])
    out = pd.concat([units, out], ignore_index=True)
    out.attrs["csv_sep"] = ";"
    return out


def logger_comments(df: pd.DataFrame, rng: np.random.Generator, k: int = 2) -> pd.DataFrame:
    """A logger's comment lines among the data (``# logger restarted``): ``k`` rows at random places away from the
    ends (and from a units row), each with the comment in the first column the file will hold (the first but the
    truth's ``true_*`` columns, which are dropped before a run is written) and the other cells empty. Applied last of
    a run's conventions: its rows are not samples."""
    n = len(df)
    at = np.sort(rng.choice(np.arange(2, n - 1), size=k, replace=False))
    first = next(c for c in df.columns if not str(c).startswith("true_"))
    comment = pd.DataFrame([{c: ("# logger restarted" if c == first else "") for c in df.columns}], dtype=object)
    parts, start = [], 0
    for j in at:
        parts += [df.iloc[start:j].astype(object), comment]
        start = int(j)
    out = pd.concat([*parts, df.iloc[start:].astype(object)], ignore_index=True)
    out.attrs = dict(df.attrs)
    return out


def logger_cut_off(df: pd.DataFrame, rng: np.random.Generator, pad: int = 4096) -> pd.DataFrame:
    """A logger stopped mid-write (a power loss): the file ends in the next sample's line cut within its second field,
    then in ``pad`` NUL bytes of the space the logger had preallocated. Both go in ``attrs["csv_tail"]``, which the
    writer appends after the rows (:func:`valve_env.studies.foreign.run_case`). Applied last of a run's conventions."""
    out = df.copy()
    out.attrs = dict(df.attrs)
    sep = str(df.attrs.get("csv_sep", ","))
    nxt = df[[c for c in df.columns if not str(c).startswith("true_")]].iloc[[-1]].copy()
    if "time_s" in nxt and len(df) > 1:
        nxt["time_s"] += float(np.median(np.diff(df["time_s"].to_numpy(dtype=float))))
    line = nxt.to_csv(header=False, index=False, sep=sep).rstrip("\r\n")
    cut = line.index(sep) + 1 + int(rng.integers(1, 4))  # one to three characters into the second field
    out.attrs["csv_tail"] = line[:cut].encode() + bytes(pad)
    return out


def own_rates(df: pd.DataFrame, columns: tuple[str, ...] = TEMPERATURES, every: int = 2) -> pd.DataFrame:
    """``columns`` logged on every ``every``-th row only, empty on the others: a logger that writes each channel at its
    own rate on the union of their times (the temperatures at half the rate of the flow, pressures and opening)."""
    out = df.copy()
    out.loc[np.arange(len(out)) % every != 0, list(columns)] = np.nan
    return out


def changes_only(df: pd.DataFrame, columns: tuple[str, ...]) -> pd.DataFrame:
    """Each of ``columns`` written only on the rows where its value changed, empty where it repeats the row before: a
    historian's export of tags stored on change, side by side on the union of their times."""
    out = df.copy()
    for c in columns:
        v = out[c].to_numpy(dtype=float)
        out.loc[np.r_[False, v[1:] == v[:-1]], c] = np.nan
    return out


def _on_opening(apply: Callable[[pd.DataFrame, np.random.Generator], pd.DataFrame]
                ) -> Callable[[pd.DataFrame, np.random.Generator], pd.DataFrame]:
    """A convention of the measured opening: a run without x_mm (its opening derived from the flow) has none to
    record, and is left as it is."""
    return lambda df, rng: apply(df, rng) if "x_mm" in df.columns else df


@dataclass(frozen=True)
class Convention:
    """A named measurement convention: ``apply(df, rng)`` returns the run as such a record.

    ``loses_information``: the record holds less evidence than the original (a shorter or sparser
    one, or a tank temperature quantised to 0.1 K, which is as large as a 6 h set-point drift's
    whole effect and leaves the smoothed temperature 4-7 times further from the truth than 0.01 K
    noise does, or an opening stored on change, whose dead band hides a stick band up to about twice
    its size), so a cause named on the original may fall back to ``none`` on it; never to another
    effect.

    ``file_only``: a convention of the file (its separator, decimal mark, a units row, comment lines), whose result
    holds text
    that only the file reader (:func:`valve_env.data_io.load_run`) reads: it is applied where the run is written to
    a file and read back (:mod:`valve_env.studies.foreign`), not where a DataFrame goes to the diagnosis."""

    name: str
    description: str
    apply: Callable[[pd.DataFrame, np.random.Generator], pd.DataFrame]
    loses_information: bool = False
    file_only: bool = False


CONVENTIONS: dict[str, Convention] = {c.name: c for c in (
    Convention("quantised_0.1", "both temperature channels quantised to 0.1 K",
               lambda df, rng: quantise(df, 0.1), loses_information=True),
    Convention("quantised_0.01", "both temperature channels quantised to 0.01 K",
               lambda df, rng: quantise(df, 0.01)),
    Convention("quantised_tank_0.1", "only T_tank_C quantised to 0.1 K",
               lambda df, rng: quantise(df, 0.1, ("T_tank_C",)), loses_information=True),
    Convention("stepped_medium", "T_med_C noiseless and stored on change (0.1 K dead band, 0.01 K resolution)",
               lambda df, rng: stepped(df, "T_med_C", 0.1)),
    Convention("noiseless_temperatures", "both temperature channels without noise, full precision",
               lambda df, rng: noiseless(df, TEMPERATURES)),
    Convention("dp_constant", "dp_mbar and ps_bar held exactly constant (a rig's set values)",
               lambda df, rng: held_constant(held_constant(df, "dp_mbar"), "ps_bar")),
    Convention("dropped_5", "5 % of the rows missing at random",
               lambda df, rng: drop_rows(df, 0.05, rng)),
    Convention("dropped_10", "10 % of the rows missing at random",
               lambda df, rng: drop_rows(df, 0.10, rng), loses_information=True),
    Convention("gap_1h", "one gap of an hour",
               lambda df, rng: gap(df, 1.0, rng), loses_information=True),
    Convention("dt_60", "one row a minute (a 60 s logger)",
               lambda df, rng: resample(df, 60.0), loses_information=True),
    Convention("slow_tank_noise", "T_tank_C with slow noise: a first-order error of sd 0.02 K and 2 min correlation "
               "time (a sensor away from the bulb, in the tank's mixing)", lambda df, rng: slow_noise(df, rng)),
    Convention("spikes", "three isolated 3 K spikes on T_tank_C",
               lambda df, rng: spikes(df, 3, rng)),
    Convention("spikes_opening", "three isolated 1 mm glitches of the opening x_mm (a position transducer's)",
               _on_opening(lambda df, rng: spikes(df, 3, rng, column="x_mm", size=1.0))),
    Convention("opening_quantised_0.01", "the opening x_mm quantised to 0.01 mm (a position transducer's resolution)",
               _on_opening(lambda df, rng: quantise(df, 0.01, ("x_mm",)))),
    Convention("opening_stored_on_change", "the opening x_mm stored on change with a 0.01 mm dead band (a historian)",
               _on_opening(lambda df, rng: df.assign(x_mm=store_on_change(df["x_mm"].to_numpy(dtype=float), 0.01))),
               loses_information=True),
    Convention("opening_zero_offset", "the opening x_mm read 0.03 mm high throughout (a position transducer's zero "
               "set off)", _on_opening(lambda df, rng: df.assign(x_mm=df["x_mm"].to_numpy(dtype=float) + 0.03))),
    Convention("opening_from_flow", "no x_mm column: the opening derived from the flow (the meter's relative error)",
               lambda df, rng: df.drop(columns=["x_mm"])),
    Convention("flow_zero_noise", "the flow meter's noise about 0 (0.5 kg/h added to every reading): a shut valve "
               "reads partly below 0", flow_zero_noise, loses_information=True),
    Convention("pump_off_1h", "the circulation pump off for an hour: dp_mbar 0 with 0.3 mbar of noise, no flow",
               lambda df, rng: pump_off(df, 1.0, rng), loses_information=True),
    Convention("flow_cut_off", "the flow meter's low-flow cut-off: flows below 3 % of the run's high flow read as 0",
               lambda df, rng: flow_cut_off(df), loses_information=True),
    Convention("own_rates", "the temperatures logged at half the rate of the other channels, on the union of their "
               "times: empty on every other row", lambda df, rng: own_rates(df), loses_information=True),
    Convention("changes_only", "the medium temperature in noiseless steps and dp_mbar and ps_bar at a rig's set values "
               "(stepped_medium and dp_constant), each written only where it changed: a historian's export of tags "
               "stored on change, on the union of their times",
               lambda df, rng: changes_only(held_constant(held_constant(stepped(df, "T_med_C", 0.1), "dp_mbar"),
                                                          "ps_bar"), ("T_med_C", "dp_mbar", "ps_bar"))),
    Convention("extra_columns", "extra columns (a timestamp, a status flag, another sensor), columns shuffled",
               lambda df, rng: extra_columns(df, rng)),
    Convention("historian_export", "1 % of the rows written twice, 0.4 % of each measured channel's cells a PI "
               "state (I/O Timeout, Bad Input, No Data) instead of a value", historian_export),
    Convention("spreadsheet_export", "saved from a spreadsheet in a decimal-comma locale: semicolons, 52,61 and "
               "21.600, a units row, 0.3 % of each measured channel's cells #N/A or #DIV/0!", spreadsheet_export,
               file_only=True),
    Convention("logger_comments", "two comment lines ('# logger restarted') among the data", logger_comments,
               file_only=True),
    Convention("logger_cut_off", "a logger stopped mid-write: the last line cut within its second field, then 4 KiB "
               "of NUL bytes", logger_cut_off, file_only=True),
)}


def frame_problem(names: tuple[str, ...] | list[str]) -> str:
    """Why conventions ``names`` cannot be applied to a run that goes to the diagnosis as a DataFrame: the first one
    that is a convention of the file (``file_only``), in one line; "" where none is."""
    name = next((n for n in names if n in CONVENTIONS and CONVENTIONS[n].file_only), None)
    return "" if name is None else (f"{name} is a convention of the file (its separator, decimal mark, units row, "
                                    "comment lines or how it ends): the foreign-data corpus runs it "
                                    "(studies/foreign_data.py)")


def apply_convention(df: pd.DataFrame, name: str, rng: np.random.Generator | None = None,
                     keep_truth: bool = False, to_file: bool = False) -> pd.DataFrame:
    """The run ``df`` recorded under convention ``name`` (:data:`CONVENTIONS`), truth columns dropped
    unless ``keep_truth``. A convention of the file (``file_only``) needs ``to_file``: its result is to be written
    (with ``attrs["csv_sep"]``) and read back by the file reader."""
    if name not in CONVENTIONS:
        raise ValueError(f"unknown convention {name!r}; known: {sorted(CONVENTIONS)}")
    if not to_file and frame_problem([name]):
        raise ValueError(frame_problem([name]))
    out = CONVENTIONS[name].apply(df, rng if rng is not None else np.random.default_rng(0))
    if not keep_truth:
        attrs = dict(out.attrs)
        out = out[[c for c in out.columns if not str(c).startswith("true_")]]
        out.attrs.update(attrs)
    return out


__all__ = ["CONVENTIONS", "Convention", "apply_convention", "changes_only", "frame_problem", "drop_rows",
           "extra_columns", "gap",
           "flow_zero_noise", "flow_cut_off", "pump_off", "own_rates",
           "held_constant", "historian_export", "logger_comments", "logger_cut_off", "noiseless", "quantise",
           "resample", "spikes", "spreadsheet_export", "stepped", "store_on_change", "truncate"]
