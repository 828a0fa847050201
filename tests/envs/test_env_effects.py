"""The valve's named effects in the environments (docs/reference.md, "The valve file"): config checks,
the env guarantees with every effect on, single against batched, hidden states in info."""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import valve_env
from valve_env import ConfigError
from valve_env.effects import REGISTRY

ALL = {
    "stiction": {"band_mm": 0.04},
    "sensor_lag": {"tau_s": 90.0},
    "medium_temperature": {"beta": 0.12},
    "setpoint_drift": {"rate_MPa_per_h": 1.0e-4},
}
STICTION = {"stiction": {"band_mm": 0.04}}
SHORT = {"horizon_h": 2.0, "max_episode_steps": 240}


def _actions(env: gym.Env, n: int, seed: int) -> np.ndarray:
    env.action_space.seed(seed)
    return np.array([env.action_space.sample() for _ in range(n)])


@pytest.mark.parametrize("effects", [STICTION, ALL], ids=["stiction", "all"])
@pytest.mark.parametrize("env_id", valve_env.ENV_IDS)
def test_env_checker_determinism_and_hidden_states(env_id: str, effects: dict) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(gym.make(env_id, valve={"effects": effects}).unwrapped)
    runs = []
    for _ in range(2):
        env = gym.make(env_id, valve={"effects": effects}, **SHORT)
        obs, info = env.reset(seed=5)
        assert {"stuck", "x_demand_mm", "p_set_MPa"} <= set(info)
        acts = _actions(env, 240, 5)
        traj = [env.step(a) for a in acts]
        runs.append(np.array([[*o, r, i["x_mm"], i["stuck"]] for o, r, _, _, i in traj]))
    assert np.array_equal(runs[0], runs[1])
    # the stem sticks part of the time and slips the rest
    assert 0.05 < runs[0][:, -1].mean() < 0.999


def test_base_valve_info_has_no_effect_keys() -> None:
    _, info = gym.make("ThermoValve-v0").reset(seed=0)
    assert not {"stuck", "x_demand_mm", "p_set_MPa"} & set(info)


@pytest.mark.parametrize("env_id", valve_env.ENV_IDS)
def test_batched_equals_single_with_every_effect(env_id: str) -> None:
    n = 3
    kw = {"valve": {"effects": ALL}, "horizon_h": 0.5}
    native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kw)
    sync = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", **kw)
    o1, i1 = native.reset(seed=2)
    o2, i2 = sync.reset(seed=2)
    np.testing.assert_allclose(o1, o2, rtol=1e-9)
    rng = np.random.default_rng(0)
    lo, hi = native.single_action_space.low, native.single_action_space.high
    for k in range(130):  # two autoresets
        a = rng.uniform(lo, hi, size=(n, lo.shape[0])).astype(np.float32)
        o1, r1, _, t1, i1 = native.step(a)
        o2, r2, _, t2, i2 = sync.step(a)
        np.testing.assert_allclose(o1, o2, rtol=1e-9, err_msg=f"step {k}")
        np.testing.assert_allclose(r1, r2, rtol=1e-9, atol=1e-12)
        assert np.array_equal(t1, t2)
        for key in ("x_mm", "F_h_N", "T_g_C", "stuck", "x_demand_mm", "p_set_MPa"):
            np.testing.assert_allclose(i1[key], i2[key], rtol=1e-9, atol=1e-12, err_msg=f"{key} at step {k}")


def test_pickling_and_state_snapshots_with_every_effect() -> None:
    env = gym.make("ThermoValveDual-v0", valve={"effects": ALL})
    env.reset(seed=3)
    for _ in range(100):
        env.step(np.array([61.0, 120.0], np.float32))
    clone = pickle.loads(pickle.dumps(env))
    u = env.unwrapped
    snap = u.get_state()
    a = np.array([57.0, 180.0], np.float32)
    branch = [env.step(a)[0] for _ in range(60)]
    assert np.array_equal(np.array(branch), np.array([clone.step(a)[0] for _ in range(60)]))
    u.set_state(snap)
    assert np.array_equal(np.array(branch), np.array([env.step(a)[0] for _ in range(60)]))


def test_first_law_closes_with_every_effect() -> None:
    env = gym.make("ThermoValveDual-v0", valve={"effects": ALL}, tapping_profile="L")
    env.reset(seed=11)
    acts = _actions(env, 2880, 11)
    for a in acts:
        *_, trunc, info = env.step(a)
    assert trunc
    e = info["energy"]
    assert e["heat_in_J"] > 1e7
    assert abs(e["heat_in_J"] - (e["stored_J"] + e["losses_J"] + e["draws_J"])) <= 1e-3 * e["heat_in_J"]


def test_effects_from_yaml_and_keyword_agree(tmp_path) -> None:
    p = tmp_path / "v.yaml"
    p.write_text("valve:\n  F_hmax: 1.5\n  effects:\n    stiction: {band_mm: 0.05, jump_mm: 0.03}\n")
    a = gym.make("ThermoValve-v0", config=str(p)).unwrapped
    b = gym.make("ThermoValve-v0", valve={"F_hmax": 1.5, "effects": {"stiction": {"band_mm": 0.05, "jump_mm": 0.03}}})
    assert a.cfg == b.unwrapped.cfg
    assert a.cfg.effects.as_dict() == {"stiction": {"band_mm": 0.05, "jump_mm": 0.03}}
    # a keyword override of another valve field keeps the file's effects
    c = gym.make("ThermoValve-v0", config=str(p), valve={"sigma": 6.0}).unwrapped
    assert c.cfg.effects == a.cfg.effects and c.cfg.valve.sigma == 6.0
    # defaults: a named effect without parameters takes the registry's defaults
    d = gym.make("ThermoValve-v0", valve={"effects": {"stiction": {}}}).unwrapped
    assert d.cfg.effects.as_dict() == {"stiction": {"band_mm": REGISTRY["stiction"].parameters[0].default}}


@pytest.mark.parametrize(
    "effects,match",
    [
        ({"stickiness": {"band_mm": 0.1}}, "unknown effect.*stickiness"),
        ({"stiction": {"band": 0.1}}, "unknown parameter.*band"),
        ({"stiction": {"band_mm": -0.1}}, "band_mm must be in"),
        ({"stiction": {"band_mm": 5.0}}, "band_mm must be in"),
        ({"stiction": {"band_mm": float("nan")}}, "band_mm must be a finite number"),
        ({"stiction": {"band_mm": None}}, "band_mm must be a finite number"),
        ({"stiction": {"band_mm": True}}, "band_mm must be a finite number"),
        ({"stiction": {"band_mm": "wide"}}, "band_mm must be a finite number"),
        ({"stiction": None}, "stiction is empty"),
        ({"sensor_lag": {"tau_s": -1}}, "tau_s must be in"),
        ({"medium_temperature": {"beta": 1.5}}, "beta must be in"),
        ({"setpoint_drift": {"rate_MPa_per_h": 1.0}}, "rate_MPa_per_h must be in"),
        ([("stiction", 0.1)], "must be a mapping"),
        ({"stiction": 0.1}, "must be a mapping"),
    ],
)
def test_bad_effects_raise_a_config_error_naming_them(effects, match) -> None:
    with pytest.raises(ConfigError, match=match):
        gym.make("ThermoValve-v0", valve={"effects": effects})
    with pytest.raises(ConfigError, match=match):
        gym.make_vec("ThermoValve-v0", num_envs=2, vectorization_mode="vector_entry_point",
                     valve={"effects": effects})
