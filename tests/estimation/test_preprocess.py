"""Pre-processing of measured runs (valve_env.valveid.preprocess): what it changes, and that it says so."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from valve_env.data_io import DataError, validate_run
from valve_env.experiment import simulate_experiment
from valve_env.valveid.diagnose import check_run, read_run
from valve_env.valveid.preprocess import CHANGE_NOTES, X_SPIKE_RANGE, describe, find_spikes, preprocess_run


@pytest.fixture(scope="module")
def run() -> pd.DataFrame:
    df = simulate_experiment(seed=5, duration_h=3.0, dt_s=20.0, effects={"stiction": {"band_mm": 0.06}})
    return df[[c for c in df.columns if not c.startswith("true_")]]


def _changes(notes: list[dict]) -> dict[tuple[str, str], object]:
    return {(n["what"], n["channel"]): n["rows"] for n in notes if n["what"] in CHANGE_NOTES}


def test_a_glitch_of_the_opening_is_replaced_and_named(run) -> None:
    df = run.copy()
    x = df["x_mm"].to_numpy().copy()
    x[[40, 200, 333]] += (1.0, -1.0, 1.0)
    df["x_mm"] = x
    out, notes = preprocess_run(validate_run(df))
    assert _changes(notes) == {("spikes_replaced", "x_mm"): [41, 201, 334]}  # file rows, 1 = the first
    assert np.allclose(out["x_mm"].to_numpy()[[40, 200, 333]], run["x_mm"].to_numpy()[[40, 200, 333]], atol=0.02)
    assert "x_mm: 3 isolated spike(s) replaced" in " ".join(describe(notes))


def test_a_sticky_stems_slips_are_not_glitches() -> None:
    """A staircase of slips, and a slip out and back within two samples of a band's size (5 % of the range),
    stay as they are; a departure of a third of the range does not."""
    rng = np.random.default_rng(0)
    x = np.repeat(np.linspace(0.2, 1.2, 40), 10) + 0.002 * rng.standard_normal(400)
    x[100] += 0.05
    assert find_spikes(x, 0.0).size >= 1  # it is a one-sample departure ...
    from valve_env.valveid.preprocess import _spike_threshold

    assert find_spikes(x, _spike_threshold("x_mm", x)).size == 0  # ... but far below a glitch
    x[300] += (X_SPIKE_RANGE + 0.1) * 1.0
    assert find_spikes(x, _spike_threshold("x_mm", x)).tolist() == [300]


def test_a_checked_run_checked_again_keeps_what_was_changed(run, tmp_path) -> None:
    """``diagnose`` checks a run that ``read_run`` checked already: the notes of the first pass (a spike
    replaced, an opening derived from the flow) must survive the second, whose data no longer shows them."""
    df = run.copy()
    T = df["T_tank_C"].to_numpy().copy()
    T[77] += 4.0
    df["T_tank_C"] = T
    df["x_mm"] = df["x_mm"].astype(object)
    df.loc[10:14, "x_mm"] = ""  # empty cells: derived from the flow
    path = tmp_path / "run.csv"
    df.to_csv(path, index=False)
    first = read_run(path)
    second = check_run(first, "again")
    want = {("spikes_replaced", "T_tank_C"): [78], ("x_mm_derived", "x_mm"): 5}
    assert _changes(first.attrs["preprocessing"]) == want
    assert _changes(second.attrs["preprocessing"]) == want
    lines = " ".join(describe(second.attrs["preprocessing"]))
    assert "x_mm: derived from the flow in 5 row(s) (x_mm empty in 5 of" in lines


def test_no_opening_column_is_said(run) -> None:
    _, notes = preprocess_run(validate_run(run.drop(columns=["x_mm"])))
    assert _changes(notes) == {("x_mm_derived", "x_mm"): len(run)}
    assert notes[0]["why"].startswith("no x_mm column")


def test_more_than_a_few_glitches_are_refused_in_one_line(run) -> None:
    df = run.copy()
    x = df["x_mm"].to_numpy().copy()
    x[10:500:40] += 1.0
    df["x_mm"] = x
    with pytest.raises(DataError, match=r"column x_mm has 13 isolated spikes \(rows 11, 51, 91"):
        preprocess_run(validate_run(df))


def test_rows_with_an_empty_cell_are_dropped_and_every_row_keeps_its_file_number(run, tmp_path) -> None:
    df = run.copy()
    df.loc[[20, 21, 150], "T_med_C"] = np.nan
    T = df["T_tank_C"].to_numpy().copy()
    T[300] += 4.0
    df["T_tank_C"] = T
    path = tmp_path / "run.csv"
    df.to_csv(path, index=False)
    checked = check_run(read_run(path), "again")
    assert len(checked) == len(run) - 3
    assert _changes(checked.attrs["preprocessing"]) == {("rows_dropped", None): [21, 22, 151],
                                                         ("spikes_replaced", "T_tank_C"): [301]}
    assert "3 row(s) with an empty cell dropped (rows 21, 22, 151)" in describe(checked.attrs["preprocessing"])


def test_rows_written_twice_are_dropped_and_named_with_the_files_numbers(run, tmp_path) -> None:
    """A sample the logger wrote twice (every column the same, time included) is dropped and named; the rows after
    it keep their file numbers, through an empty cell and a spike; a time repeated with other values is refused
    with the file's row and line."""
    df = run.copy()
    df.loc[[20], "T_med_C"] = np.nan
    T = df["T_tank_C"].to_numpy().copy()
    T[300] += 4.0
    df["T_tank_C"] = T
    twice = pd.concat([df.iloc[:10], df.iloc[[9]], df.iloc[10:200], df.iloc[[199, 199]], df.iloc[200:]],
                      ignore_index=True)
    path = tmp_path / "twice.csv"
    twice.to_csv(path, index=False)
    checked = check_run(read_run(path), "again")
    assert len(checked) == len(run) - 1
    # file rows: sample 9 is rows 10 and 11, sample 199 rows 201-203; sample 20 (empty) is row 22, sample 300 row 304
    assert _changes(checked.attrs["preprocessing"]) == {("rows_repeated", None): [11, 202, 203],
                                                         ("rows_dropped", None): [22],
                                                         ("spikes_replaced", "T_tank_C"): [304]}
    assert "3 repeated row(s) dropped (rows 11, 202, 203)" in describe(checked.attrs["preprocessing"])
    clean = df.drop(index=[20]).reset_index(drop=True)
    np.testing.assert_array_equal(checked["time_s"].to_numpy(), clean["time_s"].to_numpy())
    clash = twice.copy()
    clash.loc[10, "dp_mbar"] += 1.0  # file row 11 repeats row 10's time with another pressure
    path2 = tmp_path / "clash.csv"
    clash.to_csv(path2, index=False)
    with pytest.raises(DataError, match=r"time_s is not increasing at row 11 \(line 12\)"):
        read_run(path2)
    late = twice.copy()
    late.loc[210, "time_s"] = late.loc[209, "time_s"]  # after three dropped rows: named by the file's row
    late.to_csv(path2, index=False)
    with pytest.raises(DataError, match=r"time_s is not increasing at row 211 \(line 212\)"):
        read_run(path2)


