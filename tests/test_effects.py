"""The effect registry (valve_env.effects) and its consumers: every consumer supports every effect,
the environments' valve and the generator's valve give the same trajectory for each effect, and each
effect moves the environment's KPIs in the direction physics expects."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from valve_env import experiment, simulator
from valve_env.effects import ENGINE_INDEX, REGISTRY, parse_effects
from valve_env.physics import trajectory
from valve_env.physics.valve import setpoint_pressure
from valve_env.valvefile import read_valve, valve_text
from valve_env.valveid import oe as engine
from valve_env.valveid.diagnose import EFFECTS as DIAGNOSIS_EFFECTS
from valve_env.valveid.sde_effects import HOOKS, effect_model

NAMES = list(REGISTRY)


def _defaults(name: str) -> dict[str, float]:
    return {p.name: float(p.default) for p in REGISTRY[name].parameters}


def test_every_consumer_supports_every_effect(tmp_path) -> None:
    # generator: validation ranges and random sizes come from the registry
    assert set(experiment.EFFECTS) == set(REGISTRY) and set(experiment.STUDY_CLASSES) == {"none", *REGISTRY}
    rng = np.random.default_rng(0)
    base = experiment.simulate_experiment(seed=1, duration_h=3.0, dt_s=10.0)
    for name in NAMES:
        drawn = experiment.draw_effect(name, rng)
        assert set(drawn[name]) == set(REGISTRY[name].param_names)
        for k, v in drawn[name].items():
            p = REGISTRY[name].parameter(k)
            assert p.lower <= v <= p.upper
        df = experiment.simulate_experiment(seed=1, duration_h=3.0, dt_s=10.0, effects={name: _defaults(name)})
        assert np.max(np.abs(df["true_x_mm"] - base["true_x_mm"])) > 1e-3, name
    # diagnosis: one registry; the engine's effect vector and the trajectory's positions match its index
    assert DIAGNOSIS_EFFECTS is REGISTRY
    for const, key in ((trajectory.E_TAU, "tau_s"), (trajectory.E_BETA, "beta"), (trajectory.E_BAND, "band_mm"),
                       (trajectory.E_JUMP, "jump_mm"), (trajectory.E_RATE, "rate_MPa_per_h")):
        assert ENGINE_INDEX[key] == const
    assert set(ENGINE_INDEX) == {p.name for e in REGISTRY.values() for p in e.all_parameters}
    assert engine.E_TAU == trajectory.E_TAU
    # the estimator's SDE models: a hook and a parameter for every effect
    assert set(HOOKS) == set(REGISTRY)
    m = effect_model(NAMES)
    assert set(REGISTRY[n].parameters[0].name for n in NAMES) <= set(m.param_names)
    # environments: each effect reaches the kernel's plant vector; the valve file carries each
    for name in NAMES:
        env = gym.make("ThermoValve-v0", valve={"effects": {name: {}}}).unwrapped
        base_pp = gym.make("ThermoValve-v0").unwrapped._pp
        assert env._pp[simulator.P_EFFECTS] == 1.0
        assert not np.array_equal(env._pp[: simulator.N_PLANT], base_pp[: simulator.N_PLANT]), name
        p = tmp_path / f"{name}.yaml"
        p.write_text(valve_text({"sigma": 6.0}, {name: _defaults(name)}))
        valve, eff = read_valve(p)
        assert valve.sigma == 6.0 and eff == parse_effects({name: _defaults(name)})


def _env_and_generator(effects: dict[str, dict[str, float]]) -> tuple[np.ndarray, np.ndarray]:
    """The env's valve (x, F_h, T_g per 10 s step, one sub-step each) and the generator's valve
    (experiment's compiled physics.trajectory.valve_path) driven by the same inputs: the pocket's
    temperature at the start of each step, the supply water through the valve, dp and ps."""
    env = gym.make("ThermoValve-v0", valve={"effects": effects}, dt_s=10.0, n_sub=1, horizon_h=2.0,
                   max_episode_steps=720)
    u = env.unwrapped
    env.reset(seed=4)
    nl = u.cfg.tank.n_layers
    layer = int(u._pp[simulator.P_BULB_LAYER])
    setting = u.cfg.control.setting_C
    n = 720
    T_in, M_in, dp_in, got = np.empty(n + 1), np.empty(n + 1), np.empty(n + 1), np.empty((3, n + 1))
    got[:, 0] = [u._s[nl + simulator.S_X], u._s[nl + simulator.S_FH], u._s[nl + simulator.S_TG]]
    for k in range(n):
        T_in[k] = u._s[layer]
        M_in[k] = u._scen[k, 3]
        dp_in[k] = u.cfg.scenario.dp_mbar if k == 0 else u._dp
        _, _, _, _, info = env.step(np.array([setting], np.float32))
        dp_in[k] = u._dp
        got[:, k + 1] = [info["x_mm"], info["F_h_N"], info["T_g_C"]]
    T_in[n], M_in[n], dp_in[n] = T_in[n - 1], M_in[n - 1], dp_in[n - 1]
    vp = u.cfg.valve.to_array()
    e = u.cfg.effects.vector()
    if "sensor_lag" not in effects:
        e[ENGINE_INDEX["tau_s"]] = u.cfg.bulb.tau_s  # the env's own bulb lag
    t = np.arange(n + 1) * 10.0
    out = experiment._valve_path(t, T_in, M_in, dp_in, np.full(n + 1, u.cfg.scenario.ps_bar),
                                 float(setpoint_pressure(setting, vp)), e, vp, True, 0.0, np.zeros(n + 1),
                                 np.empty((5, n + 1)))
    want = out[[2, 1, 0]]
    return got, want


@pytest.mark.parametrize("name", [*NAMES, "all"])
def test_env_and_generator_give_the_same_valve_trajectory(name: str) -> None:
    effects = {n: _defaults(n) for n in NAMES} if name == "all" else {name: _defaults(name)}
    got, want = _env_and_generator(effects)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-12, err_msg="stem position")
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-12, err_msg="friction force")
    np.testing.assert_allclose(got[2], want[2], rtol=0, atol=1e-12, err_msg="gas temperature")
    assert np.ptp(got[0]) > 0.05  # the valve moved


def _day(effects: dict | None, seed: int = 21) -> dict[str, float]:
    env = gym.make("ThermoValve-v0", **({"valve": {"effects": effects}} if effects else {}))
    env.reset(seed=seed)
    a = np.array([env.unwrapped.cfg.control.setting_C], np.float32)  # the self-acting valve alone
    while True:
        *_, trunc, info = env.step(a)
        if trunc:
            return info["kpis"]


def test_each_effect_moves_the_kpis_the_way_physics_expects() -> None:
    base = _day(None)
    # a slower bulb: the valve closes late once the tank is hot (hotter return) and hunts in wider swings
    lag = _day({"sensor_lag": {"tau_s": 600.0}})
    assert lag["return_C"] > base["return_C"] and lag["travel_mm"] > base["travel_mm"]
    # the hot supply water heats the bulb: the valve closes early, less heat goes into the tank
    med = _day({"medium_temperature": {"beta": 0.3}})
    assert med["heat_kWh"] < base["heat_kWh"] and med["return_C"] < base["return_C"]
    # the set pressure drifts down (up): the valve seats at a lower (higher) temperature as the day goes on
    down = _day({"setpoint_drift": {"rate_MPa_per_h": -5e-4}})
    up = _day({"setpoint_drift": {"rate_MPa_per_h": 5e-4}})
    assert down["heat_kWh"] < base["heat_kWh"] < up["heat_kWh"]
    # a sticky stem swallows the small reversals of the demand
    st = _day({"stiction": {"band_mm": 0.04}})
    assert st["reversals"] < base["reversals"]


def test_a_pi_loop_limit_cycles_on_a_sticky_valve() -> None:
    """studies/stiction_limit_cycle.py in brief: with only the standing losses to cover, the PI holds a
    frictionless valve still near its seat; at a 2 % band (0.04 mm) the stem hunts in a regular cycle of
    about the band, with several times the reversals and travel."""
    from studies.stiction_limit_cycle import oscillation, run_day

    base = run_day(0.0, 101, "none")
    sticky = run_day(0.04, 101, "none")
    skip = 240
    period, amp = oscillation(sticky["x"][skip:])
    assert 2 * 60 <= period <= 30 * 60 and 0.3 * 0.04 <= amp <= 0.04, (period, amp)
    assert np.isnan(oscillation(base["x"][skip:])[0])
    assert sticky["kpis"]["reversals"] > 1.5 * base["kpis"]["reversals"]
    assert sticky["kpis"]["travel_mm"] > 3.0 * base["kpis"]["travel_mm"]
