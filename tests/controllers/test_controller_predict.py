"""The SB3 predict interface of the baselines: single and batched
observations, per-env state, episode_start resets, bumpless start, anti-windup,
and the registry."""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np
import pytest

import valve_env  # noqa: F401
from valve_env.config import ControlParams
from valve_env.controllers import (
    BASELINES,
    DahlCompensator,
    PICompensated,
    PIController,
    SelfActing,
    UnknownControllerError,
    make_controller,
)
from valve_env.controllers.base import I_SETTING, I_T_OUT, I_T_POCKET, OBS_DIM
from valve_env.params import ValveParams
from valve_env.physics.valve import friction_band_K, vapour_pressure


def _obs_batch(n: int, rng: np.random.Generator) -> np.ndarray:
    env = gym.make("ThermoValve-v0")
    obs, _ = env.reset(seed=0)
    batch = np.repeat(obs[None, :], n, axis=0).astype(np.float64)
    batch[:, I_T_OUT] = rng.uniform(50, 66, n)
    batch[:, I_T_POCKET] = batch[:, I_T_OUT] - rng.uniform(0, 2, n)
    return batch


@pytest.mark.parametrize("name", ["self_acting", "pi", "pi_compensated"])
@pytest.mark.parametrize("env_id", ["ThermoValve-v0", "ThermoValvePressure-v0", "ThermoValveDual-v0"])
def test_single_and_batched_agree(name: str, env_id: str) -> None:
    if env_id not in BASELINES[name].supported_env_ids:
        with pytest.raises(ValueError, match="does not support"):
            make_controller(name, env_id)
        return
    rng = np.random.default_rng(1)
    n, steps = 5, 30
    ctrl = make_controller(name, env_id)
    obs_seq = [_obs_batch(n, rng) for _ in range(steps)]
    # batched: one call per step
    state = None
    starts = np.ones(n, dtype=bool)
    batched = []
    for o in obs_seq:
        a, state = ctrl.predict(o, state=state, episode_start=starts)
        starts = np.zeros(n, dtype=bool)
        batched.append(a)
    act_dim = 2 if env_id == "ThermoValveDual-v0" else 1
    assert batched[0].shape == (n, act_dim) and batched[0].dtype == np.float32
    # single: each env on its own
    for i in range(n):
        st = None
        for k, o in enumerate(obs_seq):
            a, st = ctrl.predict(o[i], state=st, episode_start=np.array([k == 0]))
            assert a.shape == (act_dim,)
            np.testing.assert_allclose(a, batched[k][i], rtol=0, atol=1e-5)


def test_episode_start_resets_only_flagged_envs() -> None:
    rng = np.random.default_rng(2)
    ctrl = PICompensated()
    o = _obs_batch(4, rng)
    _, state = ctrl.predict(o, state=None)
    for _ in range(20):
        _, state = ctrl.predict(o, state=state, episode_start=np.zeros(4, bool))
    fresh = ctrl.initial_state(o)
    start = np.array([True, False, True, False])
    _, new = ctrl.predict(o, state=state, episode_start=start)
    # a reset env's memory equals a fresh env's after one step; the others continue
    _, fresh_after = ctrl.predict(o, state=fresh, episode_start=np.zeros(4, bool))
    np.testing.assert_allclose(new[start], fresh_after[start])
    assert not np.allclose(new[~start], fresh_after[~start])
    # state=None means every env starts afresh
    _, none_state = ctrl.predict(o, state=None)
    np.testing.assert_allclose(none_state, fresh_after)


def test_pi_is_bumpless_and_winds_up_no_further_than_its_limit() -> None:
    ctrl = PIController(Kp=5.0, Ti_s=300.0)
    obs = _obs_batch(1, np.random.default_rng(3))[0]
    obs[I_SETTING] = 63.3
    obs[I_T_OUT] = 50.0  # large positive error: output must not jump at switch-in
    obs[I_T_POCKET] = 50.0
    a, st = ctrl.predict(obs, episode_start=np.array([True]))
    assert a[0] == pytest.approx(63.3, abs=1e-4)  # switch-in keeps the setting in force
    a, st = ctrl.predict(obs, st)
    assert a[0] == pytest.approx(63.3 + 5.0 * 30 / 300 * 10.0, abs=1e-4)  # then only the integral moves it
    for _ in range(2000):  # a long saturation at the upper limit
        a, st = ctrl.predict(obs, st)
    assert a[0] == pytest.approx(ControlParams().setting_max_C)
    # back-calculation keeps the integrator near the limit: once the error
    # reverses, the output leaves the limit within a few steps
    obs[I_T_OUT] = 61.0
    obs[I_T_POCKET] = 61.0
    left = None
    for k in range(20):
        a, st = ctrl.predict(obs, st)
        if a[0] < 70.0:
            left = k
            break
    assert left is not None and left <= 3


