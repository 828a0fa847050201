"""Loop diagnosis: detect stiction with the shape tests' learned combination, then quantify its band with the grey-box
model (docs/loops.md).

1. **Enough data?** A record shorter than :data:`valve_env.loops.io.MIN_SAMPLES`, one whose OP or PV holds a
   single value throughout (:func:`still_channel`), or one whose control error oscillates with fewer than two
   periods in the record, gets the cause ``insufficient_data`` with the reason.
2. **Detection** (:func:`valve_env.loops.detect.detect`): the published shape tests (Horch, He et al., Kano et al.,
   Choudhury et al.'s bicoherence, the OP-PV ellipse's area), all reported; the decision is Horch's test as
   published (``rule="horch"``, the default) or their logistic combination fitted on simulated loops only
   (``rule="learned"``). It alone names ``stiction``; the grey-box model neither vetoes nor confirms it.
3. **Quantification** (when stiction is detected, or when asked: ``quantify=True``): the Hammerstein loop model
   (:mod:`valve_env.loops.model`: the two-parameter stick-slip valve, S and J in % of OP, behind a first-order or
   integrating process with dead time, a slow load and AR noise) fitted by maximum likelihood gives the band, its
   slip jump and the band's uncertainty (:func:`band_uncertainty`), beside the linear valve's fit (the
   likelihood ratio is reported, not used).
4. **Another cause** for a loop not named stiction: ``none`` when the control error does not oscillate; for an
   oscillating one, ``external_oscillation`` when the linear loop model does not reproduce the PV from the OP
   (R^2 <= 0.5), else Choudhury et al.'s reading of the bicoherence: ``nonlinear_oscillation`` when the control
   error is nonlinear (a nonlinearity other than the detected stiction sustains it), ``aggressive_tuning`` when it is
   linear (a linear loop that oscillates by itself rings: its tuning).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from valve_env.ident.tests import delta_bic, lr_pvalue
from valve_env.loops.detect import DEFAULT_RULE, detect, detection_notes
from valve_env.loops.detectors import oscillation
from valve_env.loops.io import MIN_OP_RANGE_PCT, MIN_SAMPLES, LoopData
from valve_env.loops.model import (
    BAND_J_FRACTIONS,
    Settings,
    ValveFit,
    fit_valve,
    op_jitter,
    resolution,
    scan_paths,
    scan_valve,
    simulate,
)

CAUSES: tuple[str, ...] = ("stiction", "none", "external_oscillation", "aggressive_tuning", "nonlinear_oscillation",
                           "insufficient_data")
#: the fewest oscillation periods of the control error a record must hold (docs/loops.md, "Enough data")
MIN_PERIODS = 2.0
#: relative model-error sd of the band, calibrated on simulated loops (benchmarks/loop_benchmark.py's development
#: seeds; docs/loops.md, "Band uncertainty")
BAND_REL_SD = 0.10
#: sd of the sampling offset as a share of it: the band's ends are known only to within one sample's OP move
#: (docs/loops.md, "Band uncertainty")
SAMPLING_SD_SHARE = 1.0
#: the model whose fit gives the band: the two-parameter stick-slip valve (J profiled; J = 0 is a deadband)
MODEL = "stiction"
#: the most samples the grey-box fits read (a day at 10 s): a longer record's fits read its last this many samples,
#: with a note, and its detection the whole record (the fits' time grows with the samples: 54 s of CPU for 10,800)
MAX_FIT_SAMPLES = 8640
#: the linear loop's simulation from OP must explain more than this share of the PV's variance for an oscillation to
#: count as the loop's own (docs/loops.md, "Oscillation causes")
LINEAR_R2_MIN = 0.5


@dataclass
class LoopDiagnosis:
    """A loop's diagnosis: the JSON ``result``, the ``fits`` behind it, their ``settings`` and the ``loop`` they
    read (the record, or its part the fits read: :func:`fitted_part`)."""

    result: dict[str, Any]
    fits: dict[str, ValveFit]
    settings: Settings
    loop: LoopData

    @property
    def cause(self) -> str:
        return str(self.result["cause"])

    @property
    def band_fit(self) -> ValveFit | None:
        return self.fits.get(MODEL)


def sampling_offset(op: np.ndarray) -> float:
    """The band's sampling correction, % of OP: the median OP move per sample (the record's resolution,
    :func:`valve_env.loops.model.resolution`). The valve slips between two samples, so the band fitted to the record
    is short by about one sample's move; its sd is ``SAMPLING_SD_SHARE`` times the offset."""
    return resolution(op)


