"""Loops from the environment: a PI on the sticky-valve task, its OP, PV and SP written as the loop CSV,
diagnosed (docs/loops.md, "Loops from the environment"). The valves are built explicitly through the
env's ``valve={"effects": {"stiction": {"band_mm": ...}}}`` (0.1 mm sticky, 0 smooth), not the task's band."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from studies import env_loop_study
from valve_env.loops.diagnose import LoopDiagnosis, diagnose_loop
from valve_env.loops.envloop import record_env_loop
from valve_env.loops.io import check_loop, read_loop

STICKY_MM = 0.1  # 5 % of the 2 mm stroke (docs/loops.md)


def test_env_loop_record_is_a_valid_loop_csv() -> None:
    smooth = record_env_loop(0.0, seed=0, hours=1.0, warmup_h=2.5)
    sticky = record_env_loop(STICKY_MM, seed=0, hours=1.0, warmup_h=2.5)
    for loop in (smooth, sticky):
        assert loop.n == 120 and loop.dt == 30.0
        assert np.all((loop.op >= 0) & (loop.op <= 100))
        assert 40.0 < loop.sp.mean() < 80.0
        cols = {"time_s": loop.time_s, "sp": loop.sp, "pv": loop.pv, "op": loop.op}
        assert check_loop(cols).n == loop.n
    # the sticky stem changes the loop's behaviour
    assert not np.allclose(smooth.op, sticky.op)


def test_env_loop_day_long_record() -> None:
    """A day at 30 s is 2880 samples from 0 s, the warm-up cut off; a record of no length is refused by name."""
    day = record_env_loop(0.0, seed=0, hours=24.0, warmup_h=1.0)
    assert day.n == 2880 and day.dt == 30.0 and day.time_s[0] == 0.0
    with pytest.raises(ValueError, match="hours must be > 0"):
        record_env_loop(0.0, seed=0, hours=0.0)


def test_env_loop_study_hours_reach_the_record(capsys: pytest.CaptureFixture[str]) -> None:
    """``studies/env_loop_study.py --hours/--warmup-h`` set the record's length (its summary line names them);
    a record of no length is one argparse error."""
    a, seeds = env_loop_study.parse_env_args("t", ["--seeds", "3,4", "--hours", "24", "--warmup-h", "2"])
    assert (a.hours, a.warmup_h, seeds) == (24.0, 2.0, [3, 4])
    with pytest.raises(SystemExit):
        env_loop_study.parse_env_args("t", ["--hours", "0"])
    assert "--hours must be > 0" in capsys.readouterr().err


def test_env_loop_takes_the_valves_friction() -> None:
    """``F_hmax`` sets the valve's Dahl friction on the recorded stem (the smooth stem's own hysteresis band,
    docs/loops.md, "Loops from the environment"); an out-of-range value is refused in one line naming the field, and the
    studies' ``--f-hmax`` reaches it."""
    paper = record_env_loop(0.0, seed=0, hours=1.0, warmup_h=2.5)
    light = record_env_loop(0.0, seed=0, hours=1.0, warmup_h=2.5, F_hmax=0.01)
    assert light.n == paper.n and not np.allclose(light.op, paper.op)
    from valve_env.params import ConfigError

    with pytest.raises(ConfigError, match="valve.F_hmax must be in"):
        record_env_loop(0.0, seed=0, hours=0.5, warmup_h=0.5, F_hmax=-1.0)
    a, _ = env_loop_study.parse_env_args("t", ["--f-hmax", "0.01"])
    assert a.f_hmax == 0.01


def _diagnosis_via_csv(band_mm: float, seed: int, tmp_path: Path) -> LoopDiagnosis:
    loop = record_env_loop(band_mm, seed=seed)
    path = tmp_path / f"env-{band_mm:g}-{seed}.csv"
    path.write_text(loop.to_csv_text())
    return diagnose_loop(read_loop(path), rule="learned")  # the environment's loops: the learned rule (docs/loops.md)


def _diagnose_via_csv(band_mm: float, seed: int, tmp_path: Path) -> str:
    return _diagnosis_via_csv(band_mm, seed, tmp_path).cause


def test_env_loop_smooth_is_not_stiction(tmp_path: Path) -> None:
    assert _diagnose_via_csv(0.0, 0, tmp_path) != "stiction"


@pytest.mark.slow
def test_env_acceptance_mid_stroke(tmp_path: Path) -> None:
    """The acceptance on the mid-stroke task (docs/loops.md, "Loops from the environment"): a PI (Kp 5, Ti 1500 s)
    on ThermoValveStickyCirculation-v0, seeds 700-711: the sticky stem named stiction on at least 11 of 12 records,
    the smooth one on at most 1 (about 10 min; studies/env_loop_study.py prints the same)."""
    sticky = smooth = 0
    for seed in range(700, 712):
        for band in (STICKY_MM, 0.0):
            loop = record_env_loop(band, seed=seed, env_id="ThermoValveStickyCirculation-v0", Kp=5.0, Ti_s=1500.0)
            named = diagnose_loop(loop, rule="learned").cause == "stiction"
            sticky += named and band > 0
            smooth += named and band == 0
    assert sticky >= 11 and smooth <= 1


def test_env_loop_pi_gains_override() -> None:
    """``Kp``/``Ti_s`` reach the PI: a slower PI moves the setting less on the same record."""
    stored = record_env_loop(0.0, seed=0, hours=0.5, warmup_h=0.5, env_id="ThermoValveStickyCirculation-v0")
    slow = record_env_loop(0.0, seed=0, hours=0.5, warmup_h=0.5, env_id="ThermoValveStickyCirculation-v0",
                           Kp=1.0, Ti_s=3000.0)
    assert np.abs(np.diff(slow.op)).sum() < 0.5 * np.abs(np.diff(stored.op)).sum()
