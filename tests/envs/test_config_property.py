"""Property: no accepted config gives a non-finite observation or reward, or an
observation outside the observation space (docs/configuration.md).

Configs are drawn from every field's declared range (valve_env.params.param:
the Spec in the field's metadata), all sections at once, with hypothesis's
bias towards the ends of each range; the cross-field rules are met by
construction (ordered pairs, coil within the tank, a daily supply within its
limits) or, for the explicit layer update, by raising n_sub to what it needs.
Each config runs a short episode under random, bang-bang and absurd (+-1e300,
clipped) actions. The default test keeps the horizon to two days (a long
horizon only costs scenario sampling); the slow one draws it from its whole
range and runs longer.
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, currently_in_test_context, given, settings, target
from hypothesis import strategies as st

import valve_env  # registers the environments
from valve_env.config import MAX_EPISODE_STEPS, SECTIONS, EnvConfig, make_config
from valve_env.params import SUPPLY_LIMITS_C, ConfigError, Spec

IDS = ("ThermoValve-v0", "ThermoValvePressure-v0", "ThermoValveDual-v0")
PHYSICAL = np.r_[0:8]  # the measured quantities (time of day, setting and target may sit on their faces)


def _value(spec: Spec) -> st.SearchStrategy[Any]:
    """Any value the spec accepts, its ends included."""
    if spec.kind == "choice":
        return st.sampled_from(spec.choices)
    if spec.kind == "bool":
        return st.booleans()
    assert spec.lo is not None and spec.hi is not None
    if spec.kind == "int":
        return st.integers(int(spec.lo), int(spec.hi))
    inner = st.floats(spec.lo, spec.hi, exclude_min=spec.lo_open, exclude_max=spec.hi_open, allow_nan=False)
    # the ends and a log-uniform spread over wide positive ranges, besides hypothesis's own floats
    ends = [x for x, open_ in ((spec.lo, spec.lo_open), (spec.hi, spec.hi_open)) if not open_]
    parts = [inner, st.sampled_from(ends)] if ends else [inner]
    lo = spec.lo if spec.lo > 0 else (1e-6 * spec.hi if spec.lo_open else None)
    if lo is not None and spec.hi / lo > 100:
        parts.append(st.floats(math.log(lo), math.log(spec.hi)).map(lambda v: min(max(math.exp(v), lo), spec.hi)))
    return st.one_of(parts)


def _section(cls: type) -> st.SearchStrategy[dict[str, Any]]:
    """A few of the section's fields (or all of them) anywhere in their ranges, the rest at
    their defaults: with every field moved at once the valve's forces nearly always
    saturate it shut, so configs that move some fields at a time exercise the flow, the
    heat and the draws at the ends of the ranges."""
    specs = {f.name: (f.default, f.metadata["spec"]) for f in fields(cls) if "spec" in f.metadata}

    @st.composite
    def section(draw: st.DrawFn) -> dict[str, Any]:
        moved = draw(st.one_of(st.sets(st.sampled_from(sorted(specs)), max_size=4), st.just(set(specs))))
        return {n: draw(_value(spec)) if n in moved else default for n, (default, spec) in specs.items()}

    return section()


@st.composite
def configs(draw: st.DrawFn, max_horizon_h: float) -> EnvConfig:
    d = {name: draw(_section(cls)) for name, cls in SECTIONS.items()}
    t, c, s = d["tank"], d["control"], d["scenario"]
    t["coil_layers"] = min(t["coil_layers"], t["n_layers"])
    for a, b, name in (("setting_min_C", "setting_max_C", "setting_C"), ("dp_min_mbar", "dp_max_mbar", None)):
        spec = SECTIONS["control"].__dataclass_fields__[a].metadata["spec"]
        lo, hi = sorted((c[a], c[b]))
        if lo == hi:  # both at one end: the other end
            lo, hi = (lo, spec.hi) if lo < spec.hi else (spec.lo, hi)
        c[a], c[b] = lo, hi
        if name:
            c[name] = draw(st.one_of(st.just(lo), st.just(hi), st.floats(lo, hi)))
    # an episode of 1 .. MAX_EPISODE_STEPS steps within max_horizon_h
    h_lo = c["dt_s"] / 3600.0
    h_hi = min(max_horizon_h, MAX_EPISODE_STEPS * c["dt_s"] / 3600.0)
    c["horizon_h"] = draw(st.one_of(st.just(h_lo), st.just(h_hi), st.floats(h_lo, h_hi)))
    if s["supply_profile"] in ("daily", "network"):  # the supply plan swings supply_C +- amplitude
        s["supply_amplitude_K"] = min(s["supply_amplitude_K"], s["supply_C"] - SUPPLY_LIMITS_C[0],
                                      SUPPLY_LIMITS_C[1] - s["supply_C"])
    # the explicit layer update: at least the sub-steps the tank needs (often exactly those,
    # the most extreme accepted corner), if n_sub's range allows
    drawn = c["n_sub"]
    c["n_sub"] = 1000
    try:
        need = make_config(d).min_n_sub()
    except ConfigError as exc:
        assert "control.n_sub" in str(exc)
        need = 1001
    assume(need <= 1000)
    c["n_sub"] = draw(st.sampled_from([need, max(need, drawn)]))
    return make_config(d)


@st.composite
def actions(draw: st.DrawFn, n: int, dim: int) -> np.ndarray:
    """n actions: uniform draws, the box's corners, and absurd finite values (clipped by the env)."""
    elem = st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.0, 1.0, -1e300, 1e300, -1.0, 2.0]))
    return np.array(draw(st.lists(st.lists(elem, min_size=dim, max_size=dim), min_size=n, max_size=n)))


