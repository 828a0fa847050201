"""Stiction detection: the published shape tests combined by a rule learned on simulated loops only
(docs/loops.md, "Detection").

The detectors of :mod:`valve_env.loops.detectors` (Horch's cross-correlation phase, on PV and on its increments;
He et al.'s curve fit; Kano et al.'s stuck-time index; Choudhury et al.'s bicoherence indices; the OP-PV
ellipse's area; Thornhill et al.'s oscillation regularity) each give a scale-free statistic of the record
(:func:`features`). A logistic regression on these statistics (:func:`stiction_probability`) names stiction
when its probability exceeds :data:`THRESHOLD`. Its coefficients (:mod:`valve_env.loops.detector_coefs`) were
fitted on simulated loops of wide variety (:func:`valve_env.loops.sim.random_case`: self-regulating and
integrating processes with dead time, several tunings, noise levels and record lengths, external oscillations,
stick-slip valves with S != J, deadband valves without stick) by ``studies/loop_train_detector.py``, which
writes that module; no real loop's outcome enters them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from valve_env.loops.detector_coefs import CLARITY, COEFS, FEATURES, MEANS, SCALES, THRESHOLD, TRAINING
from valve_env.loops.detectors import (
    HORCH_EVEN_DEG,
    HORCH_MIN_HALF_PERIOD,
    HORCH_ODD_DEG,
    bicoherence,
    ellipse_area,
    he_curve_fit,
    horch,
    kano,
    oscillation,
)
from valve_env.loops.io import LoopData


def features(loop: LoopData) -> tuple[dict[str, float], dict[str, dict[str, Any]]]:
    """The detectors' statistics of ``loop`` as features (names: :data:`FEATURES`), and each detector's own
    result."""
    h = horch(loop)
    hi = horch(loop, integrating=True)
    he = he_curve_fit(loop)
    he_pv = he_curve_fit(loop, on="pv")
    ka = kano(loop)
    bi = bicoherence(loop)
    el = ellipse_area(loop)
    osc = oscillation(loop.pv - loop.sp, loop.dt)
    cycles = loop.n / max(el["period_samples"], 1.0)
    f = {
        "horch_phase": h["statistic"] / 180.0,
        "horch_signed": h["phase_signed_deg"] / 180.0,
        "horch_ratio": h["ratio"],
        "horch_dpv_phase": hi["statistic"] / 180.0,
        # Horch's zero crossings against the oscillation: an oscillation's CCF crosses zero about a quarter period
        # either side of lag 0; a noise-driven loop's CCF changes sign at once on one side (the controller's integral
        # action)
        "horch_asym": min(h["tau_r"], h["tau_l"]) / max(h["tau_r"], h["tau_l"], 1e-9),
        "horch_half_cycles": math.log(max(h["tau_r"] + h["tau_l"], 0.5) / max(el["period_samples"], 1.0)),
        "he_si": he["statistic"],
        "he_si_pv": he_pv["statistic"],
        "kano_rho": ka["statistic"],
        "bic_ngi": bi["ngi"],
        "bic_nli": bi["nli"],
        "bic_peak": bi["statistic"] / bi["limit"],
        "ellipse_signed": el["signed"],
        "ellipse_abs": el["statistic"],
        "osc_regularity": math.log1p(min(osc["regularity"], 20.0)),
        "osc_acf_peak": osc["acf_peak"],
        "log_cycles": math.log(max(cycles, 0.5)),
        "osc_band_share": band_share(loop.sp - loop.pv, 1.0 / max(el["period_samples"], 1.0)),
    }
    return f, {"horch": h, "horch_dpv": hi, "he": he, "he_pv": he_pv, "kano": ka, "bicoherence": bi, "ellipse": el,
               "oscillation": osc}


def band_share(y: np.ndarray, f0: float) -> float:
    """The share of the (linear-trend-removed, Hann-windowed) periodogram of ``y`` within a factor of two of the
    frequency ``f0`` (cycles per sample): how clearly one oscillation dominates, readable from a single cycle
    (Thornhill et al.'s ACF test asks for several)."""
    from valve_env.loops.detectors import _detrend

    z = _detrend(np.asarray(y, dtype=float))
    p = np.abs(np.fft.rfft(z * np.hanning(z.size))) ** 2
    f = np.fft.rfftfreq(z.size)
    tot = float(p[1:].sum())
    return float(p[(f >= f0 / 2.0) & (f <= 2.0 * f0)].sum() / tot) if tot > 0 else 0.0


#: the features that describe an oscillation's shape; the rule also weighs each by how clearly the control error
#: oscillates (the first ACF peak, clipped to 0-1: :func:`terms`), as the shape tests read only an oscillating loop
SHAPE_FEATURES: tuple[str, ...] = ("horch_phase", "horch_signed", "horch_ratio", "horch_dpv_phase", "horch_asym",
                                   "horch_half_cycles", "he_si",
                                   "he_si_pv", "kano_rho", "bic_ngi", "bic_nli", "bic_peak", "ellipse_signed",
                                   "ellipse_abs", "log_cycles")


def design_row(f: dict[str, float], names: tuple[str, ...] = FEATURES) -> np.ndarray:
    """The raw feature vector in the order of ``names``."""
    return np.array([f[k] for k in names], dtype=float)


def terms(raw: np.ndarray, names: tuple[str, ...] = FEATURES, clarity: str | None = CLARITY) -> np.ndarray:
    """The rule's terms from raw feature rows (:func:`design_row`, one row or a matrix, columns ``names``): the
    features and, unless ``clarity`` is None, each shape feature times how clearly the control error oscillates
    (that feature clipped to 0-1: the shape tests read an oscillating loop), then the squares of all of these (a
    quadratic logistic regression: a detector's statistic may matter most in the middle of its range)."""
    raw = np.atleast_2d(raw)
    parts = [raw]
    if clarity is not None:
        w = np.clip(raw[:, names.index(clarity)], 0.0, 1.0)[:, None]
        parts.append(raw[:, [names.index(k) for k in SHAPE_FEATURES if k in names]] * w)
    lin = np.column_stack(parts)
    return np.column_stack([lin, lin ** 2])


def stiction_probability(f: dict[str, float]) -> float:
    """The learned rule's probability of stiction for the features ``f`` (:func:`features`)."""
    z = (terms(design_row(f))[0] - np.asarray(MEANS)) / np.asarray(SCALES)
    eta = float(COEFS[0] + np.dot(np.asarray(COEFS[1:]), z))
    return float(1.0 / (1.0 + math.exp(-max(min(eta, 50.0), -50.0))))


#: the decision rules: ``"horch"`` (the default) is Horch's cross-correlation test as published (stiction where the
#: OP-PV cross-correlation is odd about lag 0); ``"learned"`` the logistic regression on simulated loops above. On
#: the 46 shared real loops Horch's test named 84 % (balanced) and the learned rule 50 %: the simulated loops do not
#: teach the real ones (docs/loops.md, "Detection"), so the default is the published test and the learned rule an
#: option for research
RULES: tuple[str, ...] = ("horch", "learned")
DEFAULT_RULE = "horch"


def detect(loop: LoopData, rule: str = DEFAULT_RULE) -> dict[str, Any]:
    """The detection of ``loop`` by ``rule`` (:data:`RULES`): its verdict, the learned rule's probability and
    verdict beside it, every detector's own verdict and statistic, and the features."""
    if rule not in RULES:
        raise ValueError(f"rule must be one of {', '.join(RULES)}; got {rule!r}")
    f, det = features(loop)
    p = stiction_probability(f)
    learned = bool(p > THRESHOLD)
    verdict = bool(det["horch"]["stiction"]) if rule == "horch" else learned
    kind = ("Horch's cross-correlation test (Horch 1999), as published" if rule == "horch"
            else "logistic regression on simulated loops")
    return {"stiction": verdict, "rule": {"name": rule, "kind": kind},
            "probability": p, "threshold": THRESHOLD, "learned_stiction": learned, "learned_rule": dict(TRAINING),
            "features": f,
            "detectors": {k: {kk: v for kk, v in d.items() if isinstance(v, (bool, int, float, str)) or v is None}
                          for k, d in det.items()}}


def detection_notes(det: dict[str, Any]) -> list[str]:
    """What a reader of :func:`detect`'s verdict needs beside it: why Horch's test gave no verdict where it gave none
    (a cycle the sampling does not resolve, or a phase between its limits), and where the other rule disagrees with
    the decision (the decision stands; docs/loops.md, "Which rule")."""
    notes = []
    h = det["detectors"]["horch"]
    half = float(h["tau_r"]) + float(h["tau_l"])
    if half < HORCH_MIN_HALF_PERIOD:
        notes.append(f"Horch's test gives no verdict: the OP-PV cross-correlation's half period is {half:.3g} samples, "
                     f"under the {HORCH_MIN_HALF_PERIOD:g} it needs to resolve a cycle (a cycle about as fast as the "
                     "sampling, or none); counted as no stiction")
    elif HORCH_EVEN_DEG <= h["statistic"] <= HORCH_ODD_DEG:
        notes.append(f"Horch's test is undetermined: the OP-PV cross-correlation's phase {h['statistic']:.0f} deg lies "
                     f"between {HORCH_EVEN_DEG:g} (even: no stiction) and {HORCH_ODD_DEG:g} (odd: stiction); counted "
                     "as no stiction")
    other = "learned" if det["rule"]["name"] == "horch" else "horch"
    says = det["learned_stiction"] if other == "learned" else bool(h["stiction"])
    if says != det["stiction"]:
        why = (f"probability {det['probability']:.2f} against its threshold {det['threshold']:.2f}"
               if other == "learned" else f"phase {h['statistic']:.0f} deg")
        notes.append(f"the other detection rule (--rule {other}) says {'stiction' if says else 'no stiction'} ({why}); "
                     f"the decision is the {det['rule']['name']} rule's (docs/loops.md, \"Which rule\")")
    return notes


__all__ = ["detect", "detection_notes",
           "RULES", "DEFAULT_RULE", "features", "stiction_probability", "design_row", "terms", "FEATURES",
           "SHAPE_FEATURES", "THRESHOLD", "band_share"]
