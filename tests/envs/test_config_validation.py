"""Config validation: every bad value is refused with one line naming section.field
(docs/configuration.md), the ranges in the docstring tables are the declared ones,
and the batched env's seeds are checked."""

from __future__ import annotations

import re
from dataclasses import fields

import gymnasium as gym
import numpy as np
import pytest

import valve_env  # noqa: F401  (registers the environments)
from valve_env.config import SECTIONS, make_config
from valve_env.params import ConfigError, Spec, field_spec, param

# (gym.make keywords, what the one-line message must name); the examples first
INVALID = [
    ({"valve": {"sigma": None}}, "valve.sigma"),
    ({"valve": {"antoine_A": 1e6}}, "valve.antoine_A"),
    ({"valve": {"antoine_B": -1e9}}, "valve.antoine_B"),
    ({"tank": {"volume_l": 1e-6}}, "tank.volume_l"),
    ({"tank": {"UA_loss": 1e9}}, "tank.UA_loss"),
    ({"tank": {"cp": 1e-9}}, "tank.cp"),
    ({"tank": {"rho": 1e-9}}, "tank.rho"),
    ({"sensors": {"flow_noise_rel": 1e39}}, "sensors.flow_noise_rel"),
    ({"valve": {"Kvs": 1e12}}, "valve.Kvs"),
    ({"T_target_C": 1e6}, "control.T_target_C"),
    ({"dp_mbar": 1e9}, "scenario.dp_mbar"),
    ({"control": {"n_sub": 1e7}}, "control.n_sub"),
    ({"valve": {"sigma": "abc"}}, "valve.sigma"),
    ({"valve": {"sigma": True}}, "valve.sigma"),
    ({"sensors": {"dead_time_steps": True}}, "sensors.dead_time_steps"),
    ({"scenario": {"stochastic_draws": 1}}, "scenario.stochastic_draws"),
    ({"tapping_profile": None}, "scenario.tapping_profile"),
    ({"valve": {"F_hmax": float("nan")}}, "valve.F_hmax"),
    ({"bulb": {"tau_s": float("inf")}}, "bulb.tau_s"),
    ({"tank": {"n_layers": 8.5}}, "tank.n_layers"),
    ({"tank": {"n_layers": 8, "coil_layers": 9}}, "tank.coil_layers"),
    ({"control": {"dt_s": 1e-3}}, "control.dt_s"),
    ({"control": {"horizon_h": 1e9}}, "control.horizon_h"),
    ({"control": {"dt_s": 1.0, "horizon_h": 8000.0}}, "control.horizon_h"),  # 2.9e7 steps
    ({"control": {"setting_min_C": 70.0, "setting_max_C": 60.0}}, "control.setting_min_C"),
    ({"control": {"setting_C": 90.0}}, "control.setting_C"),
    ({"control": {"dp_min_mbar": 300.0, "dp_max_mbar": 300.0}}, "control.dp_min_mbar"),
    ({"scenario": {"supply_profile": "daily", "supply_C": 130.0, "supply_amplitude_K": 30.0}},
     "scenario.supply_amplitude_K"),
    ({"control": {"dt_s": 3600.0, "n_sub": 1}}, "control.n_sub"),  # the explicit layer update
    ({"valve": 5}, "valve"),
    ({"valve": None}, "valve"),
    ({"valve": {"not_a_field": 1.0}}, "not_a_field"),
]


def _one_line_naming(exc: BaseException, name: str) -> None:
    msg = str(exc)
    assert "\n" not in msg, msg
    assert name in msg, msg
    assert "could not convert" not in msg and "NoneType" not in msg, msg


@pytest.mark.parametrize("kwargs,name", INVALID)
def test_every_bad_value_is_refused_in_one_line_naming_its_field(kwargs, name):
    with pytest.raises(ConfigError) as info:
        gym.make("ThermoValve-v0", **kwargs)
    _one_line_naming(info.value, name)


