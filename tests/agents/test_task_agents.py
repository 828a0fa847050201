"""The agents on the benchmark tasks: observation aids, the draw feedforward of the residual, the benchmark tasks'
shipped agents (scored by ``thermovalve evaluate``) and the task leaderboard."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import valve_env
from agents.loader import available_agents, load_agent
from agents.wrappers import DrawForecast, ObsFeatures, ResidualCore, time_of_day_s
from valve_env.config import EnvConfig
from valve_env.scenario import ScenarioParams, tapping_cycle

SMALL = "ThermoValveSmallCylinder-v0"
TASK_AGENTS = [(t, n) for t in valve_env.TASK_IDS for n in available_agents(t)]


def _obs_at(t_s: np.ndarray) -> np.ndarray:
    obs = np.zeros((len(t_s), 12), np.float32)
    obs[:, 8] = np.sin(2 * np.pi * t_s / 86400.0)
    obs[:, 9] = np.cos(2 * np.pi * t_s / 86400.0)
    return obs


def test_time_of_day_is_read_back_from_the_observation() -> None:
    t = np.array([0.0, 3600.0, 43200.0, 86000.0])
    np.testing.assert_allclose(time_of_day_s(_obs_at(t)), t, atol=0.05)


@pytest.mark.parametrize("jitter", [0.0, 20.0])
def test_draw_forecast_windows_add_up_to_the_tabled_cycle(jitter: float) -> None:
    """Adjacent windows tile the day: their forecasts sum to the cycle's energy, and without
    jitter a window holds exactly the draws tabled in it."""
    sc = ScenarioParams.from_dict({"tapping_profile": "L", "draw_jitter_min": jitter,
                                   "stochastic_draws": jitter > 0})
    fc = DrawForecast.from_config({"edges_h": [0, 6, 12, 18, 24]}, EnvConfig(scenario=sc))
    total = float(tapping_cycle("L")["Qtap_kWh"].sum())
    f = fc(_obs_at(np.array([0.0, 5000.0])))
    np.testing.assert_allclose(f.sum(axis=1), total, rtol=1e-9)
    if jitter == 0.0:
        cyc = tapping_cycle("L")
        morning = cyc.loc[cyc["t_start_s"] < 6 * 3600.0 + 0.0, "Qtap_kWh"].sum()
        assert f[0, 1] == pytest.approx(cyc.loc[(cyc["t_start_s"] >= 6 * 3600) & (cyc["t_start_s"] < 12 * 3600),
                                                "Qtap_kWh"].sum())
        assert f[0, 0] == pytest.approx(morning)


def test_batched_features_and_history_are_the_single_env_s_bit_for_bit() -> None:
    """The native stack computes the draw forecast once per distinct time of day and pushes the
    frame history in place; the single env's stack computes them row by row, allocating: the same
    numbers, bit for bit (times shared by several envs, as envs started together share them)."""
    from agents.wrappers import push_history

    sc = ScenarioParams.from_dict({"tapping_profile": "M", "draw_jitter_min": 20.0, "stochastic_draws": True})
    fc = DrawForecast.from_config({"edges_h": [0.0, 0.5, 1.0, 2.0, 4.0], "times": ["T_bottom_C"]},
                                  EnvConfig(scenario=sc))
    rng = np.random.default_rng(0)
    obs = _obs_at(rng.choice([0.0, 30.0, 25200.0, 61230.0, 86370.0], size=40))
    obs[:, 2] = rng.uniform(30.0, 60.0, size=40)
    batch = fc(obs)
    assert np.array_equal(batch, np.concatenate([fc(obs[i : i + 1]) for i in range(40)]))
    hist = rng.normal(size=(40, 4, 7)).astype(np.float32)
    new = rng.normal(size=(40, 7)).astype(np.float32)
    starts = rng.uniform(size=40) < 0.3
    expected = push_history(hist, new, starts)
    assert np.array_equal(push_history(hist.copy(), new, starts, in_place=True), expected)


def test_observation_aid_errors_name_the_problem() -> None:
    env = gym.make("ThermoValve-v0", scenario={"tapping_profile": "none"})
    with pytest.raises(ValueError, match="tapping profile"):
        ObsFeatures.from_config({"obs_aids": {"draw_forecast": {}}}, env)
    with pytest.raises(ValueError, match="unknown observation aid"):
        ObsFeatures.from_config({"obs_aids": {"weather": {}}}, env)
    with pytest.raises(ValueError, match="edges_h"):
        ObsFeatures.from_config({"obs_aids": {"draw_forecast": {"edges_h": [1, 0.5]}}}, gym.make(SMALL))


def test_residual_draw_feedforward_adds_kff_per_litre() -> None:
    space = gym.make(SMALL).action_space
    core = ResidualCore.from_config({"center": ["target"], "span": [15.0], "kp": [0.0], "ki": [0.0], "kff": [1.5]},
                                    space, 30.0)
    obs = np.zeros((2, 12))
    obs[:, 11] = 60.0
    obs[:, 0] = 60.0
    obs[:, 7] = [0.0, 6.0]
    u, _ = core.step(obs, np.zeros((2, 1)), core.initial_state(2))
    np.testing.assert_allclose(u[:, 0], [60.0, 69.0])


def test_features_with_aids_are_the_same_in_training_and_deployment(tmp_path: Path) -> None:
    """A short native-VecEnv PPO run with the draw forecast: the deployed controller on the raw
    env earns exactly the rewards of the model on its training stack."""
    from stable_baselines3 import PPO

    from agents.train import train
    from agents.wrappers import make_vec_env

    short = {"control": {"horizon_h": 2.0}}
    run = train("ppo", SMALL, seed=0, timesteps=512, out=tmp_path / "r",
                overrides=["optimizer=sgd", "n_envs=2", "hyperparams.n_steps=256", "hyperparams.batch_size=128",
                           "hyperparams.n_epochs=1"],
                env_kwargs=short, progress_bar=False, eval_freq=0, command="pytest")
    import yaml

    cfg = yaml.safe_load((run / "config.yml").read_text())
    assert cfg["obs_aids"] and cfg["residual"]["kff"]
    model = PPO.load(run / "model.zip", device="cpu")
    venv = make_vec_env(SMALL, cfg, seed=0, n_envs=1, training=False)
    venv.seed(7)
    o = venv.reset()
    ctrl = load_agent("ppo", SMALL, run_dir=run)
    env = gym.make(SMALL, **short)
    raw, _ = env.reset(seed=7)
    state = None
    for t in range(240):
        a, _ = model.predict(o, deterministic=True)
        o, r_w, _, _ = venv.step(a)
        u, state = ctrl.predict(raw, state, np.array([t == 0]))
        raw, r, _, _, _ = env.step(u)
        assert r == pytest.approx(float(venv.get_original_reward()[0]), rel=1e-5, abs=1e-6)


def test_draw_owed_is_the_habit_since_the_start_less_what_the_tank_delivered() -> None:
    """draw_owed, without jitter: the tabled energy of the draws started in each window of the last hours
    (only since the episode began) less the energy delivered at the outlet above the cold mains, at
    least 0; a row that begins an episode starts with an empty memory."""
    from agents.wrappers import DrawOwed

    cfg = EnvConfig(scenario=ScenarioParams.from_dict({"tapping_profile": "L", "stochastic_draws": False}))
    owed = DrawOwed.from_config({"windows_h": [1.0, 3.0]}, cfg)
    assert owed.names == ("owed_kWh_1h", "owed_kWh_3h") and owed.memory_size == 3 * 120 + 1 + 2
    cyc = tapping_cycle("L")

    def tabled(lo_h: float, hi_h: float) -> float:  # draws started in (lo, hi], hours of the day
        s = cyc["t_start_s"] / 3600.0
        return float(cyc.loc[(s > lo_h) & (s <= hi_h), "Qtap_kWh"].sum())

    def run(start_h: float, end_h: float, draw_at_h: float | None = None, rate: float = 10.0,
            aid: DrawOwed = owed) -> np.ndarray:
        mem = np.full((1, aid.memory_size), 7.0)  # an episode's leftovers: its start clears them
        k_end = int(round((end_h - start_h) * 120))
        for k in range(k_end + 1):
            o = _obs_at(np.array([start_h * 3600.0 + 30.0 * k]))
            o[0, 0] = 55.0  # T_out_C
            if draw_at_h is not None and 0 <= k - int(round((draw_at_h - start_h) * 120)) < 2:
                o[0, 7] = rate  # l/min over the step that ended here
            f, mem = aid.step(o, mem, np.array([k == 0]))
        return f[0]

    delivered = 2 * 10.0 * 0.5 * 1.0 * 4180.0 / 3.6e6 * (55.0 - 10.0)  # two steps of 10 l/min at 45 K
    np.testing.assert_allclose(run(0.0, 8 + 1 / 6), [tabled(7 + 1 / 6, 8 + 1 / 6), tabled(5 + 1 / 6, 8 + 1 / 6)],
                               rtol=1e-6)
    np.testing.assert_allclose(run(0.0, 8 + 1 / 6, draw_at_h=8.1),
                               [tabled(7 + 1 / 6, 8 + 1 / 6) - delivered, tabled(5 + 1 / 6, 8 + 1 / 6) - delivered],
                               rtol=1e-6)
    assert tabled(7 + 1 / 6, 8 + 1 / 6) > 3.6  # the morning bath is in the window
    # an episode begun at 21:15: its 3 h window at 22:15 holds only the 21:30 draw, not the 21:00 bath
    np.testing.assert_allclose(run(21.25, 22.25)[1], tabled(21.25, 22.25), rtol=1e-6)
    assert tabled(21.25, 22.25) < tabled(19.25, 22.25) - 3.0
    # more delivered than the habit expects: nothing owed
    assert tabled(6.5, 7.5) < 4 * delivered
    assert run(0.0, 7.5, draw_at_h=7.25, rate=40.0)[0] == 0.0
    # lead_h: energy delivered up to that much before the window pays for the window's habit (an early bath)
    led = DrawOwed.from_config({"windows_h": [1.0, 3.0], "lead_h": 1.0}, cfg)
    assert led.memory_size == 4 * 120 + 1 + 2
    np.testing.assert_allclose(run(0.0, 8 + 1 / 6, draw_at_h=6.75, aid=led)[0],
                               tabled(7 + 1 / 6, 8 + 1 / 6) - delivered, rtol=1e-6)
    np.testing.assert_allclose(run(0.0, 8 + 1 / 6, draw_at_h=6.75)[0], tabled(7 + 1 / 6, 8 + 1 / 6), rtol=1e-6)
    with pytest.raises(ValueError, match="windows_h"):
        DrawOwed.from_config({"windows_h": [0.0]}, cfg)
    with pytest.raises(ValueError, match="lead_h"):
        DrawOwed.from_config({"lead_h": -1.0}, cfg)


def test_a_memory_aid_is_replayed_exactly_by_the_deployed_controller(tmp_path: Path) -> None:
    """A CEM run with draw_owed on 9 h episodes (the morning's first draws): the saved model, loaded as a
    controller on the raw env (the aid's memory in its state), earns exactly the returns the search
    measured; a plain call of the features of such an aid is refused."""
    from agents.train import train
    from agents.wrappers import ObsFeatures
    from valve_env.evaluation.evaluator import run_episodes

    nine = {"control": {"horizon_h": 9.0}}
    run = train("ppo", SMALL, seed=0, out=tmp_path / "cem", env_kwargs=nine, progress_bar=False, command="pytest",
                overrides=["cem={popsize: 4, episodes: 2, elite: 2, generations: 1, sigma: 0.3, eval_every: 1}",
                           "eval.episodes=2", "obs_aids.draw_owed={windows_h: [0.5, 2.0]}"])
    ev = np.load(run / "best" / "evaluations.npz")
    ctrl = load_agent("ppo", SMALL, run_dir=run)
    assert ctrl.features.memory_size == 4 * 60 + 1 + 2
    got = run_episodes(ctrl, SMALL, 2, 10_000, nine)["return"].to_numpy()
    np.testing.assert_allclose(got, ev["results"][int(np.argmax(ev["results"].mean(axis=1)))], rtol=1e-9)
    with pytest.raises(TypeError, match="memory"):
        ObsFeatures.from_config({"obs_aids": {"draw_owed": {}}}, gym.make(SMALL))(np.zeros(12))


def test_cem_run_is_a_ppo_model_the_loader_replays_exactly(tmp_path: Path) -> None:
    """optimizer: cem (agents.cem) on one-hour episodes: the run directory has the learning curve
    and the evaluations, and the saved PPO model, loaded as a controller on the raw env, earns
    exactly the return the search measured for it on the evaluation seeds."""
    from agents.train import train
    from valve_env.evaluation.evaluator import run_episodes

    short = {"control": {"horizon_h": 1.0}}
    run = train("ppo", SMALL, seed=0, out=tmp_path / "cem", env_kwargs=short, progress_bar=False, command="pytest",
                overrides=["cem={popsize: 4, episodes: 2, elite: 2, generations: 2, sigma: 0.3, eval_every: 1}",
                           "eval.episodes=2"])
    rows = pd.read_csv(run / "cem.csv")
    assert list(rows["generation"]) == [0, 1] and (rows["env_steps"] == [4 * 2 * 120, 2 * 4 * 2 * 120]).all()
    ev = np.load(run / "best" / "evaluations.npz")
    assert ev["results"].shape == (3, 2)
    meta = json.loads((run / "run.json").read_text())
    assert meta["optimizer"] == "cem" and meta["num_timesteps"] == 1920
    ctrl = load_agent("ppo", SMALL, run_dir=run)  # best/: the best evaluation
    got = run_episodes(ctrl, SMALL, 2, 10_000, short)["return"].to_numpy()
    np.testing.assert_allclose(got, ev["results"][int(np.argmax(ev["results"].mean(axis=1)))], rtol=1e-6)
    with pytest.raises(ValueError, match="linear action head"):
        train("ppo", SMALL, seed=0, out=tmp_path / "bad", env_kwargs=short, progress_bar=False, command="pytest",
              overrides=["hyperparams.policy_kwargs.net_arch=[8]"])


@pytest.mark.parametrize(("task", "name"), TASK_AGENTS)
def test_shipped_task_agent_is_scored_by_thermovalve_evaluate(task: str, name: str, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Through the command's own entry, ``valve_env.cli.main``, in this process (the next test runs one agent in a
    fresh interpreter, as a shell does)."""
    from valve_env.cli import main

    out = tmp_path / "eval.json"
    code = main(["evaluate", "--env", task, "--controllers", f"{name},pi", "--episodes", "1", "--seed", "5000",
                 "--json", str(out), "--env-kwargs", "horizon_h=2"])
    assert code == 0, capsys.readouterr().err
    data = json.loads(out.read_text())
    assert data["env"] == task
    assert np.isfinite(data["results"][name]["return"]["mean"])
    assert data["results"][name]["kpis"]["tdis_Kh"]["mean"] >= 0


def test_a_shipped_task_agent_through_a_fresh_interpreter(tmp_path: Path) -> None:
    """``python -m valve_env.cli evaluate`` in a new process: the agent's plug-in is found and loaded there too."""
    import subprocess
    import sys

    task, name = TASK_AGENTS[0]
    out = tmp_path / "eval.json"
    res = subprocess.run([sys.executable, "-m", "valve_env.cli", "evaluate", "--env", task, "--controllers", name,
                          "--episodes", "1", "--seed", "5000", "--json", str(out), "--env-kwargs", "horizon_h=1"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert np.isfinite(json.loads(out.read_text())["results"][name]["return"]["mean"])


def test_task_leaderboard_regenerates_into_out(tmp_path: Path, monkeypatch: Any) -> None:
    """One command writes the report into --out (never docs/ unless --docs), with the oracle's
    episodes from the cache, the scores, the goal check and the generalisation table."""
    from agents import task_leaderboard as tl

    if not TASK_AGENTS:
        pytest.skip("no shipped agent for a benchmark task")
    task = TASK_AGENTS[0][0]
    seeds = [5000, 5001]
    cache = tmp_path / "episodes.csv"
    pd.DataFrame({"task": task, "controller": "oracle", "seed": seeds, "return": [-100.0, -120.0],
                  "tdis_Kh": 0.5, "reversals": 10.0}).to_csv(cache, index=False)
    # one hour episodes keep this short: every controller is built from the task id alone, so
    # the horizon goes in through run_episodes' env_kwargs
    from valve_env.evaluation import evaluator

    orig = evaluator.run_episodes
    monkeypatch.setattr(evaluator, "run_episodes",
                        lambda c, env_id, episodes, seed, env_kwargs=None, config=None:
                        orig(c, env_id, episodes, seed, {"control": {"horizon_h": 1.0}}, config))
    out = tmp_path / "board"
    scratch = tmp_path / "scratch"  # per-run scores as python -m agents.scratch evaluate stores them
    scratch.mkdir()
    pd.DataFrame({"algo": ["sac"] * 3, "task": task, "seed": [0, 1, 2], "gap_score": [-3.0, 0.1, 0.2],
                  "cost": [9.0, 1.0, 2.0], "eval_seeds": "5000-5001", "n_timesteps": 100, "train_cpu_s": 6.0,
                  "train_wall_s": 9.0, "best_checkpoint_step": [0, 50, 100]}).to_csv(scratch / "runs.csv", index=False)
    rc = tl.main(["--tasks", task, "--episodes", "2", "--oracle-cache", str(cache), "--out", str(out),
                  "--no-generalisation", "--scratch", str(scratch)])
    assert rc == 0
    text = (out / "task_leaderboard.md").read_text()
    assert "| oracle | oracle |" in text and "gap closed" in text and "5000-5001" in text
    # the IQM of three runs trims none (rliable: scipy's 25 % trimmed mean cuts int(0.75) = 0 runs each side):
    # the gap scores' mean -0.9 and the costs' 4; the runs have no score column (n/a)
    assert f"| {task} | sac from scratch | 3 | -0.9 [" in text and "| n/a | 4 [" in text
    assert "engineered (base law:" in text
    assert "sac 1 of 3" in text  # one run's best checkpoint was the untrained policy
    assert (out / "figures" / "task_leaderboard_scratch.png").stat().st_size > 0
    data = json.loads((out / "task_leaderboard.json").read_text())
    rows = {r["controller"]: r for r in data["tasks"][task]["table"]}
    assert rows["self_acting"]["score"] == pytest.approx(0.0) and rows["oracle"]["score"] == pytest.approx(1.0)
    assert (out / "figures" / "task_leaderboard.png").stat().st_size > 0
    assert tl.main(["--tasks", task, "--episodes", "2", "--oracle-cache", str(cache), "--out", str(out),
                    "--no-generalisation"]) == 2  # no replacing without --force
    # --reuse: the built-in controllers' episodes come from the earlier board, the agents run again
    again = tmp_path / "again"
    assert tl.main(["--tasks", task, "--episodes", "2", "--oracle-cache", str(cache), "--out", str(again),
                    "--no-generalisation", "--reuse", str(out / "task_episodes.csv")]) == 0
    first, second = (pd.read_csv(d / "task_episodes.csv").set_index(["controller", "seed"]) for d in (out, again))
    pd.testing.assert_frame_equal(second.sort_index(), first.sort_index(), check_like=True)


def test_time_of_day_harmonics_and_forecast_interactions() -> None:
    """time_of_day: sin/cos of k x the clock angle; draw_forecast.times: each window's forecast
    times the named column's physical scaling (T_bottom_C: (T - 40) / 15)."""
    from agents.wrappers import TimeOfDay

    t = np.array([0.0, 21600.0, 30000.0])
    tod = TimeOfDay.from_config({"harmonics": [2, 3]}, None)
    assert tod.names == ("tod_sin2", "tod_cos2", "tod_sin3", "tod_cos3")
    ang = 2 * np.pi * t / 86400.0
    np.testing.assert_allclose(tod(_obs_at(t)), np.stack([np.sin(2 * ang), np.cos(2 * ang), np.sin(3 * ang),
                                                          np.cos(3 * ang)], axis=1), atol=1e-5)
    with pytest.raises(ValueError, match="harmonics"):
        TimeOfDay.from_config({"harmonics": [1]}, None)
    sc = ScenarioParams.from_dict({"tapping_profile": "L"})
    plain = DrawForecast.from_config({"edges_h": [0, 1, 2]}, EnvConfig(scenario=sc))
    crossed = DrawForecast.from_config({"edges_h": [0, 1, 2], "times": ["T_bottom_C"]}, EnvConfig(scenario=sc))
    assert crossed.names[2:] == ("draw_kWh_0-1h*T_bottom_C", "draw_kWh_1-2h*T_bottom_C")
    obs = _obs_at(np.array([25000.0, 70000.0]))
    obs[:, 2] = [25.0, 55.0]
    f, g = plain(obs), crossed(obs)
    np.testing.assert_allclose(g[:, :2], f)
    np.testing.assert_allclose(g[:, 2:], f * np.array([[-1.0], [1.0]]))
    with pytest.raises(ValueError, match="times"):
        DrawForecast.from_config({"times": ["T_target_C"]}, EnvConfig(scenario=sc))


def test_cem_warm_start_with_more_features_is_the_old_policy(tmp_path: Path) -> None:
    """cem.init from a model zip into a config with more observation-aid columns and more frames:
    the new weights start at 0, so the warm start earns exactly the old policy's returns; training
    seeds that would include the held-out or ranking seeds are refused."""
    from stable_baselines3 import PPO

    from agents.cem import BatchedLinearPolicies, warm_start
    from agents.train import train

    short = {"control": {"horizon_h": 1.0}}
    run = train("ppo", SMALL, seed=0, out=tmp_path / "cem", env_kwargs=short, progress_bar=False, command="pytest",
                overrides=["cem={popsize: 4, episodes: 2, elite: 2, generations: 1, sigma: 0.3, eval_every: 1}",
                           "eval.episodes=2"])
    import yaml

    cfg = yaml.safe_load((run / "config.yml").read_text())
    zip_ = run / "best" / "best_model.zip"
    old = BatchedLinearPolicies(SMALL, cfg, 2)
    theta = warm_start(zip_, old.k, old.feat_dim, old.n_act)
    net = PPO.load(zip_, device="cpu").policy.action_net
    np.testing.assert_allclose(theta[:-1], net.weight.detach().numpy().ravel(), rtol=1e-6)
    big = {**cfg, "frame_stack": cfg["frame_stack"] + 2,
           "obs_aids": {**cfg["obs_aids"], "time_of_day": {"harmonics": [2, 3]}}}
    new = BatchedLinearPolicies(SMALL, big, 2)
    assert new.n_params > old.n_params
    theta2 = warm_start(zip_, new.k, new.feat_dim, new.n_act)
    np.testing.assert_allclose(new.returns(theta2[None], [3, 4]), old.returns(theta[None], [3, 4]), rtol=1e-9)
    # the layout, on the run's final head (its best checkpoint may be the all-zero start): the old frames
    # are the newest ones, the old columns the first of each frame, the rest 0; the source's frame count
    # comes from its config (a 2-frame head also fits 4 frames of half the columns)
    final = run / "model.zip"
    theta_f = warm_start(final, old.k, old.feat_dim, old.n_act)[:-1].reshape(old.k, old.feat_dim)
    assert np.all(theta_f != 0)
    W2 = warm_start(final, new.k, new.feat_dim, new.n_act)[:-1].reshape(new.k, new.feat_dim)
    np.testing.assert_array_equal(W2[new.k - old.k:, :old.feat_dim], theta_f)
    assert not W2[: new.k - old.k].any() and not W2[:, old.feat_dim:].any()
    more_frames = BatchedLinearPolicies(SMALL, {**cfg, "frame_stack": 2 * cfg["frame_stack"]}, 2)
    W3 = warm_start(final, more_frames.k, more_frames.feat_dim, more_frames.n_act)[:-1].reshape(more_frames.k, -1)
    np.testing.assert_array_equal(W3[more_frames.k - old.k:], theta_f)
    assert not W3[: more_frames.k - old.k].any()
    with pytest.raises(ValueError, match="does not fit"):
        warm_start(zip_, 1, old.feat_dim, old.n_act)
    from agents.cem import warm_start_chain

    run2 = train("ppo", SMALL, seed=0, out=tmp_path / "cem2", env_kwargs=short, progress_bar=False,
                 command="pytest 2", overrides=["cem={popsize: 4, episodes: 2, elite: 2, generations: 1, "
                                                f"sigma: 0.01, eval_every: 1, init: {zip_}}}", "eval.episodes=2"])
    cfg2 = yaml.safe_load((run2 / "config.yml").read_text())
    assert warm_start_chain(cfg2) == [{"init": str(zip_), "command": "pytest"}]
    assert warm_start_chain(cfg) == []
    with pytest.raises(ValueError, match="ranking"):
        train("ppo", SMALL, seed=995, out=tmp_path / "bad", env_kwargs=short, progress_bar=False, command="pytest",
              overrides=["cem={popsize: 4, episodes: 2, elite: 2, generations: 3}"])


def test_residual_shut_band_holds_the_integrator_while_the_valve_is_shut() -> None:
    """shut_band: with the outlet above target and the output more than the band below the pocket
    temperature (the valve is shut), the integrator holds; elsewhere it integrates as before."""
    space = gym.make("ThermoValveStickyValve-v0").action_space
    cfg = {"center": ["target"], "span": [5.0], "kp": [8.0], "ki": [20.0]}
    plain = ResidualCore.from_config(cfg, space, 30.0)
    held = ResidualCore.from_config({**cfg, "shut_band": 0.5}, space, 30.0)
    obs = np.zeros((3, 12))
    obs[:, 11] = 60.0
    obs[:, [0, 1]] = [[60.5, 60.5], [60.1, 60.1], [59.5, 59.5]]
    integ = np.array([[-0.1], [0.3], [-0.1]])  # row 0: output 60 - 4 - 2 < 60.5 - 0.5: shut; row 1: 65 open
    _, i_plain = plain.step(obs, np.zeros((3, 1)), integ)
    _, i_held = held.step(obs, np.zeros((3, 1)), integ)
    np.testing.assert_allclose(i_plain[:, 0], integ[:, 0] + np.array([-0.5, -0.1, 0.5]) * 30.0 / 3600.0)
    np.testing.assert_allclose(i_held[:, 0], [integ[0, 0], i_plain[1, 0], i_plain[2, 0]])
    with pytest.raises(ValueError, match="shut_band"):
        ResidualCore.from_config({**cfg, "shut_band": -1.0}, space, 30.0)


def test_cem_population_on_sync_vector_env_earns_the_native_returns() -> None:
    """The training-throughput benchmark's CEM reference (SyncVectorEnv over single envs, the same
    features, residual and heads) evaluates exactly what the native batched env does, in blocks of 8
    envs cut from the population as benchmarks/train_throughput.py cuts them."""
    import importlib.util

    from agents.cem import BatchedLinearPolicies
    from agents.train import load_algo_config

    spec = importlib.util.spec_from_file_location(
        "train_throughput", Path(__file__).resolve().parents[2] / "benchmarks" / "train_throughput.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    cem_chunks = bench.cem_chunks

    cfg = load_algo_config("ppo", SMALL)
    cfg["env_kwargs"] = {"control": {"horizon_h": 1.0}}
    native = BatchedLinearPolicies(SMALL, cfg, 4 * 4)
    sync = BatchedLinearPolicies(SMALL, cfg, 8, vectorization_mode="sync")
    theta = 0.3 * np.random.default_rng(1).standard_normal((4, native.n_params))
    seeds = [7, 8, 9, 10]
    want = native.returns(theta, seeds)
    got = np.full_like(want, np.nan)
    for cs, js in cem_chunks(4, 4):
        got[cs, js] = sync.returns(theta[cs], seeds[js])
    np.testing.assert_array_equal(got, want)
    assert np.ptp(want) > 0  # the candidates differ
    assert [(c.start, j.start) for c, j in cem_chunks(2, 16)] == [(0, 0), (0, 8), (1, 0), (1, 8)]
    with pytest.raises(ValueError, match="blocks of 8"):
        cem_chunks(3, 4)