# --------------------------------------------------------------------------- the opening's own conventions
def test_the_openings_noise_level_follows_its_convention() -> None:
    from valve_env.studies.conventions import store_on_change
    from valve_env.valveid.stiction import OPENING_RESOLUTION_FLOOR_MM, opening_noise
    from valve_env.valveid.temperature import noise_sd

    smooth = 0.8 + 0.3 * np.sin(np.arange(3000) / 150.0)
    noisy = smooth + 0.0024 * np.random.default_rng(1).standard_normal(smooth.size)
    n = opening_noise(noisy)
    assert n.method == "mad" and n.sd == noise_sd(noisy)  # a noisy opening keeps the sd it always had
    q = opening_noise(np.round(noisy / 0.01) * 0.01)
    assert q.method == "quantisation" and q.resolution == 0.01 and q.sd == pytest.approx(0.01 / np.sqrt(12))
    soc = opening_noise(store_on_change(noisy, 0.01))
    assert soc.method == "store_on_change" and 0.01 < soc.resolution < 0.0115 and soc.held_fraction > 0.8
    assert soc.sd == pytest.approx(soc.resolution / np.sqrt(3))
    flat = opening_noise(smooth)
    assert flat.method == "resolution_floor" and flat.sd == pytest.approx(OPENING_RESOLUTION_FLOOR_MM / np.sqrt(12))
    for each in (n, q, soc, flat):  # every convention says what it is, in the JSON's terms
        d = each.describe()
        assert d["method"] == each.method and d["noise_sd_mm"] == each.sd and d["why"]


def test_the_slips_of_a_quantised_opening_are_the_stems_not_the_quantums(run) -> None:
    """Quantised to a sixth of the band, the opening's quantum steps (the noise dithering between two levels) are
    not slips: its noise level is the quantisation's, not the 0 of its second differences. Taken at that 0, a
    dozen steps of one quantum were the slips, and the band their 0.01 mm."""
    from valve_env.valveid.stiction import slips

    x = run["x_mm"].to_numpy()
    raw = slips(x, 2.0)
    quantised = slips(np.round(x / 0.01) * 0.01, 2.0)
    assert abs(np.median(raw) - 0.06) < 0.01
    assert 1 <= quantised.size <= raw.size + 1 and abs(np.median(quantised) - 0.06) < 0.015
