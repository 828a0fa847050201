"""The causal bound's machinery on ThermoValveSmallCylinder-v0 (studies/smallcylinder_causal.py): the draws
rebuilt from a seed are the env's, a sampled future keeps the past and the started draws, and with the true
day as every future the controller plans exactly as the oracle."""

from __future__ import annotations

import numpy as np
import pytest

from studies.smallcylinder_causal import (
    ENV_ID,
    HabitMPC,
    day_draws,
    gap_closed,
    gap_interval,
    resample_future,
    scenario_columns,
)
from valve_env.controllers import make_controller
from valve_env.controllers.oracle import Oracle
from valve_env.evaluation.evaluator import make_env


@pytest.fixture(scope="module")
def midday():
    """The task env at 20:10 of day 7 (its evening bath begins at 20:35), driven there by pi."""
    env = make_env(ENV_ID)
    obs, _ = env.reset(seed=7)
    pi = make_controller("pi", ENV_ID)
    state, start = None, np.ones(1, bool)
    for _ in range(2420):
        a, state = pi.predict(obs[None], state=state, episode_start=start)
        start[:] = False
        obs, *_ = env.step(a[0])
    yield env, obs
    env.close()


@pytest.mark.parametrize("seed", [0, 7, 48123])
def test_the_draws_rebuilt_from_the_seed_are_the_envs(seed: int) -> None:
    env = make_env(ENV_ID)
    env.reset(seed=seed)
    core = env.unwrapped
    d = day_draws(core.cfg, seed)
    assert d.start_s.size == 24 and np.count_nonzero(d.f_kgs == d.f_kgs.max()) == 2
    np.testing.assert_array_equal(scenario_columns(d, 2880, 30.0), core.get_state().scenario[:, :3])
    env.close()


def test_a_sampled_future_keeps_the_past_and_redraws_the_rest(midday) -> None:
    env, _ = midday
    st = env.unwrapped.get_state()
    now = st.k * 30.0
    truth = day_draws(env.unwrapped.cfg, 7)
    done = truth.start_s < now
    assert 0 < done.sum() < done.size
    rng = np.random.default_rng(0)
    futs = [resample_future(truth, env.unwrapped.cfg.scenario, now, 86400.0, rng) for _ in range(50)]
    for f in futs:
        np.testing.assert_array_equal(f.start_s[done], truth.start_s[done])
        np.testing.assert_array_equal(f.energy_J[done], truth.energy_J[done])
        assert (f.start_s[~done] >= now).all() and (f.start_s[~done] < 86400.0).all()
        np.testing.assert_array_equal(scenario_columns(f, 2880, 30.0)[: st.k], st.scenario[: st.k, :3])
    later = np.array([f.start_s[~done] for f in futs])
    assert later.std(axis=0).min() > 60.0  # redrawn, not copied
    # a draw far from now keeps its habit: mean start within 3 standard errors of the tabled one
    far = truth.tabled_s[~done] > now + 3 * 3600.0
    se = 1200.0 / np.sqrt(len(futs))
    assert np.all(np.abs(later[:, far].mean(axis=0) - truth.tabled_s[~done][far]) < 3.5 * se)


def test_with_the_true_day_as_every_future_it_plans_as_the_oracle(midday) -> None:
    env, obs = midday
    core = env.unwrapped
    st = core.get_state()
    small = {"samples": 8, "horizon_steps": 60, "block_steps": 10, "iterations": 2}
    oracle = Oracle(ENV_ID, **small).bind_envs([env])
    habit = HabitMPC(ENV_ID, futures=2, true_future=True, **small).bind_envs([env])
    sampled = HabitMPC(ENV_ID, futures=2, **small).bind_envs([env])
    mem = oracle.initial_state(obs[None])[0, : oracle._n_pi]
    prev = np.zeros((60, 1))
    plan = oracle.plan(core, st, obs, mem, prev)
    assert np.abs(plan).max() > 0.1  # the bath ahead moves the plan
    np.testing.assert_array_equal(habit.plan(core, st, obs, mem, prev), plan)
    assert not np.array_equal(sampled.plan(core, st, obs, mem, prev), plan)


def test_the_gap_closed_and_its_paired_interval() -> None:
    rng = np.random.default_rng(1)
    base = 300 + 30 * rng.standard_normal(20)
    oracle = base - 100 + 5 * rng.standard_normal(20)
    x = base - 40 + 5 * rng.standard_normal(20)
    g = gap_closed(x, base, oracle)
    lo, hi = gap_interval(x, base, oracle, n_resamples=999)
    assert 0.3 < g < 0.5 and lo < g < hi and hi - lo < 0.2
    assert gap_closed(oracle, base, oracle) == pytest.approx(1.0)


def test_it_replans_when_a_draw_starts(midday) -> None:
    env, obs = midday
    core = env.unwrapped
    snap = core.get_state()
    habit = HabitMPC(ENV_ID, futures=1, samples=4, horizon_steps=12, block_steps=4, replan_steps=6,
                     iterations=1).bind_envs([env])
    state, start = None, np.ones(1, bool)
    o = obs
    try:
        for _ in range(60):  # 20:10 to 20:40: a draw at 20:25 and the bath at 20:35
            a, state = habit.predict(o[None], state=state, episode_start=start)
            start[:] = False
            o, *_ = env.step(a[0])
    finally:
        core.set_state(snap)
    assert habit.event_plans >= 1
    assert habit.plans_made >= 10 + habit.event_plans


def test_with_the_agents_base_law_a_zero_plan_acts_as_that_law() -> None:
    pytest.importorskip("stable_baselines3")
    env = make_env(ENV_ID)
    obs, _ = env.reset(seed=3)
    law = make_controller("ppo", ENV_ID).base_law()
    habit = HabitMPC(ENV_ID, futures=1, base_law="ppo", samples=4)
    mem = habit.initial_state(obs[None])[:, : habit._n_pi]
    state, start = None, np.ones(1, bool)
    for _ in range(1000):  # through the first morning draws (07:00-08:20): the feedforward acts
        a, state = law.predict(obs[None], state=state, episode_start=start)
        start[:] = False
        b = habit._base_action(obs[None].astype(np.float64), mem, np.zeros((1, 1)))
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-4)  # the agent's float32 action
        obs, *_ = env.step(a[0])
    env.close()
