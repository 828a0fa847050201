"""A short training run produces a loadable model that acts like the SB3
policy on its training wrappers, from raw observations."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

import valve_env  # noqa: F401
from agents.loader import AgentController, load_agent, load_from_files
from agents.train import ship
from agents.wrappers import make_vec_env

TINY_PPO = ("n_envs=2", "hyperparams.n_steps=128", "hyperparams.batch_size=64", "hyperparams.n_epochs=2")


def test_run_directory_has_everything(short_run: Path, short: dict) -> None:
    for name in ("config.yml", "command.txt", "run.json", "model.zip", "vecnormalize.pkl", "obs_norm.json"):
        assert (short_run / name).is_file(), name
    cfg = yaml.safe_load((short_run / "config.yml").read_text())
    assert cfg["algo"] == "ppo" and cfg["seed"] == 3 and cfg["n_timesteps"] == 2048
    assert cfg["env_kwargs"] == short and cfg["frame_stack"] >= 2
    assert (short_run / "command.txt").read_text().strip() == "pytest short_run"
    meta = json.loads((short_run / "run.json").read_text())
    assert meta["seed"] == 3 and meta["num_timesteps"] >= 2048 and meta["wall_time_s"] > 0
    assert cfg["vec_env"] == "native"  # configs/ppo.yml's default; VecMonitor: one file for all envs
    monitors = sorted((short_run / "monitor").glob("*.monitor.csv"))
    assert [m.name for m in monitors] == ["native.monitor.csv"]
    lines = monitors[0].read_text().splitlines()
    assert lines[1].startswith("r,l,t,rmse_K") and len(lines) > 2  # episodes with KPI columns
    assert list((short_run / "tb").glob("events.out.tfevents.*"))
    assert (short_run / "best" / "best_model.zip").is_file() and (short_run / "best" / "obs_norm.json").is_file()


def test_loaded_agent_steps_the_raw_env_with_valid_actions(short_run: Path, short: dict) -> None:
    ctrl = load_agent("ppo", "ThermoValve-v0", run_dir=short_run)
    env = gym.make("ThermoValve-v0", **short)
    obs, _ = env.reset(seed=11)
    state = None
    start = True
    done = False
    info: dict = {}
    while not done:
        act, state = ctrl.predict(obs, state, np.array([start]))
        start = False
        assert act.shape == (1,) and act.dtype == np.float32
        assert env.action_space.contains(act)
        obs, _, term, trunc, info = env.step(act)
        done = term or trunc
    assert "kpis" in info and np.isfinite(info["kpis"]["rmse_K"])


def _assert_replays_training_stack(run: Path, short: dict) -> None:
    """The deployed controller (raw obs -> raw action) replays frame stack,
    scaling/normalisation and the residual exactly: same rewards as the SB3
    model on the wrapped, normalised VecEnv."""
    cfg = yaml.safe_load((run / "config.yml").read_text())
    model = PPO.load(run / "model.zip", device="cpu")
    venv = make_vec_env("ThermoValve-v0", cfg, seed=0, n_envs=1, training=False)
    venv = VecNormalize.load(str(run / "vecnormalize.pkl"), venv.venv)
    venv.training = False
    venv.norm_reward = False
    venv.seed(21)
    o = venv.reset()
    # the final model and its statistics (load_agent(run_dir=...) prefers best/)
    ctrl = load_from_files(run / "model.zip", run / "config.yml", run / "obs_norm.json", "ThermoValve-v0", "ppo")
    env = gym.make("ThermoValve-v0", **short)
    raw, _ = env.reset(seed=21)
    state = None
    r_wrapped, r_raw = [], []
    for t in range(120):
        a, _ = model.predict(o, deterministic=True)
        o, _, _, _ = venv.step(a)
        r_wrapped.append(float(venv.get_original_reward()[0]))
        u, state = ctrl.predict(raw, state, np.array([t == 0]))
        raw, r, _, _, _ = env.step(u)
        r_raw.append(r)
    np.testing.assert_allclose(r_raw, r_wrapped, rtol=1e-5, atol=1e-7)


def test_controller_matches_the_policy_on_its_training_wrappers(short_run: Path, short: dict) -> None:
    _assert_replays_training_stack(short_run, short)


def test_controller_replays_running_normalisation_and_plain_rescaling(tmp_path: Path, short: dict) -> None:
    """The other wrapper options: VecNormalize observation statistics, no
    physical scaling, a plain RescaleAction (no residual), another stack depth."""
    from agents.train import train

    run = train(
        "ppo", "ThermoValve-v0", seed=1, timesteps=1024, out=tmp_path / "alt",
        overrides=[*TINY_PPO, "normalize.norm_obs=true", "obs_scaling=none", "residual=null", "frame_stack=3",
                   "energy_shaping=false"],
        env_kwargs=short, progress_bar=False, eval_freq=0, command="pytest",
    )
    cfg = yaml.safe_load((run / "config.yml").read_text())
    assert cfg["residual"] is None and cfg["frame_stack"] == 3
    assert json.loads((run / "obs_norm.json").read_text())["norm_obs"] is True
    _assert_replays_training_stack(run, short)


def test_batched_predict_equals_single_and_resets_rows(short_run: Path, short: dict) -> None:
    ctrl = load_agent("ppo", "ThermoValve-v0", run_dir=short_run)
    envs = [gym.make("ThermoValve-v0", **short) for _ in range(3)]
    obs = np.stack([e.reset(seed=40 + i)[0] for i, e in enumerate(envs)])
    sb, ss = None, [None, None, None]
    for t in range(30):
        starts = np.array([t == 0, t == 0 or t == 15, t == 0])
        ab, sb = ctrl.predict(obs, sb, starts)
        for i in range(3):
            ai, ss[i] = ctrl.predict(obs[i], ss[i], starts[i : i + 1])
            np.testing.assert_allclose(ab[i], ai, rtol=1e-6)
        obs = np.stack([e.step(ab[i])[0] for i, e in enumerate(envs)])
    assert sb.shape == (3, ctrl.state_size)


def test_ship_and_load_from_a_zoo(short_run: Path, tmp_path: Path) -> None:
    path = ship(short_run, zoo_dir=tmp_path)
    assert path == tmp_path / "ThermoValve-v0" / "ppo.zip"
    assert (tmp_path / "ThermoValve-v0" / "ppo.yml").is_file()
    assert (tmp_path / "ThermoValve-v0" / "ppo_obs_norm.json").is_file()
    ctrl = load_agent("ppo", "ThermoValve-v0", zoo=tmp_path)
    obs, _ = gym.make("ThermoValve-v0").reset(seed=0)
    act, _ = ctrl.predict(obs)
    assert 40.0 <= float(act[0]) <= 80.0
    with pytest.raises(ValueError, match="no shipped agent"):
        load_agent("sac", "ThermoValve-v0", zoo=tmp_path)
    with pytest.raises(ValueError, match="trained on"):
        (tmp_path / "ThermoValveDual-v0").mkdir()
        for suffix in (".zip", ".yml", "_obs_norm.json"):
            src = tmp_path / "ThermoValve-v0" / f"ppo{suffix}"
            (tmp_path / "ThermoValveDual-v0" / f"ppo{suffix}").write_bytes(src.read_bytes())
        load_agent("ppo", "ThermoValveDual-v0", zoo=tmp_path)


def test_make_controller_delegates_agents_to_the_loader(short_run: Path, tmp_path: Path) -> None:
    from valve_env.controllers import make_controller

    ship(short_run, zoo_dir=tmp_path)
    ctrl = make_controller("ppo", "ThermoValve-v0", zoo=tmp_path)
    assert isinstance(ctrl, AgentController)


def test_train_cli_help_and_config_errors(tmp_path: Path) -> None:
    from agents.train import load_algo_config
    from valve_env.cli import build_parser

    args = build_parser().parse_args(["train", "--algo", "ppo", "--env", "ThermoValve-v0", "--no-progress"])
    assert args.algo == "ppo" and args.no_progress
    for algo in ("ppo", "sac", "td3"):
        for env_id in valve_env.ENV_IDS:
            cfg = load_algo_config(algo, env_id)
            assert cfg["policy"] == "MlpPolicy" and cfg["frame_stack"] >= 2 and cfg["normalize"]
    with pytest.raises(KeyError, match="no entry"):
        load_algo_config("ppo", "Pendulum-v1")


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_off_policy_algos_train_briefly(algo: str, tmp_path: Path, short: dict) -> None:
    from agents.train import train

    run = train(algo, "ThermoValve-v0", seed=0, timesteps=300, out=tmp_path / algo,
                overrides=["hyperparams.learning_starts=100", "hyperparams.batch_size=32"],
                env_kwargs=short, progress_bar=False, eval_freq=0, command="pytest")
    ctrl = load_agent(algo, "ThermoValve-v0", run_dir=run)
    obs, _ = gym.make("ThermoValve-v0").reset(seed=0)
    act, _ = ctrl.predict(obs)
    assert 40.0 <= float(act[0]) <= 80.0


def test_a_failed_run_leaves_the_earlier_run_and_a_finished_one_replaces_it_whole(tmp_path: Path, short: dict) -> None:
    """A run fills a hidden directory beside its --out and takes its place at the end (valve_env.outputs.atomic_dir).
    A refused retrain with --force had rewritten config.yml, command.txt and run.json of the run it was to replace
    before failing, leaving another env's config beside the old model; and a finished retrain left the earlier
    run's other files behind."""
    from agents.train import train

    run = tmp_path / "run"
    kw: dict = {"seed": 0, "timesteps": 256, "overrides": list(TINY_PPO), "env_kwargs": short,
                "progress_bar": False, "eval_freq": 0}
    assert train("ppo", "ThermoValve-v0", out=run, command="first", **kw) == run
    (run / "stale.txt").write_text("from before")
    before = {f.name: f.read_bytes() for f in run.iterdir() if f.is_file()}
    with pytest.raises(AssertionError, match="n_steps"):  # SB3 refuses the model after the run has begun
        train("ppo", "ThermoValve-v0", out=run, command="refused",
              **{**kw, "overrides": [*TINY_PPO, "hyperparams.n_steps=0"]})
    assert {f.name: f.read_bytes() for f in run.iterdir() if f.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no hidden directory left
    train("ppo", "ThermoValve-v0", out=run, command="second", **kw)
    assert not (run / "stale.txt").exists()
    assert (run / "command.txt").read_text() == "second\n" and (run / "model.zip").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
