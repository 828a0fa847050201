"""ThermoValve RL agents: training, shipped models, leaderboard and Dask sweeps."""
