"""Branching rollouts from a saved simulator state (the building block of MPC).

Runs the default scenario to 07:00, saves the state, and tries three constant
settings for the next two hours from the same state, printing each branch's
outlet temperature and heat use. ``valve_env.wrappers.snapshot``/``restore``
save and restore the whole env as gym.make wraps it (sensor noise and dead
time included, when the ``sensors:`` section asks for them).

    python examples/branching_rollouts.py
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import valve_env  # noqa: F401  (registers the environments)
from valve_env.wrappers import restore, snapshot


def main() -> None:
    env = gym.make("ThermoValve-v0")
    env.reset(seed=0)
    for _ in range(7 * 120):
        env.step(np.array([62.0], np.float32))
    snap = snapshot(env)
    for setting in (58.0, 62.0, 66.0):
        restore(env, snap)
        heat0 = env.unwrapped.energy_account()["heat_in_J"]
        T = [env.step(np.array([setting], np.float32))[0][0] for _ in range(240)]
        heat = (env.unwrapped.energy_account()["heat_in_J"] - heat0) / 3.6e6
        print(f"setting {setting:4.1f} degC: outlet min {min(T):5.2f} mean {np.mean(T):5.2f} degC, heat {heat:.2f} kWh")


if __name__ == "__main__":
    main()
