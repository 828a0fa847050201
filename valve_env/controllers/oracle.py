"""``oracle``: a model-predictive controller with the true plant and perfect
preview of the scenario, the bound on what a controller can achieve
(docs/controllers.md, "oracle").

It is not a controller a real installation could run: it reads the *true*
state of the env it controls (:meth:`ThermoValveEnv.get_state`: the tank's
layers, the bulb, the stem and its friction, the whole episode's draws and
supply already drawn at reset) and optimises the env's own reward over a
receding horizon on exact copies of the plant. Nothing about the future is
estimated: the batched env it simulates on
(:class:`valve_env.envs.vector.ThermoValveVectorEnv`, made from the same
configuration by the env id's vector entry point) is the same kernel,
loaded with :meth:`~valve_env.envs.vector.ThermoValveVectorEnv.set_state`,
so its rollouts are bit-identical to what the real env will do under the
same actions.

The optimiser is the cross-entropy method (Rubinstein & Kroese 2004, *The
Cross-Entropy Method*, Springer; as used for sampling-based MPC by Chua et
al. 2018, "Deep reinforcement learning in a handful of trials using
probabilistic dynamics models", NeurIPS) over move-blocked action sequences:

* the plan covers ``horizon_steps`` control steps, piecewise constant over
  blocks of ``block_steps`` (so ``horizon_steps / block_steps`` knots per
  action dimension);
* each iteration simulates ``samples`` sequences from one state, all in one
  batched env (one kernel call per control step), scores each by the sum of
  the env's rewards over the horizon (cut at the episode's end), refits a
  Gaussian over the knots to the ``elite_frac`` best and keeps the best
  sequence seen;
* sample 0 is always the previous plan shifted in time (warm start), so a
  new plan never scores worse than continuing the old one over the same
  horizon;
* the best sequence's first ``replan_steps`` actions are sent; because the
  model is exact, the real env follows the simulated trajectory to the bit,
  and replanning more often than the blocks change only refines the
  optimisation.

Use: ``thermovalve evaluate --controllers oracle`` (the evaluator binds the
oracle to its envs), or in code::

    oracle = make_controller("oracle", "ThermoValve-v0")
    oracle.bind_envs([env])          # the envs whose observations predict() will get, in batch order
    action, state = oracle.predict(obs, state, episode_start)

``predict`` works on single and batched observations like every controller;
row i of a batch is env i of the bound list.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from valve_env import simulator as sim
from valve_env.controllers.base import I_T_OUT, I_T_TARGET, Controller
from valve_env.controllers.baselines import PIController


@dataclass(frozen=True)
class OracleSettings:
    """The MPC's settings (docs/controllers.md, "oracle", says how they were chosen)."""

    horizon_steps: int = 120
    """Prediction horizon, control steps (120 x 30 s = 1 h)."""
    block_steps: int = 12
    """Steps per piecewise-constant block of the plan (move blocking)."""
    replan_steps: int = 6
    """Steps sent from one plan before the next is made."""
    samples: int = 128
    """Action sequences simulated per iteration (the batched env's width)."""
    iterations: int = 3
    """Cross-entropy iterations per plan."""
    elite_frac: float = 0.1
    """Fraction of the samples the Gaussian is refitted to."""
    init_std_frac: float = 0.15
    """First iteration's standard deviation of the knots, as a fraction of the action range."""
    min_std_frac: float = 0.005
    """Floor of the knots' standard deviation, fraction of the action range."""
    seed: int = 0
    """Seed of the sampler (the oracle is deterministic for a given seed)."""
    perturb: str = "output"
    """What the plan moves: ``"output"`` adds it to the PI's output (the setting), ``"target"`` to
    the PI's target (the outlet temperature the PI holds: a charge of the tank is one constant knot),
    ``"setting"`` is the valve's setting itself, as an offset from the outlet target (no PI: the
    self-acting valve's own proportional action sets the flow, so a plan can charge the tank slowly
    with a cold return; the zero plan is ``self_acting``)."""
    terminal_value: bool = False
    """Value the heat stored in the tank at the horizon's end as the task layer settles it at the
    episode's end (:meth:`TaskLayer.settle`; nothing on the original ids): a plan shorter than the
    rest of the day then neither empties nor overfills the tank for free."""

    def __post_init__(self) -> None:
        for name in ("horizon_steps", "block_steps", "replan_steps", "samples", "iterations"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"oracle {name} must be an integer >= 1, got {v!r}")
        if self.replan_steps > self.horizon_steps:
            raise ValueError(f"oracle replan_steps ({self.replan_steps}) must not exceed horizon_steps "
                             f"({self.horizon_steps})")
        if self.samples < 2:
            raise ValueError(f"oracle samples must be >= 2, got {self.samples!r}")
        if not 0.0 < self.elite_frac <= 1.0:
            raise ValueError(f"oracle elite_frac must be in (0, 1], got {self.elite_frac!r}")
        if self.perturb not in ("output", "target", "setting"):
            raise ValueError(f"oracle perturb must be 'output', 'target' or 'setting', got {self.perturb!r}")
        for name in ("init_std_frac", "min_std_frac"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"oracle {name} must be finite and > 0, got {v!r}")


