"""Reading and checking loop records: both formats, the one-line errors, manual-mode segments."""

from __future__ import annotations

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
    ({"pv": np.where(np.arange(300) == 17, np.nan, 50.0)}, "column pv has 1 NaN"),
    ({"time_s": np.r_[np.arange(100) * 10.0, np.arange(200) * 10.0]}, "time is not strictly increasing at sample 101"),
    ({"op": np.full(300, 42.0)}, "constant OP"),
])
def test_bad_records_name_the_problem(tmp_path: Path, override: dict, needle: str) -> None:
    p = _write_csv(tmp_path / "bad.csv", **override)
    with pytest.raises(LoopDataError, match=needle) as exc:
        read_loop(p)
    assert "\n" not in str(exc.value)


def test_too_short_and_missing_column(tmp_path: Path) -> None:
    with pytest.raises(LoopDataError, match="too short a record"):
        read_loop(_write_csv(tmp_path / "short.csv", n=50))
    p = tmp_path / "nocol.csv"
    p.write_text("time_s,sp,pv\n0,1,2\n")
    with pytest.raises(LoopDataError, match="missing column"):
        read_loop(p)


def test_manual_mode_dropped_with_a_note(tmp_path: Path) -> None:
    mode = np.ones(400)
    mode[:60] = 0.0
    loop = read_loop(_write_csv(tmp_path / "m.csv", n=400, mode=mode))
    assert loop.n == 340
    assert loop.time_s[0] == 0.0
    assert any("manual mode" in note for note in loop.notes)
    mode[150:] = 0.0
    with pytest.raises(LoopDataError, match="too short a record in automatic mode"):
        read_loop(_write_csv(tmp_path / "m2.csv", n=400, mode=mode))
