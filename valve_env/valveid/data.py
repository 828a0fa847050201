"""The data container of the identification framework: a measured run ready for a likelihood.

    df = load_run("run.csv")          # valve_env.data_io: the one loader and validation
    data = RunData.from_frame(df)     # the latent temperatures estimated (IRW-RTS smoothing)

A run is read and validated once, by :func:`valve_env.data_io.load_run` (a file) or
:func:`valve_env.data_io.validate_run` (a DataFrame): docs/reference.md, section 2. The EKF
likelihood takes the validated DataFrame itself (its model's ``prepare`` adds the denoised inputs,
:mod:`valve_env.valveid.temperature`); the output-error likelihood takes a :class:`RunData`:
the raw channels with the smoothed temperatures (:func:`~valve_env.valveid.temperature.smooth_temperature`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import pandas as pd

from valve_env.valveid.stiction import OpeningNoise, opening_noise
from valve_env.valveid.temperature import ChannelNoise, channel_noise, read_only, smooth_temperature


def opening_scale(x: np.ndarray) -> tuple[np.ndarray | None, OpeningNoise | None, float]:
    """Where the opening's noise grows with its level (:meth:`valve_env.valveid.stiction.OpeningNoise.sd_at`): each
    sample's noise sd relative to the record's (root mean square 1), the opening's noise and the sd it is relative
    to; else (None, None, 1.0)."""
    on = opening_noise(x)
    if on.level_sd is None:
        return None, None, 1.0
    g = np.asarray(on.sd_at(x), dtype=np.float64)
    norm = math.sqrt(float(np.mean(g * g)))
    return np.ascontiguousarray(g / norm), on, norm


@dataclass(frozen=True)
class RunData:
    """A measured run prepared for the output-error likelihood: raw channels and latent (smoothed)
    temperatures with their rates and noise sd. Frozen: a changed run is a new one
    (``dataclasses.replace``), so that the likelihood may keep a run's valve paths by its identity
    (:meth:`valve_env.valveid.fitting.Model._valve_path`); its arrays are read-only views."""

    t: np.ndarray
    T_raw: np.ndarray
    M_raw: np.ndarray
    x: np.ndarray
    dp: np.ndarray
    ps: np.ndarray
    T: np.ndarray
    vT: np.ndarray
    M: np.ndarray
    vM: np.ndarray
    s_T: float
    s_M: float
    name: str = "run"
    #: how each temperature channel was recorded (quantum, noise; :func:`channel_noise`), so that a
    #: copy measured again (:meth:`remeasure`) follows the record's convention
    T_noise: ChannelNoise | None = None
    M_noise: ChannelNoise | None = None
    #: where the opening's noise grows with its level (:func:`valve_env.valveid.stiction.noise_by_level`: an opening
    #: derived from a flow meter's reading): each sample's noise sd relative to the record's (root mean square 1 over
    #: the record), which scales the white noise of the likelihoods; None where one sd holds
    x_scale: np.ndarray | None = None
    #: the record's opening noise by level and the sd that ``x_scale`` is relative to (:meth:`noise_scale_at`)
    x_noise: OpeningNoise | None = None
    x_norm: float = 1.0

    def __post_init__(self) -> None:
        # the arrays as read-only views (:func:`~valve_env.valveid.temperature.read_only`): the run is not to be
        # written in place, and its kernels then compile once
        for f in fields(self):
            a = getattr(self, f.name)
            if isinstance(a, np.ndarray):
                object.__setattr__(self, f.name, read_only(a))

    def noise_scale_at(self, x: np.ndarray) -> float | np.ndarray:
        """The opening's white-noise sd at the openings ``x`` (a simulated path) relative to the record's, as
        ``x_scale`` is for the record's own: 1.0 where one sd holds."""
        if self.x_noise is None:
            return 1.0
        return np.asarray(self.x_noise.sd_at(x), dtype=np.float64) / self.x_norm

    @classmethod
    def from_arrays(cls, t: np.ndarray, T_tank: np.ndarray, T_med: np.ndarray, x: np.ndarray, dp: np.ndarray,
                    ps: np.ndarray, name: str = "run") -> RunData:
        f = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
        t, T_tank, T_med, x, dp, ps = map(f, (t, T_tank, T_med, x, dp, ps))
        T, vT, s_T, _ = smooth_temperature(t, T_tank)
        M, vM, s_M, _ = smooth_temperature(t, T_med)
        return cls(t, T_tank, T_med, x, dp, ps, T, vT, M, vM, s_T, s_M, name, channel_noise(T_tank),
                   channel_noise(T_med), *opening_scale(x))

    @property
    def quantised(self) -> bool:
        """Whether a temperature channel's noise lies below its quantisation step (its record is a
        staircase: the rounding, not white noise, is its measurement error)."""
        return any(n is not None and n.method == "quantisation" for n in (self.T_noise, self.M_noise))

    def remeasure(self, T: np.ndarray, M: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Latent tank and medium temperatures measured again as this run's channels were
        (:meth:`valve_env.valveid.temperature.ChannelNoise.remeasure`; white noise of ``s_T``/``s_M``
        where the run carries no channel record)."""
        def one(level: np.ndarray, noise: ChannelNoise | None, sd: float) -> np.ndarray:
            if noise is None:
                return level + sd * rng.standard_normal(level.shape[0])
            return noise.remeasure(level, sd, rng)

        Tm = one(T, self.T_noise, self.s_T)
        return Tm, one(M, self.M_noise, self.s_M)

    @classmethod
    def from_frame(cls, df: pd.DataFrame, name: str = "run") -> RunData:
        """From a validated run (:func:`valve_env.data_io.validate_run`: x_mm present)."""
        return cls.from_arrays(df["time_s"].to_numpy(), df["T_tank_C"].to_numpy(), df["T_med_C"].to_numpy(),
                               df["x_mm"].to_numpy(), df["dp_mbar"].to_numpy(), df["ps_bar"].to_numpy(), name)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def slice(self, a: int, b: int) -> RunData:
        s = slice(a, b)
        return RunData(self.t[s], self.T_raw[s], self.M_raw[s], self.x[s], self.dp[s], self.ps[s], self.T[s],
                       self.vT[s], self.M[s], self.vM[s], self.s_T, self.s_M, self.name, self.T_noise, self.M_noise,
                       None if self.x_scale is None else self.x_scale[s], self.x_noise, self.x_norm)

    @property
    def median_dt(self) -> float:
        return float(np.median(np.diff(self.t)))


__all__ = ["RunData", "opening_scale"]
