"""The benchmark's normalised score on real evaluation output: 0 for self_acting, 1 for the oracle by
construction, pi between; the report's table and findings from run_cell records."""

from __future__ import annotations

import math

import pytest

from valve_env.tasks import benchmark as bm

SHORT = {"horizon_h": 1.0}


def _records(task: str, names: list[str], episodes: int = 2) -> list[dict]:
    cells = [bm.Cell(task, n, episodes, 0, dict(SHORT)) for n in names]
    cells.append(bm.Cell(task, bm.SMOOTH, episodes, 0, {**SHORT, **bm.smooth_valve(task)}))
    return [bm.run_cell(c) for c in cells]


def test_scores_are_zero_and_one_at_the_references_on_real_output() -> None:
    recs = _records("ThermoValveStickyValve-v0", ["self_acting", "pi", "pi_compensated"])
    table = bm.task_table(recs)
    cost = dict(zip(table["controller"], table["cost"], strict=True))
    assert cost["self_acting"] != cost["pi"]
    sc = bm.normalised_scores(cost, high="pi")
    assert sc["self_acting"] == 0.0 and sc["pi"] == 1.0
    expected = (cost["self_acting"] - cost["pi_compensated"]) / (cost["self_acting"] - cost["pi"])
    assert sc["pi_compensated"] == pytest.approx(expected)
    # without the oracle the table's scores are undefined, and the findings say there is no headroom figure
    assert table["score"].isna().all()
    found = bm.findings(table)["ThermoValveStickyValve-v0"]
    assert "headroom_pct" not in found and found["best_baseline"] in cost
    assert found["valve_change_pct"] == pytest.approx(
        100 * (found["pi_iae_Kh_task_valve"] / found["pi_iae_Kh_smooth_valve"] - 1))
    text = bm.markdown_report(table, bm.findings(table))
    assert "ThermoValveStickyValve-v0" in text and "valve matters" in text


def test_missing_or_equal_references_give_nan() -> None:
    assert all(math.isnan(v) for v in bm.normalised_scores({"pi": 1.0, "self_acting": 2.0}).values())
    assert all(math.isnan(v) for v in bm.normalised_scores({"oracle": 1.0, "self_acting": 1.0}).values())


def test_pi_lies_between_self_acting_and_the_oracle() -> None:
    """On real output with the oracle (the sampling MPC) on the district-heating task."""
    assert "oracle" in bm.known_controllers("ThermoValveDistrictHeating-v0")
    recs = _records("ThermoValveDistrictHeating-v0", ["self_acting", "pi", "oracle"], episodes=1)
    table = bm.task_table(recs)
    sc = dict(zip(table["controller"], table["score"], strict=True))
    assert sc["self_acting"] == 0.0 and sc["oracle"] == 1.0
    assert 0.0 < sc["pi"] < 1.0


def test_cells_cover_every_task_and_the_smooth_valve() -> None:
    cells = bm.make_cells(["ThermoValveStickyValve-v0", "ThermoValveDistrictHeating-v0"], ["self_acting", "pi"])
    keys = {c.key for c in cells}
    assert "ThermoValveStickyValve-v0__pi@smooth_valve" in keys and len(cells) == 6
    smooth = next(c for c in cells if c.controller == bm.SMOOTH)
    assert smooth.env_kwargs == {"valve": {"F_hmax": 1e-3, "effects": {"stiction": None}}}
    assert smooth.seed == bm.HELD_OUT_SEED
    # the smooth valve is the task's without its stiction (effects combine by name; null removes one)
    from valve_env.tasks import get_task

    assert get_task("ThermoValveStickyValve-v0").config().effects.names == ("stiction",)
    cfg = get_task(smooth.task).config(**smooth.env_kwargs)
    assert not cfg.effects and cfg.valve.F_hmax == 1e-3
    dh = next(c for c in cells if c.controller == bm.SMOOTH and c.task == "ThermoValveDistrictHeating-v0")
    assert dh.env_kwargs == {"valve": {"F_hmax": 1e-3, "effects": {}}}
    with pytest.raises(ValueError):
        bm.make_cells(["ThermoValveStickyValve-v0"], ["no_such_controller"])