@pytest.mark.parametrize("kwargs,name", INVALID[:12])
def test_the_batched_env_takes_the_same_path(kwargs, name):
    with pytest.raises(ConfigError) as info:
        gym.make_vec("ThermoValve-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    _one_line_naming(info.value, name)


@pytest.mark.parametrize(
    "text,name",
    [
        ("valve:\n  sigma:\n", "valve.sigma"),  # a YAML key with no value
        ("valve:\n", "'valve'"),  # an empty section
        ("valve: 5\n", "'valve'"),
        ("valve:\n  sigma: abc\n", "valve.sigma"),
        ("valve:\n  sigma: 1e3\n", "valve.sigma"),  # YAML 1.1 reads this as text: the message says so
        ("valve:\n  sigma: .nan\n", "valve.sigma"),
        ("tank:\n  n_layers: yes\n", "tank.n_layers"),
        ("- 1\n- 2\n", "mapping of sections"),
        ("valve: [1, 2\n", "not valid YAML"),
        ("7: {}\n", "unknown section"),
    ],
)
def test_bad_yaml_files_are_refused_in_one_line(tmp_path, text, name):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        gym.make("ThermoValve-v0", config=str(p))
    _one_line_naming(info.value, name)


def test_a_binary_file_is_not_read_as_yaml(tmp_path):
    p = tmp_path / "bin.yaml"
    p.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(ConfigError) as info:
        gym.make("ThermoValve-v0", config=str(p))
    _one_line_naming(info.value, "not UTF-8")


def test_numbers_are_normalised_and_good_values_accepted():
    cfg = make_config(tank={"n_layers": 10.0, "coil_layers": np.int64(5)}, valve={"sigma": np.float32(5.5)})
    assert type(cfg.tank.n_layers) is int and cfg.tank.n_layers == 10 and type(cfg.tank.coil_layers) is int
    assert type(cfg.valve.sigma) is float and cfg.valve.sigma == 5.5
    # every shipped scenario config is within the ranges (tests/envs/test_env.py also runs them)
    assert make_config("configs/scenarios/pressure_disturbance.yaml").scenario.dp_noise_mbar == 30.0


def test_every_field_declares_its_range_and_the_docstring_table_shows_it():
    for section, cls in SECTIONS.items():
        assert cls.SECTION == section
        doc = cls.__doc__
        rows = {}
        for line in doc.splitlines():
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if len(cells) >= 4 and not set(cells[0]) <= {"-"}:
                for name in cells[0].split(","):
                    rows[name.strip()] = cells[-1]
        for f in fields(cls):
            spec = f.metadata.get("spec")
            assert isinstance(spec, Spec), f"{section}.{f.name} declares no range"
            assert f.metadata["range"] == (spec.lo, spec.hi) and f.metadata["unit"] == spec.unit
            assert f.name in rows, f"{section}.{f.name} is missing from the docstring table"
            assert rows[f.name].startswith(spec.describe()), (section, f.name, rows[f.name], spec.describe())
            if spec.kind in ("float", "int"):
                assert spec.why, f"{section}.{f.name} gives no reason for its range"
                assert spec.contains(float(f.default)), f"{section}.{f.name}'s default is outside its range"


def test_a_new_parameter_declares_its_range_with_param():
    """The way a registry of parameters (e.g. the valve's effects) declares and checks one."""
    from dataclasses import dataclass
    from typing import ClassVar

    from valve_env.params import check_fields

    @dataclass(frozen=True)
    class Lag:
        SECTION: ClassVar[str] = "valve.effects.sensor_lag"
        tau_s: float = param(60.0, 0.0, 3600.0, "s", "a sensor's lag", lo_open=True)

        def __post_init__(self) -> None:
            check_fields(self)

    assert Lag(tau_s=5).tau_s == 5.0
    with pytest.raises(ConfigError, match=re.escape("valve.effects.sensor_lag.tau_s must be in (0, 3600] s")):
        Lag(tau_s=0.0)
    assert field_spec(Lag, "tau_s").describe() == "(0, 3600]"


@pytest.mark.parametrize("seed", [1.5, True, -1, "7", [1, 2.5], [0], {"a": 1}])
def test_batched_reset_seeds_are_checked(seed):
    env = gym.make_vec("ThermoValve-v0", num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError) as info:
        env.reset(seed=seed)
    assert "\n" not in str(info.value) and "seed" in str(info.value)


def test_batched_reset_accepts_int_list_and_none():
    env = gym.make_vec("ThermoValve-v0", num_envs=2, vectorization_mode="vector_entry_point")
    a, _ = env.reset(seed=3)
    b, _ = env.reset(seed=[3, 4])
    assert np.array_equal(a, b)
    c, _ = env.reset(seed=[np.int64(3), None])
    assert np.array_equal(a[0], c[0])
    env.reset(seed=None)
    single = gym.make("ThermoValve-v0")
    with pytest.raises(ValueError, match="seed"):
        single.reset(seed=True)


def test_the_docs_table_of_ranges_is_the_declared_one():
    from pathlib import Path

    from valve_env.config import ranges_table

    doc = (Path(__file__).resolve().parents[2] / "docs" / "configuration.md").read_text()
    regenerate = "python -c 'import valve_env.config as c; print(c.ranges_table())'"
    assert ranges_table() in doc, f"regenerate docs/configuration.md's table: {regenerate}"
