"""The public name of :mod:`valve_env.envs.wrappers` (the measurement wrappers, snapshots): the same
objects, so ``from valve_env.wrappers import SensorNoise, snapshot, restore`` keeps working. The
wrappers live in the envs package, which builds them into every env (docs/architecture.md)."""

from valve_env.envs.wrappers import (
    EnvSnapshot,
    ObservationDelay,
    SensorNoise,
    noisy_observation,
    restore,
    snapshot,
)

__all__ = ["EnvSnapshot", "ObservationDelay", "SensorNoise", "noisy_observation", "restore", "snapshot"]
