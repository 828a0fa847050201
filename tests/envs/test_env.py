"""The ThermoValve environments: API, determinism, first law, actions, errors."""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import valve_env
from valve_env import ConfigError

IDS = valve_env.ENV_IDS


def rollout(env: gym.Env, seed: int, actions: np.ndarray | None = None, n: int | None = None):
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    obs_l, rew_l, info_l = [obs], [], []
    k = 0
    while True:
        a = actions[k] if actions is not None else env.action_space.sample()
        obs, r, term, trunc, info = env.step(a)
        obs_l.append(obs)
        rew_l.append(r)
        info_l.append(info)
        k += 1
        if term or trunc or (n is not None and k >= n):
            break
    return np.array(obs_l), np.array(rew_l), info_l


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_and_sb3_env_checkers(env_id):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the "use a [-1, 1] action space" advice: actions are physical units
        env = gym.make(env_id, render_mode="rgb_array")
        check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(gym.make(env_id))


@pytest.mark.parametrize("env_id", IDS)
def test_make_needs_no_argument_and_has_a_time_limit(env_id):
    env = gym.make(env_id)
    assert env.spec is not None and env.spec.max_episode_steps == 2880
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert {"x_mm", "F_h_N", "T_g_C"} <= set(info)


@pytest.mark.parametrize("env_id", IDS)
def test_seeded_rollouts_are_bit_identical(env_id):
    o1, r1, i1 = rollout(gym.make(env_id), seed=7, n=500)
    o2, r2, i2 = rollout(gym.make(env_id), seed=7, n=500)
    assert np.array_equal(o1, o2) and np.array_equal(r1, r2)
    assert [i["F_h_N"] for i in i1] == [i["F_h_N"] for i in i2]


def test_a_different_seed_gives_a_different_stochastic_scenario():
    env = gym.make("ThermoValve-v0")
    env.reset(seed=1)
    s1 = env.unwrapped.get_state().scenario
    env.reset(seed=2)
    s2 = env.unwrapped.get_state().scenario
    assert not np.array_equal(s1[:, 0], s2[:, 0])  # draw timetables differ
    # the tabled cycle without randomness is the same for every seed
    env = gym.make("ThermoValve-v0", stochastic_draws=False, T_init_spread_K=0.0)
    env.reset(seed=1)
    d1 = env.unwrapped.get_state().scenario
    env.reset(seed=2)
    assert np.array_equal(d1, env.unwrapped.get_state().scenario)


def test_env_survives_pickling_mid_episode():
    env = gym.make("ThermoValve-v0")
    env.reset(seed=3)
    for _ in range(100):
        env.step(np.array([61.0], np.float32))
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(50):
        a = np.array([58.0], np.float32)
        o1, r1, *_ = env.step(a)
        o2, r2, *_ = clone.step(a)
        assert np.array_equal(o1, o2) and r1 == r2


def test_first_law_closes_over_a_day_within_0_1_percent():
    env = gym.make("ThermoValveDual-v0", tapping_profile="L")
    _, _, infos = rollout(env, seed=11)
    e = infos[-1]["energy"]
    assert e["heat_in_J"] > 1e7  # the day used real heat
    balance = e["stored_J"] + e["losses_J"] + e["draws_J"]
    assert abs(e["heat_in_J"] - balance) <= 1e-3 * e["heat_in_J"]
    kpis = infos[-1]["kpis"]
    assert set(kpis) == {
        "rmse_K", "iae_Kh", "tdis_Kh", "unmet_kWh", "heat_kWh", "pump_kWh", "return_C", "travel_mm", "reversals",
    }
    assert kpis["heat_kWh"] == pytest.approx(e["heat_in_J"] / 3.6e6)
    # the draws took the tapping cycle's energy (L: 11.655 kWh, +-20 % seeded variation)
    assert 0.6 * 11.655 < e["draws_J"] / 3.6e6 < 1.4 * 11.655


@pytest.mark.parametrize(
    "env_id,low,high",
    [
        ("ThermoValve-v0", [45.0], [75.0]),
        ("ThermoValvePressure-v0", [0.0], [300.0]),  # the self-acting valve absorbs moderate dp changes
        ("ThermoValveDual-v0", [45.0, 100.0], [75.0, 100.0]),
        ("ThermoValveDual-v0", [62.0, 0.0], [62.0, 300.0]),
    ],
)
def test_every_action_dimension_moves_the_plant(env_id, low, high):
    results = []
    for a in (low, high):
        env = gym.make(env_id)
        acts = np.tile(np.array(a, np.float32), (2880, 1))
        obs, _, infos = rollout(env, seed=5, actions=acts)
        results.append((infos[-1]["kpis"]["heat_kWh"], obs[:, 0].mean()))
    (heat_lo, tout_lo), (heat_hi, tout_hi) = results
    assert abs(heat_hi - heat_lo) > 0.05 * max(heat_lo, heat_hi)
    assert abs(tout_hi - tout_lo) > 1.0


def test_hidden_state_is_in_info_not_in_the_observation():
    env = gym.make("ThermoValve-v0")
    obs, info = env.reset(seed=0)
    hs = env.unwrapped.hidden_state
    assert info["F_h_N"] == hs["F_h_N"] and info["x_mm"] == hs["x_mm"]
    assert len(obs) == len(valve_env.envs.OBS_NAMES) == 12


def test_friction_hysteresis_is_exercised_and_bounded_in_an_episode():
    env = gym.make("ThermoValve-v0")
    _, _, infos = rollout(env, seed=4)
    F = np.array([i["F_h_N"] for i in infos])
    assert np.abs(F).max() <= valve_env.ValveParams().F_hmax + 1e-12
    assert F.max() > 0.5 and F.min() < -0.5  # both directions visited


