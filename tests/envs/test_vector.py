"""The native batched env equals N single envs (gymnasium's SyncVectorEnv over
gym.make) with the same seeds, step by step, across resets and autoreset."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space
from gymnasium.wrappers.vector import RecordEpisodeStatistics
from hypothesis import given, settings
from hypothesis import strategies as st

import valve_env
from valve_env import simulator as sim
from valve_env.envs.vector import (
    ThermoValveDualVectorEnv,
    ThermoValvePressureVectorEnv,
    ThermoValveVectorEnv,
)

CLASSES = {
    "ThermoValve-v0": ThermoValveVectorEnv,
    "ThermoValvePressure-v0": ThermoValvePressureVectorEnv,
    "ThermoValveDual-v0": ThermoValveDualVectorEnv,
}
RTOL = 1e-9
SHORT = {"horizon_h": 0.5}  # 60 steps of 30 s: several autoresets in a short test


def _pair(env_id: str, n: int, **kw: Any) -> tuple[gym.vector.VectorEnv, gym.vector.VectorEnv]:
    native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kw)
    sync = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", **kw)
    return native, sync


def _assert_info_equal(a: dict[str, Any], b: dict[str, Any], where: str) -> None:
    assert set(a) == set(b), f"{where}: info keys differ: {sorted(set(a) ^ set(b))}"
    for key in b:
        if isinstance(b[key], dict):
            _assert_info_equal(a[key], b[key], f"{where}/{key}")
            continue
        va, vb = np.asarray(a[key]), np.asarray(b[key])
        assert va.shape == vb.shape, f"{where}/{key}: shape {va.shape} != {vb.shape}"
        assert va.dtype == vb.dtype, f"{where}/{key}: dtype {va.dtype} != {vb.dtype}"
        if vb.dtype == np.bool_:
            assert np.array_equal(va, vb), f"{where}/{key}"
        else:
            np.testing.assert_allclose(va, vb, rtol=RTOL, atol=1e-12, equal_nan=True, err_msg=f"{where}/{key}")


def _run_equal(
    native: gym.vector.VectorEnv,
    sync: gym.vector.VectorEnv,
    actions: np.ndarray,
    seed: int | list[int],
    *,
    reset_every: int | None = None,
) -> int:
    """Step both with the same actions; returns how many episode ends were seen."""
    o1, i1 = native.reset(seed=seed)
    o2, i2 = sync.reset(seed=seed)
    np.testing.assert_allclose(o1, o2, rtol=RTOL)
    _assert_info_equal(i1, i2, "reset")
    ends = 0
    for k, a in enumerate(actions):
        if reset_every and k and k % reset_every == 0:
            o1, i1 = native.reset(seed=k)
            o2, i2 = sync.reset(seed=k)
            np.testing.assert_allclose(o1, o2, rtol=RTOL)
            _assert_info_equal(i1, i2, f"reset at {k}")
            continue
        o1, r1, te1, tr1, i1 = native.step(a)
        o2, r2, te2, tr2, i2 = sync.step(a)
        assert o1.dtype == o2.dtype == np.float32
        np.testing.assert_allclose(o1, o2, rtol=RTOL, err_msg=f"obs at step {k}")
        np.testing.assert_allclose(r1, r2, rtol=RTOL, atol=1e-12, err_msg=f"reward at step {k}")
        assert r1.dtype == r2.dtype
        assert np.array_equal(te1, te2) and np.array_equal(tr1, tr2), f"done flags at step {k}"
        _assert_info_equal(i1, i2, f"step {k}")
        ends += int(tr2.sum())
    return ends


@pytest.mark.parametrize("env_id", valve_env.ENV_IDS)
def test_make_vec_returns_the_native_class(env_id: str) -> None:
    for mode in ("vector_entry_point", None):
        env = gym.make_vec(env_id, num_envs=3, vectorization_mode=mode)
        assert type(env) is CLASSES[env_id]
        assert env.num_envs == 3
        assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
        env.close()


@pytest.mark.parametrize("env_id", valve_env.ENV_IDS)
def test_batched_equals_sync_vector_env_across_autoresets(env_id: str) -> None:
    n = 4
    native, sync = _pair(env_id, n, **SHORT)
    rng = np.random.default_rng(11)
    box = native.single_action_space
    lo, hi = box.low.astype(np.float64), box.high.astype(np.float64)
    # a tenth of the actions fall outside the box (clipping is compared too)
    acts = (lo + (hi - lo) * rng.uniform(-0.1, 1.1, size=(200, n, lo.size))).astype(np.float32)
    ends = _run_equal(native, sync, acts, seed=5)
    assert ends >= 3 * n  # every env ended (kpis compared) and auto-reset several times


@pytest.mark.parametrize("env_id", valve_env.ENV_IDS)
def test_batched_equals_sync_on_the_default_day(env_id: str) -> None:
    """The registered day (2880 steps, TimeLimit 2880), its KPIs at the end, and the autoreset after it."""
    native, sync = _pair(env_id, 2)
    acts = np.repeat(native.action_space.sample()[None], 2890, axis=0)
    assert _run_equal(native, sync, acts, seed=[3, 99]) == 2


def test_time_limit_shorter_than_the_horizon_truncates_without_kpis() -> None:
    native, sync = _pair("ThermoValve-v0", 2, horizon_h=1.0, max_episode_steps=50)
    acts = np.full((130, 2, 1), 61.0, np.float32)
    _run_equal(native, sync, acts, seed=1)
    native.reset(seed=0)
    for _ in range(49):
        native.step(acts[0])
    *_, trunc, info = native.step(acts[0])
    assert trunc.all() and "kpis" not in info


def test_reseeding_mid_episode_and_reset_mask() -> None:
    native, sync = _pair("ThermoValveDual-v0", 3, **SHORT)
    acts = np.tile(np.array([[60.0, 120.0]], np.float32), (90, 3, 1))
    _run_equal(native, sync, acts, seed=[4, 8, 15], reset_every=37)
    mask = np.array([True, False, True])
    o1, i1 = native.reset(seed=[1, 2, 3], options={"reset_mask": mask.copy()})
    o2, i2 = sync.reset(seed=[1, 2, 3], options={"reset_mask": mask.copy()})
    np.testing.assert_allclose(o1, o2, rtol=RTOL)
    _assert_info_equal(i1, i2, "masked reset")
    for k in range(70):
        r1, r2 = native.step(acts[0]), sync.step(acts[0])
        np.testing.assert_allclose(r1[0], r2[0], rtol=RTOL, err_msg=f"step {k}")
        np.testing.assert_allclose(r1[1], r2[1], rtol=RTOL, atol=1e-12)
        _assert_info_equal(r1[4], r2[4], f"step {k}")


def test_sensor_noise_and_dead_time_match_the_single_env_wrappers() -> None:
    sensors = {"noise_K": 0.1, "flow_noise_rel": 0.02, "dead_time_steps": 2}
    native, sync = _pair("ThermoValve-v0", 3, sensors=sensors, **SHORT)
    rng = np.random.default_rng(2)
    acts = rng.uniform(45, 75, size=(130, 3, 1)).astype(np.float32)
    _run_equal(native, sync, acts, seed=21)


@pytest.mark.parametrize("overrides", [{"supply_profile": "random", "dp_noise_mbar": 10.0}, {"tapping_profile": "L"}])
def test_scenario_variants_match(overrides: dict[str, Any]) -> None:
    native, sync = _pair("ThermoValve-v0", 2, **overrides, **SHORT)
    acts = np.full((70, 2, 1), 58.0, np.float32)
    _run_equal(native, sync, acts, seed=0)


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 4), setting=st.floats(30.0, 90.0))
def test_random_seeds_and_sizes_match(seed: int, n: int, setting: float) -> None:
    native, sync = _pair("ThermoValve-v0", n, horizon_h=0.25)
    acts = np.full((40, n, 1), setting, np.float32)
    _run_equal(native, sync, acts, seed=seed)


def test_invalid_actions_are_rejected_like_the_single_env() -> None:
    env = gym.make_vec("ThermoValve-v0", num_envs=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([[60.0], [np.nan]], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 1), np.float32))
    *_, info = env.step(np.array([[60.0], [500.0]], np.float32))
    assert info["action_clipped"].tolist() == [False, True]
    assert info["_action_clipped"].tolist() == [False, True]


def test_spaces_and_gymnasium_vector_wrappers() -> None:
    env = gym.make_vec("ThermoValvePressure-v0", num_envs=5, horizon_h=0.1)
    assert env.observation_space == batch_space(env.single_observation_space, 5)
    assert env.action_space == batch_space(env.single_action_space, 5)
    single = gym.make("ThermoValvePressure-v0")
    assert env.single_observation_space == single.observation_space
    assert env.single_action_space == single.action_space
    wrapped = RecordEpisodeStatistics(env)
    obs, _ = wrapped.reset(seed=3)
    assert obs in env.observation_space
    wrapped.action_space.seed(0)
    episodes = 0
    for _ in range(30):
        obs, r, term, trunc, info = wrapped.step(wrapped.action_space.sample())
        assert obs in env.observation_space
        assert np.all(np.isfinite(r))
        if "episode" in info:
            episodes += int(info["_episode"].sum())
    assert episodes == 10  # 12 steps, the autoreset step, 12 steps


def test_per_env_accounting_closes_the_first_law() -> None:
    env = gym.make_vec("ThermoValve-v0", num_envs=3, horizon_h=1.0)
    env.reset(seed=0)
    for _ in range(119):
        env.step(np.full((3, 1), 62.0, np.float32))
    *_, trunc, info = env.step(np.full((3, 1), 62.0, np.float32))
    assert trunc.all() and info["_kpis"].all()
    e = info["energy"]
    balance = e["heat_in_J"] - (e["stored_J"] + e["losses_J"] + e["draws_J"])
    assert np.all(np.abs(balance) <= 1e-6 * np.maximum(e["heat_in_J"], 1.0))


def test_one_kernel_for_single_and_batched_envs() -> None:
    # threaded and serial batched steps both run _step_block, which calls the single env's functions
    for kernel in (sim.env_step_batch, sim.env_step_batch_serial):
        assert {"check_actions", "_step_block"} <= set(kernel.py_func.__code__.co_names)
    # the same block kernel (the single env is a block of one column), inputs and clock
    names = sim._step_block.py_func.__code__.co_names
    assert {"plant_step", "load_inputs", "apply_action", "clock"} <= set(names)
    assert {"plant_step", "load_inputs", "apply_action", "fill_obs"} <= set(sim.env_step.py_func.__code__.co_names)
    assert "clock" in sim.fill_obs.py_func.__code__.co_names


def test_large_batch_uses_threads_and_still_matches() -> None:
    n = ThermoValveVectorEnv.parallel_threshold + 3
    native = gym.make_vec("ThermoValve-v0", num_envs=n, horizon_h=0.1)
    acts = np.linspace(45, 75, n, dtype=np.float32)[:, None]
    native.reset(seed=9)
    for _ in range(25):
        o1, r1, *_ = native.step(acts)
    for i in (0, n - 1):
        single = gym.make("ThermoValve-v0", horizon_h=0.1)
        o, _ = single.reset(seed=9 + i)
        done = False
        for _ in range(25):  # NEXT_STEP autoreset: the step after the end resets
            if done:
                o, _ = single.reset()
                done = False
            else:
                o, r, te, tr, _ = single.step(acts[i])
                done = te or tr
        np.testing.assert_allclose(o1[i], o, rtol=RTOL)


def test_openmp_waiting_defaults_keep_what_the_user_set() -> None:
    """``import valve_env`` sets OpenMP's waiting (passive after a short spin) before numba starts its
    threads, unless the user chose: a fresh interpreter with and without the user's values."""
    import os
    import subprocess
    import sys

    code = "import os, valve_env; print(os.environ['OMP_WAIT_POLICY'], os.environ['GOMP_SPINCOUNT'])"
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["passive", "30000"]
    env.update(OMP_WAIT_POLICY="active", GOMP_SPINCOUNT="7")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["active", "7"]