def test_pi_dead_zone_limit_follows_the_pocket_temperature() -> None:
    ctrl = PIController(Kp=5.0, Ti_s=300.0, closed_margin_K=2.0)
    obs = _obs_batch(1, np.random.default_rng(4))[0]
    obs[I_T_OUT] = 64.0
    obs[I_T_POCKET] = 63.0
    st = None
    for _ in range(500):
        a, st = ctrl.predict(obs, st)
    assert a[0] == pytest.approx(61.0, abs=1e-4)  # the valve is shut; lower settings would only wind up


def test_self_acting_holds_its_setting() -> None:
    obs = _obs_batch(3, np.random.default_rng(5))
    assert np.all(SelfActing()(obs) == np.float32(ControlParams().T_target_C))
    assert np.all(SelfActing(setting_C=62.0)(obs) == 62.0)
    np.testing.assert_array_equal(SelfActing("ThermoValveDual-v0", dp_mbar=80.0)(obs[0]), [60.0, 80.0])
    assert SelfActing("ThermoValvePressure-v0")(obs[0]).tolist() == [100.0]


def test_compensator_inverse_model() -> None:
    comp = DahlCompensator()
    vp = ValveParams().to_array()
    obs = np.zeros((1, OBS_DIM))
    obs[0, I_T_POCKET] = 50.0
    mem = comp.initial_state(obs)
    for k in range(200):  # pocket warming steadily: the friction estimate goes to +F_hmax
        obs[0, I_T_POCKET] = 50.0 + 0.05 * (k + 1)
        fh = comp.update(obs, mem)
    assert fh[0] == pytest.approx(ValveParams().F_hmax, rel=1e-6)
    assert mem[0, 1] < obs[0, I_T_POCKET]  # the bulb estimate lags the pocket
    t_des = np.array([60.0])
    cmd = comp.command(t_des, fh)
    # exact inverse: the commanded set pressure plus F_h / A_b equals the desired one
    assert vapour_pressure(cmd, vp) + fh / ValveParams().A_b == pytest.approx(vapour_pressure(t_des, vp), rel=1e-12)
    # and the shift is the friction band, F_hmax / (A_b dp_b/dT)
    assert (t_des - cmd)[0] == pytest.approx(friction_band_K(60.0, vp), rel=0.01)
    assert comp.shift_K(t_des, fh)[0] == pytest.approx(friction_band_K(60.0, vp), rel=1e-9)


def test_compensator_tracks_the_hidden_friction_force() -> None:
    """Validation only (the controller never reads info): the Dahl estimate
    driven by the observed pocket temperature follows the simulator's F_h."""
    env = gym.make("ThermoValve-v0")
    ctrl = PICompensated()
    obs, _ = env.reset(seed=4)
    st = None
    est, true = [], []
    for _ in range(1500):
        a, st = ctrl.predict(obs, st)
        obs, _, _, _, info = env.step(a)
        est.append(st[0, -1])  # the compensator's F_h estimate
        true.append(info["F_h_N"])
    err = np.abs(np.array(est) - np.array(true))
    assert np.mean(err) < 0.1 * ValveParams().F_hmax
    assert np.corrcoef(est, true)[0, 1] > 0.95


def test_registry_delegates_unknown_names_to_the_agent_loader(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "agents.loader", None)  # makes the import fail
    with pytest.raises(UnknownControllerError, match="'ppo'"):
        make_controller("ppo", "ThermoValve-v0")
    with pytest.raises(ValueError, match="unknown env id"):
        make_controller("pi", "Nope-v0")
    assert isinstance(make_controller("pi"), PIController)