def _check(env: gym.Env, cfg: EnvConfig, u: np.ndarray, seed: int) -> None:
    """Every observation finite and in the box, every reward finite; without temperature
    noise, every observed temperature within the range of the temperatures that drive the
    tank (the explicit update's mixtures: a maximum principle, stricter than the box)."""
    space = env.observation_space
    lo, hi = env.action_space.low.astype(np.float64), env.action_space.high.astype(np.float64)
    obs, _ = env.reset(seed=seed)
    assert np.all(np.isfinite(obs)) and space.contains(obs), (obs, cfg)
    # start at the sampled scenario's heaviest draw (a short episode from midnight would
    # see none: the cycles start at 07:00); its rows are still all the scenario model's
    base = env.unwrapped
    state = base.get_state()
    state.scenario = np.roll(state.scenario, -int(np.argmax(state.scenario[:, 0])), axis=0)
    base.set_state(state)
    t = cfg.tank
    drivers = [t.T_cold, t.T_ambient, *state.scenario[:, 3], *state.state[: t.n_layers]]
    t_lo, t_hi = min(drivers) - 1e-4, max(drivers) + 1e-4
    span = (space.high - space.low).astype(np.float64)
    edge = 0.0
    for a in u:
        scaled = np.where(np.abs(a) > 2.0, a, lo + a * (hi - lo))  # 0..1 across the box, beyond it, or absurd
        obs, r, term, trunc, info = env.step(scaled)
        assert np.all(np.isfinite(obs)) and space.contains(obs), (obs, space, cfg)
        assert np.isfinite(r), (r, cfg)
        assert all(np.isfinite(v) for v in info.values() if isinstance(v, float)), (info, cfg)
        if cfg.sensors.noise_K == 0:
            assert np.all((obs[:5] >= t_lo) & (obs[:5] <= t_hi)), (obs[:5], t_lo, t_hi, cfg)
        if cfg.sensors.noise_K == 0 and cfg.sensors.flow_noise_rel == 0:  # (noise is clipped at the faces)
            up = (obs - space.low) / span  # towards the upper faces; and the temperatures' lower ones
            edge = max(edge, float(np.max(up[PHYSICAL])), float(np.max(1.0 - up[:5])))
        if trunc or term:
            assert all(np.isfinite(v) for v in info["energy"].values())
            obs, _ = env.reset()
            assert np.all(np.isfinite(obs)) and space.contains(obs), (obs, cfg)
            state = base.get_state()
            t_lo = min(t_lo, *state.scenario[:, 3], *state.state[: t.n_layers]) - 1e-4
            t_hi = max(t_hi, *state.scenario[:, 3], *state.state[: t.n_layers]) + 1e-4
    if currently_in_test_context():
        target(edge, label="reach towards the observation box's faces")


