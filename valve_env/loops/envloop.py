"""Loop records from the project's own environment: a PI on the sticky-valve task
(ThermoValveStickyValve-v0 by default; ``env_id="ThermoValveStickyCirculation-v0"`` for the stem mid-stroke, with
a circulation loop, docs/tasks.md) trimming the valve's temperature setting, written as a loop CSV
(docs/loops.md, "Loops from the environment").

OP is the setting as % of the action range (40-80 degC -> 0-100 %), PV the outlet temperature,
SP the outlet target. The valve is always set explicitly through the env's named effect,
``valve={"effects": {"stiction": {"band_mm": band_mm}}}``: ``band_mm = 0`` (or ``None``) is the smooth
valve, whatever band the task itself uses.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import valve_env  # noqa: F401  (registers the environments)
from valve_env.controllers.baselines import PIController
from valve_env.loops.io import LoopData

ENV_ID = "ThermoValveStickyValve-v0"
#: the record's length and the warm-up before it, h (docs/loops.md, "Loops from the environment")
RECORD_H = 4.0
WARMUP_H = 3.0


def record_env_loop(band_mm: float | None, seed: int = 0, hours: float = RECORD_H, warmup_h: float = WARMUP_H,
                    noise_K: float = 0.01, env_id: str = ENV_ID, filter_s: float = 0.0,
                    Kp: float | None = None, Ti_s: float | None = None, F_hmax: float | None = None) -> LoopData:
    """Run the PI for ``warmup_h + hours`` on ``env_id`` (30 s steps) with the stem's stick band
    ``band_mm`` (0 or None: a smooth stem) and return the record of the last ``hours`` (the warm-up
    holds the tank's start-up heating, when the loop is saturated). The temperature sensors carry
    white noise of ``noise_K`` per sample (docs/loops.md, "Loops from the environment", on the choice);
    ``filter_s`` is the PI's first-order measurement filter (the historian records the unfiltered PV);
    ``Kp`` (K of setting per K) and ``Ti_s`` override the PI's stored gains for ``env_id``; ``F_hmax`` (N) the
    valve's Dahl friction (default: the paper's 1.31 N, whose hysteresis loop is 0.8 K of setting wide, 2 % of OP:
    wider than the 0.1 mm stick band's 0.6 K; docs/loops.md, "Loops from the environment")."""
    if not (hours > 0.0 and warmup_h >= 0.0):  # also rejects NaN
        raise ValueError(f"record_env_loop: hours must be > 0 and warmup_h >= 0, got {hours!r} and {warmup_h!r}")
    total = hours + warmup_h
    kw: dict = {"horizon_h": total, "max_episode_steps": int(round(total * 120)), "sensors": {"noise_K": noise_K},
                "valve": {"effects": {"stiction": {"band_mm": float(band_mm or 0.0)}}}}
    if F_hmax is not None:
        kw["valve"]["F_hmax"] = float(F_hmax)
    env = gym.make(env_id, **kw)
    space = env.action_space
    assert isinstance(space, gym.spaces.Box)
    lo, hi = float(space.low[0]), float(space.high[0])
    ctrl = PIController(env_id, Kp=Kp, Ti_s=Ti_s, filter_s=filter_s)
    obs, _ = env.reset(seed=seed)
    state = None
    t, sp, pv, op = [], [], [], []
    dt = float(env.unwrapped.config.control.dt_s) if hasattr(env.unwrapped, "config") else 30.0
    k = 0
    done = False
    start = True
    while not done:
        act, state = ctrl.predict(obs, state, np.array([start]), deterministic=True)
        start = False
        a = np.asarray(act, dtype=np.float32).reshape(env.action_space.shape)
        obs, _, term, trunc, info = env.step(a)
        done = bool(term or trunc)
        k += 1
        t.append(k * dt)
        sp.append(float(obs[11]))
        pv.append(float(obs[0]))
        op.append(100.0 * (float(np.clip(a[0], lo, hi)) - lo) / (hi - lo))
    env.close()
    skip = int(round(warmup_h * 3600.0 / dt))
    t, sp, pv, op = t[skip:], sp[skip:], pv[skip:], op[skip:]
    tag = f"env-pi-{'stiction-' + format(band_mm, 'g') + 'mm' if band_mm else 'smooth'}-seed{seed}"
    return LoopData(time_s=np.asarray(t) - t[0], sp=np.asarray(sp), pv=np.asarray(pv), op=np.asarray(op), tag=tag,
                    source=env_id)


__all__ = ["record_env_loop", "ENV_ID", "RECORD_H", "WARMUP_H"]
