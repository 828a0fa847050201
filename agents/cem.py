"""Policy search by the cross-entropy method on the native batched env (``optimizer: cem``).

A config block with ``optimizer: cem`` (agents/configs/ppo.yml) makes ``thermovalve train --algo ppo``
optimise the policy's *action head* directly, instead of PPO's gradient updates: the policy is
SB3's PPO ``MlpPolicy`` with ``net_arch: {pi: [], vf: [...]}``, so its deterministic action is
linear in the training stack's features (scaled observation, observation aids, frame history)
and the residual maps it to the setting (agents.wrappers.ResidualCore). The result is saved as
an ordinary PPO model (model.zip, best/best_model.zip): the loader, ``thermovalve evaluate``,
the leaderboards and ``--ship`` treat it like any PPO agent.

Why (docs/agents.md, "The benchmark tasks"): on the small cylinder PPO's per-step Gaussian
exploration could not find the draw-time corrections within millions of steps (the training
return drifted down while the step-0 policy stayed best), a known weakness of per-step
exploration on a slow plant. A population method scores whole 24 h episodes and needs
no value function or per-step credit assignment (CEM: Rubinstein and Kroese 2004; evolution
strategies as an RL method: Salimans et al. 2017, arXiv:1703.03864).

Each generation (hyperparameters in the config's ``cem:`` block):

* ``popsize`` candidates theta_c = mu + sigma * eps_c (candidate 0 is mu itself), each run on
  the same ``episodes`` training seeds (common random numbers), fresh seeds every generation
  (seed + generation * episodes + j; a run whose training seeds would include the held-out
  5000-5009 or the ranking seeds 1000-1009 is refused);
* all popsize x episodes envs in ONE native batched env, one kernel call per control step,
  the candidates' linear heads applied at once (an einsum);
* mu <- mean of the ``elite`` best candidates (mean return over the episodes), sigma <- their
  std plus ``noise`` x (1 - g / generations) (extra noise against premature collapse);
* ``init: RUN_DIR`` or ``init: MODEL.zip`` starts mu at an earlier CEM run's best checkpoint or a
  shipped agent (observation-aid columns appended since, or older frames, start at weight 0);
* every ``eval_every`` generations mu is scored on the fixed evaluation seeds (seed + 10000 ..,
  ``eval.episodes``; never the leaderboard's) and the best is kept in ``best/`` with
  ``evaluations.npz`` as PPO's EvalCallback writes it.

``cem.csv`` in the run directory has one row per generation (env steps, population mean,
elite mean, mu's training return, sigma): the learning curve (``thermovalve curves``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: the first of the 10 seeds the sweep and the leaderboard rank agents on: never a training seed
RANK_SEED = 1000
CEM_DEFAULTS: dict[str, Any] = {
    "popsize": 32, "episodes": 8, "elite": 8, "generations": 30, "sigma": 0.3, "noise": 0.05,
    "eval_every": 5,
}


class BatchedLinearPolicies:
    """The training stack's features and residual for popsize x episodes envs of the native batched
    env, with one linear action head per candidate (rows c * episodes .. (c + 1) * episodes - 1)."""

    def __init__(self, env_id: str, cfg: Mapping[str, Any], n_envs: int,
                 vectorization_mode: str = "vector_entry_point") -> None:
        """``vectorization_mode``: the native batched env (training), or ``"sync"``: gymnasium's
        SyncVectorEnv over ``n_envs`` single envs, the same features, residual and heads on top
        (benchmarks/train_throughput.py's reference)."""
        import gymnasium as gym

        from agents.wrappers import ObsFeatures, ResidualCore

        kw = dict(cfg.get("env_kwargs") or {})
        self.vec: Any = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode=vectorization_mode, **kw)
        if vectorization_mode == "vector_entry_point":
            base: Any = self.vec.unwrapped
            base.parallel_threshold = n_envs + 1  # serial kernel: the machine is shared (agents.vec_env)
        single = gym.make(env_id, **kw)
        self.features = ObsFeatures.from_config(cfg, single)
        space = single.action_space
        assert isinstance(space, gym.spaces.Box)
        self.core = ResidualCore.from_config(cfg["residual"], space, float(single.unwrapped.cfg.control.dt_s))  # type: ignore[attr-defined]
        self.obs_dim = int(single.observation_space.shape[0])  # type: ignore[index]
        single.close()
        self.k = int(cfg.get("frame_stack", 1) or 1)
        self.feat_dim = self.features.size(self.obs_dim)
        self.n = n_envs
        self.n_act = self.core.n_act

    @property
    def n_params(self) -> int:
        return (self.k * self.feat_dim + 1) * self.n_act

    def unpack(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(W (c, m, d), b (c, m)) from parameter rows theta (c, n_params)."""
        d = self.k * self.feat_dim
        c = theta.shape[0]
        return theta[:, : d * self.n_act].reshape(c, self.n_act, d), theta[:, d * self.n_act:]

    def returns(self, theta: np.ndarray, seeds: Sequence[int]) -> np.ndarray:
        """Episode returns (c, e): candidate c (theta row) on each of the e ``seeds``."""
        from agents.wrappers import push_history

        c, e = theta.shape[0], len(seeds)
        if c * e != self.n:
            raise ValueError(f"{c} candidates x {e} seeds != {self.n} envs")
        W, b = self.unpack(theta)
        W = np.repeat(W, e, axis=0)
        b = np.repeat(b, e, axis=0)
        obs, _ = self.vec.reset(seed=[int(s) for _ in range(c) for s in seeds])
        hist = np.zeros((self.n, self.k, self.feat_dim))
        memory = self.features.initial_memory(self.n)
        integ = self.core.initial_state(self.n)
        starts = np.ones(self.n, bool)
        ret = np.zeros(self.n)
        while True:
            feat, memory = self.features.step(obs, memory, starts)
            hist = push_history(hist, feat.astype(np.float64), starts)
            starts = np.zeros(self.n, bool)
            x = hist.reshape(self.n, -1).astype(np.float32).astype(np.float64)
            a = np.einsum("nmd,nd->nm", W, x) + b
            u, integ = self.core.step(obs, a, integ)
            obs, r, term, trunc, _ = self.vec.step(u.astype(np.float32))
            ret += r
            if np.any(term | trunc):
                if not np.all(term | trunc):
                    raise RuntimeError("episodes of one batch ended at different steps")
                return ret.reshape(c, e)

    def close(self) -> None:
        self.vec.close()


def set_linear_head(model: Any, theta: np.ndarray, k_feat: int, n_act: int) -> None:
    """Write one parameter row into the PPO policy's action head (its mean is W x + b)."""
    import torch

    net = model.policy.action_net
    d = k_feat
    with torch.no_grad():
        net.weight.copy_(torch.as_tensor(theta[: d * n_act].reshape(n_act, d), dtype=net.weight.dtype))
        net.bias.copy_(torch.as_tensor(theta[d * n_act:], dtype=net.bias.dtype))


def warm_start(src: Path, k: int, feat_dim: int, n_act: int) -> np.ndarray:
    """The linear head of ``src`` (a CEM run directory: its best/best_model.zip; or a model zip, e.g. a
    shipped agent's) as one parameter row. If this config appends observation-aid columns to each
    frame, or keeps more frames, the new weights start at 0: the warm start is then exactly the old
    policy. The source's frame count is read from its config (the run's config.yml, the agent's
    <name>.yml); without one, only one of the two changes is told apart."""
    from stable_baselines3 import PPO

    path = src if src.suffix == ".zip" else src / "best" / "best_model.zip"
    net: Any = PPO.load(path, device="cpu").policy.action_net
    W = net.weight.detach().numpy().astype(float)
    b = net.bias.detach().numpy().astype(float)
    k_src = _source_frames(src)
    if k_src is not None:  # the source's own frame count: more frames and more columns at once are fine
        fits = [(k_src, W.shape[1] // k_src)] if W.shape[1] % k_src == 0 and k_src <= k else []
        fits = [(k0, f0) for k0, f0 in fits if f0 <= feat_dim]
    else:  # no config beside it: the same frame count with more columns, or more frames of the same columns
        fits = [(k0, W.shape[1] // k0) for k0 in range(1, k + 1) if W.shape[1] % k0 == 0]
        fits = [(k0, f0) for k0, f0 in fits if f0 <= feat_dim and (k0 == k or f0 == feat_dim)]
    if W.shape[0] != n_act or not fits:
        raise ValueError(f"cem.init {src}: a head of shape {W.shape} does not fit {k} frames x {feat_dim} "
                         f"features -> {n_act} actions")
    k0, f0 = fits[-1]
    Wn = np.zeros((n_act, k, feat_dim))  # history is oldest first: the old frames are the newest ones
    Wn[:, k - k0:, :f0] = W.reshape(n_act, k0, f0)
    return np.concatenate([Wn.ravel(), b])


def _source_frames(src: Path) -> int | None:
    """``frame_stack`` of the config a warm-start source was trained with (a run directory's config.yml, also
    for its best/best_model.zip or model.zip; a shipped agent's <name>.yml), or None if there is none."""
    if src.suffix != ".zip":
        cfg_path = src / "config.yml"
    elif src.with_suffix(".yml").is_file():
        cfg_path = src.with_suffix(".yml")
    else:
        run = src.parent.parent if src.parent.name == "best" else src.parent
        cfg_path = run / "config.yml"
    if not cfg_path.is_file():
        return None
    return int(yaml_load(cfg_path).get("frame_stack", 1) or 1)


def cem_train(env_id: str, cfg: Mapping[str, Any], seed: int, run_dir: Path, model: Any,
              meta: dict[str, Any]) -> dict[str, Any]:
    """Run the CEM (module docstring) and save model.zip, best/ and cem.csv; returns run.json's extras."""
    if not cfg.get("residual"):
        raise ValueError("optimizer: cem needs a residual: block (the linear head corrects a base law)")
    if (cfg.get("normalize") or {}).get("norm_obs", False):
        raise ValueError("optimizer: cem needs normalize.norm_obs: false (fixed features)")
    net_arch = (cfg.get("hyperparams", {}).get("policy_kwargs") or {}).get("net_arch")
    if not (isinstance(net_arch, Mapping) and not net_arch.get("pi")):
        raise ValueError("optimizer: cem needs policy_kwargs.net_arch: {pi: [], vf: [...]} (a linear action head)")
    opt = {**CEM_DEFAULTS, **dict(cfg.get("cem") or {})}
    P, E, K, G = int(opt["popsize"]), int(opt["episodes"]), int(opt["elite"]), int(opt["generations"])
    if not (2 <= K < P and E >= 1 and G >= 1):
        raise ValueError(f"cem: need 2 <= elite < popsize, episodes >= 1, generations >= 1; got {opt}")
    from valve_env.tasks.benchmark import HELD_OUT_SEED

    train_seeds = range(seed, seed + G * E)
    for lo, what in ((HELD_OUT_SEED, "held-out (thermovalve benchmark)"), (RANK_SEED, "ranking (sweep, leaderboard)")):
        if lo < train_seeds.stop and train_seeds.start < lo + 10:
            raise ValueError(f"cem: the training seeds {seed}..{train_seeds.stop - 1} include the {what} seeds "
                             f"{lo}-{lo + 9}; pick another --seed")
    ev = dict(cfg.get("eval") or {})
    n_eval = int(ev.get("episodes", 4))
    pols = BatchedLinearPolicies(env_id, cfg, P * E)
    ev_pols = BatchedLinearPolicies(env_id, cfg, n_eval)
    eval_seeds = [seed + 10_000 + j for j in range(n_eval)]
    rng = np.random.default_rng(seed)
    mu = np.zeros(pols.n_params)
    if opt.get("init"):  # warm start: an earlier CEM run's best checkpoint, or a shipped agent's zip
        mu = warm_start(Path(str(opt["init"])), pols.k, pols.feat_dim, pols.n_act)
    sigma = np.full(pols.n_params, float(opt["sigma"]))
    rows: list[dict[str, float]] = []
    evals_t: list[int] = []
    evals_r: list[np.ndarray] = []
    best = (-np.inf, mu.copy())
    steps = 0
    ep_len = None
    (run_dir / "best").mkdir(exist_ok=True)
    t0 = time.time()

    def evaluate(g: int) -> None:
        nonlocal best
        r = ev_pols.returns(mu[None, :], eval_seeds)[0]
        evals_t.append(steps)
        evals_r.append(r)
        if r.mean() > best[0]:
            best = (float(r.mean()), mu.copy())
        np.savez(run_dir / "best" / "evaluations.npz", timesteps=np.array(evals_t), results=np.array(evals_r),
                 ep_lengths=np.full((len(evals_t), n_eval), ep_len or 0))

    for g in range(G):
        if g % int(opt["eval_every"]) == 0:
            evaluate(g)
        eps = rng.standard_normal((P, pols.n_params))
        eps[0] = 0.0
        theta = mu + sigma * eps
        seeds = [seed + g * E + j for j in range(E)]
        R = pols.returns(theta, seeds)
        ep_len = int(pols.vec.unwrapped.cfg.control.n_steps)
        steps += P * E * ep_len
        score = R.mean(axis=1)
        elite = np.argsort(score)[::-1][:K]
        mu = theta[elite].mean(axis=0)
        sigma = theta[elite].std(axis=0) + float(opt["noise"]) * (1.0 - g / G)
        rows.append({"generation": g, "env_steps": steps, "wall_s": round(time.time() - t0, 1),
                     "pop_mean": float(score.mean()), "elite_mean": float(score[elite].mean()),
                     "mu_return": float(score[0]), "sigma_mean": float(sigma.mean())})
        with open(run_dir / "cem.csv", "w") as fh:
            fh.write(",".join(rows[0]) + "\n")
            fh.writelines(",".join(str(v) for v in r.values()) + "\n" for r in rows)
    evaluate(G)
    pols.close()
    ev_pols.close()
    d = pols.k * pols.feat_dim
    set_linear_head(model, mu, d, pols.n_act)
    model.save(str(run_dir / "model.zip"))
    set_linear_head(model, best[1], d, pols.n_act)
    model.save(str(run_dir / "best" / "best_model.zip"))
    no_norm = json.dumps({"norm_obs": False})
    for p in (run_dir / "obs_norm.json", run_dir / "best" / "obs_norm.json"):
        p.write_text(no_norm)
    wall = time.time() - t0
    return {"wall_time_s": round(wall, 1), "steps_per_s": round(steps / max(wall, 1e-9), 1),
            "num_timesteps": int(steps), "optimizer": "cem", "cem": opt,
            "best_eval": {"mean_return": best[0],
                          "timesteps": int(evals_t[int(np.argmax([r.mean() for r in evals_r]))])}}


def warm_start_chain(cfg: Mapping[str, Any]) -> list[dict[str, str]]:
    """The commands that made a config's ``cem.init`` model, nearest first (each earlier run's
    own warm start follows it), read from the run directories' command.txt and config.yml or a
    shipped agent's <name>.yml: what ``--ship`` records beside an agent so it can be rebuilt."""
    chain: list[dict[str, str]] = []
    init = (cfg.get("cem") or {}).get("init") if cfg.get("optimizer") == "cem" else None
    while init and len(chain) < 20:
        src = Path(str(init))
        run = src.parent.parent if src.name == "best_model.zip" else (src if src.suffix != ".zip" else None)
        if run is not None and (run / "command.txt").is_file():
            chain.append({"init": str(init), "command": (run / "command.txt").read_text().strip()})
            nxt = yaml_load(run / "config.yml")
        elif src.suffix == ".zip" and src.with_suffix(".yml").is_file():
            nxt = yaml_load(src.with_suffix(".yml"))
            chain.append({"init": str(init), "command": str((nxt.get("shipped_from") or {}).get("command", "?"))})
            chain.extend(nxt.get("warm_start") or [])
            break
        else:
            chain.append({"init": str(init), "command": "unknown (no command.txt or shipped .yml beside it)"})
            break
        init = (nxt.get("cem") or {}).get("init") if nxt.get("optimizer") == "cem" else None
    return chain


def yaml_load(path: Path) -> dict[str, Any]:
    import yaml

    return dict(yaml.safe_load(path.read_text()) or {})