def test_out_of_range_actions_are_clipped_and_flagged():
    env = gym.make("ThermoValve-v0")
    env.reset(seed=0)
    obs, r, *_, info = env.step(np.array([500.0], np.float32))
    assert info.get("action_clipped") is True
    assert obs[10] == pytest.approx(80.0)
    assert np.all(np.isfinite(obs)) and np.isfinite(r)


@pytest.mark.parametrize("bad", [[np.nan], [np.inf], [-np.inf]])
def test_non_finite_actions_raise_a_clear_error(bad):
    env = gym.make("ThermoValve-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array(bad, np.float32))


def test_wrong_action_shape_raises():
    env = gym.make("ThermoValveDual-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.array([60.0], np.float32))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6)), min_size=1, max_size=40))
def test_no_nan_in_observations_for_any_finite_actions(actions):
    env = gym.make("ThermoValveDual-v0")
    env.reset(seed=0)
    for a in actions:
        obs, r, *_ = env.step(np.array(a, np.float32))
        assert np.all(np.isfinite(obs)) and np.isfinite(r)
        assert env.observation_space.contains(obs)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"tapping_profile": "XXL"}, "tapping_profile"),
        ({"supply_C": float("nan")}, "supply_C"),
        ({"valve": {"sigma": -2.0}}, "sigma"),
        ({"valve": {"not_a_field": 1.0}}, "not_a_field"),
        ({"tank": {"n_layers": 4}}, "n_layers"),
        ({"dt_s": 0.0}, "dt_s"),
        ({"bogus": 1}, "bogus"),
        ({"config": "does/not/exist.yaml"}, "does not exist"),
    ],
)
def test_invalid_configs_raise_a_clear_error(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        gym.make("ThermoValve-v0", **kwargs)


def test_config_files_and_keywords_select_scenarios(tmp_path):
    cfg = tmp_path / "my.yaml"
    cfg.write_text("scenario:\n  tapping_profile: S\n  supply_C: 60\nvalve:\n  F_hmax: 2.0\n")
    env = gym.make("ThermoValve-v0", config=str(cfg), supply_C=65.0)
    c = env.unwrapped.cfg
    assert c.scenario.tapping_profile == "S" and c.scenario.supply_C == 65.0 and c.valve.F_hmax == 2.0
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenario: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        gym.make("ThermoValve-v0", config=str(bad))


def test_shipped_scenario_configs_load():
    from valve_env.data import scenario_files

    files = scenario_files()
    assert len(files) >= 4
    for name in files:
        env = gym.make("ThermoValve-v0", config=name)
        obs, _ = env.reset(seed=0)
        assert np.all(np.isfinite(obs))


def test_sensor_noise_and_dead_time_are_wrappers():
    from valve_env.wrappers import ObservationDelay, SensorNoise

    env = gym.make("ThermoValve-v0", sensors={"noise_K": 0.05, "dead_time_steps": 2})
    chain = []
    e = env
    while hasattr(e, "env"):
        chain.append(type(e))
        e = e.env
    assert SensorNoise in chain and ObservationDelay in chain
    clean = gym.make("ThermoValve-v0")
    o_noisy, _ = env.reset(seed=1)
    o_clean, _ = clean.reset(seed=1)
    assert not np.array_equal(o_noisy[:5], o_clean[:5])
    assert np.allclose(o_noisy[:5], o_clean[:5], atol=0.5)
    # the physics is untouched: same hidden state under the same actions
    for _ in range(20):
        env.step(np.array([60.0], np.float32))
        clean.step(np.array([60.0], np.float32))
    assert env.unwrapped.hidden_state == clean.unwrapped.hidden_state


def test_state_can_be_saved_and_restored_for_branching():
    env = gym.make("ThermoValve-v0").unwrapped
    env.reset(seed=9)
    for _ in range(300):
        env.step(np.array([60.0], np.float32))
    snap = env.get_state()
    branch_a = [env.step(np.array([55.0], np.float32))[0] for _ in range(100)]
    env.set_state(snap)
    branch_b = [env.step(np.array([55.0], np.float32))[0] for _ in range(100)]
    assert np.array_equal(np.array(branch_a), np.array(branch_b))
    env.set_state(snap)
    other = [env.step(np.array([75.0], np.float32))[0] for _ in range(100)]
    assert not np.array_equal(np.array(branch_a), np.array(other))


def test_render_rgb_array():
    env = gym.make("ThermoValveDual-v0", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(50):
        env.step(env.action_space.sample())
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8
    assert img.std() > 10  # something was drawn


def test_user_valve_parameters_reach_the_physics():
    env = gym.make("ThermoValve-v0", valve={"F_hmax": 3.0, "sigma": 20.0})
    _, _, infos = rollout(env, seed=4, n=2000)
    assert max(abs(i["F_h_N"]) for i in infos) > 1.31


def test_multi_day_horizons_repeat_the_tapping_cycle_every_day():
    from valve_env.scenario import ScenarioParams, make_scenario

    days = 3
    sc = make_scenario(ScenarioParams(), np.random.default_rng(0), 2880 * days, 30.0, 10.0, 4180.0)
    daily_kWh = [sc.draw_W[d * 2880 : (d + 1) * 2880].sum() * 30.0 / 3.6e6 for d in range(days)]
    for e in daily_kWh:
        assert 0.6 * 5.845 < e < 1.4 * 5.845  # cycle M each day, +-20 % seeded variation
    assert len(set(daily_kWh)) == days  # each day has its own randomness
    env = gym.make("ThermoValve-v0", horizon_h=48.0, max_episode_steps=5760)
    _, _, infos = rollout(env, seed=0, actions=np.full((5760, 1), 60.0, np.float32))
    assert len(infos) == 5760 and "kpis" in infos[-1]