#: per task, the settings that replace the stored ones (docs/controllers.md, "oracle"; chosen on tuning
#: seeds 0-4, never on the held-out 5000+): on the district-heating tasks the bill rewards buying heat
#: hours before it is drawn, so the plan runs to the end of the day (a shorter plan pays no power peak by
#: deferring every charge, and must guess the stored heat's worth), replanned every 2 h with 20 iterations
#: (the preview is perfect: fewer, deeper plans beat more, shallower ones at less cost), in half-hour knots
#: of the valve's own setting (the PI, given a raised target, opens the valve fully and pays the return tariff on a hot
#: return; the valve alone throttles), with the heat left in the tank valued as the task settles it;
#: on the sticky task the cost is the stem's 12-min limit cycle, which a short horizon with fine blocks
#: and more iterations follows better
_DISTRICT_HEATING: dict[str, Any] = {"horizon_steps": 2880, "block_steps": 60, "replan_steps": 240,
                                     "iterations": 20, "perturb": "setting", "terminal_value": True}
_STICKY: dict[str, Any] = {"horizon_steps": 40, "block_steps": 4, "replan_steps": 4, "iterations": 8}
TASK_SETTINGS: dict[str, dict[str, Any]] = {
    "ThermoValveDistrictHeating-v0": _DISTRICT_HEATING,
    "ThermoValveDistrictHeatingPower-v0": _DISTRICT_HEATING,
    # v1 (the store behind a mixing valve): v0's settings, checked on tuning seeds 0-4 (docs/controllers.md)
    "ThermoValveDistrictHeating-v1": _DISTRICT_HEATING,
    "ThermoValveDistrictHeatingPower-v1": _DISTRICT_HEATING,
    "ThermoValveStickyValve-v0": _STICKY,
    # the stem mid-stroke: v0's settings, not tuned on this task (docs/controllers.md)
    "ThermoValveStickyCirculation-v0": _STICKY,
}


class OracleNotBoundError(RuntimeError):
    """``predict`` was called before :meth:`Oracle.bind_envs`."""


