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
band directly, without the valve model. Used by :class:`valve_env.valveid.fitting.Model` for
``band_mm``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from valve_env.ident.tests import sd_from_second_differences
from valve_env.valveid.temperature import noise_sd, quantum

#: the finest opening resolution a channel is taken to have where the data shows none (mm; a position
#: transducer's): its quantisation sd is the least noise sd the opening is given
OPENING_RESOLUTION_FLOOR_MM = 1.0e-3
#: a channel that holds its value between more than this share of consecutive samples, in full precision and
#: off any grid, is stored on change (a historian's dead band) or written without noise
HELD_SHARE = 0.5
#: the quantile of the non-zero changes that measures a stored-on-change channel's dead band (all its changes
#: exceed the dead band)
DEAD_BAND_QUANTILE = 0.05
#: an opening quantised to q, or stored on change with a dead band d, records a smooth stem that moves slowly as a
#: staircase: stick-slip with S = J of about that resolution (1.1-1.3 d on a `none` run stored at d = 0.005, 0.01
#: and 0.02 mm; 1.3 q on a set-point drift run quantised to 0.01 mm). Stiction is named there only with a band
#: beyond this many resolutions
RESOLUTION_BAND_FACTOR = 2.0
#: noise that grows with the opening (an opening derived from a flow meter's reading, whose error is relative to the
#: flow: the section 2 run without x_mm): the opening's range off its two ends (by :data:`LEVEL_EDGE_MM`) is cut into
#: up to :data:`LEVEL_BINS` bins of equal count (at least 3, of :data:`LEVEL_MIN_PER_BIN` samples or more), and where
#: the noisiest bin's robust sd exceeds the quietest's :data:`LEVEL_RATIO` times the slips are judged against the
#: noise at their own opening. White noise of a position transducer gives ratios of 1.2-1.3 on generated 12 h runs at
#: 10 s; a flow meter's 0.1 % gives 3-14 (docs/diagnosis.md, "An opening derived from the flow")
LEVEL_BINS = 5
LEVEL_MIN_PER_BIN = 100
LEVEL_RATIO = 2.5
LEVEL_EDGE_MM = 0.02


@dataclass(frozen=True)
class OpeningNoise:
    """The measurement-noise level of the opening channel and how it was found (the opening's counterpart of
    :class:`valve_env.valveid.temperature.ChannelNoise`).

    ``sd`` (mm): the robust second-difference sd (``method="mad"``) where the channel is noisy; else the
    quantisation sd q / sqrt(12) of a quantised one (``"quantisation"``); else, where it holds its value
    between most samples in full precision, the error of a historian's dead band d stored on change, uniform
    within +-d, sd d / sqrt(3) (``"store_on_change"``, ``resolution`` = d, the least non-zero change); else the
    floor :data:`OPENING_RESOLUTION_FLOOR_MM` / sqrt(12) (``"resolution_floor"``). Never 0 or NaN. A smooth stem
    recorded on change looks like stick-slip with S = J = d; so does a sticky stem written without noise, which
    no transducer gives."""

    sd: float
    method: str
    #: the record's own step (mm): the quantum of a quantised opening, the dead band of one stored on change; None
    #: for the other two methods
    resolution: float | None
    held_fraction: float
    #: where a noisy opening's noise grows with its level (:func:`noise_by_level`): the inner edges of the opening's
    #: bins (mm) and each bin's robust sd (mm); None where one sd holds over the whole range
    level_edges: tuple[float, ...] | None = None
    level_sd: tuple[float, ...] | None = None

    def sd_at(self, x: np.ndarray) -> float | np.ndarray:
        """The noise sd at each opening of ``x`` (mm): the sd of its level's bin where the noise grows with the
        opening, else the one ``sd`` (a float)."""
        if self.level_edges is None or self.level_sd is None:
            return self.sd
        idx = np.searchsorted(np.asarray(self.level_edges), np.asarray(x, dtype=float), side="right")
        return np.asarray(self.level_sd)[idx]

    def describe(self) -> dict[str, object]:
        if self.method == "mad":
            why = "the robust sd of its second differences"
        elif self.method == "quantisation":
            why = f"its quantisation step {self.resolution:g} mm (q / sqrt(12))"
        elif self.method == "store_on_change":
            why = (f"it holds its value between {self.held_fraction:.0%} of consecutive samples and changes by at "
                   f"least {self.resolution:.3g} mm: a historian's dead band stored on change (or a record without "
                   "noise), error uniform within it (d / sqrt(3)); a stick band up to about that size cannot be told "
                   "from it")
        elif self.level_sd is not None:
            why = (f"the transducer resolution floor {OPENING_RESOLUTION_FLOOR_MM:g} mm (q / sqrt(12)): most of the "
                   "record shows less noise")
        else:
            why = (f"the transducer resolution floor {OPENING_RESOLUTION_FLOOR_MM:g} mm (q / sqrt(12)): the channel "
                   "shows no noise")
        out: dict[str, object] = {"channel": "x_mm", "noise_sd_mm": self.sd, "method": self.method,
                                  "resolution_mm": self.resolution, "held_fraction": round(self.held_fraction, 4),
                                  "why": why}
        if self.level_sd is not None and self.level_edges is not None:
            out["noise_sd_by_level_mm"] = [float(v) for v in self.level_sd]
            out["level_edges_mm"] = [float(v) for v in self.level_edges]
            out["why"] = (f"{why}; it grows with the opening, from {min(self.level_sd):.3g} to "
                          f"{max(self.level_sd):.3g} mm over {len(self.level_sd)} bins of its range (an opening "
                          "derived from a flow meter's reading has the meter's relative error): each slip is judged "
                          "against the noise at its own opening")
        return out


