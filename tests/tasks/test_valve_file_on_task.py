"""A valve file on a task (docs/tasks.md, "A valve file on a task"): the task's own effects stay, the
file's are added, an effect both name takes the file's parameters with a warning naming both, and
``null`` removes one; the ``valve=`` keyword combines the same way."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import valve_env  # noqa: F401  (registers the environments)
from valve_env.config import EffectOverrideWarning
from valve_env.params import ConfigError
from valve_env.valvefile import valve_text

TASK = "ThermoValveStickyValve-v0"  # its own effect: stiction, band_mm 0.1
BASE = {"sigma": 6.0, "F_hmax": 1.2, "p_bset": 0.0776}
SHORT = {"horizon_h": 1.0, "max_episode_steps": 120}


def _valve_file(tmp_path: Path, effects: dict, name: str = "valve.yaml") -> Path:
    """A valve file as ``thermovalve diagnose --valve-out`` writes it (valve_env.valvefile)."""
    p = tmp_path / name
    p.write_text(valve_text(BASE, effects, source="test"))
    return p


def _rollout(env: gym.Env) -> tuple[np.ndarray, list[bool]]:
    env.reset(seed=3)
    x, stuck = [], []
    for k in range(120):
        _, _, _, trunc, info = env.step(np.array([50.0 if (k // 20) % 2 else 70.0], np.float32))
        x.append(info["x_mm"])
        stuck.append(bool(info.get("stuck", False)))  # reported where the valve has stiction
        if trunc:
            break
    return np.array(x), stuck


def test_a_valve_file_adds_its_effects_to_the_tasks_own(tmp_path: Path) -> None:
    vfile = _valve_file(tmp_path, {"sensor_lag": {"tau_s": 90.0}})
    with warnings.catch_warnings():
        warnings.simplefilter("error", EffectOverrideWarning)  # nothing overridden: no warning
        env = gym.make(TASK, config=str(vfile), **SHORT)
        cfg = env.unwrapped.cfg
        assert cfg.effects.as_dict() == {"sensor_lag": {"tau_s": 90.0}, "stiction": {"band_mm": 0.1}}
        assert (cfg.valve.sigma, cfg.valve.F_hmax) == (6.0, 1.2)  # the file's base parameters
        x_both, stuck = _rollout(env)
        assert any(stuck), "the task's stiction no longer holds the stem (no info['stuck'])"
        # both effects act: without the file's sensor lag, or without the task's stiction, the stem moves otherwise
        x_task, _ = _rollout(gym.make(TASK, valve=BASE, **SHORT))
        x_file, _ = _rollout(gym.make(TASK, config=str(vfile), valve={"effects": {"stiction": None}}, **SHORT))
        assert not np.allclose(x_both, x_task) and not np.allclose(x_both, x_file)
        # the batched env builds the same configuration and reports the stem's state too
        venv = gym.make_vec(TASK, num_envs=2, vectorization_mode="vector_entry_point", config=str(vfile))
        assert venv.unwrapped.cfg.effects == cfg.effects
        venv.reset(seed=0)
        info = venv.step(np.full((2, 1), 60.0, np.float32))[-1]
        assert "stuck" in info and info["stuck"].shape == (2,)


def test_a_valve_file_that_overrides_a_tasks_effect_warns_naming_both(tmp_path: Path) -> None:
    vfile = _valve_file(tmp_path, {"stiction": {"band_mm": 0.04}, "sensor_lag": {"tau_s": 90.0}}, "sticky.yaml")
    with pytest.warns(EffectOverrideWarning) as rec:
        env = gym.make(TASK, config=str(vfile), **SHORT)
    msg = str(rec[0].message)
    assert "stiction" in msg and "0.04" in msg and "0.1" in msg and TASK in msg and "sticky.yaml" in msg, msg
    assert env.unwrapped.cfg.effects.as_dict() == {"sensor_lag": {"tau_s": 90.0}, "stiction": {"band_mm": 0.04}}
    # told once per process: the envs of an evaluation, built from the same file, do not repeat it
    with warnings.catch_warnings():
        warnings.simplefilter("error", EffectOverrideWarning)
        gym.make_vec(TASK, num_envs=2, vectorization_mode="vector_entry_point", config=str(vfile))
    # the same parameters as the task's are no override
    same = _valve_file(tmp_path, {"stiction": {"band_mm": 0.1}}, "same.yaml")
    with warnings.catch_warnings():
        warnings.simplefilter("error", EffectOverrideWarning)
        assert gym.make(TASK, config=str(same)).unwrapped.cfg.effects.as_dict() == {"stiction": {"band_mm": 0.1}}


def test_the_keyword_combines_by_the_same_rule_without_a_warning() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", EffectOverrideWarning)
        eff = gym.make(TASK, valve={"effects": {"medium_temperature": {"beta": 0.1}}}).unwrapped.cfg.effects
        assert set(eff.names) == {"stiction", "medium_temperature"}
        eff = gym.make(TASK, valve={"effects": {"stiction": {"band_mm": 0.02}}}).unwrapped.cfg.effects
        assert eff.as_dict() == {"stiction": {"band_mm": 0.02}}
        assert not gym.make(TASK, valve={"effects": {"stiction": None}}).unwrapped.cfg.effects
        assert gym.make(TASK, valve={"effects": {}}).unwrapped.cfg.effects.names == ("stiction",)


def test_null_removes_only_an_effect_that_is_there(tmp_path: Path) -> None:
    p = tmp_path / "drop.yaml"
    p.write_text("valve:\n  effects:\n    stiction: null\n")
    assert not gym.make(TASK, config=str(p)).unwrapped.cfg.effects
    with pytest.raises(ConfigError, match=r"stiction is empty \(None\).*no stiction to remove"):
        gym.make("ThermoValve-v0", config=str(p))
