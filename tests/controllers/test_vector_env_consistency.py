"""The controllers' batched predict driving the native batched env
(``gym.make_vec``) gives the evaluator's per-episode KPIs and returns."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import valve_env  # noqa: F401
from valve_env.controllers import make_controller
from valve_env.evaluation import evaluate_detailed

pytest.importorskip("valve_env.envs.vector")

N = 3
KW = {"horizon_h": 6.0}


@pytest.mark.parametrize("name", ["pi", "pi_compensated"])
def test_batched_predict_on_the_vector_env_matches_the_evaluator(name: str) -> None:
    n_steps = 6 * 120
    venv = gym.make_vec("ThermoValve-v0", num_envs=N, vectorization_mode="vector_entry_point", **KW)
    ctrl = make_controller(name)
    obs, _ = venv.reset(seed=0)
    state = None
    start = np.ones(N, dtype=bool)
    ret = np.zeros(N)
    info: dict = {}
    for _ in range(n_steps):
        act, state = ctrl.predict(obs, state, start)
        start = np.zeros(N, dtype=bool)
        obs, r, _, _, info = venv.step(act)
        ret += r
    venv.close()
    _, per_ep = evaluate_detailed([name], "ThermoValve-v0", N, 0, KW)
    np.testing.assert_allclose(np.asarray(info["kpis"]["rmse_K"]), per_ep[name]["rmse_K"], rtol=1e-9)
    np.testing.assert_allclose(np.asarray(info["kpis"]["tdis_Kh"]), per_ep[name]["tdis_Kh"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ret, per_ep[name]["return"], atol=1e-5)