def _run(cfg: EnvConfig, env_id: str, u: np.ndarray, seed: int) -> None:
    env = gym.make(env_id, config=cfg, max_episode_steps=cfg.control.n_steps)
    _check(env, cfg, u[:, : env.action_space.shape[0]], seed)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(cfg=configs(max_horizon_h=48.0), env_id=st.sampled_from(IDS), u=actions(30, 2), seed=st.integers(0, 2**31))
def test_every_accepted_config_gives_finite_observations_in_the_box(cfg, env_id, u, seed):
    _run(cfg, env_id, u, seed)


@pytest.mark.slow
@settings(max_examples=400, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.large_base_example])
@given(cfg=configs(max_horizon_h=8784.0), env_id=st.sampled_from(IDS), u=actions(200, 2), seed=st.integers(0, 2**31))
def test_every_accepted_config_gives_finite_observations_in_the_box_long(cfg, env_id, u, seed):
    _run(cfg, env_id, u, seed)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(cfg=configs(max_horizon_h=2.0), u=actions(30, 2), seed=st.integers(0, 2**31))
def test_the_batched_env_too(cfg, u, seed):
    """The batched env builds the same config through the same checks and the same kernel."""
    env = gym.make_vec("ThermoValveDual-v0", num_envs=3, vectorization_mode="vector_entry_point", config=cfg)
    space = env.single_observation_space
    lo, hi = env.single_action_space.low.astype(np.float64), env.single_action_space.high.astype(np.float64)
    obs, _ = env.reset(seed=seed)
    for a in u:
        scaled = np.where(np.abs(a) > 2.0, a, lo + a * (hi - lo))
        obs, r, *_ = env.step(np.tile(scaled, (3, 1)))
        assert np.all(np.isfinite(obs)) and np.isfinite(r).all()
        assert all(space.contains(o) for o in obs), (obs, cfg)


def test_the_strategies_reach_the_ends_of_the_ranges():
    """Sanity of the generator: a config at every field's lower end and one at every upper
    end (where the cross-field rules allow) are accepted and stay in the box."""
    for end in (0, 1):
        d: dict[str, dict[str, Any]] = {}
        for name, cls in SECTIONS.items():
            d[name] = {}
            for f in fields(cls):
                spec = f.metadata["spec"]
                if spec.kind in ("float", "int") and not (spec.lo_open if end == 0 else spec.hi_open):
                    d[name][f.name] = (spec.lo, spec.hi)[end]
        c = d["control"]
        c.update(setting_min_C=10.0, setting_max_C=120.0, setting_C=62.0, dp_min_mbar=0.0, dp_max_mbar=2000.0)
        c["horizon_h"] = 2.0 * c["dt_s"] / 3600.0 * 20
        try:
            cfg = make_config(d)
        except ConfigError as exc:  # the explicit update: raise n_sub as the message says
            assert "control.n_sub" in str(exc)
            d["control"]["n_sub"] = int(str(exc).split("control.n_sub >= ")[1].split(",")[0])
            cfg = make_config(d)
        for env_id in IDS:
            _run(cfg, env_id, np.array([[0.0, 1.0], [1.0, 0.0], [1e300, -1e300]] * 10), 0)


@pytest.mark.parametrize("n_layers,dt_s", [(6, 60.0), (50, 30.0)])
def test_a_small_tank_under_heavy_draws_stays_within_its_temperatures(n_layers, dt_s):
    """A 20 l tank with the L cycle's 10 l/min taps at the fewest sub-steps accepted
    (EnvConfig.min_n_sub): without the draw's room in that rule and draw_flow's limit, the
    explicit update overshoots by hundreds of kelvin within a day."""
    d: dict[str, dict[str, Any]] = {
        "tank": {"volume_l": 20.0, "n_layers": n_layers, "UA_coil": 10.0, "coil_layers": 1},
        "control": {"dt_s": dt_s, "n_sub": 1000, "horizon_h": 24.0},
        "scenario": {"tapping_profile": "L", "draw_energy_cv": 2.0, "draw_jitter_min": 240.0},
    }
    d["control"]["n_sub"] = make_config(d).min_n_sub()
    cfg = make_config(d)
    with pytest.raises(ConfigError, match="control.n_sub"):
        make_config(d, control={"n_sub": cfg.control.n_sub - 1})
    for seed in range(3):
        _run(cfg, "ThermoValve-v0", np.full((300, 1), 0.5), seed)


# -- the benchmark tasks: every current id, single and batched, over a whole episode -------------

POLICIES = ("random", "bang_bang", "extreme")


