"""The evaluator: seeds shared across controllers, docs/reference.md, section 7 structure,
consistency with a single rollout, output files."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from valve_env.controllers import make_controller
from valve_env.evaluation import evaluate, evaluate_detailed, rollout, write_outputs
from valve_env.simulator import KPI_NAMES

SHORT = {"horizon_h": 3.0}


def test_spec_structure_and_determinism() -> None:
    s1 = evaluate(["self_acting", "pi"], "ThermoValve-v0", episodes=2, seed=5, env_kwargs=SHORT)
    s2 = evaluate(["self_acting", "pi"], "ThermoValve-v0", episodes=2, seed=5, env_kwargs=SHORT)
    assert s1 == s2
    assert set(s1) == {"env", "episodes", "results"} and s1["env"] == "ThermoValve-v0" and s1["episodes"] == 2
    for res in s1["results"].values():
        assert set(res) == {"return", "kpis"}
        assert set(res["return"]) == {"mean", "std"}
        assert list(res["kpis"]) == list(KPI_NAMES)
        assert all(set(v) == {"mean", "std"} for v in res["kpis"].values())


def test_episode_i_is_seed_plus_i_for_every_controller() -> None:
    _, per_ep = evaluate_detailed(["pi", "pi_compensated"], "ThermoValve-v0", episodes=3, seed=11, env_kwargs=SHORT)
    for name, df in per_ep.items():
        assert df["seed"].tolist() == [11, 12, 13]
        traj = rollout(make_controller(name), "ThermoValve-v0", seed=12, env_kwargs=SHORT)
        for k in KPI_NAMES:
            assert traj.attrs["kpis"][k] == pytest.approx(df.loc[1, k], rel=1e-9, abs=1e-12), (name, k)
        assert traj["reward"].sum() == pytest.approx(df.loc[1, "return"], abs=1e-5)


def test_scenario_selection_changes_results() -> None:
    base = evaluate(["self_acting"], "ThermoValve-v0", episodes=1, seed=0, env_kwargs=SHORT)
    cold = evaluate(["self_acting"], "ThermoValve-v0", episodes=1, seed=0, env_kwargs={**SHORT, "supply_C": 58.0})
    assert cold["results"]["self_acting"]["kpis"]["rmse_K"]["mean"] != base["results"]["self_acting"]["kpis"][
        "rmse_K"]["mean"]


def test_bad_input_is_rejected() -> None:
    with pytest.raises(ValueError, match="unknown env id"):
        evaluate(["pi"], "Nope-v0", episodes=1)
    with pytest.raises(ValueError, match="unknown environment option"):
        evaluate(["pi"], "ThermoValve-v0", episodes=1, env_kwargs={"nonsense": 1})
    with pytest.raises(ValueError, match="episodes"):
        evaluate(["pi"], "ThermoValve-v0", episodes=0)


def test_outputs_are_written(tmp_path) -> None:
    summary, per_ep = evaluate_detailed(["self_acting", "pi"], "ThermoValve-v0", episodes=2, seed=0,
                                        env_kwargs=SHORT)
    trajs = {n: rollout(make_controller(n), "ThermoValve-v0", 0, SHORT) for n in per_ep}
    paths = write_outputs(summary, per_ep, tmp_path, trajs)
    for p in paths.values():
        assert p.is_file() and p.stat().st_size > 0
    table = paths["table"].read_text()
    assert "| pi |" in table and "rmse_K" in table
    csv = pd.read_csv(paths["summary_csv"])
    assert csv["controller"].tolist() == ["self_acting", "pi"]
    assert np.isclose(csv.loc[1, "rmse_K_mean"], summary["results"]["pi"]["kpis"]["rmse_K"]["mean"])
