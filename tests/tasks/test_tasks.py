"""The benchmark tasks: Gymnasium's checker, seeded determinism, batched equals single,
the task layer's bill by hand, and the original ids untouched."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import SyncVectorEnv

import valve_env
from valve_env import simulator as sim
from valve_env.tasks import TASKS, get_task
from valve_env.tasks.env import ThermoValveTaskVectorEnv

NEW = valve_env.TASK_IDS
SHORT = {"horizon_h": 1.0, "max_episode_steps": 120}


def test_every_task_is_registered_and_listed() -> None:
    assert set(NEW) >= {"ThermoValveSmallCylinder-v0", "ThermoValveDistrictHeating-v0"}
    for task_id in NEW:
        assert task_id.startswith("ThermoValve") and task_id in gym.registry
        task = get_task(task_id)
        assert task.sources, f"{task_id} cites no source"
        cls = gym.make(task_id).unwrapped
        doc = type(cls).__doc__ or ""
        for head in ("## Description", "## Action space", "## Observation space", "## Reward", "## KPIs",
                     "## Version history"):
            assert head in doc, f"{task_id}'s spec sheet has no {head!r}"


@pytest.mark.parametrize("task_id", NEW)
def test_gymnasium_env_checker(task_id: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(gym.make(task_id).unwrapped, skip_render_check=True)


@pytest.mark.parametrize("task_id", NEW)
def test_seeded_rollouts_are_bit_identical(task_id: str) -> None:
    def run() -> tuple[np.ndarray, np.ndarray]:
        env = gym.make(task_id, **SHORT)
        obs, _ = env.reset(seed=7)
        env.action_space.seed(7)
        o, r = [obs], []
        for _ in range(120):
            obs, rew, _, trunc, info = env.step(env.action_space.sample())
            o.append(obs)
            r.append(rew)
        assert trunc and "kpis" in info
        return np.array(o), np.array(r)

    o1, r1 = run()
    o2, r2 = run()
    assert np.array_equal(o1, o2) and np.array_equal(r1, r2)
    env = gym.make(task_id, **SHORT)
    o3, _ = env.reset(seed=8)
    assert not np.array_equal(o3, o1[0])  # another seed, another start


@pytest.mark.parametrize("task_id", NEW)
def test_batched_equals_single_across_autoresets(task_id: str) -> None:
    n = 3
    native = gym.make_vec(task_id, num_envs=n, **SHORT)
    assert isinstance(native, ThermoValveTaskVectorEnv)
    sync = SyncVectorEnv([lambda: gym.make(task_id, **SHORT) for _ in range(n)])
    assert native.single_observation_space == sync.single_observation_space
    o1, _ = native.reset(seed=5)
    o2, _ = sync.reset(seed=5)
    np.testing.assert_allclose(o1, o2, rtol=1e-6)
    rng = np.random.default_rng(3)
    box = native.single_action_space
    ends = 0
    for k in range(300):
        a = (box.low + (box.high - box.low) * rng.uniform(size=(n, box.shape[0]))).astype(np.float32)
        o1, r1, _, t1, i1 = native.step(a)
        o2, r2, _, t2, i2 = sync.step(a)
        np.testing.assert_allclose(o1, o2, rtol=1e-6, err_msg=f"obs at step {k}")
        np.testing.assert_allclose(r1, r2, rtol=1e-9, atol=1e-12, err_msg=f"reward at step {k}")
        assert np.array_equal(t1, t2)
        if t1.any():
            ends += int(t1.sum())
            assert set(i1["kpis"]) == set(i2["kpis"])
            for key, v in i2["kpis"].items():
                if not key.startswith("_"):
                    np.testing.assert_allclose(i1["kpis"][key][t1], v[t1], rtol=1e-9, err_msg=key)
    assert ends >= 2 * n


def test_district_heating_bill_by_hand() -> None:
    """The bill in info['kpis'] is the price times the heat, plus 1 % per K of return above 40 degC,
    plus the stored heat's change settled at the mean price at the end."""
    env = gym.make("ThermoValveDistrictHeating-v0", **SHORT)
    layer = env.unwrapped.layer
    env.reset(seed=2)
    E0 = env.unwrapped.stored_energy_J()
    energy = tariff = 0.0
    total_r = 0.0
    for k in range(120):
        obs, r, _, trunc, info = env.step(np.array([70.0], np.float32))
        out = env.unwrapped._out
        e = layer.price_at(np.array([k]))[0] * out[sim.O_HEAT_W] * 30.0 / 3.6e9
        energy += e
        tariff += e * 0.01 * max(out[sim.O_T_RET] - 40.0, 0.0)
        total_r += r
        assert obs[12] == pytest.approx(layer.price_at(np.array([k + 1]))[0], rel=1e-6)
    kp = info["kpis"]
    assert kp["energy_cost_eur"] == pytest.approx(energy, rel=1e-9)
    assert kp["return_tariff_eur"] == pytest.approx(tariff, rel=1e-9)
    settle = 80.0 * (E0 - env.unwrapped.stored_energy_J()) / 3.6e9
    assert kp["storage_settlement_eur"] == pytest.approx(settle, rel=1e-9) and settle < 0  # 70 degC: a surplus
    assert kp["cost_eur"] == pytest.approx(energy + tariff + settle, rel=1e-9) and energy > 0


