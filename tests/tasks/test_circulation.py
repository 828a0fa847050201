"""The hot-water circulation loop (physics.tank.circulation_heat) and ThermoValveStickyCirculation-v0, the sticky
task whose stem works mid-stroke (docs/tasks.md, "ThermoValveStickyCirculation-v0")."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import valve_env  # noqa: F401
from valve_env import simulator as sim
from valve_env.config import make_config
from valve_env.controllers import make_controller
from valve_env.evaluation import rollout
from valve_env.evaluation.evaluator import run_episodes
from valve_env.params import TankParams, ValveParams
from valve_env.physics.tank import circulation_heat, circulation_return_factor
from valve_env.physics.valve import flow_kgh
from valve_env.tasks import get_task

SEAT, CIRC = "ThermoValveStickyValve-v0", "ThermoValveStickyCirculation-v0"


def test_circulation_heat_is_flow_times_cp_times_the_loop_s_drop() -> None:
    """Two tanks of 8 layers, the return into layer 4: the layers' heat sums to -m cp (T_top - T_ret),
    the reported loop loss is m cp (T_top - T_ret), T_ret follows the cooling pipe, and only the
    return's layer and those above it change."""
    T = np.stack([np.linspace(40.0, 60.0, 8), np.linspace(50.0, 62.0, 8)], axis=1)
    m, UA, T_amb, cp, k = 110.0 / 3600.0, 16.0, 20.0, 4180.0, 4
    Q = np.zeros_like(T)
    total = np.zeros(2)
    circulation_heat(T, m, UA, T_amb, k, cp, Q, total)
    T_ret = T_amb + (T[-1] - T_amb) * np.exp(-UA / (m * cp))
    np.testing.assert_allclose(total, m * cp * (T[-1] - T_ret), rtol=1e-12)
    np.testing.assert_allclose(Q.sum(axis=0), -m * cp * (T[-1] - T_ret), rtol=1e-12)
    assert np.all(Q[:k] == 0.0)
    np.testing.assert_allclose(Q[k], m * cp * (T_ret - T[k]), rtol=1e-12)
    # the task's loop: 0.6 kW at a 60 degC outlet, a drop under W 551's 5 K, the return above 55 degC
    drop = 40.0 * (1.0 - circulation_return_factor(m, UA, cp))
    assert 4.0 < drop < 5.0 and 550.0 < m * cp * drop < 650.0
    assert circulation_return_factor(0.0, UA, cp) == 0.0


def test_the_loop_is_off_by_default_and_v1_without_it_is_v0_bit_for_bit() -> None:
    assert TankParams().circ_kgh == 0.0 and sim.pack_plant(make_config(None))[sim.P_CIRC_M] == 0.0
    kw = {"horizon_h": 2.0}
    a = rollout(make_controller("pi", SEAT), SEAT, 3, kw)
    b = rollout(make_controller("pi", CIRC), CIRC, 3, {**kw, "tank": {"circ_kgh": 0.0}})
    np.testing.assert_array_equal(a.to_numpy(), b.to_numpy())


def test_v1_energy_account_closes_with_the_loop_s_loss() -> None:
    """3 h of the circulation task under pi: heat in = stored + losses + draws, and the losses are the standing loss
    plus the loop's m cp (T_top - T_ret), about 0.6 kW at the outlet's 60 degC."""
    env = gym.make(CIRC, horizon_h=3.0, max_episode_steps=360)
    ctrl = make_controller("pi", CIRC)
    obs, _ = env.reset(seed=1)
    state, start, done = None, True, False
    while not done:
        act, state = ctrl.predict(obs, state, np.array([start]), deterministic=True)
        start = False
        obs, _, term, trunc, _ = env.step(act)
        done = term or trunc
    acc = env.unwrapped.energy_account()
    assert acc["heat_in_J"] == pytest.approx(acc["stored_J"] + acc["losses_J"] + acc["draws_J"], rel=1e-9)
    t = get_task(CIRC).config().tank
    m = t.circ_kgh / 3600.0
    loop_W = m * t.cp * (60.0 - 20.0) * (1.0 - circulation_return_factor(m, t.circ_UA, t.cp))
    standing_W = t.UA_loss * (60.0 - 20.0)
    assert acc["losses_J"] / 10800.0 == pytest.approx(loop_W + standing_W, rel=0.05)


def test_v1_stem_works_mid_stroke_at_night() -> None:
    """02:00-05:00 (no draws on cycle M), seeds 0-1: pi's mean primary flow is at least 1.5 stiction
    bands' flow (on v0 it is an eighth of one), so the stem works away from its seat."""
    band = get_task(CIRC).sections["valve"]["effects"]["stiction"]["band_mm"]
    q_band = flow_kgh(band, 100.0, ValveParams().to_array()) - flow_kgh(0.0, 100.0, ValveParams().to_array())
    for seed in (0, 1):
        tr = rollout(make_controller("pi", CIRC), CIRC, seed, {"horizon_h": 5.0})
        night = tr[(tr["t_h"] > 2.0) & (tr["t_h"] < 5.0)]
        assert night["q_primary_kgh"].mean() >= 1.5 * q_band
        assert night["x_mm"].mean() >= 1.5 * band


def test_the_wear_aware_pi_cuts_pi_s_error_and_reversals_on_the_circulation_task() -> None:
    """8 h of the circulation task, tuning seeds 0-2: the event-based, SIMC-retuned pi_wear cuts both pi's iae and its
    stem reversals (on v0, at the seat, no controller does both: docs/controllers.md)."""
    kw = {"horizon_h": 8.0}
    res = {n: run_episodes(make_controller(n, CIRC), CIRC, 3, 0, env_kwargs=kw).sum(numeric_only=True)
           for n in ("pi", "pi_wear")}
    assert res["pi_wear"]["iae_Kh"] < 0.8 * res["pi"]["iae_Kh"]
    assert res["pi_wear"]["reversals"] < res["pi"]["reversals"]
    assert res["pi_wear"]["tdis_Kh"] <= res["pi"]["tdis_Kh"] + 1e-9