def _policy_actions(policy: str, rng: np.random.Generator, n_steps: int, shape: tuple[int, ...],
                    lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n_steps, *shape) actions: uniform in the box; the box's corners held for a random 1-240
    steps each (a relay: long enough to charge the store to the supply, or let it cool); or
    +-1e300 (clipped by the env), likewise held."""
    if policy == "random":
        return rng.uniform(lo, hi, size=(n_steps, *shape))
    corners = np.empty((n_steps, *shape))
    k = 0
    while k < n_steps:
        hold = int(rng.integers(1, 241))
        corners[k: k + hold] = rng.integers(0, 2, size=shape)
        k += hold
    if policy == "bang_bang":
        return lo + corners * (hi - lo)
    return np.where(corners > 0, 1e300, -1e300)


def _assert_in_box(obs: np.ndarray, space: gym.spaces.Box, what: str) -> None:
    """Every row of ``obs`` finite and in ``space`` (vectorised: Box.contains row by row is slow),
    then Box.contains on the worst row, so gymnasium's own test agrees."""
    o = np.atleast_2d(obs)
    assert np.all(np.isfinite(o)), what
    low = np.argwhere(o < space.low)
    high = np.argwhere(o > space.high)
    assert low.size == 0 and high.size == 0, (
        f"{what}: below the box at (row, column) {low[:5].tolist()}, above at {high[:5].tolist()}; "
        f"columns' minima {o.min(axis=0)}, maxima {o.max(axis=0)}")
    assert space.contains(o[np.argmin(((o - space.low) / (space.high - space.low)).min(axis=1))])


@pytest.mark.parametrize("policy", POLICIES)
@pytest.mark.parametrize("task_id", valve_env.CURRENT_TASK_IDS)
def test_every_current_task_stays_in_its_box_batched(task_id: str, policy: str) -> None:
    """64 envs, a whole episode and into the next (autoreset): every observation finite and in
    the box, every reward finite. A relay charging the store to the supply and a supply plan
    dipping below it make the coil give heat back (a negative heat flow, docs/tasks.md)."""
    n = 64
    env = gym.make_vec(task_id, num_envs=n, vectorization_mode="vector_entry_point")
    space = env.single_observation_space
    lo, hi = env.single_action_space.low.astype(np.float64), env.single_action_space.high.astype(np.float64)
    n_steps = env.unwrapped.cfg.control.n_steps
    obs, _ = env.reset(seed=11)
    _assert_in_box(obs, space, f"{task_id} reset")
    u = _policy_actions(policy, np.random.default_rng(11), n_steps + 10, (n, lo.size), lo, hi)
    ended = 0
    for k, a in enumerate(u):
        obs, r, term, trunc, _ = env.step(a.astype(np.float32) if policy != "extreme" else a)
        _assert_in_box(obs, space, f"{task_id} {policy} step {k}")
        assert np.all(np.isfinite(r)), (task_id, policy, k)
        ended += int(np.sum(term | trunc))
    assert ended == n, f"{ended} of {n} episodes ended"
    env.close()


@pytest.mark.parametrize("policy", POLICIES)
@pytest.mark.parametrize("task_id", valve_env.CURRENT_TASK_IDS)
def test_every_current_task_stays_in_its_box_single(task_id: str, policy: str) -> None:
    """The single env (gym.make, its wrappers included), a whole episode and a reset."""
    env = gym.make(task_id)
    space = env.observation_space
    lo, hi = env.action_space.low.astype(np.float64), env.action_space.high.astype(np.float64)
    obs, _ = env.reset(seed=5)
    _assert_in_box(obs, space, f"{task_id} reset")
    u = _policy_actions(policy, np.random.default_rng(5), 3000, (lo.size,), lo, hi)
    ended = False
    for k, a in enumerate(u):
        obs, r, term, trunc, info = env.step(a.astype(np.float32) if policy != "extreme" else a)
        _assert_in_box(obs, space, f"{task_id} {policy} step {k}")
        assert np.isfinite(r), (task_id, policy, k)
        if term or trunc:
            assert all(np.isfinite(v) for v in info["kpis"].values() if v == v), info["kpis"]
            ended = True
            obs, _ = env.reset()
            _assert_in_box(obs, space, f"{task_id} reset after the episode")
    assert ended, "the run did not reach an episode's end"