def crosses_back(x: np.ndarray) -> bool:
    """Whether the valve path ``x`` reverses its direction of motion at least once in the record."""
    dx = np.diff(x)
    moves = np.sign(dx[np.abs(dx) > 1e-9 * max(1.0, float(np.max(np.abs(x))))])
    return bool(np.any(moves[1:] != moves[:-1]))


def band_resolved(fit: ValveFit, op: np.ndarray) -> bool:
    """Whether the record resolves the band of ``fit``: at least one sample's OP move, and crossed back by the fitted
    valve at least once (a valve that only moves on in one direction shows that the band exceeds every push back,
    not the band)."""
    return bool(fit.S >= sampling_offset(op) and crosses_back(fit.path(op)))


def band_halves(loop: LoopData, s: Settings, jittered: bool | None = None) -> tuple[float, float]:
    """The band (fitted band plus sampling offset, as ``band_pct``) read from each half of the record alone, by the
    same fit (:func:`fit_band`, with the valve ``jittered`` or not as the whole record's): their difference measures
    how well the record reproduces its own band, which the profile likelihood does not when the model is only near
    the truth (docs/loops.md, "Band uncertainty")."""
    bands = []
    for a, b in ((0, loop.n // 2), (loop.n // 2, loop.n)):
        half = LoopData(time_s=loop.time_s[a:b] - loop.time_s[a], sp=loop.sp[a:b], pv=loop.pv[a:b], op=loop.op[a:b],
                        tag=loop.tag, source=loop.source)
        bands.append(fit_band(half, s, jittered).S + sampling_offset(half.op))
    return bands[0], bands[1]


def band_uncertainty(fit: ValveFit, offset: float = 0.0, halves: tuple[float, float] | None = None,
                     valves: tuple[float, ...] = ()) -> tuple[float, float, float, float]:
    """The band, its sd and 95 % interval (not below 0): the fitted band plus the sampling ``offset``; the sd combines
    the profile-likelihood interval (``{S: 2 (ll_max - ll(S)) <= 3.84}``, interpolated in log S, sd = width / 3.92), the
    model-error sd ``BAND_REL_SD * band``, the offset's own sd, for a valve driven by the controller's
    within-sample jitter (``fit.jitter``) that jitter's sd at each of the band's two ends, and, given the bands of the
    record's two ``halves`` (:func:`band_halves`), the sd of the band that their difference implies for the whole
    record (``|b1 - b2| / 2``: each half's sd is ``|b1 - b2| / sqrt(2)``, the whole record's ``1 / sqrt(2)`` of it),
    and, given the bands of the two ``valves`` that could have moved between the samples (:func:`fit_bands`), half
    their difference: the record does not say which valve it was."""
    S = np.array([p[0] for p in fit.profile])
    ll = np.array([p[1] for p in fit.profile])
    dev = 2.0 * (ll.max() - ll)
    i = int(np.argmax(ll))
    logS = np.log(S)

    def edge(step: int) -> float:
        j = i
        while 0 <= j + step < S.size and dev[j + step] <= 3.84:
            j += step
        if not 0 <= j + step < S.size:
            return float(S[j])
        t = (3.84 - dev[j]) / max(dev[j + step] - dev[j], 1e-12)
        return float(math.exp(logS[j] + t * (logS[j + step] - logS[j])))

    lo, hi = edge(-1) + offset, edge(+1) + offset
    sd_prof = max(hi - lo, 0.0) / 3.92
    band = fit.S + offset
    # the valve slips where the controller's hidden within-sample jitter (sd fit.jitter) first reaches each of the
    # band's two ends, so each end is known to within that jitter's sd
    sd_halves = abs(halves[0] - halves[1]) / 2.0 if halves is not None else 0.0
    sd_valves = (max(valves) - min(valves)) / 2.0 if valves else 0.0
    sd = math.sqrt(sd_prof ** 2 + (BAND_REL_SD * band) ** 2 + (SAMPLING_SD_SHARE * offset) ** 2
                   + 2.0 * fit.jitter ** 2 + sd_halves ** 2 + sd_valves ** 2)
    # a band is not negative: the interval stops at 0 where band - 1.96 sd would pass it
    return band, sd, max(min(lo, band - 1.96 * sd), 0.0), max(hi, band + 1.96 * sd)


def select_noise_order(loop: LoopData, orders: tuple[int, ...] = (0, 1, 2)) -> Settings:
    """The AR order of the noise by BIC of the linear-valve model (then fixed for every candidate)."""
    best: tuple[float, Settings] | None = None
    for p in orders:
        s = Settings(dt=loop.dt, noise_order=p)
        fit = fit_valve(loop.op, loop.pv, "linear", s)
        if best is None or fit.bic < best[0]:
            best = (fit.bic, s)
    assert best is not None
    return best[1]


def fit_bands(loop: LoopData, s: Settings, jittered: bool | None = None) -> tuple[ValveFit, ...]:
    """The stick-slip valve's maximum-likelihood fits that give the band (docs/loops.md, "Model"), one per valve: J / S
    profiled over ``BAND_J_FRACTIONS``, the band grid holding the best distinct bands of a dense least-squares search
    (:func:`~valve_env.loops.model.scan_valve`: the likelihood is rugged in S, and the coarse grid alone misses its
    narrow ridges). The valves have the same parameters and samples: the valve at ``s.band_substeps`` steps per sample
    on the mean-preserving sub-sample OP, and, when the record shows the controller's output jittering within its
    samples (a controller scanning every ``s.scan_s``: :func:`~valve_env.loops.model.op_jitter`), the valve at a step
    per scan driven by that jitter. ``jittered`` True or False fits only that one (the jitter valve falls back to the
    smooth one where the record shows no jitter)."""
    jitter = op_jitter(loop.op, loop.dt, s.scan_s)
    variants = []
    if jittered is not True or jitter <= 0.0:
        variants.append(replace(s, substeps=s.band_substeps, jitter=0.0))
    if jittered is not False and jitter > 0.0:
        variants.append(replace(s, substeps=max(s.band_substeps, round(loop.dt / s.scan_s)), jitter=jitter))
    fits = []
    for sb in variants:
        scan = scan_valve(loop.pv, scan_paths(loop.op, sb.substeps, sb.jitter), sb)
        fits.append(fit_valve(loop.op, loop.pv, MODEL, sb, extra_S=scan.starts or (scan.S,),
                              j_fractions=BAND_J_FRACTIONS))
    return tuple(fits)


def likeliest(fits: tuple[ValveFit, ...]) -> ValveFit:
    """The more likely of :func:`fit_bands`' valves: the fit that gives the band (the first on a tie)."""
    return max(fits, key=lambda f: f.loglik)


def fit_band(loop: LoopData, s: Settings, jittered: bool | None = None) -> ValveFit:
    """The fit that gives the band: :func:`likeliest` of :func:`fit_bands`."""
    return likeliest(fit_bands(loop, s, jittered))


def sd_text(sd: float) -> str:
    """An sd to two significant digits, a trailing zero kept (1.0, not 1)."""
    return f"{sd:#.2g}".rstrip(".")


def model_label(st: dict[str, Any]) -> str:
    """The one name of the fitted valve, used alike in the report's headline, table and figure."""
    return (f"stick-slip valve, band S = {st['band_pct']:.3g} +/- {sd_text(st['std_pct'])} % of OP, "
            f"slip jump J = {st['jump_pct']:.3g} %")


def finding(name: str, fit: ValveFit, lin: ValveFit, s: Settings) -> dict[str, Any]:
    """One candidate's line of ``findings`` (SPEC section 10): its likelihood, and the likelihood ratio, p value and
    BIC difference against the linear valve (reported, not used by the decision)."""
    df = fit.n_params - lin.n_params
    lr = 2.0 * (fit.loglik - lin.loglik)
    return {"candidate": name, "valve": name, "loglik": fit.loglik, "n_params": fit.n_params, "n": fit.n,
            "lr_stat": lr, "p_value": lr_pvalue(lr, df) if df else 1.0,
            "delta_bic": delta_bic(lr, df, fit.n), "S_pct": fit.S, "J_pct": fit.J,
            "process": fit.process.describe(s.dt)}


def _insufficient(loop: LoopData, reason: str) -> LoopDiagnosis:
    result = {"cause": "insufficient_data", "reason": reason, "findings": [],
              "loop": {"tag": loop.tag, "source": loop.source, "n_samples": loop.n, "dt_s": loop.dt,
                       "op_scaled_from": list(loop.op_scaled_from) if loop.op_scaled_from else None},
              "notes": list(loop.notes)}
    return LoopDiagnosis(result, {}, Settings(dt=loop.dt), loop)


def still_channel(loop: LoopData) -> str | None:
    """Why the record holds no response to test, or None: an OP that never moves (the controller held the valve;
    range below :data:`valve_env.loops.io.MIN_OP_RANGE_PCT`), or a PV that holds one value while the OP moves (a
    valve that does not move, a transmitter that does not read or a flow below its range; the historian's
    value, which may be a frozen or fill value, is named). Either is a well-formed record that cannot decide
    (SPEC section 10: ``insufficient_data``), not bad input."""
    op_range = float(np.ptp(loop.op))
    if op_range < MIN_OP_RANGE_PCT:
        return (f"OP holds {float(loop.op[0]):.6g} % throughout (range {op_range:.3g} %): the controller did not "
                "move the valve, so the record holds no valve response to test")
    if float(np.ptp(loop.pv)) == 0.0:
        return (f"PV holds {float(loop.pv[0]):.6g} throughout while OP moves from {float(loop.op.min()):.4g} to "
                f"{float(loop.op.max()):.4g} %: no process response to test (a valve that does not move, a "
                "transmitter that does not read, or a flow below its range)")
    return None


def fitted_part(loop: LoopData, most: int | None = None) -> tuple[LoopData, str | None]:
    """The part of ``loop`` the grey-box fits read: the whole record, or its last ``most`` (default
    :data:`MAX_FIT_SAMPLES`) samples, with the note that says so."""
    most = MAX_FIT_SAMPLES if most is None else most
    if loop.n <= most:
        return loop, None
    k = loop.n - most
    part = replace(loop, time_s=loop.time_s[k:] - loop.time_s[k], sp=loop.sp[k:], pv=loop.pv[k:], op=loop.op[k:],
                   mv=None if loop.mv is None else loop.mv[k:], notes=[])
    return part, (f"the grey-box fits (the band, the linear model) read the record's last {most} samples "
                  f"({most * loop.dt / 3600.0:.3g} of {loop.n * loop.dt / 3600.0:.3g} h), the detection the whole "
                  "record: the fits' time grows with the samples")


def diagnose_loop(loop: LoopData, quantify: bool | None = None, settings: Settings | None = None,
                  rule: str = DEFAULT_RULE, progress: Callable[[str], None] | None = None) -> LoopDiagnosis:
    """Diagnose one loop record (module doc); returns the docs/reference.md section 10 result and the fits behind it.
    ``quantify`` True fits the band whatever the detection says; None (the default) fits it when stiction is
    detected; False never. ``rule``: the detection's decision rule (:data:`valve_env.loops.detect.RULES`).
    ``progress``: called with the name of each finished step (the detection, the linear model, the band, the band
    on the record's halves), e.g. to advance a progress bar. The fits read :func:`fitted_part` of the record."""
    tick = progress if progress is not None else (lambda _msg: None)
    if loop.n < MIN_SAMPLES:
        return _insufficient(loop, f"too short a record ({loop.n} samples; at least {MIN_SAMPLES} needed)")
    still = still_channel(loop)
    if still is not None:
        return _insufficient(loop, still)
    osc = oscillation(loop.pv - loop.sp, loop.dt)
    if osc["oscillating"] and loop.n * loop.dt < MIN_PERIODS * osc["period_s"]:
        return _insufficient(loop, f"the record ({loop.n * loop.dt:g} s) holds fewer than {MIN_PERIODS:g} periods of "
                                   f"its oscillation (period {osc['period_s']:.0f} s)")
    det = detect(loop, rule)
    tick("detection")
    stiction = det["stiction"]
    need_fit = stiction if quantify is None else quantify
    fits: dict[str, ValveFit] = {}
    s = settings or Settings(dt=loop.dt)
    q, window = fitted_part(loop)
    if need_fit or osc["oscillating"]:
        s = settings or select_noise_order(q)
        s = replace(s, dt=q.dt)
        fits["linear"] = fit_valve(q.op, q.pv, "linear", s)
        tick("linear model")
    result: dict[str, Any] = {"cause": "stiction" if stiction else "none"}
    if need_fit:
        valves = fit_bands(q, s)
        fit = fits[MODEL] = likeliest(valves)
        tick("band")
        offset = sampling_offset(q.op)
        halves = band_halves(q, s, jittered=fit.jitter > 0.0)
        tick("band on the halves")
        band, sd, lo, hi = band_uncertainty(fit, offset, halves, tuple(v.S for v in valves))
        st = {"band_pct": band, "std_pct": sd, "ci95_pct": [lo, hi], "jump_pct": fit.J, "band_fitted_pct": fit.S,
              "sampling_offset_pct": offset, "band_resolved": band_resolved(fit, q.op),
              "kind": "deadband (J = 0)" if fit.J <= 0.0 else "stick-slip", "model": MODEL,
              "initial_direction": "up" if fit.direction > 0 else "down", "valve_substeps": fit.substeps,
              "op_jitter_pct": fit.jitter, "halves_band_pct": list(halves),
              "valves_band_pct": {("jitter" if v.jitter > 0.0 else "sub-sample"): v.S + offset for v in valves},
              "detected": bool(stiction)}
        st["label"] = model_label(st)
        result["stiction"] = st
    linear_r2 = None
    if osc["oscillating"] and not stiction:
        lin = fits["linear"]
        sim = simulate(lin.path(q.op), lin.process)
        k0 = s.k0
        linear_r2 = 1.0 - float(np.var(q.pv[k0:] - sim[k0:]) / max(float(np.var(q.pv[k0:])), 1e-300))
        if linear_r2 <= LINEAR_R2_MIN:
            result["cause"] = "external_oscillation"
        else:
            nonlinear = det["detectors"]["bicoherence"]["nonlinear"]
            result["cause"] = "nonlinear_oscillation" if nonlinear else "aggressive_tuning"
    result["findings"] = ([finding(k, f, fits["linear"], s) for k, f in fits.items()] if fits else [])
    result["detection"] = det
    result["oscillation"] = {**osc, "linear_sim_r2": linear_r2}
    result["loop"] = {"tag": loop.tag, "source": loop.source, "n_samples": loop.n, "dt_s": loop.dt,
                      "op_range_pct": [float(loop.op.min()), float(loop.op.max())],
                      "op_scaled_from": list(loop.op_scaled_from) if loop.op_scaled_from else None}
    if "linear" in fits:
        result["loop"]["process"] = fits["linear"].process.describe(s.dt)
    result["notes"] = list(loop.notes) + detection_notes(det) + ([window] if window and fits else [])
    return LoopDiagnosis(result, fits, s, q)


__all__ = ["CAUSES", "LoopDiagnosis", "diagnose_loop", "band_uncertainty", "sampling_offset", "band_resolved",
           "crosses_back", "band_halves", "MODEL", "MIN_PERIODS", "fit_band", "fit_bands", "likeliest", "finding",
           "model_label", "sd_text", "select_noise_order", "still_channel", "fitted_part", "MAX_FIT_SAMPLES"]
