"""The stick band measured from the slips of the opening (a moment estimator).

Under the (S, J) stick-slip model of the stem (:mod:`valve_env.physics.stickslip`; J = S, the
diagnosis's model) a stem that has come to rest, where the demanded opening stopped or reversed,
stays put until the demand has moved the band away, then slips onto the demand and follows it. In
the sampled opening each slip is a plateau followed by a jump of the band plus the motion of the
rest of that sampling interval. :func:`jump_band` finds these (a flat stretch, a jump that
persists) and measures each slip as the jump from the plateau's level to the level of the following
samples' straight line half an interval after the plateau's last sample (which removes the motion
within the interval on average); the band is the median over the slips. The same estimator reads
the staircase of a stem that re-sticks right after every slip (each step a plateau and a jump of the
band). The likelihood of the stick-slip filter is rough in the band and the band trades off against
the Dahl friction's F_hmax (both make hysteresis), which traps the joint fit; the slips measure the
band directly, without the valve model. Used by :class:`valve_env.diagnosis.fitting.Model` for
``band_mm``.
"""

from __future__ import annotations

import math

import numpy as np

from valve_env.estimation.valve_model import noise_sd as _smooth_noise_sd


def _away_from_stops(x: np.ndarray, stroke: float, edge_mm: float) -> np.ndarray:
    """Mask of the steps of ``x`` whose both ends lie more than ``edge_mm`` from the end stops."""
    lo, hi = edge_mm, stroke - edge_mm
    return (x[:-1] > lo) & (x[1:] > lo) & (x[:-1] < hi) & (x[1:] < hi)


def noise_sd(x: np.ndarray) -> float:
    """sd of the white noise on the opening: the robust second-difference estimate of
    :func:`valve_env.estimation.valve_model.noise_sd` (the stem moves smoothly between slips, which
    are outliers of the second differences)."""
    return _smooth_noise_sd(np.asarray(x, dtype=float))


def resting_noise_sd(x: np.ndarray, stroke: float, band: float | None = None) -> float:
    """sd of the white noise on the opening of a sticking stem (the replicate noise of the bootstrap):
    :func:`noise_sd`, whose second differences set the slips apart as outliers whatever the band (kept
    with its arguments for the callers)."""
    return noise_sd(x)


def slips(x: np.ndarray, stroke: float, s_w: float | None = None, z: float = 4.0, plateau: int = 3,
          after: int = 3, edge_mm: float = 0.02, flat: float = 3.5, persist: float = 3.0,
          ramp: float = 1.0, events: list[tuple[int, float, float, float]] | None = None) -> np.ndarray:
    """The sizes (mm) of the slips of a sticking stem in the measured opening ``x`` (module docstring).

    A slip is a step larger than ``z`` noise sd of a difference after ``plateau`` samples that span
    less than ``flat`` noise sd, whose next ``after`` samples lie beyond the plateau's level by
    ``persist`` sd of the difference of the two means and do not step back, all away from the end
    stops by ``edge_mm``. Its size is the distance from the plateau's mean to the next samples'
    straight line half an interval after the plateau. A slip after which the stem moves on by more
    than ``ramp`` times its size per sample is not measured: where the demand moves fast after the
    slip (a step of the tank temperature), the jump cannot be told from the motion that follows it
    within the interval, and the straight line through the next samples, which slow down, measured it
    at a third to a half of the band (two of 14 slips of a generated day, seed 631); the bootstrap
    world's smoothed temperatures make fewer such fast slips, so these slips also set its bias apart
    from the estimator's. ``s_w``: the noise sd (default :func:`noise_sd`). ``events``: if given, each slip is appended
    to it as (index of the plateau's last sample, direction +-1, plateau level mm, size mm)."""
    x = np.asarray(x, dtype=float)
    s = max(noise_sd(x) if s_w is None else float(s_w), 1e-6)
    n = x.size
    d = np.diff(x)
    thr = z * math.sqrt(2.0) * s
    lift = persist * s * math.sqrt(1.0 / plateau + 1.0 / after)
    tpost = np.arange(1, after + 1, dtype=float)
    out: list[float] = []
    k = plateau - 1
    while k < n - 1 - after:
        dk = d[k]
        if abs(dk) <= thr:
            k += 1
            continue
        pre = x[k - plateau + 1:k + 1]
        post = x[k + 1:k + 1 + after]
        sg = 1.0 if dk > 0 else -1.0
        lev0 = float(pre.mean())
        ok = (np.ptp(pre) <= flat * s and min(pre.min(), post.min()) > edge_mm
              and max(pre.max(), post.max()) < stroke - edge_mm and sg * (post.mean() - lev0) > lift
              and not np.any(sg * np.diff(post) < -thr))
        if not ok:
            k += 1
            continue
        slope, icpt = np.polyfit(tpost, post, 1)
        size = sg * (icpt + 0.5 * slope - lev0)
        if abs(slope) > ramp * size:
            k += 1
            continue
        out.append(size)
        if events is not None:  # (last sample of the plateau, direction, plateau level, size)
            events.append((k, sg, lev0, size))
        k += after
    return np.array(out)


def jump_band(x: np.ndarray, stroke: float, s_w: float | None = None, min_jumps: int = 4,
              **options: float) -> tuple[float, int]:
    """Band (mm) from the slips of the measured opening (the median of :func:`slips`, which takes
    ``options``); (nan, n) with fewer than ``min_jumps`` slips."""
    sz = slips(x, stroke, s_w, **options)  # type: ignore[arg-type]
    if sz.size < min_jumps:
        return float("nan"), int(sz.size)
    return float(np.median(sz)), int(sz.size)


def band_sampling(x_true: np.ndarray, noise_sd_mm: float, stroke: float, draws: int = 200,
                  seed: int = 0) -> np.ndarray:
    """The band estimator's sampling distribution on a known opening: :func:`jump_band` of
    ``x_true`` plus fresh white noise of ``noise_sd_mm``, ``draws`` times (nan where too few jumps).

    With the true opening of a generated run (``true_x_mm``) this is the estimator's own spread and
    bias for that run, which no method that sees only the measured opening can know: the yardstick
    the bootstrap's sd and bias correction are measured against (``benchmarks/diagnosis_coverage.py``);
    with a simulated opening it tells how precisely a planned experiment measures the band."""
    x_true = np.asarray(x_true, dtype=float)
    if not (math.isfinite(noise_sd_mm) and noise_sd_mm >= 0):
        raise ValueError(f"noise_sd_mm must be finite and >= 0, got {noise_sd_mm}")
    if draws < 2:
        raise ValueError(f"draws must be at least 2, got {draws}")
    return band_draws(x_true, noise_sd_mm, stroke, draws, np.random.default_rng(seed))


def band_draws(x_true: np.ndarray, noise_sd_mm: float, stroke: float, draws: int,
               rng: np.random.Generator) -> np.ndarray:
    """``draws`` band estimates (:func:`jump_band`) of ``x_true`` plus white noise of ``noise_sd_mm``
    from ``rng``, nan where too few jumps: :func:`band_sampling` without its checks, and the band's
    extra replicates of the bootstrap (:func:`valve_env.estimation.bootstrap.bootstrap`)."""
    return np.array([jump_band(x_true + noise_sd_mm * rng.standard_normal(x_true.shape[0]), stroke)[0]
                     for _ in range(draws)])


__all__ = ["band_sampling", "jump_band", "noise_sd", "resting_noise_sd", "slips"]
