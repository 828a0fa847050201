"""Uncertainty of a named effect's parameters: a model-based bootstrap of the whole chain (Efron and Tibshirani
1993, ch. 6; Ljung 1999, sec. 9.7).

The fitted valve is taken as the truth and simulated from the smoothed temperatures (:func:`world_opening`); each
replicate gets temperature noise of the measured sd and, on the opening, the run's residuals in circular blocks
(white resting noise with stiction, :func:`replicate_run`); it is smoothed and re-estimated as the run was
(:func:`bootstrap`, driven by :func:`valve_env.ident.bootstrap.replicates`). Runaway refits are set aside, the
bias is corrected only where clear and normal, a smooth effect is bracketed by a refit on TV-denoised temperatures
(:func:`apply_bootstrap`), and stiction's band takes its spread from the measured slips
(:func:`_band_spread_from_slips`). :meth:`valve_env.valveid.estimator.ValveEstimator.bootstrap` is the entry point.

Why the Hessian is not enough, and each rule's evidence: docs/diagnosis.md, "Uncertainty of the named effects";
docs/uncertainty.md, "Errors in variables and robust uncertainty".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from valve_env.effects import REGISTRY as EFFECTS
from valve_env.ident.bootstrap import (
    Summary,
    block_resample,
    replicates,
    residual_block_length,
    screen_refits,
    summarise,
)
from valve_env.valveid.fitting import FitResult, Model, RunData
from valve_env.valveid.robust import stick_slip_check
from valve_env.valveid.stick_profile import sj_filter_loglik, sj_profile
from valve_env.valveid.stiction import band_draws, band_spread, jump_band, opening_noise
from valve_env.valveid.temperature import denoise_temperature

#: Name of the method, as written into the JSON.
METHOD = "model-based bootstrap (residual blocks)"
#: Whether a named effect's estimate and sd take the pre-processing bracket (:func:`apply_bootstrap`).
BRACKET = True
#: The bracket's second pre-processing (:func:`denoised_run`) and the weight of the difference in the sd.
BRACKET_DENOISER = "tv"
BRACKET_WEIGHT = 0.5
#: Whether the refit on the bracket's denoiser is corrected by its replicates' clear bias (else that bias enters
#: its sd only; :func:`bootstrap`)
BRACKET_CORRECT = False
#: stiction's band as the breakaway travel S where the slips are shorter (:func:`breakaway_band`)
BREAKAWAY = True
#: the least median of the demand's travel while stuck over the slip, and the least S / J of the stick-slip
#: filter's (S, J) profile, at which the band is taken as S (:func:`breakaway_evident`; docs/diagnosis.md, "What
#: ``band_mm`` is on a valve with J < S"): on development runs whose travel passed the first threshold the
#: filter's profile read 1.75-4.0 on `force` valves and 1.0-1.5 on J = S valves)
BREAKAWAY_TRAVEL = 1.0
BREAKAWAY_RATIO = 1.75
#: the filter profile's S / J reads low on the fitted valve (its demand's error near the reversals: on the true
#: demand the same filter read S within -4 to -12 % on the three runs tried): the geometric mean of the reading over
#: the true S / J, and the standard error of its log, over the 11 development ``force`` runs where the band is taken as
#: S (independent seeds 20270302, 20270306, 20270311, 20270331). The band
#: is the reading over this factor (:func:`breakaway_band`)
BREAKAWAY_READ = 0.789
BREAKAWAY_READ_SE = 0.056


@dataclass
class BootstrapResult:
    """Replicate estimates of the effect parameters and their summary."""

    names: list[str]
    replicates: np.ndarray  # (B, k)
    estimate: dict[str, float]
    std: dict[str, float]
    bias: dict[str, float]
    interval_95: dict[str, tuple[float, float]]
    B: int = 0
    corrected: dict[str, float] = field(default_factory=dict)
    bias_corrected: dict[str, bool] = field(default_factory=dict)
    #: sd of the re-estimates each parameter's sd was built from (the band's include its extra replicates)
    spread: dict[str, float] = field(default_factory=dict)
    #: replicates set aside as failed refits (:func:`screen_refits`)
    dropped: int = 0
    #: re-estimates of stiction's band in all (the ``B`` refits plus replicate openings alone), else 0
    band_B: int = 0
    #: more than half of the refits were gross (:func:`screen_refits`): none set aside, none bias-corrected
    split: bool = False
    #: Shapiro-Wilk p-value of each parameter's re-estimates (below :data:`NORMAL_P`: not bias-corrected)
    normality_p: dict[str, float] = field(default_factory=dict)
    #: the parts of stiction's band sd (:func:`_band_spread_from_slips`), else empty
    band_parts: dict[str, float] = field(default_factory=dict)
    #: stiction's breakaway travel S beside its slip J (:func:`breakaway_band`), else empty
    stick_slip: dict[str, object] = field(default_factory=dict)
    #: how each replicate's latent temperatures were prepared before its refit: ``"irw"`` (the IRW-RTS
    #: smoother, as the ML estimate) or the bracket's denoiser (:func:`replicate_denoiser`)
    denoiser: str = "irw"
    #: with replicates prepared by the bracket's denoiser, the run's own refit on it (:func:`preprocessing_refit`):
    #: the estimate that ``corrected`` corrects, else empty
    refit: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        extra: dict[str, object] = {"band_replicates": int(self.band_B)} if self.band_B else {}
        if self.band_parts:
            extra["band_sd_parts"] = {k: int(v) if k == "n_slips" else float(v) for k, v in self.band_parts.items()}
        if self.stick_slip:
            extra["stick_slip"] = dict(self.stick_slip)
        return {"method": METHOD, "replicates": int(self.B), "replicates_prepared": self.denoiser, **extra,
                "dropped_replicates": int(self.dropped),
                "split_replicates": bool(self.split),
                "normality_p": {k: float(v) for k, v in self.normality_p.items()},
                "bias": {k: float(v) for k, v in self.bias.items()},
                "bias_corrected": {k: bool(v) for k, v in self.bias_corrected.items()},
                "uncorrected_estimate": {k: float(v) for k, v in self.estimate.items()},
                "spread": {k: float(v) for k, v in self.spread.items()},
                "interval_95": {k: [float(a), float(b)] for k, (a, b) in self.interval_95.items()}}


def replicate_run(model: Model, data: RunData, values: dict[str, float], rng: np.random.Generator,
                  truth_step_s: float = 1.0, x_noise_sd: float | np.ndarray | None = None,
                  x_true: np.ndarray | None = None, resid_block: int | None = None) -> RunData:
    """One bootstrap replicate of ``data`` under ``values`` (see the module docstring).

    ``x_true``: the bootstrap world's true opening, if already simulated (:func:`world_opening`).
    ``x_noise_sd``: with stiction, the sd of the white noise on the opening, one or one per sample (default:
    :func:`valve_env.valveid.stiction.opening_noise` of ``data``' opening, at each sample's opening of ``x_true``).
    ``resid_block``: without stiction, the opening's noise is the residuals ``data.x - x_true``
    resampled in circular blocks of this length (default: :func:`residual_block_length`)."""
    if x_true is None:
        x_true = world_opening(model, data, values, truth_step_s)
    n = len(data)
    if "stiction" in model.effects:
        # the band is measured from the steps of the opening: their noise is measured directly on the
        # resting steps, the slips set apart (the filter's s_w and s_e also absorb its misfit and would
        # overstate it; so would the median of all steps, slips included, at coarse sampling)
        if x_noise_sd is None:
            x_noise_sd = opening_noise(data.x).sd_at(x_true)
        y = x_true + x_noise_sd * rng.standard_normal(n)
    else:
        resid = data.x - x_true
        block = resid_block if resid_block is not None else residual_block_length(resid)
        y = x_true + block_resample(resid, block, rng)
    T, M = data.remeasure(data.T, data.M, rng)  # as the run's channels were recorded
    return RunData.from_arrays(data.t, T, M, y, data.dp, data.ps, name=f"{data.name} (bootstrap)")


def world_opening(model: Model, data: RunData, values: dict[str, float], truth_step_s: float = 1.0) -> np.ndarray:
    """The bootstrap world's true opening: the valve simulated from the smoothed temperatures with
    ``values`` on sub-steps of at most ``truth_step_s``, the temperatures going in straight lines between
    the samples as the estimator's do (a world whose temperatures turn between the samples on cubic splines
    made half the refits of a set-point drift run away, docs/diagnosis.md)."""
    step = min(truth_step_s, model.max_step_s)
    if "stiction" in model.effects:
        step = _mean_substep(data.t, step)
    fine = Model(model.effects, model.valve, max_step_s=step)
    x_true, _, _ = fine.simulate(data, values)
    return x_true


def _mean_substep(t: np.ndarray, step: float) -> float:
    """The sub-step cap whose sub-steps last ``step`` on average over the record.

    The stem slips at the first sub-step where the demand is the band away, so a slip overshoots the
    band by up to the demand's motion over one sub-step; the jumps' bias (which the bootstrap
    corrects) scales with the sub-step. The simulation splits each sample interval into equal
    sub-steps of at most the cap, which for uneven sampling makes them shorter than the cap (0.87 s
    on average for a cap of 1 s at 5 s +- 20 % jitter); the cap is raised until they last ``step``
    on average, like the fixed clock of the truth."""
    h = np.diff(np.asarray(t, dtype=float))
    h = h[h > 0]
    if h.size == 0:
        return step
    best, err = step, math.inf
    for c in step * (1.0 + 0.01 * np.arange(101)):
        e = abs(float(h.sum()) / float(np.ceil(h / c - 1e-9).sum()) - step)
        if e < err:
            best, err = float(c), e
    return best


def _refit(model: Model, rep: RunData, values: dict[str, float], names: list[str]) -> dict[str, float]:
    """Re-estimate on a replicate, as :meth:`Model.fit` estimates: stiction's band from the jumps of
    the opening (:func:`valve_env.valveid.stiction.jump_band`, no valve model needed), the smooth
    parameters by L-BFGS-B from the truth of the bootstrap world (with the band fixed), where any of
    ``names`` (the parameters bootstrapped) is one of them."""
    out = dict(values)
    fixed: dict[str, float] = {}
    for p in model.eff_params:
        if p.name == "band_mm":
            fixed[p.name] = out[p.name] = _band_from(model, rep.x, values[p.name])
    if any(k != "band_mm" for k in names):
        out = model._fit_smooth(rep, out, fixed, 200, False).params
    return out


def _band_from(model: Model, x: np.ndarray, band: float) -> float:
    """The band re-estimated from the jumps of a replicate opening ``x`` (``band`` if too few jumps)."""
    b, _ = jump_band(x, float(model.valve.stroke))
    return b if math.isfinite(b) else float(band)


def bootstrap(model: Model, data: RunData, fit: FitResult, B: int = 16, seed: int = 0,
              truth_step_s: float = 1.0, bias_z: float = 2.0, band_B: int = 48,
              names: list[str] | None = None) -> BootstrapResult:
    """Model-based bootstrap (module docstring) of the effect parameters of ``fit``, a fit of ``model`` to ``data``.

    ``B`` replicates re-estimate every effect parameter; stiction's band, which needs no refit, is
    re-estimated on ``band_B`` replicates in all (the ``B`` plus replicate openings alone). ``names``:
    the parameters to bootstrap (default the effects'; e.g. the base model's ``sigma``, ``F_hmax``,
    ``p_bset``, :meth:`valve_env.valveid.estimator.ValveEstimator.bootstrap`)."""
    rng = np.random.default_rng(seed)
    if names is None:
        names = [p.name for e in model.effects for p in EFFECTS[e].parameters]
    stuck = "stiction" in model.effects
    x_true = world_opening(model, data, fit.params, truth_step_s)
    # the opening's noise for the copies: its one sd, or, where it grows with the opening, the sd at each sample's
    # opening (of the world's opening for the copies, of the record's for its slips' spread)
    noise_x = opening_noise(data.x) if stuck else None
    s_x = noise_x.sd_at(x_true) if noise_x is not None else None
    block = None if stuck else residual_block_length(data.x - x_true)
    denoiser = replicate_denoiser(model, names)
    rows, _ = replicates(
        B, rng, lambda r: replicate_run(model, data, fit.params, r, truth_step_s, s_x, x_true, block),
        lambda rep: _refit(model, rep if denoiser == "irw" else denoised_run(rep, denoiser), fit.params, names))
    reps = np.array([[pr[k] for k in names] for pr in rows], dtype=float).reshape(B, len(names))
    est = {k: float(fit.params[k]) for k in names}
    # failed refits (a refit that ran away) are set aside; the band's re-estimates need no refit
    refitted = [i for i, k in enumerate(names) if k != "band_mm"]
    dropped, split = screen_refits(reps[:, refitted]) if refitted else (np.zeros(B, dtype=bool), False)
    kept = reps[~dropped]
    # the band's re-estimates need no refit (only the jumps of a replicate opening): more of them, so
    # that the Monte Carlo error of the band's bias and spread (the jumps' estimate is heavy-tailed)
    # does not dominate its sd
    extra = np.empty(0)
    if stuck and s_x is not None:
        extra = band_draws(x_true, s_x, float(model.valve.stroke), max(band_B - B, 0), rng)
        extra = np.where(np.isfinite(extra), extra, fit.params["band_mm"])  # too few jumps: as _band_from
    by_name = {k: (np.concatenate([reps[:, i], extra]) if k == "band_mm" else kept[:, i]) for i, k in enumerate(names)}
    # re-estimates split into groups with no majority: no bias correction (the mean lies between them)
    keep = set(names) - {"band_mm"} if split else set()
    if denoiser != "irw" and not BRACKET_CORRECT:
        # the world's denoiser bias is not the real one (the world's temperatures are the smoothed ones): it enters
        # the sd (root-mean-square error about the world's truth), the estimate is left as refitted
        keep |= set(bracketed(model, names))
    sm = summarise(names, est, by_name, bias_z, no_correction=keep)
    refit: dict[str, float] = {}
    if denoiser != "irw":
        # the re-estimates were made the way the run's refit on the denoiser is made: their bias about the world's
        # truth is that refit's, so the correction and the interval are about the refit
        refit = preprocessing_refit(model, data, fit, names)
        for k in bracketed(model, names):
            lo, hi = sm.interval_95[k]
            sm.interval_95[k] = (lo + refit[k] - est[k], hi + refit[k] - est[k])
            sm.corrected[k] = refit[k] - sm.bias[k] if sm.bias_corrected[k] else refit[k]
    parts: dict[str, float] = {}
    sj: dict[str, object] = {}
    if stuck and s_x is not None:
        assert noise_x is not None
        parts = _band_spread_from_slips(sm, data.x, noise_x.sd_at(data.x), float(model.valve.stroke), band_B,
                                        fit.params["band_mm"], rng)
        if "band_mm" in names and BREAKAWAY:
            sj = breakaway_band(model, data, fit, sm)
    for k in names:
        sm.interval_95[k] = within_range(model, k, *sm.interval_95[k])
    return BootstrapResult(names, reps, est, sm.std, sm.bias, sm.interval_95, B, sm.corrected, sm.bias_corrected,
                           sm.spread, int(dropped.sum()), B + len(extra) if stuck else 0, split, sm.normality_p,
                           parts, sj, denoiser, refit)


def within_range(model: Model, name: str, lo: float, hi: float) -> tuple[float, float]:
    """The interval ``(lo, hi)`` of the effect parameter ``name`` intersected with its physical range
    (:class:`valve_env.effects.EffectParameter`'s ``lower`` and ``upper``): the basic bootstrap's reflected interval and
    the band's estimate +- 1.96 sd can reach past an edge (a band below 0 mm) where the estimate lies near it."""
    p = next((q for q in model.eff_params if q.name == name), None)
    return (lo, hi) if p is None else (max(lo, p.lower), min(hi, p.upper))


def replicate_denoiser(model: Model, names: list[str]) -> str:
    """How the bootstrap prepares a replicate's temperatures before refitting it: as the reported estimate
    was made. Where the bracket is on and ``names`` hold a named smooth effect's parameter (:func:`bracketed`),
    the reported estimate is the refit on the bracket's denoiser (:func:`preprocessing_refit`), so the
    replicates are refitted on it too, and their bias about the world's truth is that pre-processing's error in a
    world of smooth temperatures; else ``"irw"``."""
    return BRACKET_DENOISER if BRACKET and bracketed(model, names) else "irw"


def denoised_run(data: RunData, denoiser: str = BRACKET_DENOISER) -> RunData:
    """``data`` with its latent temperatures from the other pre-processing of the framework
    (:func:`valve_env.valveid.temperature.denoise_temperature`, plain TV by default) instead of the
    IRW-RTS smoother; the raw channels, the opening and the noise levels stay."""
    from dataclasses import replace


    T, vT = denoise_temperature(data.T_raw, data.t, denoiser=denoiser)
    M, vM = denoise_temperature(data.M_raw, data.t, denoiser=denoiser)
    return replace(data, T=T, vT=vT, M=M, vM=vM)


def bracketed(model: Model, names: list[str]) -> list[str]:
    """The parameters among ``names`` that take the pre-processing bracket: the effects' fitted ones
    (stiction's band is measured from the slips; the base model's are the base fit's business,
    :func:`valve_env.valveid.eiv.fit_eiv`, where plain TV is the biased side on sharp reversals)."""
    return [p.name for p in model.eff_params if p.name in names and p.name != "band_mm"]


def preprocessing_refit(model: Model, data: RunData, fit: FitResult, names: list[str]) -> dict[str, float]:
    """The estimates of ``names`` refitted (from ``fit``) on the TV-denoised temperatures
    (:func:`denoised_run`): the errors-in-variables bracket of a named effect (docs/uncertainty.md,
    "Errors in variables and robust uncertainty"). Stiction's band is measured from the slips, not from the
    temperatures: it is not refitted (its entry is the estimate's)."""
    smooth = bracketed(model, names)
    if not smooth:
        return {k: float(fit.params[k]) for k in names}
    g = model.fit(denoised_run(data), start=fit.params, with_std=False)
    return {k: float(g.params[k]) if k in smooth else float(fit.params[k]) for k in names}


def apply_bootstrap(model: Model, data: RunData, fit: FitResult, b: BootstrapResult,
                    bracket: bool | None = None) -> dict[str, str]:
    """Put the bootstrap ``b`` of ``fit`` (a fit of ``model`` to ``data``) into ``fit``: each bootstrapped
    parameter's sd becomes the bootstrap's, at least its inverse-Hessian/HAC sd (kept in
    ``fit.extra["hessian_std_<name>"]``), and its estimate the bias-corrected one. Returns where each
    sd came from (``"hessian"`` or ``"bootstrap"``, ``"+bracket"`` where the bracket was added).

    Why the floor: where the likelihood is flat along a ridge (a slow drift of the set point against a
    slow model error), refits started at the bootstrap world's truth stop near it and the replicates
    understate the spread the ridge allows.

    With ``bracket`` (default :data:`BRACKET`), the errors in variables of the pre-processing: the
    effects' fitted parameters (:func:`bracketed`) are refitted on the TV-denoised temperatures
    (:func:`preprocessing_refit`); the estimate is that refit's, and the sd the larger of the
    bootstrap's and the inverse Hessian's, with half the two pre-processings' difference added in
    quadrature (docs/uncertainty.md, "Errors in variables and robust uncertainty"). ``fit.extra`` keeps both
    estimates (``irw_<name>``, ``tv_<name>``)."""
    fit.extra.update({f"hessian_std_{k}": float(fit.std.get(k, float("nan"))) for k in b.names})
    on = bracketed(model, b.names) if (BRACKET if bracket is None else bracket) else []
    alt = (b.refit or preprocessing_refit(model, data, fit, b.names)) if on else {}
    source = {}
    for k, v in b.std.items():
        h = fit.extra[f"hessian_std_{k}"]
        floor = math.isfinite(h) and h > v
        sd = h if floor else v
        source[k] = "hessian" if floor else "bootstrap"
        if k in on:
            fit.extra[f"irw_{k}"] = float(fit.params[k])
            fit.extra[f"tv_{k}"] = alt[k]
            d = alt[k] - float(fit.params[k])
            fit.std[k] = float(math.sqrt(sd**2 + (BRACKET_WEIGHT * d) ** 2))
            # replicates refitted as the refit was made (:func:`replicate_denoiser`): the refit bias-corrected
            fit.params[k] = b.corrected[k] if b.refit else alt[k]
            source[k] += "+bracket"
        else:
            fit.std[k] = sd
            fit.params[k] = b.corrected[k]
    return source


def withhold_conditional_std(fit: FitResult, names: list[str]) -> dict[str, float]:
    """In a fit with stiction, the sd of every parameter the bootstrap did not re-estimate (not in ``names``: the
    base model's and the noise model's) is withheld (NaN, ``null`` in JSON). Their inverse-Hessian/HAC sd is
    conditional on the band, held at the slips' median, and read off a likelihood with kinks in them (a slip moves
    by a sample as a parameter crosses a value): on three generated 12 h sticky runs at 10 s it gave F_hmax an sd
    of 0.0006-0.0007 N where two estimates lay 0.022 N from the truth (38 and 33 sd), and refits with the band one
    sd either side moved them by under 0.001 N (docs/diagnosis.md, "Known limits"). Returns the withheld sds, which
    ``fit`` keeps in ``extra`` (:func:`conditional_std` reads them)."""
    out: dict[str, float] = {}
    for k, v in list(fit.std.items()):
        if k in names or not math.isfinite(v):
            continue
        out[k] = float(v)
        fit.extra[CONDITIONAL + k] = float(v)
        fit.std[k] = float("nan")
    return out


#: the prefix of a withheld sd's key in ``FitResult.extra`` (:func:`withhold_conditional_std`)
CONDITIONAL = "conditional_std_"


def conditional_std(fit: FitResult) -> dict[str, float]:
    """The sds :func:`withhold_conditional_std` withheld from ``fit``, by parameter (empty where none was)."""
    return {k[len(CONDITIONAL):]: float(v) for k, v in fit.extra.items() if k.startswith(CONDITIONAL)}


def _band_spread_from_slips(sm: Summary, x: np.ndarray, s_x: float | np.ndarray, stroke: float, draws: int,
                            band: float, rng: np.random.Generator) -> dict[str, float]:
    """The band's sd from the measured opening's own slips, replacing the bootstrap world's spread
    (:func:`valve_env.valveid.stiction.band_spread`: the larger of the sd of the band re-estimated on
    copies of ``x`` with fresh white noise of its sd ``s_x``, and of the sd from the slips' own spread);
    returns its parts (``band_sd_parts`` in the JSON). ``sm.spread`` keeps the added-noise copies' sd
    (the sd of the re-estimates).

    Why not the bootstrap world's spread: its opening, simulated open loop from the fitted valve, slips
    more regularly than the measured one (0.44 of the estimator's true sampling sd on seed 631). Why the
    slips' own spread: the added noise alone gave 1-sd coverage of 1/5 on fresh
    `reset`/`sj` runs of the independent simulator (docs/uncertainty.md). The added-noise mean is not used
    (added noise moves the median of the slips up, the noise of the measurement moved it down), so the
    bias stays the bootstrap world's, and the sd carries it in quadrature whether it was corrected or not:
    the world is the project's stick-slip (J = S, the stem moves with the demand after a slip), and where
    the valve re-sticks after every slip (the independent simulator's `reset`) its correction moved bands
    measured within 2 % to 2-4 % off (6 of 12 development runs). ``sm`` is updated in place: spread,
    sd and the 95 % interval about the (corrected) estimate, the added-noise quantiles widened to the sd."""
    sd, parts, r = band_spread(x, stroke, s_x, draws, rng, band)
    on = opening_noise(x)
    if on.resolution is not None:  # quantised or stored on change
        # the band is measured no finer than the record's own steps (a quantum, a dead band): where the slips
        # are one or none and the copies all read one band, their sd is 0, not the band's
        parts["resolution_mm"] = on.resolution
        sd = max(sd, on.resolution / math.sqrt(12.0))
    noise = parts["noise_sd_mm"]
    k = "band_mm"
    sm.spread[k] = noise
    se = noise / math.sqrt(r.size)
    # the world's bias in quadrature whether corrected or not: the correction is made in the project's stick-slip
    # world (the stem moves with the demand after a slip), and a stem that re-sticks after every slip has
    # another (docstring); a corrected band adds the correction's Monte Carlo error too
    sm.std[k] = float(math.sqrt(sd**2 + sm.bias[k] ** 2 + (se**2 if sm.bias_corrected[k] else 0.0)))
    lo, hi = np.percentile(r - r.mean(), [2.5, 97.5])
    w = sm.std[k] / noise if noise > 0 else 1.0
    sm.interval_95[k] = (float(sm.corrected[k] - w * hi), float(sm.corrected[k] - w * lo))
    return parts


def breakaway_band(model: Model, data: RunData, fit: FitResult, sm: Summary) -> dict[str, object]:
    """Stiction's band as the breakaway travel S where the slips say that the stem slips less than it sticks
    (docs/diagnosis.md, "What ``band_mm`` is on a valve with J < S"): returns the ``stick_slip`` block of the
    JSON, and where it is applied updates ``sm`` in place (the band's estimate, sd and 95 % interval).

    The band measured from the slips (``sm``'s, bias-corrected) is the slip J. The (S, J) profile of the stick-slip
    filter's likelihood (:func:`valve_env.valveid.stick_profile.sj_profile` with
    :func:`~valve_env.valveid.stick_profile.sj_filter_loglik`) gives the ratio k = S / J with its sd; it is applied
    where :func:`breakaway_evident` says so (the profile reads S / J clearly above 1 and the stick-slip check's
    statistic does not contradict it).
    Then k is the profile's reading corrected for its low reading on the fitted valve (:func:`calibrated_ratio`),
    the band is k J and its sd ``sqrt((k sd_J)^2 + (J sd_k)^2)``: the slips' sd scaled and the
    calibrated profile's width (the (S, J) trade-off). Where the profile reads S > J but the stuck travel does not
    confirm it (:func:`breakaway_unconfirmed`), the band stays the slips' J and its sd takes half the distance to the
    calibrated S in quadrature (``unconfirmed_S_mm`` in the block). Elsewhere the band stays the slips' (J = S), and
    the block reports the profile for information. The block: ``S_mm``, ``S_sd_mm`` (the band reported), ``J_mm``,
    ``J_sd_mm`` (the slips'), ``applied``, where applied ``S_over_J`` and ``S_over_J_sd`` (the calibrated k), the filter
    profile's reading (:meth:`~valve_env.valveid.stick_profile.SJProfile.to_json`), the
    open-loop profile's (``open_loop``, for information) and the check's
    ``travel_over_slip_median``."""

    k = "band_mm"
    J, sd_J = float(sm.corrected[k]), float(sm.std[k])
    if not (math.isfinite(J) and J > 0.0):
        return {}
    check = stick_slip_check(model, data, fit, warn=False)
    values = {**fit.params, k: float(fit.params[k])}
    # the open-loop profile, reported for information, and the stick-slip filter's, which
    # decides and measures S
    prof_ol = sj_profile(model, data, values)
    prof = sj_profile(model, data, values, loglik=sj_filter_loglik)
    med = float(check["travel_over_slip_median"])
    applied = breakaway_evident(med, prof.ratio, prof.ratio_sd)
    out: dict[str, object] = {"J_mm": J, "J_sd_mm": sd_J, "applied": applied, **prof.to_json(),
                              "open_loop": prof_ol.to_json(), "travel_over_slip_median": med}
    if applied:
        ratio, ratio_sd = calibrated_ratio(prof.ratio, prof.ratio_sd)
        S = ratio * J
        sd = math.sqrt((ratio * sd_J) ** 2 + (J * ratio_sd) ** 2)
        extra = {"S_over_J": ratio, "S_over_J_sd": ratio_sd}
    elif breakaway_unconfirmed(med, prof.ratio, prof.ratio_sd):
        # the profile reads S > J and the stuck travel does not confirm it: the band stays the slips' J, and its sd
        # takes the choice between the two readings (J = S, or the calibrated S) in quadrature, half their distance,
        # so that the 2-sd interval reaches the calibrated S
        ratio, _ = calibrated_ratio(prof.ratio, prof.ratio_sd)
        S, sd = J, math.hypot(sd_J, 0.5 * (ratio - 1.0) * J)
        extra = {"unconfirmed_S_mm": ratio * J}
    else:  # the slips' band and sd as they are
        out.update({"S_mm": J, "S_sd_mm": sd_J})
        return out
    sm.corrected[k] = S
    sm.std[k] = sd
    sm.interval_95[k] = (S - 1.96 * sd, S + 1.96 * sd)
    out.update({"S_mm": S, "S_sd_mm": sd, **extra})
    return out


def calibrated_ratio(ratio: float, ratio_sd: float) -> tuple[float, float]:
    """The breakaway's S / J and its sd from the filter profile's reading ``ratio`` (sd ``ratio_sd``, the profile's
    width): the reading over :data:`BREAKAWAY_READ`, the factor by which it read low on development ``force`` valves,
    its sd the width scaled alike and the factor's own standard error (:data:`BREAKAWAY_READ_SE`, of its log) in
    quadrature. The spread of the reading about the factor (sd 0.19 of its log on those runs) is not added: the
    scaled width covered it (10 of 11 development runs within 1 sd, leaving each out of the factor in turn)."""
    k = float(ratio) / BREAKAWAY_READ
    return k, math.hypot(float(ratio_sd) / BREAKAWAY_READ, k * BREAKAWAY_READ_SE)


def breakaway_unconfirmed(travel_over_slip: float, ratio: float, ratio_sd: float) -> bool:
    """Whether the (S, J) profile reads a slip shorter than the breakaway travel as :func:`breakaway_evident` asks
    (S / J at least :data:`BREAKAWAY_RATIO` and at least one of its sd above 1), but the stem's travel while stuck
    over the slip (below :data:`BREAKAWAY_TRAVEL`, or none measured) does not confirm it: the band stays the slips'
    J, with the choice between J and the calibrated S in its sd (:func:`breakaway_band`). Of 62 stiction runs of the
    independent simulator's coverage studies (seeds 20271188-91, 20271196-99 and 7201, all development material now)
    it held on three: two ``force`` valves (S / J read 1.75, travel 0.81 and 0.97) and one ``reset`` valve (J = S,
    read 1.75, travel 0.88)."""
    return bool(ratio >= BREAKAWAY_RATIO and ratio - 1.0 >= ratio_sd
                and not (math.isfinite(travel_over_slip) and travel_over_slip >= BREAKAWAY_TRAVEL))


def breakaway_evident(travel_over_slip: float, ratio: float, ratio_sd: float) -> bool:
    """Whether the band is the (S, J) profile's S rather than the slips' J (:func:`breakaway_band`): the profile's
    S / J (the stick-slip filter's) is at least :data:`BREAKAWAY_RATIO` and at least one of its sd
    ``ratio_sd`` above 1 (a flat profile is no evidence of J < S; a J = S run of
    tests/diagnosis/test_uncertainty.py read 1.75 +- 1.27 and took S at +90 %, while every development ``force``
    run that takes S reads 1.18-4.7 sd above 1), and the fitted demand's travel
    while stuck over the slip
    (the stick-slip check's statistic, :func:`valve_env.valveid.robust.stuck_travel`'s median; nan with no
    slip measured) at least :data:`BREAKAWAY_TRAVEL`: the stem stuck longer than it slipped.

    Neither profile alone is a test of J < S: the open-loop profile put J = S valves up to 2.0
    and ``force`` valves at 1.75-2.75; the filter's puts some J = S valves at 1.25-2.25 too. Those valves stuck
    less long than they slipped (travel ratio below 1: a stem that re-sticks after every slip), while on the
    ``force`` valves the ratio is above 1 (their slip J is shorter than the breakaway travel). On the development
    runs that pass the travel test the filter's profile read 1.0-1.5 on J = S valves and 1.75-4.0 on ``force``
    valves (docs/diagnosis.md, "What ``band_mm`` is on a valve with J < S")."""
    return bool(math.isfinite(travel_over_slip) and travel_over_slip >= BREAKAWAY_TRAVEL
                and ratio >= BREAKAWAY_RATIO and ratio - 1.0 >= ratio_sd)
