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


def _hand_records(costs: dict[str, list[float]], seeds: list[int], task: str = "T") -> list[dict]:
    """run_cell-shaped records with the given per-episode costs (the oracle split per seed, as make_cells does)."""
    recs = []
    for name, cs in costs.items():
        eps = [{"episode": i, "seed": s, "return": -c, "iae_Kh": 1.0} for i, (s, c) in enumerate(zip(seeds, cs,
                                                                                                   strict=True))]
        if name == "oracle":
            recs += [{"cell": {"task": task, "controller": name}, "episodes": [e]} for e in eps]
        else:
            recs.append({"cell": {"task": task, "controller": name}, "episodes": eps})
    return recs


def test_gap_score_and_its_intervals_on_a_hand_made_case() -> None:
    """pi costs 3, 5, 4, 4 (mean 4), the oracle 1, 2, 1, 2 (mean 1.5); ``good`` closes 60 % of pi's gap on
    every episode, ``noisy`` 58 % on average; self_acting costs 10, 12, 11, 11 (mean 11)."""
    import json

    import numpy as np

    seeds = [5000, 5001, 5002, 5003]
    pi, orc = np.array([3.0, 5.0, 4.0, 4.0]), np.array([1.0, 2.0, 1.0, 2.0])
    good = pi - 0.6 * (pi - orc)
    noisy = good + np.array([0.3, -0.2, 0.1, 0.0])
    table = bm.task_table(_hand_records({"self_acting": [10.0, 12.0, 11.0, 11.0], "pi": list(pi),
                                         "good": list(good), "noisy": list(noisy), "oracle": list(orc)}, seeds))
    r = table.set_index("controller")
    # the gap score: (4 - cost) / (4 - 1.5); the old score: (11 - cost) / (11 - 1.5), kept beside it
    assert r.loc["pi", "gap_score"] == 0.0 and r.loc["oracle", "gap_score"] == 1.0
    assert r.loc["good", "gap_score"] == pytest.approx(0.6)
    assert r.loc["noisy", "gap_score"] == pytest.approx((4.0 - 2.55) / 2.5)
    assert r.loc["self_acting", "gap_score"] == pytest.approx(-2.8)
    assert r.loc["pi", "score"] == pytest.approx(7.0 / 9.5) and r.loc["self_acting", "score"] == 0.0
    # the cost's t-interval: 4 +- t(0.975, 3) sd / sqrt(4), sd = sqrt(2/3)
    half = 3.182446305284263 * math.sqrt(2.0 / 3.0) / 2.0
    assert (r.loc["pi", "cost_ci_lo"], r.loc["pi", "cost_ci_hi"]) == pytest.approx((4.0 - half, 4.0 + half))
    # the bootstrap is paired over the episodes: good closes 60 % on each, so every resample gives 0.6
    assert (r.loc["good", "gap_score_ci_lo"], r.loc["good", "gap_score_ci_hi"]) == pytest.approx((0.6, 0.6))
    lo, hi = r.loc["noisy", "gap_score_ci_lo"], r.loc["noisy", "gap_score_ci_hi"]
    assert lo < r.loc["noisy", "gap_score"] < hi and hi - lo < 0.5
    # the references' own scores are 0 and 1 exactly
    assert (r.loc["pi", "gap_score_ci_lo"], r.loc["oracle", "gap_score_ci_hi"]) == (0.0, 1.0)
    # reproducible (seeded resampling)
    assert bm.task_table(_hand_records({"pi": list(pi), "noisy": list(noisy), "oracle": list(orc)}, seeds)).set_index(
        "controller").loc["noisy", "gap_score_ci_lo"] == lo
    # the report shows the cost and the gap score with their intervals beside the old score; the JSON holds them
    text = bm.markdown_report(table, bm.findings(table))
    assert "| good | 2.5 [1.51, 3.49] | 0.6 [0.6, 0.6] | 0.895 |" in text, text
    rows = {row["controller"]: row for row in json.loads(bm.report_json(table, {}, {}))["table"]}
    assert rows["good"]["gap_score"] == pytest.approx(0.6) and rows["noisy"]["gap_score_ci_lo"] == pytest.approx(lo)
    assert rows["pi"]["score"] == pytest.approx(7.0 / 9.5)


def test_gap_score_is_nan_without_its_references_or_a_second_episode() -> None:
    table = bm.task_table(_hand_records({"self_acting": [2.0, 3.0], "pi": [1.0, 2.0]}, [0, 1]))
    assert table["gap_score"].isna().all() and table["gap_score_ci_lo"].isna().all()
    one = bm.task_table(_hand_records({"pi": [2.0], "good": [1.5], "oracle": [1.0]}, [0])).set_index("controller")
    assert one.loc["good", "gap_score"] == pytest.approx(0.5)
    assert math.isnan(one.loc["good", "gap_score_ci_lo"]) and math.isnan(one.loc["good", "cost_ci_lo"])
    assert "| good | 1.5 | 0.5 | n/a |" in bm.markdown_report(one.reset_index(), {})
