"""``thermovalve bench`` runs and writes every figure; speed itself is never asserted."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from valve_env import bench, cli


@pytest.fixture
def small_bench(monkeypatch: pytest.MonkeyPatch) -> None:
    """The --quick run at toy sizes, so the test stays light."""
    monkeypatch.setattr(bench, "QUICK_SIZES", (1, 16))
    monkeypatch.setattr(bench, "QUICK_SYNC_SIZES", (16,))
    monkeypatch.setattr(bench, "MEMORY_N", 32)
    monkeypatch.setattr(bench, "EVIDENCE_N", 64)
    monkeypatch.setattr(bench, "YEAR_DAYS", 2)
    monkeypatch.setattr(bench, "MEASURE_STARTUP", False)


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="thermovalve")
    bench.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return int(args.func(args))


def test_bench_is_a_cli_subcommand() -> None:
    assert "valve_env.bench" in cli.SUBCOMMAND_MODULES


@pytest.mark.slow  # about a minute on 2 cores: it times every part of the package (make test-slow)
def test_bench_quick_writes_every_figure(small_bench: None, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "bench.json"
    assert _run(["bench", "--quick", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    for key in ("machine", "single_env", "batched", "sync", "ratios", "best_batched", "memory", "pi_year",
                "evidence", "estimation", "diagnosis", "targets"):
        assert key in res, key
    for key in ("cpu", "logical_cores", "python", "numpy", "numba", "gymnasium"):
        assert key in res["machine"]
    s = res["single_env"]
    assert s["thermovalve_steps_per_s"] > 0 and s["pendulum_steps_per_s"] > 0
    assert math.isclose(s["ratio"], s["thermovalve_steps_per_s"] / s["pendulum_steps_per_s"])
    assert [r["num_envs"] for r in res["batched"]] == [1, 16]
    assert all(r["env_steps_per_s"] > 0 and r["env_steps_per_s_incl_resets"] > 0 for r in res["batched"])
    assert res["ratios"]["batched_vs_sync_at_16"] > 0
    assert res["memory"]["num_envs"] == 32 and res["memory"]["peak_MB"] > 0
    assert "tracemalloc" in res["memory"]["method"]
    year = res["pi_year"]
    assert ("not available" in year) or (year["env_steps"] == 2 * 2880 and year["seconds"] > 0)
    ev = res["evidence"]
    assert ev["kernel_step_us"]["speedup"] > 0
    assert {"numba_loop_ns_per_env_step", "numpy_arrays_ns_per_env_step"} <= set(ev["numpy_vs_numba_valve_part"][0])
    assert ev["threads_vs_serial"]["num_envs"] == 64
    # the other engineers' figures: either there, or an explicit reason
    for key in ("estimation", "diagnosis"):
        assert isinstance(res[key], dict) and res[key]
    for t in res["targets"].values():
        assert {"target", "measured", "met"} <= set(t)
    table = capsys.readouterr().out
    assert "| ratio ThermoValve / Pendulum |" in table and "SyncVectorEnv" in table


def test_year_harness_takes_any_predict_controller() -> None:
    class Constant:
        def predict(self, observation: np.ndarray, state: object = None, episode_start: object = None,
                    deterministic: bool = True) -> tuple[np.ndarray, object]:
            return np.full((observation.shape[0], 1), 61.0, np.float32), state

    res = bench.run_year(Constant(), days=3, horizon_h=0.5)
    assert res["episodes"] == 3 and res["env_steps"] == 3 * 60
    assert set(res["mean_kpis"]) >= {"rmse_K", "heat_kWh"}
    assert np.isfinite(res["mean_return"])


def test_identification_figures_are_never_silently_missing() -> None:
    def no_such_figure() -> dict[str, float]:
        raise ImportError("no module named valve_env.no_such_module_for_bench")

    res = bench._guarded(no_such_figure)
    assert "not available" in res and "no_such_figure" in res["not available"]
    assert "no_such_module_for_bench" in res["not available"]


class _SlowResetVecEnv:
    """A stand-in vector env: every 5th step ends the episode, and the step after it
    (the autoreset) takes 20 ms where a plain step takes none."""

    num_envs = 4

    def __init__(self) -> None:
        import gymnasium as gym

        self.action_space = gym.spaces.Box(-1.0, 1.0, (4, 1))
        self.k = 0
        self.reset_steps = 0

    def step(self, _a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        import time

        self.k += 1
        if self.k % 5 == 1 and self.k > 1:  # the step after an end: the autoreset
            self.reset_steps += 1
            time.sleep(0.02)
        end = np.full(4, self.k % 5 == 0)
        return np.zeros((4, 1)), np.zeros(4), np.zeros(4, bool), end, {}


def test_vector_rate_times_stepping_only() -> None:
    # the autoreset steps are run but not timed (resets count once, from env.reset)
    env = _SlowResetVecEnv()
    rate, steps = bench._vector_rate(env, seconds=0.1, min_steps=20)  # type: ignore[arg-type]
    assert env.reset_steps >= 3
    assert steps >= 20
    assert rate > 4 * steps / 0.02  # one timed reset step of 20 ms would have capped the rate there
