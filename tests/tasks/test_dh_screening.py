"""Screening a district-heating task variant: the oracle bills as the env it controls does (a ``tariff=``
override included), and ``controllers_bench.py --env-kwargs`` rejects bad input in one line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest

import valve_env  # noqa: F401  (registers the task ids)
from valve_env.controllers import make_controller

DH = "ThermoValveDistrictHeating-v0"


def test_oracle_simulator_carries_the_bound_envs_tariff() -> None:
    """An oracle bound to an env with a tariff override plans on a simulator with that tariff; the
    default env's simulator keeps the default, and the two do not share one."""
    envs = [gym.make(DH, tariff={"surcharge_per_K": 0.02, "price_max_rel": 1.8}), gym.make(DH)]
    try:
        for e in envs:
            e.reset(seed=0)
        o = make_controller("oracle", DH, samples=2)
        o.bind_envs(envs)
        sims = [o._simulator(e.unwrapped) for e in envs]
        assert sims[0] is not sims[1]
        assert sims[0].layer.tariff.surcharge_per_K == 0.02 and sims[0].layer.tariff.price_max_rel == 1.8
        assert sims[1].layer.tariff == envs[1].unwrapped.layer.tariff
        assert sims[1].layer.tariff.surcharge_per_K == 0.01
        o.close()
    finally:
        for e in envs:
            e.close()


@pytest.mark.parametrize("bad", ["{\"tariff\": ", '{"tariff": {"surcharge_per_K": -1}}', "[]"])
def test_controllers_bench_rejects_bad_env_kwargs_in_one_line(bad: str) -> None:
    """``bound --env-kwargs``: malformed JSON, an out-of-range tariff value or a non-object stop before
    any episode with one error line and exit status 2."""
    script = Path(__file__).resolve().parents[2] / "benchmarks" / "controllers_bench.py"
    res = subprocess.run([sys.executable, str(script), "bound", "--tasks", DH, "--env-kwargs", bad],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("thermovalve: error:")]
    assert len(errors) == 1 and "--env-kwargs" in errors[0]
    assert res.stdout == ""
