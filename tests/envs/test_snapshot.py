"""Snapshots hold every wrapper's state: after restore, a branch is exactly a fresh
replay of it, with dead time (ObservationDelay's delay line) and sensor noise (the
env's generator) and gym.make's TimeLimit (valve_env.wrappers.snapshot/restore)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import valve_env  # noqa: F401  (registers the environments)
from valve_env.wrappers import restore, snapshot

PREFIX = [np.array([60.0 + 10.0 * np.sin(k / 7.0)]) for k in range(60)]
BRANCH_A = [np.array([45.0])] * 25
BRANCH_B = [np.array([78.0 - k]) for k in range(25)]


def _roll(env: gym.Env, actions: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, list[bool]]:
    out = [env.step(a) for a in actions]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out]), [o[3] for o in out]


@pytest.mark.parametrize(
    "sensors",
    [{"dead_time_steps": 3}, {"dead_time_steps": 5, "noise_K": 0.2, "flow_noise_rel": 0.05}, {"noise_K": 0.1}],
)
def test_a_restored_branch_is_a_fresh_replay(sensors):
    env = gym.make("ThermoValve-v0", sensors=sensors)
    env.reset(seed=11)
    _roll(env, PREFIX)
    snap = snapshot(env)
    obs_a, _, _ = _roll(env, BRANCH_A)
    restore(env, snap)
    obs_b, rew_b, _ = _roll(env, BRANCH_B)

    fresh = gym.make("ThermoValve-v0", sensors=sensors)
    fresh.reset(seed=11)
    _roll(fresh, PREFIX)
    ref_obs, ref_rew, _ = _roll(fresh, BRANCH_B)
    assert np.array_equal(obs_b, ref_obs) and np.array_equal(rew_b, ref_rew)
    assert not np.array_equal(obs_a, obs_b)


def test_the_bare_env_state_alone_would_replay_the_abandoned_branch():
    """Why the delay line must be in the snapshot: restoring only the simulator gives
    the abandoned branch's observations for the first dead_time_steps steps."""
    k = 4
    env = gym.make("ThermoValve-v0", sensors={"dead_time_steps": k})
    env.reset(seed=2)
    _roll(env, PREFIX)
    sim = env.unwrapped.get_state()
    obs_a, _, _ = _roll(env, BRANCH_A)
    env.unwrapped.set_state(sim)
    naive, _, _ = _roll(env, BRANCH_B)
    assert np.all(naive[:k, 10] == 45.0) and np.all(obs_a[-k:, 10] == 45.0)  # branch A's setting in force
    fresh = gym.make("ThermoValve-v0", sensors={"dead_time_steps": k})
    fresh.reset(seed=2)
    _roll(fresh, PREFIX)
    ref, _, _ = _roll(fresh, BRANCH_B)
    assert not np.array_equal(naive[:k], ref[:k]) and np.array_equal(naive[k:], ref[k:])


def test_time_limit_counts_from_the_restored_step():
    env = gym.make("ThermoValve-v0", max_episode_steps=80, sensors={"dead_time_steps": 2})
    env.reset(seed=5)
    _roll(env, PREFIX)  # 60 steps
    snap = snapshot(env)
    _, _, trunc_a = _roll(env, BRANCH_A[:20])
    assert trunc_a[-1] and not any(trunc_a[:-1])
    env.reset(seed=6)  # even after a reset in between
    restore(env, snap)
    _, _, trunc_b = _roll(env, BRANCH_B[:20])
    assert trunc_b == trunc_a


def test_batched_and_dual_envs_and_refusals():
    env = gym.make("ThermoValveDual-v0", sensors={"dead_time_steps": 1})
    env.reset(seed=0)
    snap = snapshot(env)
    first = env.step(np.array([70.0, 200.0]))[0]
    restore(env, snap)
    assert np.array_equal(env.step(np.array([70.0, 200.0]))[0], first)
    # a wrapper that keeps state of its own and does not take part is refused, not left behind
    stats = gym.wrappers.RecordEpisodeStatistics(gym.make("ThermoValve-v0"))
    stats.reset(seed=0)
    with pytest.raises(TypeError, match="RecordEpisodeStatistics"):
        snapshot(stats)
    # a snapshot fits only the same stack of wrappers
    other = gym.make("ThermoValveDual-v0")
    other.reset(seed=0)
    with pytest.raises(ValueError, match="wrappers"):
        restore(other, snap)