def noise_by_level(x: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """Where the noise of the opening ``x`` grows with its level: (inner bin edges, each bin's robust sd), mm; None
    where one sd holds (see :data:`LEVEL_RATIO`), or where the record is too short to tell. Each bin's sd is the
    robust sd of the second differences centred in it (:func:`~valve_env.ident.tests.sd_from_second_differences`)."""
    x = np.asarray(x, dtype=float)
    if x.size < 3:
        return None
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    lev = x[1:-1]
    inside = (lev > float(x.min()) + LEVEL_EDGE_MM) & (lev < float(x.max()) - LEVEL_EDGE_MM)
    bins = min(LEVEL_BINS, int(inside.sum()) // LEVEL_MIN_PER_BIN)
    if bins < 3:
        return None
    edges = np.quantile(lev[inside], np.linspace(0.0, 1.0, bins + 1))[1:-1]
    which = np.searchsorted(edges, lev[inside], side="right")
    d2 = d2[inside]
    sds = []
    for b in range(bins):
        db = d2[which == b]
        if db.size < LEVEL_MIN_PER_BIN:
            return None
        sds.append(max(sd_from_second_differences(db), OPENING_RESOLUTION_FLOOR_MM / math.sqrt(12.0)))
    if max(sds) <= LEVEL_RATIO * min(sds):
        return None
    return tuple(float(e) for e in edges), tuple(sds)


def opening_noise(x: np.ndarray) -> OpeningNoise:
    """The noise level of the opening channel of any measurement convention (see :class:`OpeningNoise`)."""
    x = np.asarray(x, dtype=float)
    mad = noise_sd(x)
    held = float(np.mean(np.diff(x) == 0.0)) if x.size > 1 else 1.0
    floor = OPENING_RESOLUTION_FLOOR_MM / math.sqrt(12.0)
    if math.isfinite(mad) and mad > floor:
        return OpeningNoise(mad, "mad", None, held, *(noise_by_level(x) or (None, None)))
    q = quantum(x)
    if q is not None:
        return OpeningNoise(max(q / math.sqrt(12.0), floor), "quantisation", q, held)
    d = np.abs(np.diff(x))
    d = d[d > 0.0]
    if held > HELD_SHARE and d.size >= 3:
        band = float(np.quantile(d, DEAD_BAND_QUANTILE))
        return OpeningNoise(max(band / math.sqrt(3.0), floor), "store_on_change", band, held)
    # noise below the floor over most of the range, but not over all of it (an opening derived from the flow whose
    # valve rests near its seat for most of the record: the flow meter's relative error vanishes there)
    return OpeningNoise(floor, "resolution_floor", None, held, *(noise_by_level(x) or (None, None)))


def slips(x: np.ndarray, stroke: float, s_w: float | np.ndarray | None = None, z: float = 4.0, plateau: int = 3,
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
    from the estimator's. ``s_w``: the noise sd, one or one per sample (default: :func:`opening_noise`'s at each
    sample, :meth:`OpeningNoise.sd_at`). ``events``: if given, each slip is appended
    to it as (index of the plateau's last sample, direction +-1, plateau level mm, size mm)."""
    x = np.asarray(x, dtype=float)
    # the noise sd: one for the record, or (where the noise grows with the opening) the one at each sample's opening
    s_at = opening_noise(x).sd_at(x) if s_w is None else s_w
    local = np.ndim(s_at) > 0
    s_k = np.maximum(np.asarray(s_at, dtype=float), 1e-6) if local else None
    s = max(float(s_at), 1e-6) if not local else 0.0  # type: ignore[arg-type]
    n = x.size
    d = np.diff(x)
    thr = z * math.sqrt(2.0) * s
    lift = persist * s * math.sqrt(1.0 / plateau + 1.0 / after)
    tpost = np.arange(1, after + 1, dtype=float)
    out: list[float] = []
    k = plateau - 1
    while k < n - 1 - after:
        dk = d[k]
        if s_k is not None:  # the noise at the plateau's end
            s = float(s_k[k])
            thr = z * math.sqrt(2.0) * s
            lift = persist * s * math.sqrt(1.0 / plateau + 1.0 / after)
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


#: the fewest slips that measure the band on their own (:func:`jump_band`; fewer leave the band to the likelihood)
MIN_JUMPS = 4


def jump_band(x: np.ndarray, stroke: float, s_w: float | None = None, min_jumps: int = MIN_JUMPS,
              **options: float) -> tuple[float, int]:
    """Band (mm) from the slips of the measured opening (the median of :func:`slips`, which takes
    ``options``); (nan, n) with fewer than ``min_jumps`` slips."""
    sz = slips(x, stroke, s_w, **options)  # type: ignore[arg-type]
    if sz.size < min_jumps:
        return float("nan"), int(sz.size)
    return float(np.median(sz)), int(sz.size)


def slips_sd(sizes: np.ndarray, rng: np.random.Generator, resamples: int = 999) -> float:
    """sd (mm) of the median of the slip ``sizes`` (the band of :func:`jump_band`) from the slips' own spread:
    the standard error of a nonparametric bootstrap of the sizes (``scipy.stats.bootstrap``, the median
    re-taken on ``resamples`` resamples, drawn from ``rng``) times the small-sample factor
    ``t(0.975, n - 1) / z(0.975)`` of ``n`` slips (1.62 for 4, 1.07 for 20), the widening a Student t
    interval gives a sd estimated from few values. nan with fewer than 2 slips.

    The bootstrap of a median from few values is coarse (its resampled medians take few distinct values);
    the factor keeps 2 sd from being an over-confident interval there (docs/diagnosis.md, "Parameter
    uncertainty: the coverage study")."""
    from scipy import stats

    sz = np.asarray(sizes, dtype=float)
    sz = sz[np.isfinite(sz)]
    if sz.size < 2:
        return float("nan")
    if np.ptp(sz) == 0:
        return 0.0
    res = stats.bootstrap((sz,), np.median, n_resamples=resamples, method="percentile", random_state=rng)
    return float(res.standard_error * stats.t.ppf(0.975, sz.size - 1) / stats.norm.ppf(0.975))


def band_spread(x: np.ndarray, stroke: float, s_w: float | np.ndarray, draws: int, rng: np.random.Generator,
                band: float) -> tuple[float, dict[str, float], np.ndarray]:
    """The sampling sd (mm) of :func:`jump_band`'s band measured on the opening ``x``, its parts, and the
    added-noise re-estimates: (sd, parts, draws). The sd is the larger of two (docs/diagnosis.md,
    "Parameter uncertainty: the coverage study"):

    * ``noise_sd_mm``: the sd of the band re-estimated on ``draws`` copies of ``x`` with fresh white noise
      of its sd ``s_w`` added (:func:`band_draws`; a copy with too few slips counts as ``band``): which noisy
      steps pass for a slip, and the noise on each slip's plateau and landing;
    * ``slips_sd_mm``: the sd of the median from the slips' own spread (:func:`slips_sd`), from 2 slips on.
      With fewer than :func:`jump_band`'s ``min_jumps`` the band is the likelihood's, not their median, but the
      slips are still the only measurement of how far apart its events lie, and with 2-3 slips the added-noise
      copies find too few slips and keep the band (a spread of 0: a 2-slip run of project seed 20270332 reported
      6.6e-5 mm for a band 18 % off); the small-sample factor makes it wide there (6.5 for 2 slips).
      The slips differ by more than their noise: by where within its sampling interval each slip falls and
      how fast the demand moves on (a stem that moves with the demand after a slip is measured anywhere in
      that interval's travel), and a stem that re-sticks after every slip by its overshoot. The
      added-noise copies keep each slip where it fell and do not see this.

    Each slip's size already holds its noise, so the two are not added: where the noise makes most of the
    slips' spread the first is the larger (it also sees the detection), else the second."""
    r = band_draws(x, s_w, stroke, max(draws, 2), rng)
    r = np.where(np.isfinite(r), r, band)
    noise = float(np.std(r, ddof=1))
    sz = slips(x, stroke, s_w)
    between = slips_sd(sz, rng)  # nan with fewer than 2 slips
    sd = max(noise, between) if math.isfinite(between) else noise
    return sd, {"noise_sd_mm": noise, "slips_sd_mm": between, "n_slips": int(sz.size)}, r


def band_sampling(x_true: np.ndarray, noise_sd_mm: float, stroke: float, draws: int = 200,
                  seed: int = 0) -> np.ndarray:
    """The band estimator's sampling distribution on a known opening: :func:`jump_band` of
    ``x_true`` plus fresh white noise of ``noise_sd_mm``, ``draws`` times (nan where too few jumps).

    With the true opening of a generated run (``true_x_mm``) this is the estimator's own spread and
    bias for that run, which no method that sees only the measured opening can know: the yardstick
    the bootstrap's sd and bias correction are measured against (``studies/diagnosis_coverage.py``);
    with a simulated opening it tells how precisely a planned experiment measures the band."""
    x_true = np.asarray(x_true, dtype=float)
    if not (math.isfinite(noise_sd_mm) and noise_sd_mm >= 0):
        raise ValueError(f"noise_sd_mm must be finite and >= 0, got {noise_sd_mm}")
    if draws < 2:
        raise ValueError(f"draws must be at least 2, got {draws}")
    return band_draws(x_true, noise_sd_mm, stroke, draws, np.random.default_rng(seed))


def band_draws(x_true: np.ndarray, noise_sd_mm: float | np.ndarray, stroke: float, draws: int,
               rng: np.random.Generator) -> np.ndarray:
    """``draws`` band estimates (:func:`jump_band`) of ``x_true`` plus white noise of ``noise_sd_mm`` (one, or one
    per sample) from ``rng``, nan where too few jumps: :func:`band_sampling` without its checks, and the band's
    extra replicates of the bootstrap (:func:`valve_env.valveid.bootstrap.bootstrap`)."""
    return np.array([jump_band(x_true + noise_sd_mm * rng.standard_normal(x_true.shape[0]), stroke)[0]
                     for _ in range(draws)])


__all__ = ["MIN_JUMPS", "band_sampling", "band_spread", "jump_band", "noise_by_level", "slips",
           "slips_sd"]