class Oracle(Controller):
    """Sampling-based MPC on the true plant with perfect preview (module docstring).

    Memory per env (SB3 ``state``): the inner PI's memory, the current plan
    (one perturbation per step of the horizon, ``horizon_steps * act_dim``
    values) and the number of its steps already sent.
    """

    name: ClassVar[str] = "oracle"

    def __init__(self, env_id: str = "ThermoValve-v0", **settings: Any) -> None:
        super().__init__(env_id)
        from valve_env.controllers.compensators import _stored

        self.settings = OracleSettings(**{**_stored(env_id, self.name), **TASK_SETTINGS.get(env_id, {}), **settings})
        s = self.settings
        self.horizon = int(s.horizon_steps)
        self.base = PIController(env_id)
        self._n_pi = self.base.state_size
        self._n_plan = self.horizon * self.act_dim
        self.state_size = self._n_pi + self._n_plan + 1
        self._envs: list[Any] = []
        self._keys: dict[int, Any] = {}
        self._sims: dict[Any, Any] = {}
        self._lo = np.zeros(self.act_dim)
        self._hi = np.zeros(self.act_dim)
        self.plans_made = 0
        self.sim_steps = 0

    # -- binding to the true plant ---------------------------------------------------
    def bind_envs(self, envs: Sequence[gym.Env]) -> Oracle:
        """The envs this oracle controls, in the order of the rows of the observations
        ``predict`` will get (wrappers are looked through to the ThermoValve env)."""
        bound = []
        for e in envs:
            core = e.unwrapped
            if not (hasattr(core, "get_state") and hasattr(core, "cfg")):
                raise TypeError(f"the oracle needs envs with get_state() and cfg, got {type(core).__name__}")
            bound.append(core)
        self._envs = bound
        self._keys = {id(c): _sim_key(c) for c in bound}
        return self

    def _simulator(self, core: Any) -> Any:
        """The batched env (``samples`` copies of the plant) for ``core``'s configuration: one per
        distinct configuration, shared by the bound envs that have it (each plan loads its own
        snapshot), so a batch of envs does not rebuild it at every step."""
        key = self._keys.get(id(core))
        if key is None:  # not bound through bind_envs (a direct plan() call)
            key = self._keys[id(core)] = _sim_key(core)
        vec: Any = self._sims.get(key)
        if vec is None:
            tariff = _tariff_of(core)
            kwargs: dict[str, Any] = {"config": core.cfg} if tariff is None else {"config": core.cfg, "tariff": tariff}
            vec = self._sims[key] = gym.make_vec(
                self.env_id, num_envs=int(self.settings.samples), vectorization_mode="vector_entry_point", **kwargs
            )
            vec.reset(seed=int(self.settings.seed))
            space = vec.single_action_space
            self._lo = np.asarray(space.low, np.float64)
            self._hi = np.asarray(space.high, np.float64)
        return vec

    # -- Controller interface ------------------------------------------------------
    def initial_state(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        mem = np.zeros((n, self.state_size))
        mem[:, : self._n_pi] = self.base.initial_state(obs)
        mem[:, -1] = np.inf  # no plan yet: make one at the first step
        return mem

    def step(self, obs: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = obs.shape[0]
        if len(self._envs) != n:
            raise OracleNotBoundError(
                f"the oracle has {len(self._envs)} bound envs but got {n} observations: it needs the true plant; "
                "call oracle.bind_envs(envs) with the envs in batch order (thermovalve evaluate does this)"
            )
        act = np.empty((n, self.act_dim))
        ad, H = self.act_dim, self.horizon
        p0, p1 = self._n_pi, self._n_pi + self._n_plan
        for i, core in enumerate(self._envs):
            st = core.get_state()
            if int(st.k) >= int(core.cfg.control.n_steps):  # the episode is over: nothing to plan
                act[i] = self._in_force(st)
                continue
            _check_observation(obs[i], st, core)
            self._simulator(core)
            plan = state[i, p0:p1].reshape(H, ad)
            age = state[i, -1]
            if self._replan_due(core, st, age):
                prev = np.zeros((H, ad)) if not np.isfinite(age) else _shifted(plan, int(age))
                plan = self.plan(core, st, obs[i], state[i, :p0], prev)
                age = 0
            pi_mem = state[i : i + 1, :p0]
            act[i] = self._base_action(obs[i : i + 1], pi_mem, plan[int(age)][None, :])[0]
            state[i, :p0] = pi_mem[0]
            state[i, p0:p1] = plan.reshape(-1)
            state[i, -1] = age + 1
        return act, state

    def _replan_due(self, core: Any, st: Any, age: float) -> bool:
        """Whether :meth:`step` plans anew for ``core`` in state ``st``, its plan ``age`` steps old (nan: none yet):
        every ``replan_steps``. A subclass that scores plans on other futures may add reasons."""
        return not np.isfinite(age) or age >= self.settings.replan_steps

    # -- the optimiser ---------------------------------------------------------------
    def _base_action(self, obs: np.ndarray, pi_mem: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The PI's action perturbed by ``delta`` (n, act_dim): on the PI's manipulated variable
        inside its limits (anti-windup sees it), on a held channel (Dual's dp) added and clipped."""
        if self.settings.perturb == "setting":  # the valve's own setting, the plan added to the target
            u = np.clip(obs[:, I_T_TARGET] + delta[:, 0], self.base.u_min, self.base.u_max)
        elif self.settings.perturb == "target":
            shifted = obs.copy()
            shifted[:, I_T_TARGET] += delta[:, 0]
            u = self.base.pi_output(shifted, pi_mem)
        else:
            u = self.base.pi_output(obs, pi_mem, feedforward=delta[:, 0])
        a = self.base._assemble(u)
        if self.act_dim > 1:
            a[:, 1:] = np.clip(a[:, 1:] + delta[:, 1:], self._lo[1:], self._hi[1:])
        return a

    def plan(self, core: Any, st: Any, obs: np.ndarray, pi_mem: np.ndarray, prev: np.ndarray) -> np.ndarray:
        """The best perturbation sequence ``(horizon_steps, act_dim)`` from the snapshot ``st`` of
        ``core`` (whose observation is ``obs`` and the PI's memory ``pi_mem``), warm-started from
        ``prev``; the cross-entropy method over knots of ``block_steps`` steps."""
        s = self.settings
        vec = self._simulator(core)
        span = self._hi - self._lo
        n, H, B = int(s.samples), self.horizon, int(s.block_steps)
        n_knots = -(-H // B)
        h_eff = min(H, int(core.cfg.control.n_steps) - int(st.k))
        rng = np.random.default_rng([int(s.seed), int(st.k)])
        mean = prev[::B][:n_knots].copy()  # (n_knots, ad)
        std = np.broadcast_to(s.init_std_frac * span, mean.shape).copy()
        n_elite = max(2, int(round(s.elite_frac * n)))
        best_seq, best_ret = prev.copy(), -np.inf
        for it in range(int(s.iterations)):
            knots = np.clip(mean + std * rng.standard_normal((n, *mean.shape)), -span, span)
            knots[0] = mean
            seqs = np.repeat(knots, B, axis=1)[:, :H]  # (n, H, ad)
            if it == 0:
                seqs[0] = prev  # the previous plan exactly (its knots may not be block-aligned)
            ret = self._rollout(vec, st, obs, pi_mem, seqs, h_eff)
            j = int(np.argmax(ret))
            if ret[j] > best_ret:
                best_ret, best_seq = float(ret[j]), seqs[j].copy()
            elite = knots[np.argsort(ret)[-n_elite:]]
            mean = elite.mean(axis=0)
            std = np.maximum(elite.std(axis=0), s.min_std_frac * span)
        self.plans_made += 1
        return best_seq

    def _rollout(
        self, vec: Any, st: Any, obs: np.ndarray, pi_mem: np.ndarray, seqs: np.ndarray, h_eff: int
    ) -> np.ndarray:
        """Sum of rewards of each perturbation sequence over ``h_eff`` steps from ``st``."""
        n = seqs.shape[0]
        sens = vec.cfg.sensors
        # the planner's step (no info, no autoreset, no generator) when the observations are the kernel's
        lean = hasattr(vec, "plan_step") and not (sens.noise_K > 0 or sens.flow_noise_rel > 0
                                                  or sens.dead_time_steps > 0)
        if lean:
            vec.set_state(st, rng=False)
        else:
            vec.set_state(st)
        mem = np.repeat(pi_mem[None, :], n, axis=0)
        o = np.repeat(np.asarray(obs, np.float64)[None, :], n, axis=0)
        ret = np.zeros(n)
        settle = (self.settings.terminal_value and hasattr(vec, "layer")
                  and int(st.k) + h_eff < int(vec.cfg.control.n_steps))
        E_start = vec.stored_energy_J() if settle else None
        for t in range(h_eff):
            a = self._base_action(o, mem, seqs[:, t])
            if lean:
                o, r = vec.plan_step(a)
            else:
                o, r, _, _, _ = vec.step(a)
            o = o.astype(np.float64)
            ret += r
        if settle:  # the horizon ends before the episode: its stored heat is settled as at the end
            ret += vec.layer.settle(vec.stored_energy_J() - E_start)[0]
        self.sim_steps += h_eff
        return ret

    def _in_force(self, st: Any) -> np.ndarray:
        values = {"setting": [st.setting_C], "pressure": [st.dp_mbar], "dual": [st.setting_C, st.dp_mbar]}
        return np.array(values[self.mode], np.float64)

    def describe(self) -> dict[str, Any]:
        """The settings, for reports."""
        return asdict(self.settings)

    def close(self) -> None:
        for vec in self._sims.values():
            vec.close()
        self._sims.clear()


def _tariff_of(core: Any) -> dict[str, Any] | None:
    """The bound env's task-layer tariff as keyword arguments (None without one): the oracle's simulator
    must bill as the env it controls does, a ``tariff=`` override included."""
    tariff = getattr(getattr(core, "layer", None), "tariff", None)
    return None if tariff is None else asdict(tariff)


def _sim_key(core: Any) -> tuple[str, str, type]:
    """What makes two bound envs share a simulator: the same configuration, tariff and class."""
    return repr(core.cfg), repr(_tariff_of(core)), type(core)


def _shifted(plan: np.ndarray, by: int) -> np.ndarray:
    """``plan`` advanced by ``by`` steps, its last value held over the freed tail."""
    if by <= 0:
        return plan.copy()
    by = min(by, plan.shape[0])
    return np.concatenate([plan[by:], np.repeat(plan[-1:], by, axis=0)])


def _check_observation(obs: np.ndarray, st: Any, core: Any) -> None:
    """Guard against a mis-bound oracle: the observation must be the bound env's (exact when its
    sensors add no noise or dead time)."""
    sens = core.cfg.sensors
    if sens.noise_K > 0 or sens.flow_noise_rel > 0 or sens.dead_time_steps > 0:
        return
    expected = float(np.float32(st.out[sim.O_T_TOP]))
    if abs(float(obs[I_T_OUT]) - expected) > 1e-3:
        raise OracleNotBoundError(
            f"the oracle's bound env is at T_out {expected:.4f} degC but the observation says "
            f"{float(obs[I_T_OUT]):.4f}: bind_envs() got the envs in another order than the batch"
        )