def test_power_charge_is_billed_on_the_highest_clock_hour() -> None:
    """ThermoValveDistrictHeatingPower-v0 is ThermoValveDistrictHeating-v0 plus a power charge: the
    rate times the highest clock hour's metered heat per hour, as much less return; the meter's two
    observations are the hour so far and the peak so far."""
    env = gym.make("ThermoValveDistrictHeatingPower-v0", control={"horizon_h": 2.5})
    ref = gym.make("ThermoValveDistrictHeating-v0", control={"horizon_h": 2.5})
    env.reset(seed=4)
    ref.reset(seed=4)
    heat, total_r, total_ref = [], 0.0, 0.0
    for k in range(300):
        a = np.array([75.0 if 150 <= k < 200 else 58.0], np.float32)  # a charge in the second hour
        obs, r, _, trunc, info = env.step(a)
        o_ref, r_ref, _, _, i_ref = ref.step(a)
        np.testing.assert_array_equal(obs[:19], o_ref)  # the same plant and forecasts
        heat.append(env.unwrapped._out[sim.O_HEAT_W] * 30.0)
        total_r += r
        total_ref += r_ref
        hours = [sum(heat[i:i + 120]) / 3.6e6 for i in range(0, len(heat), 120)]
        assert obs[20] == pytest.approx(max(hours), rel=1e-5)  # the peak so far, kW
        assert obs[19] == pytest.approx(0.0 if (k + 1) % 120 == 0 else hours[-1], rel=1e-5, abs=1e-7)
    kp, kp_ref = info["kpis"], i_ref["kpis"]
    assert trunc and kp["peak_hourly_kW"] == pytest.approx(max(hours), rel=1e-9) and int(np.argmax(hours)) == 1
    assert kp["power_charge_eur"] == pytest.approx(0.192 * max(hours), rel=1e-9)
    assert kp["cost_eur"] == pytest.approx(kp_ref["cost_eur"] + kp["power_charge_eur"], rel=1e-9)
    assert total_ref - total_r == pytest.approx(100.0 * kp["power_charge_eur"], rel=1e-9)


def test_district_heating_price_and_network_swing() -> None:
    env = gym.make("ThermoValveDistrictHeating-v0")
    env.reset(seed=0)
    scen = env.unwrapped.get_state().scenario
    supply, dp = scen[:, 3], scen[:, 4]
    assert 65 < supply.min() < 75 < supply.max() < 85  # winter supply with a daily swing
    assert dp.max() - dp.min() > 50  # dp falls with the network load
    price = env.unwrapped.layer.price_at(np.arange(2880))
    assert price.mean() == pytest.approx(80.0, rel=1e-3) and price.max() / price.min() > 2


def test_the_original_ids_are_unchanged() -> None:
    """The original ids keep their classes and their step: no task layer, 12 observations."""
    for task_id, task in TASKS.items():
        if task.is_original:
            env = gym.make(task_id)
            assert type(env.unwrapped).__module__ == "valve_env.envs.thermovalve"
            assert env.observation_space.shape == (12,)


def test_batched_equals_single_with_sensor_noise_on_the_forecast_task() -> None:
    """Noise on the plant's observations only (the forecasts are exact), each env from its own generator."""
    kw = {**SHORT, "sensors": {"noise_K": 0.05, "flow_noise_rel": 0.015}}
    task_id = "ThermoValveDistrictHeating-v0"
    native = gym.make_vec(task_id, num_envs=2, **kw)
    sync = SyncVectorEnv([lambda: gym.make(task_id, **kw) for _ in range(2)])
    o1, _ = native.reset(seed=9)
    o2, _ = sync.reset(seed=9)
    np.testing.assert_allclose(o1, o2, rtol=1e-6)
    a = np.full((2, 1), 61.0, np.float32)
    for _ in range(50):
        o1, r1, *_ = native.step(a)
        o2, r2, *_ = sync.step(a)
        np.testing.assert_allclose(o1, o2, rtol=1e-6)
        np.testing.assert_allclose(r1, r2, rtol=1e-9)
    layer = native.layer
    np.testing.assert_allclose(o1[:, 12], layer.price_at(native.step_index), rtol=1e-6)  # forecasts are exact


@pytest.mark.parametrize("task_id", ["ThermoValve-v0", "ThermoValveDistrictHeating-v0",
                                     "ThermoValveDistrictHeatingPower-v0"])
def test_plan_step_follows_step_from_a_snapshot(task_id: str) -> None:
    """The oracle's lean step (plan_step) gives the same plant observations and rewards, task
    terms included, as step() from the same snapshot, and ends where a real episode ends."""
    env = gym.make(task_id, control={"horizon_h": 0.25})
    env.reset(seed=3)
    for _ in range(10):
        env.step(np.array([58.0], np.float32))
    st = env.unwrapped.get_state()
    a = np.array([[55.0], [62.0], [70.0]])
    ref = gym.make_vec(task_id, num_envs=3, vectorization_mode="vector_entry_point", control={"horizon_h": 0.25})
    lean = gym.make_vec(task_id, num_envs=3, vectorization_mode="vector_entry_point", control={"horizon_h": 0.25})
    ref.reset(seed=0)
    ref.set_state(st)
    lean.reset(seed=0)
    lean.set_state(st, rng=False)  # as the oracle loads it: its generators are not drawn from
    for _ in range(30 - 10):
        o_ref, r_ref, *_ = ref.step(a)
        o, r = lean.plan_step(a)
        np.testing.assert_array_equal(o, o_ref[:, : sim.N_OBS])
        np.testing.assert_array_equal(r, r_ref)
    with pytest.raises(RuntimeError, match="ended"):
        lean.plan_step(a)
